"""The cost of the portable LLVM target: pi_hallway rendered with Dr.Jit's native target and with the pinned
portable one (`forward.llvm_target`), the same θ, spp and seeds, one process per target (a process has one
target), rounds interleaved so machine noise hits both alike. Per target: median seconds per render, wall
and CPU (all of the process's threads), after two warm-up renders. ratio = portable / native CPU seconds.

Full: 40×30 at 96 spp (the quick config's renders), 4 rounds of 12 renders; reduced: 16×12 at 32 spp,
1 round of 3.
"""
from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys

#: run in a fresh process with NLOSBENCH_LLVM_TARGET set: prints one JSON line of per-render seconds
_CHILD = """
import json, sys, time
import nlosbench as nb
w, h, spp, reps = (int(a) for a in sys.argv[1:5])
m = nb.scenes.get("pi_hallway", defines={"width": w, "height": h})
for i in range(2):
    m.render([0.75 + 0.01 * i], spp, 1000 + i)
wall, cpu = [], []
for i in range(reps):
    t, c = time.perf_counter(), time.process_time()
    m.render([0.8 + 0.9 * i / reps], spp, i)
    wall.append(time.perf_counter() - t)
    cpu.append(time.process_time() - c)
print(json.dumps({"wall": wall, "cpu": cpu, "target": m.content_key()["render"]["llvm_target"]["cpu"]}))
"""


def _child(target: str, args: list[int]) -> dict:
    env = {**os.environ, "NLOSBENCH_LLVM_TARGET": target}
    out = subprocess.run([sys.executable, "-c", _CHILD, *map(str, args)], env=env, capture_output=True, text=True,
                         check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def run(reduced: bool = False) -> list[dict]:
    w, h, spp, rounds, reps = (16, 12, 32, 1, 3) if reduced else (40, 30, 96, 4, 12)
    got: dict[str, dict] = {"native": {"wall": [], "cpu": []}, "portable": {"wall": [], "cpu": []}}
    for _ in range(rounds):
        for name in got:
            r = _child(name, [w, h, spp, reps])
            got[name]["wall"] += r["wall"]
            got[name]["cpu"] += r["cpu"]
            got[name]["cpu_target"] = r["target"]
    med = {n: {k: statistics.median(v[k]) for k in ("wall", "cpu")} for n, v in got.items()}
    return [{"bench": "llvm_target_portable_vs_native", "scene": f"pi_hallway {w}x{h}", "spp": spp,
             "renders": rounds * reps, "native_target": got["native"]["cpu_target"],
             "native_wall_s": med["native"]["wall"], "portable_wall_s": med["portable"]["wall"],
             "native_cpu_s": med["native"]["cpu"], "portable_cpu_s": med["portable"]["cpu"],
             "ratio": med["portable"]["cpu"] / med["native"]["cpu"]}]


if __name__ == "__main__":
    from . import main

    main(__name__)
