"""`rig calibrate-rcm`: the remote centre of motion by pivot calibration (appendix A.2, Table 6.1).

With the insertion q3 held, the tool pivots about the RCM whatever q1 and q2 do, so a
marker body on the tool has a constant offset b_tip (body frame) to a constant point
b_post (mocap frame): b_post = R_k b_tip + p_k (eq. A.9). The arm sweeps q1 with q2 = 0,
q2 with q1 = 0, then a Lissajous figure of q1 and q2 through the workspace; all tool
poses go into the algebraic one-step least squares of eq. A.10, and into the two-step and
sphere-fit variants, each with RANSAC rejection of outlier frames (calibration.pivot).
Frames in which the measured q3 strayed from its median by more than --q3-tolerance are
not used (the offset b_tip changes with q3), and are counted.

Outputs per arm, in metres in the mocap frame: the RCM (b_post), the tool offset
(b_tip), the RMS per axis of the per-frame RCM estimates about the fit (Table 6.1's
"RMS error"), and the RCM frame: origin at the RCM, y along minus the yaw axis, x along
minus the pitch axis (the dVRK's measured_cp convention, rig.model.psm_kinematics.RCM_FRAME),
from the single-joint sweeps. `rig register` uses these frames. On the simulated rig the
result also gives the errors against the simulated truth (the residual RMS is not an
accuracy). Figure 6.2's picture, the per-frame RCM estimates and the fit, is saved as a PNG.

Offline: `--from-csv take.csv --body Tool` reads a Motive export (m or mm, quaternions)
and runs the same pivot fits on that body's poses.
"""

from __future__ import annotations

import math
import sys

import click
import numpy as np

from calibration.axis_fit import axis_angle
from calibration.fit_error import FitError
from calibration.pivot import PivotFit
from calibration.rcm import DEFAULTS, METHODS, arm_bodies, calibrate_arm, pivot_all
from calibration.registration import pose_error
from procedures.mocap_capture import RCM_PHASES, lissajous, measure_rcm_phases, open_devices, tracker_stats
from rig.commands.exit_codes import EXIT_INPUT, EXIT_MISSED, InputError
from rig.commands.options import config_from_context
from rig.commands.parameters import Parameter
from rig.commands.procedure import procedure_command
from rig.commands.report import emit_result, exit_for_status
from rig.model import psm_kinematics as K
from rig.runs import provenance
from rig.runs.run import Run

PROCEDURE = "calibrate-rcm"
#: m: pivot-fit RMS above which a calibration is not used. Table 6.1 gives the RCM's
#: wander over the q1-q2 workspace as RMS per axis: 0.62, 0.62, 0.31 mm on the hardware
#: (0.9 mm together) and 0.85, 1.91, 1.08 mm in the Gazebo simulation (2.4 mm); the
#: simulated rig here gives 1.8 mm with 0.25 mm marker noise. Twice the worst of these is
#: the bound: past it the markers did not turn about one point (a loose body, a moving RCM).
RMS_BOUND = 0.005


def missed_bound(arms: dict) -> str | None:
    """Why a calibration of `arms` ({name: {"rms": m}}) is not good enough, or None."""
    high = [f"{a} {r['rms'] * 1e3:.2f} mm" for a, r in arms.items() if not r.get("rms", math.inf) <= RMS_BOUND]
    if not high:
        return None
    return (f"pivot-fit RMS {', '.join(high)} above the bound {RMS_BOUND * 1e3:g} mm: check that the marker "
            "body is rigid on the tool and the arm's RCM holds, then calibrate again")
STEPS = RCM_PHASES + ("pivot calibration", "save the result and Figure 6.2")
PARAMETERS = [
    Parameter("arm", "all", "", "Arm to calibrate, or 'all' for every arm of the rig", type=str),
    Parameter("q1_range", DEFAULTS["q1_range"], "rad", "q1 amplitude of the sweeps", minimum=0.0, maximum=float(K.Q_MAX[0])),
    Parameter("q2_range", DEFAULTS["q2_range"], "rad", "q2 amplitude of the sweeps", minimum=0.0, maximum=float(K.Q_MAX[1])),
    Parameter("q3", DEFAULTS["q3"], "m", "Insertion held throughout", minimum=0.02, maximum=0.24),
    Parameter("duration", DEFAULTS["duration"], "s", "Length of the Lissajous figure (0: single-joint sweeps only)",
              minimum=0.0, maximum=600.0),
    Parameter("method", DEFAULTS["method"], "", "Pivot method reported as the result (all three are computed)",
              choices=METHODS, type=str),
    Parameter("ransac_threshold", DEFAULTS["ransac_threshold"], "m", "RANSAC inlier distance to the pivot point",
              minimum=1e-4, maximum=0.05),
    Parameter("q3_tolerance", DEFAULTS["q3_tolerance"], "m", "Frames whose q3 strays further from its median are left out "
              "of the eq. A.10 fits (the main fit models the insertion shift)", minimum=1e-5, maximum=0.01),
    Parameter("seed", -1, "", "Seed of the simulated rig (-1: the configuration's)", type=int),
]


def truth_errors(world, arm: str, res: dict, fit: PivotFit, q3: float) -> dict:
    """Errors against the simulated truth (m, deg)."""
    F_true = world.arms[arm].rcm_world
    rcm_true = F_true[:3, 3]
    dt, dr = pose_error(np.array(res["rcm_frame"]), F_true)
    return {"rcm_true": rcm_true.tolist(), "rcm_error": float(np.linalg.norm(fit.post - rcm_true)),
            "rcm_error_xyz": (fit.post - rcm_true).tolist(),
            "rcm_frame_rotation_error_deg": math.degrees(dr),
            "yaw_axis_error_deg": math.degrees(axis_angle(res["yaw_axis"], -F_true[:3, 1])),
            "pitch_axis_error_deg": math.degrees(axis_angle(res["pitch_axis"], -F_true[:3, 0])),
            "methods": {m: float(np.linalg.norm(np.array(v["rcm"]) - rcm_true))
                        for m, v in res["methods"].items() if isinstance(v, dict)}}


def figures(fits: dict[str, PivotFit], truths: dict[str, np.ndarray | None], path) -> None:
    """Per-frame RCM estimates R_k b_tip + p_k and the fitted RCM, in mm about the fit."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(fits), 3, figsize=(13, 4.2 * len(fits)), squeeze=False)
    for row, (arm, fit) in enumerate(fits.items()):
        P = (fit.points[fit.inliers] - fit.post) * 1e3
        out = fit.points[~fit.inliers & np.all(np.isfinite(fit.points), axis=1)]
        O = (out - fit.post) * 1e3
        for col, (i, j, name) in enumerate(((0, 1, "x-y"), (0, 2, "x-z"), (1, 2, "y-z"))):
            ax = axes[row, col]
            ax.plot(P[:, i], P[:, j], ".", ms=2, alpha=0.4, label="RCM estimate per frame")
            if len(O):
                ax.plot(O[:, i], O[:, j], "x", ms=3, color="0.5", label="rejected (RANSAC)")
            ax.plot(0, 0, "r+", ms=16, mew=2, label="fitted RCM")
            t = truths.get(arm)
            if t is not None:
                d = (np.asarray(t) - fit.post) * 1e3
                ax.plot(d[i], d[j], "kx", ms=10, mew=2, label="true RCM (simulation)")
            ax.set_xlabel("xyz"[i] + " (mm)")
            ax.set_ylabel("xyz"[j] + " (mm)")
            ax.set_aspect("equal", adjustable="datalim")
            ax.set_title(f"{arm} {name}: RMS {fit.rms_xyz[i] * 1e3:.2f} / {fit.rms_xyz[j] * 1e3:.2f} mm")
        axes[row, 0].legend(fontsize=7, markerscale=3)
    fig.suptitle("Remote centre of motion (cf. thesis Figure 6.2)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def table_6_1(arms: dict) -> str:
    lines = ["Table 6.1 form (mm, mocap frame):",
             f"  {'RCM':8} {'x':>9} {'y':>9} {'z':>9} | RMS {'x':>6} {'y':>6} {'z':>6}"]
    for arm, r in arms.items():
        c, s = np.array(r["rcm"]) * 1e3, np.array(r["rms_xyz"]) * 1e3
        lines.append(f"  {arm:8} {c[0]:9.2f} {c[1]:9.2f} {c[2]:9.2f} |     {s[0]:6.2f} {s[1]:6.2f} {s[2]:6.2f}")
        if r.get("tip_offset") is not None:
            b = np.array(r["tip_offset"]) * 1e3
            lines.append(f"    tool offset (the pivot, the RCM, in the marker body frame): "
                         f"{b[0]:.2f} {b[1]:.2f} {b[2]:.2f} mm")
        if "truth" in r:
            t = r["truth"]
            lines.append(f"    error against the simulated truth: RCM {t['rcm_error'] * 1e3:.3f} mm, "
                         f"RCM frame {t['rcm_frame_rotation_error_deg']:.4f} deg")
    return "\n".join(lines)


def report(result: dict) -> str:
    """Table 6.1 of the arms (or the body) calibrated."""
    return table_6_1(result["arms"])


# ----------------------------------------------------------------------------- measuring

def run(cfg, parameters: dict, run_root=None, progress: bool = True,
        procedure: str = PROCEDURE) -> dict:
    """The live procedure as a function (CLI, bench and `rig register` call it)."""
    arms = list(cfg.arms) if parameters["arm"] == "all" else [parameters["arm"]]
    for a in arms:
        if a not in cfg.arms:
            raise InputError(f"no arm {a!r} in {cfg.source}; arms: {', '.join(cfg.arms)}")
    _, vmax = lissajous(parameters["q1_range"], parameters["q2_range"], parameters["q3"], parameters["duration"])
    if vmax > 0.8 * K.DQ_MAX[0]:
        raise InputError(f"the Lissajous figure would reach {vmax:.2f} rad/s; lengthen --duration "
                                   f"or lower the ranges (limit {0.8 * K.DQ_MAX[0]:.1f} rad/s, 80% of Table 4.2)")
    seed = None if parameters["seed"] < 0 else parameters["seed"]
    dev = open_devices(cfg, seed=seed, arms=arms)
    try:
        # every arm walks the first five steps: the list a user sees counts them per arm
        steps = [f"{name} ({a})" for a in arms for name in STEPS[:5]
                 if name != STEPS[3] or parameters["duration"] > 0] + [STEPS[5]]
        with Run(procedure, parameters=parameters, config=cfg.snapshot(), seed=seed, steps=steps,
                 root=run_root, progress=progress) as run:
            dev.person.detach_object()
            dev.person.confirm("Mount a marker body on each tool and clear the workspace")
            results, fits, truths = {}, {}, {}
            for a in arms:
                bodies = arm_bodies(a, dev.tracker.bodies)
                caps = measure_rcm_phases(dev, run, a, parameters, sorted(set(bodies.values())))
                with run.step(f"{STEPS[4]} ({a})"):
                    res, fit = calibrate_arm(caps, a, bodies, parameters)
                if dev.world is not None:
                    res["truth"] = truth_errors(dev.world, a, res, fit, parameters["q3"])
                    truths[a] = np.array(res["truth"]["rcm_true"])
                results[a], fits[a] = res, fit
            with run.step(STEPS[5]):
                figures(fits, truths, run.dir / "rcm.png")
                first = results[arms[0]]
                result = {"rcm": first["rcm"], "tip_offset": first["tip_offset"], "rms": first["rms"],
                          "arm": arms[0], "frame": "mocap", "arms": results,
                          "plot": str(run.dir / "rcm.png"), "tracker": tracker_stats(dev.tracker),
                          "summary": {f"{a} rcm (m)": r["rcm"] for a, r in results.items()}
                          | {f"{a} rms (m)": r["rms"] for a, r in results.items()}}
                result["provenance"] = provenance.live(cfg, arms, run.dir)
                missed = missed_bound(results)
                run.finish(result, "failed" if missed else "completed", missed)
    finally:
        dev.close()
    return run.result


def run_offline(path: str, body: str, parameters: dict, run_root=None, progress: bool = True) -> dict:
    """Pivot calibration of `body` from a Motive CSV export (no arm moves, no RCM frame)."""
    from drivers.mocap.motive_csv import MotiveCsvError, read_motive_csv
    from drivers.common.quaternion import matrix_to_quat_xyzw

    try:
        take = read_motive_csv(path)
        track = take.body(body)
    except MotiveCsvError as exc:
        raise InputError(str(exc)) from None
    R, p = track.rotation(), track.position
    params = dict(parameters, from_csv=str(path), body=body)
    with Run(PROCEDURE, parameters=params, config={"source": str(path)}, steps=list(STEPS[4:]),
             root=run_root, progress=progress) as run:
        with run.step(STEPS[4]):
            for k in np.flatnonzero(track.valid):
                run.recorder.pose(f"/mocap/{body}/pose", float(track.time[k]), p[k],
                                  matrix_to_quat_xyzw(R[k]), "mocap")
            fit, allf = pivot_all(R, p, parameters["ransac_threshold"], parameters["method"])
        with run.step(STEPS[5]):
            figures({body: fit}, {}, run.dir / "rcm.png")
            res = {**fit.summary(), "methods": allf["table"], "body": body,
                   "frames_occluded": int((~track.valid).sum()), "length_unit": take.length_unit}
            result = {"rcm": res["rcm"], "tip_offset": res["tip_offset"], "rms": res["rms"], "frame": "mocap",
                      "source": str(path), "arms": {body: res}, "plot": str(run.dir / "rcm.png"),
                      "summary": {"rcm (m)": res["rcm"], "rms (m)": res["rms"]},
                      "provenance": provenance.recording(path, body)}
            missed = missed_bound({body: res})
            run.finish(result, "failed" if missed else "completed", missed)
    return run.result


@procedure_command(PROCEDURE, STEPS, PARAMETERS)
@click.option("--from-csv", "from_csv", type=click.Path(dir_okay=False, exists=True), default=None,
              help="Calibrate offline from an OptiTrack Motive CSV export (m or mm, quaternions).")
@click.option("--body", default=None, help="Rigid body of the tool in the --from-csv file.")
def command(ctx, parameters, from_csv, body, as_json: bool) -> None:
    """Remote centre of motion by pivot calibration (appendix A.2, Table 6.1).

    Sweeps q1 and q2 with q3 held and tracks the tool body; fits b_tip and b_post (the RCM)
    by the one-step least squares of eq. A.10, two-step and sphere fits with RANSAC. Prints,
    per arm, the RCM and its RMS (mm, mocap frame: the form of Table 6.1) and the tool
    offset (mm); result.json and --json give them in m, at least {"rcm": [x, y, z],
    "tip_offset": [x, y, z], "rms": r}. Saves rcm.png (Figure 6.2).
    """
    if (from_csv is None) != (body is None):
        raise click.UsageError("--from-csv and --body go together (the file and the tool's rigid body name)")
    try:
        if from_csv:
            result = run_offline(from_csv, body, parameters)
        else:
            result = run(config_from_context(ctx), parameters)
    except FitError as exc:
        where = f" (run folder {exc.run_dir})" if getattr(exc, "run_dir", None) else ""
        click.echo(f"rig {PROCEDURE}: refused: {exc}{where}", err=True)
        # a run of the rig that could not be fitted missed its purpose; a take given as a
        # file that cannot carry the fit is the user's input
        sys.exit(EXIT_INPUT if from_csv else EXIT_MISSED)
    emit_result(result, as_json, report(result) + f"\nrun folder: {result['run_dir']}")
    exit_for_status(PROCEDURE, result)
