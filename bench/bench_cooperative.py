"""Issue 6 benchmark: `rig cooperative` on the simulated rig against the issue's targets.

Conditions (as the issue sets them): load-cell noise 0.02 N rms at 500 Hz, stiction
(breakaway 1 N) on joint 3 of every arm, and a controller model whose parameters are off
by 15 % (each body's mass and inertia and each drive parameter scaled by 1 +/- 0.15, seeded).
The master moves 5 cm in 5 s. The issue asks for strings of 20000 N/m and stiffer: a
50000 N/m string is run too, against the same targets. Prints figure, value, target, pass/fail.

    python bench/bench_cooperative.py [--seeds 1]

Tuning log of the effort path's presets (rig.control.cooperative_gains.preset), measured
with this bench's conditions unless said otherwise; re-run it after changing a gain.

- Spring, desired inertia Md 1 kg: 0.5 kg gave 0.10 N in-process, but a control loop held
  up by the machine (over the wire, two CPU burners: holds of 10-20 ms) rang on joint 2
  up to the effort ceiling. In-process at 500 Hz with the measured joints a tick late and
  holds of up to 7 periods on 30 % of the ticks, 0.5 and 0.75 kg aborted and 1 kg held
  (0.14-0.18 N; holds of up to 11 periods on 15 %: 0.21-0.35 N).
- String, Kp 200 N/m: of 50-800 N/m this gave the smallest error while moving (a softer
  slave lags the master, a stiffer one passes the master's lag into the string).
- String, k_fp 10: of 0-20 tried (15 % model error, stiction), 4 gave 0.28 N while
  moving, 10-20 about 0.23 N (following the plan); 10 keeps a factor 2 from the largest
  tried.
- String, damping ratio 0.3: over the wire the state is about a tick old when the command
  acts, and 0.7 then rang at half the loop rate on joint 3 up to the effort ceiling.
  In-process, 3 cm move at 500 Hz, measured joints one tick late: 0.7 and 0.5 aborted,
  0.4 / 0.3 / 0.2 held (0.115 / 0.109 / 0.109 N); two ticks late only 0.2 held. On this
  bench's cases (1 N stiction, 15 % model error, 1 kHz) 0.2 aborted on the 50 kN/m string
  and 0.3 gave 0.142 / 0.164 N (0.7: 0.108 / 0.148).
- A desired inertia of 0.35 kg on the string limit-cycled (the sampled, filtered force
  arrives too late for an arm-object mode above 200 rad/s).
- Slaves follow the master's measured motion, not its plan: on a 20 kN/m string
  following the plan gave 0.24 N while moving, following the measurement 0.17 N; at
  100 kN/m 0.39 N and 0.21 N.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _table import print_table  # noqa: E402

from rig import config  # noqa: E402
from rig.model.psm_dynamics import BODY_NAMES, Body, DriveParameters, PSMDynamics, PSMParameters  # noqa: E402

PSM3 = {"base_xyz": [0.5364, 0.5730, 0.0], "base_rpy": [0.0, 0.0, -np.pi / 2]}


def model_with_error(error: float, seed: int) -> PSMDynamics:
    rng = np.random.default_rng(seed)
    p = PSMParameters()
    bodies = {}
    for b in BODY_NAMES:
        s = 1 + error * rng.choice([-1, 1])
        B = p.bodies[b]
        bodies[b] = Body(B.mass * s, B.com, B.inertia * s)
    d = p.drive
    scale = lambda v: v * (1 + error * rng.choice([-1, 1], size=3))  # noqa: E731
    return PSMDynamics(PSMParameters(bodies, DriveParameters(scale(d.Fc), scale(d.Fv), scale(d.Fo), scale(d.Ia))))


def run_case(kind: str, arms: list[str], seed: int, mode: str = "impedance", deadband: float = 0.4,
             duration: float = 5.0, stiffness: float | None = None) -> dict:
    from procedures import cooperative
    from procedures.cooperative import PARAMETERS

    doc = {"rig": {"seed": seed},
           "arms": {"PSM1": {}, "PSM2": {"base_xyz": [config.DEFAULT_PSM2_X, 0, 0], "base_rpy": [0, 0, np.pi]}},
           "object": {"kind": kind, "stiffness": stiffness or (2450.0 if kind == "spring" else 20000.0),
                      "rest_length": 0.10 if len(arms) == 2 else 0.099, "arms": arms},
           "loadcell": {"noise": 0.02},
           "effects": {}}
    if "PSM3" in arms:
        doc["arms"]["PSM3"] = PSM3
    for a in arms:
        doc["effects"][a] = {"stiction": [0.0, 0.0, 1.0]}
    cfg = config.parse(doc, f"bench ({kind}, {len(arms)} arms)")
    # every parameter of the procedure at its default (the success tolerance too), these set
    params = {p.name: p.default for p in PARAMETERS}
    params.update({"force": 5.0, "duration": duration, "settle": 2.0, "hold_after": 2.0, "deadband": deadband,
                   "tension_ceiling": 15.0})
    move = np.array([0.05, 0.0, 0.0])
    return cooperative.run(cfg, arms, arms[-1] if len(arms) == 2 else "PSM1", params, move, np.zeros(3), mode,
                           model=model_with_error(0.15, seed), seed=seed, progress=False)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--seeds", type=int, default=1, help="seeds per case (worst case reported)")
    a = ap.parse_args()
    os.environ.setdefault("RIG_LOGS", tempfile.mkdtemp(prefix="bench-coop-"))
    rows = []
    loop_times = []
    for label, kind, arms, stiffness in (("spring 2450 N/m", "spring", ["PSM1", "PSM2"], None),
                                         ("string 20000 N/m", "string", ["PSM1", "PSM2"], None),
                                         ("string 50000 N/m", "string", ["PSM1", "PSM2"], 50000.0),
                                         ("three arms, spring", "spring", ["PSM1", "PSM2", "PSM3"], None)):
        results = [run_case(kind, arms, seed, stiffness=stiffness) for seed in range(a.seeds)]
        worst = lambda key: max(r[key] for r in results)  # noqa: E731
        loop_times += [r["loop_time_us"]["median"] / len(arms) for r in results]
        rows.append((f"{label}: max |F - 5 N| during motion (N)", f"{worst('max_error_during_motion'):.3f}",
                     "<= 0.25 (thesis 0.5)", worst("max_error_during_motion") <= 0.25))
        rows.append((f"{label}: start-up overshoot (N)", f"{worst('overshoot'):.3f}", "<= 0.5 (thesis 1-2)",
                     worst("overshoot") <= 0.5))
        rows.append((f"{label}: RMS error after settling (N)", f"{worst('rms_error'):.3f}", "report", True))
        rows.append((f"{label}: settling time (s)", f"{worst('settling_time'):.2f}", "report", True))
        rows.append((f"{label}: limit cycle", str(any(r["limit_cycle"] for r in results)), "False",
                     not any(r["limit_cycle"] for r in results)))
    med = statistics.median(loop_times)
    rows.append(("controller step per arm, median (us)", f"{med:.0f}", "< 200", med < 200))
    small = run_case("spring", ["PSM1", "PSM2"], 0, mode="position", deadband=0.05, duration=2.0)
    large = run_case("spring", ["PSM1", "PSM2"], 0, mode="position", deadband=0.4, duration=2.0)
    rows.append(("position mode, deadband 0.05 N: limit cycle (reversals)",
                 f"{small['limit_cycle']} ({small['hold_reversals']})", "True", small["limit_cycle"]))
    rows.append(("position mode, deadband 0.4 N: limit cycle (reversals)",
                 f"{large['limit_cycle']} ({large['hold_reversals']})", "False", not large["limit_cycle"]))
    ok = print_table("Issue 6: cooperative force tracking on the simulated rig", rows)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
