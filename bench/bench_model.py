"""Issue 2 benchmarks: model evaluation time and the simulated rig's real-time factor.

    python bench/bench_model.py [--seconds 10]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _table import print_table  # noqa: E402

from rig import config  # noqa: E402
from rig.model.psm_dynamics import PSMDynamics  # noqa: E402
from rig.sim.world import world_from_config  # noqa: E402


def median_us(fn, args_list, repeat=2000) -> float:
    times = []
    for i in range(repeat):
        args = args_list[i % len(args_list)]
        t0 = time.perf_counter()
        fn(*args)
        times.append(time.perf_counter() - t0)
    return statistics.median(times) * 1e6


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--seconds", type=float, default=10.0, help="simulated seconds for the real-time factor")
    a = ap.parse_args()
    dyn = PSMDynamics()
    rng = np.random.default_rng(0)
    samples = [(rng.uniform([-1.5, -0.9, 0.0], [1.5, 0.9, 0.24]), rng.uniform(-1, 1, 3)) for _ in range(64)]

    def all_terms(q, dq):
        dyn.mass_matrix(q)
        dyn.coriolis(q, dq)
        dyn.gravity_torque(q)
        dyn.tip_jacobian(q)

    rows = []
    for name, fn, args in [
        ("M(q)", dyn.mass_matrix, [(q,) for q, _ in samples]),
        ("C(q,dq) dq", dyn.coriolis, samples),
        ("g(q)", dyn.gravity_torque, [(q,) for q, _ in samples]),
        ("J(q) tip", dyn.tip_jacobian, [(q,) for q, _ in samples]),
        ("M + C dq + g + J together", all_terms, samples),
    ]:
        us = median_us(fn, args)
        rows.append((f"{name} median per evaluation", f"{us:.1f} us", "< 50 us", us < 50))

    world = world_from_config(config.load())
    world.advance(0.01)  # compile the kernel before timing
    n = int(round(a.seconds / world.dt))
    t0 = time.perf_counter()
    for _ in range(n):
        world.step()
    wall = time.perf_counter() - t0
    rtf = a.seconds / wall
    rows.append(("sim: 2 arms + spring object at 1 kHz, real-time factor", f"{rtf:.0f}", ">= 50", rtf >= 50))
    ok = print_table("Issue 2: PSM model and simulated rig", rows)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
