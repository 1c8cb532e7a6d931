"""Monte Carlo accuracy of the kinematic fits against known truth (issue 4 targets).

Synthetic scenes (calibration.synthetic) with 0.25 mm Gaussian marker noise:
* RCM: a tool body pivoting about a known point, sweeps q1 +/-1.5 rad (q2 = 0) then
  q2 +/-0.9 rad (q1 = 0), 400 frames, 3 markers; one-step pivot (eq. A.10).
* Axis: a link body with 3 markers rotating +/-1.5 rad about a known axis relative to a
  static reference body (its pose averaged over the sweep, as for the world and link-1
  bodies in the thesis 4.1.1 sweeps), 300 frames; bias-compensated and plain
  Gamage-Lasenby. Also, for information: the reference tracked frame by frame (a moving
  reference, e.g. parallelogram links), and the small-range bias (+/-0.1 rad) of the
  axis point, plain against compensated.
* Registration: PSM2 base relative to PSM1 base from 40 touched points (0.25 mm on each
  arm's tip) and from mocap base bodies (200 static frames each).

Prints max and median over the seeds against the targets, and the ratio of the RMS
error to the fit's own predicted standard deviation (near 1 when the reported
uncertainty is honest). Usage: python bench/bench_kinematic_calibration.py [--seeds 50]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from calibration.axis_fit import axis_angle, fit_axis_bias_compensated, fit_axis_gamage_lasenby
from calibration.pivot import fit_pivot
from calibration.registration import (pose_error, register_from_mocap, register_from_touch_points,
                                      to_static_reference)
from calibration.synthetic import hinge_scene, pivot_scene, registration_scene

TARGETS = {"rcm_mm": 0.2, "axis_deg": 0.1, "reg_mm": 0.5, "reg_deg": 0.2}


def run(seeds: int) -> list[tuple]:
    rcm, rcm_z = {m: [] for m in ("one_step", "two_step", "sphere")}, []
    ax_gl, ax_bc, ax_z, pt_bc, ax_moving, small_gl, small_bc = [], [], [], [], [], [], []
    touch_mm, touch_deg, mocap_mm, mocap_deg, reg_z = [], [], [], [], []
    for seed in range(seeds):
        rng = np.random.default_rng(seed)
        ps = pivot_scene(rng, n_frames=400)
        for m in rcm:
            f = fit_pivot(ps.R, ps.p, method=m)
            rcm[m].append(np.linalg.norm(f.post - ps.rcm) * 1e3)
            if m == "one_step":
                rcm_z.append(np.linalg.norm(f.post - ps.rcm) ** 2 / np.trace(f.post_cov))
        hs = hinge_scene(rng, angle_range=(-1.5, 1.5), n_frames=300)
        X, _ = to_static_reference(hs.moving_markers, hs.ref_markers, hs.ref_template)
        a = fit_axis_bias_compensated(X)
        am = fit_axis_bias_compensated(hs.markers_in_reference())
        ax_moving.append(np.rad2deg(axis_angle(am.direction, hs.direction)))
        g = fit_axis_gamage_lasenby(X)
        ax_bc.append(np.rad2deg(axis_angle(a.direction, hs.direction)))
        ax_gl.append(np.rad2deg(axis_angle(g.direction, hs.direction)))
        ax_z.append(axis_angle(a.direction, hs.direction) ** 2 / np.trace(a.direction_cov))
        d = a.point - hs.point
        pt_bc.append(np.linalg.norm(d - (d @ hs.direction) * hs.direction) * 1e3)
        hs = hinge_scene(rng, angle_range=(-0.1, 0.1), n_frames=300)
        X, _ = to_static_reference(hs.moving_markers, hs.ref_markers, hs.ref_template)
        for fit, out in ((fit_axis_gamage_lasenby, small_gl), (fit_axis_bias_compensated, small_bc)):
            d = fit(X).point - hs.point
            out.append(np.linalg.norm(d - (d @ hs.direction) * hs.direction) * 1e3)
        rs = registration_scene(rng, n_points=40, workspace=0.1)
        t = register_from_touch_points(rs.tips_1, rs.tips_2)
        e_t, e_r = pose_error(t.matrix(), rs.T_1_2)
        touch_mm.append(e_t * 1e3)
        touch_deg.append(np.rad2deg(e_r))
        reg_z.append(e_r ** 2 / np.trace(t.cov[:3, :3]))
        mo = register_from_mocap(rs.T_m_b1, rs.T_m_b2)
        e_t, e_r = pose_error(mo.matrix(), rs.T_1_2)
        mocap_mm.append(e_t * 1e3)
        mocap_deg.append(np.rad2deg(e_r))
    rows = []

    def row(name, values, target, unit, z=None):
        v = np.asarray(values)
        ok = v.max() < target if target is not None else None
        rows.append((name, unit, float(v.max()), float(np.median(v)), target,
                     None if z is None else float(np.sqrt(np.mean(z))), ok))

    row("RCM position, one-step (A.10)", rcm["one_step"], TARGETS["rcm_mm"], "mm", rcm_z)
    row("RCM position, two-step", rcm["two_step"], TARGETS["rcm_mm"], "mm")
    row("RCM position, sphere fit (info)", rcm["sphere"], None, "mm")
    row("axis direction, bias-compensated GL", ax_bc, TARGETS["axis_deg"], "deg", ax_z)
    row("axis direction, plain GL", ax_gl, TARGETS["axis_deg"], "deg")
    row("axis point (perpendicular), BC GL", pt_bc, None, "mm")
    row("axis dir., ref tracked per frame (info)", ax_moving, None, "deg")
    row("axis point, 11.5 deg range, plain GL", small_gl, None, "mm")
    row("axis point, 11.5 deg range, BC GL", small_bc, None, "mm")
    row("registration, touch points", touch_mm, TARGETS["reg_mm"], "mm")
    row("registration, touch points", touch_deg, TARGETS["reg_deg"], "deg", reg_z)
    row("registration, mocap bodies", mocap_mm, TARGETS["reg_mm"], "mm")
    row("registration, mocap bodies", mocap_deg, TARGETS["reg_deg"], "deg")
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=50)
    args = ap.parse_args()
    t0 = time.perf_counter()
    rows = run(args.seeds)
    dt = time.perf_counter() - t0
    print(f"kinematic calibration, {args.seeds} seeds, 0.25 mm marker noise ({dt:.1f} s)")
    print(f"{'quantity':<38} {'unit':>4} {'max':>8} {'median':>8} {'target':>8} {'err/std':>8}  result")
    failed = False
    for name, unit, mx, med, target, z, ok in rows:
        tgt = f"< {target:g}" if target is not None else "-"
        zs = f"{z:.2f}" if z is not None else "-"
        res = "-" if ok is None else ("pass" if ok else "FAIL")
        failed |= ok is False
        print(f"{name:<38} {unit:>4} {mx:8.4f} {med:8.4f} {tgt:>8} {zs:>8}  {res}")
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
