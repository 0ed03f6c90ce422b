"""What decides a Mitsuba render's bits besides the scene and (θ, spp, seed): `render_identity()`.

One dict, kept in every Mitsuba model's content key (hence the render cache's key, the render bank's
store key and the run fingerprint) and in a published run's machine.json:

- `llvm_target`: Dr.Jit's LLVM code-generation target (`llvm_target.py`): 'native' (the host's CPU name,
  feature list and vector width) or 'portable' (pinned);
- `libllvm`: the libLLVM version Dr.Jit compiles with;
- `host`: the CPU's vector ISA level and vendor, which decide Embree's mesh intersections whatever the
  target (Embree's ISA cannot be pinned);
- `versions`: Mitsuba, Dr.Jit, NumPy, torch.

Not in it: Dr.Jit's thread count. With the box pixel filter renders are identical for 1, 2 and 4 threads
(pi_hallway 40×30, 96 spp: 8 blocks of work; measured), and the pool workers run with fewer threads than
the main process.
"""
from __future__ import annotations

from . import llvm_target


def render_identity() -> dict:
    """The render-deciding facts of this process (JSON-ready; call after the model pinned its target)."""
    import drjit
    import mitsuba
    import numpy
    import torch

    target = llvm_target.current()
    return {"llvm_target": {"name": llvm_target.pinned() or llvm_target.requested(),
                            **(target.as_dict() if target else {})},
            "libllvm": llvm_target.llvm_version(),
            "host": llvm_target.host_isa(),
            "versions": {"mitsuba": mitsuba.__version__, "drjit": drjit.__version__, "numpy": numpy.__version__,
                         "torch": torch.__version__}}
