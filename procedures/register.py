"""`rig register`: the transforms between the arms' bases for cooperative work (thesis 7.7.1).

The cooperative controller (7.7) needs every arm's RCM frame in one common frame. Two ways:

* `--method mocap`: each arm's RCM frame in the mocap frame from `rig calibrate-rcm`
  (pivot point and the yaw and pitch axes); the newest completed calibrate-rcm run is
  used when it holds every arm (`--remeasure` measures again inside this run). The common
  frame is the mocap frame.
* `--method touch`: both tool tips touch the same N physical points (a person guides
  them on the real rig, by the console's clutch or with the arm in `free`; the simulated
  rig moves them there with its true geometry). Each arm's tool tip (the jaw's tip on the
  wrist-yaw axis, not the shaft end 9.1 mm behind it) in its own RCM frame comes from its
  measured joints, the wrist's included (rig.model.psm_arm_kinematics.tool_tip_in_rcm), and
  a rigid fit of the point pairs (Kabsch, calibration.registration) gives
  T_rcm_ref_rcm_arm. The common frame is the reference arm's configured placement
  (rig.toml base_xyz/base_rpy of the first arm).

Saved in result.json: `transforms[arm]` with "T_ref_rcm_arm_rcm" (4x4, maps the arm's RCM
frame coordinates to the reference arm's RCM frame) and "T_ref_base_arm_base" (the same
between frames 0), and `rcm_frames[arm]` (4x4, each arm's RCM frame in the common frame),
which `rig cooperative` reads through rig.runs.paths.latest_result("register"). On the
simulated rig the errors against the true placement (cfg.base_matrix) are reported.
Units: m, rad (deg in printed text).
"""

from __future__ import annotations

import math
import sys

import click
import numpy as np

from calibration.fit_error import FitError
from calibration.rcm import DEFAULTS as RCM_DEFAULTS, arm_bodies, calibrate_arm
from calibration.registration import invert, pose_error, register_from_touch_points
from procedures.mocap_capture import Collector, measure_rcm_phases, open_devices, settle
from rig.commands.exit_codes import InputError
from rig.commands.options import config_from_context
from rig.commands.parameters import Parameter
from rig.commands.procedure import procedure_command
from rig.commands.report import emit_result, exit_for_status
from rig.model import psm_kinematics as K
from rig.model.psm_arm_kinematics import tool_tip_in_rcm
from rig.runs import provenance
from rig.runs.run import Run

PROCEDURE = "register"
#: the procedure whose results hold each arm's RCM frame in the mocap frame
CALIBRATE_RCM = "calibrate-rcm"
#: m: touch-point residual RMS above which a registration is not used. The tips meet within
#: the touch accuracy (a person guiding them: ~1 mm); 2 mm is the RCM calibration's own
#: bound (Table 6.1 scale), past it the tension's direction errs by more than a degree.
RESIDUAL_BOUND = 0.002
STEPS = ("open the rig and take the object off", "measure", "fit the transforms", "save")
PARAMETERS = [
    Parameter("method", "touch", "", "touch: tool tips on common points; mocap: RCM frames from calibrate-rcm",
              choices=("touch", "mocap"), type=str),
    Parameter("points", 8, "", "Common points to touch (touch method)", minimum=4, maximum=50, type=int),
    Parameter("spread", 0.03, "m", "Half-size of the box the touch points fill", minimum=0.002, maximum=0.08),
    Parameter("remeasure", False, "", "mocap: measure the RCM frames now even if calibrate-rcm results exist",
              type=bool),
    Parameter("seed", -1, "", "Seed of the simulated rig (-1: the configuration's)", type=int),
]


def touch_points(cfg, arms: list[str], n: int, spread: float, seed: int = 0) -> np.ndarray:
    """N world points (m) for the tips to meet: below the midpoint of the arms' configured
    RCMs, at the q3 = 0.12 m reach, spread over a box of half-size `spread` (corners first,
    so four or more points are never coplanar)."""
    rcms = np.array([(cfg.base_matrix(a) @ K.RCM_FRAME)[:3, 3] for a in arms])
    reach = 0.12 - K.L_RCC + K.L_TOOL
    centre = rcms.mean(axis=0) + np.array([0.0, 0.0, -reach])
    corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float)
    order = [0, 3, 5, 6, 7, 4, 2, 1]  # a tetrahedron first, then the other corners
    pts = [corners[i] for i in order]
    rng = np.random.default_rng(seed)
    while len(pts) < n:
        pts.append(rng.uniform(-1, 1, 3))
    return centre + spread * np.array(pts[:n])


def measure_touch(dev, run, cfg, arms: list[str], parameters: dict) -> dict:
    """Touch the common points; returns each arm's tips in its RCM frame and the truth."""
    pts = touch_points(cfg, arms, parameters["points"], parameters["spread"])
    tips = {a: [] for a in arms}
    touch_err = []
    for a in arms:
        run.claim(dev.arms[a])
    with run.step(STEPS[1], total=len(pts)) as st:
        for i, goal in enumerate(pts):
            dev.person.touch({a: dev.arms[a] for a in arms}, i, goal)
            col = Collector(f"touch {i + 1}", [])
            # Read while the tips are held together: the last 3 ms. Over the wire the first
            # samples after the touch may still be from before it (in flight), so a real or
            # served rig waits longer and keeps only the newest.
            settle(dev, run, col, [dev.arms[a] for a in arms], 0.003 if dev.world is not None else 0.05)
            for a in arms:
                t = np.asarray(col.js_t[a])
                q = np.median(np.asarray(col.js_q[a])[t >= t[-1] - 0.003], axis=0)
                # the tool tips are what meet, the wrist-yaw length beyond the shaft end
                tips[a].append(tool_tip_in_rcm(q, _wrist(dev.arms[a])))
            if dev.world is not None:
                w = [dev.world.arms[a].rcm_world @ np.append(tool_tip_in_rcm(dev.world.q[dev.world.arms[a].sl]), 1.0)
                     for a in arms]
                touch_err.append(max(float(np.linalg.norm(x[:3] - w[0][:3])) for x in w[1:]))
            st.advance()
    return {"tips": {a: np.array(v) for a, v in tips.items()}, "points_world": pts,
            "touch_error": touch_err}


def _wrist(arm):
    """The wrist's roll, pitch and yaw (rad) of a whole dVRK arm (`RosArm.measured_arm`), or
    None for an arm of joints 1-3 only (its wrist is straight)."""
    measured = getattr(arm, "measured_arm", None)
    if measured is None:
        return None
    q, _ = measured()
    return q[3:6] if len(q) >= 6 else None


def rcm_frames_from_calibration(cfg, dev, run, arms: list[str], parameters: dict) -> tuple[dict, str]:
    """Each arm's RCM frame in the mocap frame: from the newest calibrate-rcm run of every
    arm on this rig (rig.runs.provenance), or measured now (calibrate_rcm's phases in this run)."""
    def frames_of(data: dict) -> dict:
        return {a: np.array(r["rcm_frame"]) for a, r in data.get("arms", {}).items()
                if isinstance(r, dict) and "rcm_frame" in r}

    if not parameters["remeasure"]:
        found = provenance.find(CALIBRATE_RCM, cfg, arms=arms,
                                usable=lambda run, data: all(a in frames_of(data) for a in arms))
        for line in found.skipped:
            run.say(f"rig {PROCEDURE}: {line}")
        if found.run_dir is not None:
            return frames_of(found.data), str(found.run_dir)
    p = dict(RCM_DEFAULTS)
    frames = {}
    with run.step(STEPS[1]):
        for a in arms:
            bodies = arm_bodies(a, dev.tracker.bodies)
            caps = measure_rcm_phases(dev, run, a, p, sorted(set(bodies.values())))
            res, _ = calibrate_arm(caps, a, bodies, p)
            frames[a] = np.array(res["rcm_frame"])
    return frames, "measured in this run"


def run(cfg, parameters: dict, run_root=None, progress: bool = True) -> dict:
    arms = list(cfg.arms)
    if len(arms) < 2:
        raise InputError(f"{cfg.source}: registration needs at least two arms, got {arms}")
    ref = arms[0]
    seed = None if parameters["seed"] < 0 else parameters["seed"]
    dev = open_devices(cfg, seed=seed, arms=arms)
    try:
        with Run(PROCEDURE, parameters=parameters, config=cfg.snapshot(), seed=seed, steps=list(STEPS),
                 root=run_root, progress=progress) as run:
            with run.step(STEPS[0]):
                dev.person.detach_object()
            result: dict = {"method": parameters["method"], "reference_arm": ref, "transforms": {}}
            T_rcm = {ref: np.eye(4)}
            if parameters["method"] == "touch":
                m = measure_touch(dev, run, cfg, arms, parameters)
                with run.step(STEPS[2]):
                    for a in arms[1:]:
                        fit = register_from_touch_points(m["tips"][ref], m["tips"][a])
                        T_rcm[a] = fit.matrix()
                        result["transforms"][a] = {"residual_rms": fit.residual_rms,
                                                   "rotation_std_deg": math.degrees(fit.rotation_std),
                                                   "translation_std": fit.translation_std, "points": fit.n}
                # the reference arm's configured placement anchors the common frame
                F_ref = cfg.base_matrix(ref) @ K.RCM_FRAME
                result["frame"] = f"world via the configured placement of {ref}"
                result["touch_points_world"] = m["points_world"].tolist()
                if m["touch_error"]:
                    result["touch_error_max"] = max(m["touch_error"])
            else:
                frames, source = rcm_frames_from_calibration(cfg, dev, run, arms, parameters)
                with run.step(STEPS[2]):
                    for a in arms[1:]:
                        T_rcm[a] = invert(frames[ref]) @ frames[a]
                        result["transforms"][a] = {}
                F_ref = frames[ref]
                result["frame"] = "mocap"
                result["rcm_source"] = source
            with run.step(STEPS[3]):
                result["rcm_frames"] = {a: (F_ref @ T_rcm[a]).tolist() for a in arms}
                for a in arms[1:]:
                    result["transforms"][a]["T_ref_rcm_arm_rcm"] = T_rcm[a].tolist()
                    result["transforms"][a]["T_ref_base_arm_base"] = (K.RCM_FRAME @ T_rcm[a] @ K.RCM_FRAME_INV).tolist()
                if dev.world is not None:
                    result["truth"] = truth_errors(cfg, arms, T_rcm)
                result["summary"] = {f"{ref}->{a} translation (m)": T_rcm[a][:3, 3].tolist() for a in arms[1:]}
                result["provenance"] = provenance.live(cfg, arms, run.dir)
                high = [f"{a} {t['residual_rms'] * 1e3:.2f} mm" for a, t in result["transforms"].items()
                        if t.get("residual_rms") is not None and not t["residual_rms"] <= RESIDUAL_BOUND]
                missed = (f"touch-point residual {', '.join(high)} RMS above the bound {RESIDUAL_BOUND * 1e3:g} mm: "
                          "touch the points again (the tips must meet)") if high else None
                run.finish(result, "failed" if missed else "completed", missed)
    finally:
        dev.close()
    return run.result


def truth_errors(cfg, arms: list[str], T_rcm: dict) -> dict:
    """Errors against the true placement cfg.base_matrix (m, deg), RCM-to-RCM and base-to-base."""
    ref = arms[0]
    out = {}
    for a in arms[1:]:
        B = invert(cfg.base_matrix(ref)) @ cfg.base_matrix(a)
        F = K.RCM_FRAME_INV @ B @ K.RCM_FRAME
        dt, dr = pose_error(T_rcm[a], F)
        bt, br = pose_error(K.RCM_FRAME @ T_rcm[a] @ K.RCM_FRAME_INV, B)
        out[a] = {"rcm_translation_error": dt, "rcm_rotation_error_deg": math.degrees(dr),
                  "base_translation_error": bt, "base_rotation_error_deg": math.degrees(br)}
    return out


def report(result: dict) -> str:
    lines = [f"registration by {result['method']} (reference {result['reference_arm']}, frame: {result['frame']})"]
    for a, t in result["transforms"].items():
        T = np.array(t["T_ref_rcm_arm_rcm"])
        lines.append(f"  {a} RCM in {result['reference_arm']} RCM frame: t = {np.round(T[:3, 3], 5).tolist()} m")
        if "residual_rms" in t:
            lines.append(f"    touch-point residual {t['residual_rms'] * 1e3:.3f} mm RMS over {t['points']} points")
        if "truth" in result:
            e = result["truth"][a]
            lines.append(f"    error against the simulated truth: RCM frames {e['rcm_translation_error'] * 1e3:.3f} mm, "
                         f"{e['rcm_rotation_error_deg']:.4f} deg; bases {e['base_translation_error'] * 1e3:.3f} mm, "
                         f"{e['base_rotation_error_deg']:.4f} deg")
    return "\n".join(lines)


@procedure_command(PROCEDURE, STEPS, PARAMETERS)
def command(ctx, parameters, as_json: bool) -> None:
    """Base-to-base registration of the arms (thesis 7.7.1), saved for `rig cooperative`.

    Transforms are 4x4 (m); the reference is the first arm of the configuration.
    """
    try:
        result = run(config_from_context(ctx), parameters)
    except FitError as exc:
        where = f" (run folder {exc.run_dir})" if getattr(exc, "run_dir", None) else ""
        click.echo(f"rig {PROCEDURE}: refused: {exc}{where}", err=True)
        sys.exit(1)
    emit_result(result, as_json, report(result) + f"\nrun folder: {result['run_dir']}")
    exit_for_status(PROCEDURE, result)
