"""Benchmark: the kinematic calibration procedures on the simulated rig over several seeds.

Runs `rig link-lengths`, `rig calibrate-rcm` (PSM1) and `rig register` (touch points and
mocap RCM frames) as the CLI does (procedure functions, recorded runs in a temporary
folder) with the default 0.25 mm marker noise, and prints the worst error against the
simulated truth over the seeds next to issue 4's targets. Errors, not residuals.

    python bench/bench_calibration_procedures.py [--seeds 0 1 2] [--no-mocap-register]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench._table import print_table  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--no-mocap-register", action="store_true", help="skip the slow mocap registration")
    args = ap.parse_args()
    tmp = tempfile.mkdtemp(prefix="bench-cal-")
    os.environ["RIG_LOGS"] = tmp
    from procedures import calibrate_rcm, link_lengths, register
    from rig import config
    from rig.commands.parameters import resolve

    cfg = config.load(None)
    worst = {"len": 0.0, "len_name": "", "axis": 0.0, "axis_name": "", "ll_rcm": 0.0, "rcm": 0.0,
             "rcm_frame": 0.0, "rcm_a10": 0.0, "touch_t": 0.0, "touch_r": 0.0, "mocap_t": 0.0, "mocap_r": 0.0,
             "mocap_bt": 0.0}
    t0 = time.perf_counter()
    for s in args.seeds:
        r = link_lengths.run(cfg, resolve(link_lengths.PARAMETERS, {"seed": s}), progress=False)
        e = r["truth"]["errors"]
        name, v = max(e["lengths"].items(), key=lambda kv: abs(kv[1]))
        if abs(v) > worst["len"]:
            worst["len"], worst["len_name"] = abs(v), name
        name, v = max(e["axes_deg"].items(), key=lambda kv: kv[1])
        if v > worst["axis"]:
            worst["axis"], worst["axis_name"] = v, name
        worst["ll_rcm"] = max(worst["ll_rcm"], e["rcm"])
        r = calibrate_rcm.run(cfg, resolve(calibrate_rcm.PARAMETERS, {"seed": s, "arm": "PSM1"}),
                                            progress=False)
        t = r["arms"]["PSM1"]["truth"]
        worst["rcm"] = max(worst["rcm"], t["rcm_error"])
        worst["rcm_frame"] = max(worst["rcm_frame"], t["rcm_frame_rotation_error_deg"])
        worst["rcm_a10"] = max([worst["rcm_a10"]] + list(t["methods"].values()))
        r = register.run(cfg, resolve(register.PARAMETERS, {"seed": s}), progress=False)
        t = r["truth"]["PSM2"]
        worst["touch_t"] = max(worst["touch_t"], t["rcm_translation_error"], t["base_translation_error"])
        worst["touch_r"] = max(worst["touch_r"], t["rcm_rotation_error_deg"])
        if not args.no_mocap_register:
            r = register.run(cfg, resolve(register.PARAMETERS, {"seed": s, "method": "mocap",
                                                                        "remeasure": True}), progress=False)
            t = r["truth"]["PSM2"]
            worst["mocap_t"] = max(worst["mocap_t"], t["rcm_translation_error"])
            worst["mocap_bt"] = max(worst["mocap_bt"], t["base_translation_error"])
            worst["mocap_r"] = max(worst["mocap_r"], t["rcm_rotation_error_deg"])
    n = len(args.seeds)
    rows = [
        (f"link length error, worst of 6 x {n} seeds ({worst['len_name']})", f"{worst['len'] * 1e3:.3f} mm", "< 0.3 mm",
         worst["len"] < 0.3e-3),
        (f"axis direction error, worst of 6 axes x {n} ({worst['axis_name']})", f"{worst['axis']:.4f} deg", "< 0.1 deg",
         worst["axis"] < 0.1),
        ("RCM from link-lengths axes (z1 x zR)", f"{worst['ll_rcm'] * 1e3:.3f} mm", "< 0.2 mm", worst["ll_rcm"] < 0.2e-3),
        ("calibrate-rcm RCM error (one-step + insertion)", f"{worst['rcm'] * 1e3:.3f} mm", "< 0.2 mm", worst["rcm"] < 0.2e-3),
        ("calibrate-rcm RCM frame orientation error", f"{worst['rcm_frame']:.4f} deg", "< 0.1 deg", worst["rcm_frame"] < 0.1),
        ("calibrate-rcm A.10 family (q3-held frames) worst", f"{worst['rcm_a10'] * 1e3:.3f} mm", "report only", True),
        ("register touch: translation (RCM and base)", f"{worst['touch_t'] * 1e3:.3f} mm", "< 0.5 mm", worst["touch_t"] < 0.5e-3),
        ("register touch: rotation", f"{worst['touch_r']:.4f} deg", "< 0.2 deg", worst["touch_r"] < 0.2),
    ]
    if not args.no_mocap_register:
        rows += [
            ("register mocap: RCM-frame translation", f"{worst['mocap_t'] * 1e3:.3f} mm", "< 0.5 mm", worst["mocap_t"] < 0.5e-3),
            ("register mocap: rotation", f"{worst['mocap_r']:.4f} deg", "< 0.2 deg", worst["mocap_r"] < 0.2),
            ("register mocap: base-to-base translation", f"{worst['mocap_bt'] * 1e3:.3f} mm", "report (0.5 m lever)", True),
        ]
    ok = print_table(f"Kinematic calibration procedures, simulated rig, 0.25 mm marker noise, seeds {args.seeds} "
                     f"({time.perf_counter() - t0:.0f} s)", rows)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
