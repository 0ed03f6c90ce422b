"""Render the portable-target reference image that tests/test_llvm_target.py compares against, bit for bit:
pi_hallway at 16×12 px, θ = 1.3 m (NLOS), 64 spp, seed 3, with Dr.Jit's LLVM target pinned to the portable
one (`nlosbench.forward.llvm_target.PORTABLE`). Writes OUT/pi_hallway_16x12_portable.npy (float32, H×W×3)
and OUT/pi_hallway_16x12_portable.json (the render identity of the process that made it).

    python scripts/make_target_reference.py tests/data      # the committed reference
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
NAME = "pi_hallway_16x12_portable"
#: the model spec (`nlosbench.scenes.build`) and the render's arguments
SPEC = {"name": "pi_hallway", "options": {"defines": {"width": 16, "height": 12}}, "llvm_target": "portable"}
THETA, SPP, SEED = [1.3], 64, 3


def make(out: Path) -> Path:
    """Render the reference into folder `out`; return the .npy path."""
    import numpy as np

    from nlosbench import scenes

    model = scenes.build(SPEC)
    image = model.render(THETA, spp=SPP, seed=SEED).numpy()
    out.mkdir(parents=True, exist_ok=True)
    np.save(out / f"{NAME}.npy", image)
    (out / f"{NAME}.json").write_text(json.dumps(model.content_key()["render"], indent=2) + "\n")
    return out / f"{NAME}.npy"


if __name__ == "__main__":
    sys.path.insert(0, str(ROOT))
    print(make(Path(sys.argv[1])))
