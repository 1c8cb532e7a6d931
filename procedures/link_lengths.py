"""`rig link-lengths`: joint axes and link lengths of a PSM from motion capture (thesis 4.1.1, A.1).

Marker bodies (three markers each) sit on the yaw link, the pitch back link, the pitch
bottom link, the pitch end link and the tool, plus one on the table ("world"). The arm
sweeps q1 over its range with q2 = 0, then q2 with q1 = 0 (thesis 4.1.1), then a short
insertion stroke of q3 with q1 = q2 = 0 to locate the tool axis. Every joint state and
mocap frame goes to the run's MCAP.

Frames of reference. Each phase is expressed in the world body's frame W, its pose
averaged over the phase (`mean_pose`), so its marker noise does not enter the fits. During
the q2 sweep the yaw link is static too, so W is a static reference for every axis fixed
to the yaw link.

Axes (all in W; a direction's sign is the joint's positive sense, from the measured joints):

* z1, the yaw axis: the yaw body's markers during the q1 sweep (Gamage-Lasenby, A.1);
* z2, the pitch axis: the pitch back body during the q2 sweep (Gamage-Lasenby);
* zR, the RCM pitch axis: the pitch end body turns about a line through the remote
  centre of motion parallel to z2 as q2 sweeps (Gamage-Lasenby);
* z3, the joint between the pitch back and pitch bottom links, and z4, the joint between
  the pitch bottom and pitch end links: both links move, so these come from the two
  bodies' poses together (SARA, `calibration.joint_axis`);
* the insertion axis: the direction the tool body moves along during the q3 stroke,
  through the RCM (the point of zR nearest z1).

Each axis fixed to the yaw link is fitted twice, plain Gamage-Lasenby and with
Halvorsen's bias compensation; both are reported, the compensated one is used.

Link lengths (Figure 4.2a is not in the text available to this project, so the Table 4.1
names are defined here on the model's parallelogram O2-O3-O4-RCM, where O2..O4 are the
joint axes z2..z4 of Table 4.3 and every distance is measured in a plane perpendicular to
the (parallel) axes, `calibration.axis_fit.distance_in_plane`):

* l1  = |z2 - z3|, the pitch back link (crank): DH a3 = 0.150 m;
* l2  = |zR - z4|, the pitch end link between the bottom link and the RCM line, the
        parallelogram's second crank: a3 in the model;
* l3  = |z3 - z4|, the pitch bottom link: DH a4 = 0.516 m;
* l4  = |z2 - zR|, the side of the parallelogram on the yaw link, from the pitch axis to
        the RCM: a4 in the model;
* l12 = the common perpendicular between the yaw axis z1 and the pitch axis z2: 0 in the
        model (they intersect, Table 4.3 a2 = 0); it measures how far the RCM can be off
        the yaw axis;
* l2' = the offset of the insertion axis from z4 at q2 = 0, perpendicular to both the
        insertion axis and the pitch axes: a3 sin(beta) = 0.141 m in the model.

The DH lengths they imply: a3 = inverse-variance mean of l1 and l2, a4 = that of l3 and
l4, beta = asin(l2' / a3) and, keeping Table 4.3's a6 = -0.043 m (the tool offset the
rotations cannot see), a5 = (a3 sin(beta) + a6) / cos(beta) from the exact-RCM condition
(rig.model.psm_kinematics). Every value carries a one-sigma uncertainty propagated from the
fits. Units: m and rad (degrees only in printed text).
"""

from __future__ import annotations

import math
import sys

import click
import numpy as np

from calibration.axis_fit import axis_angle, common_perpendicular, distance_in_plane
from calibration.captures import Capture, body_points
from calibration.fit_error import FitError
from procedures.link_lengths_fit import fit_link_lengths
from procedures.mocap_capture import Collector, move_capture, open_devices, settle, tracker_stats
from rig.commands.exit_codes import InputError
from rig.commands.options import config_from_context
from rig.commands.parameters import Parameter
from rig.commands.procedure import procedure_command
from rig.commands.report import emit_result, exit_for_status
from rig.model import psm_kinematics as K
from rig.runs import provenance
from rig.runs.run import Run

PROCEDURE = "link-lengths"
STEPS = (
    "power on and home the arm",
    "sweep q1 with q2 = 0",
    "sweep q2 with q1 = 0",
    "stroke q3 with q1 = q2 = 0",
    "fit the joint axes",
    "compute the link lengths",
    "save the result and plot",
)

PARAMETERS = [
    Parameter("arm", "PSM1", "", "Arm to measure", type=str),
    Parameter("q1_range", float(K.Q_MAX[0]), "rad", "Sweep q1 over +/- this (the full range by default)",
              minimum=0.0, maximum=float(K.Q_MAX[0])),
    Parameter("q2_range", float(K.Q_MAX[1]), "rad", "Sweep q2 over +/- this (the full range by default)",
              minimum=0.0, maximum=float(K.Q_MAX[1])),
    Parameter("q3", 0.12, "m", "Insertion held during the q1 and q2 sweeps", minimum=0.02, maximum=0.24),
    Parameter("q3_stroke", 0.10, "m", "Insertion stroke of the q3 phase (from --q3 outwards)",
              minimum=0.0, maximum=0.2),
    Parameter("passes", 2, "", "Sweeps back and forth of q2 (the passive joints' fits average over them; "
              "q1 sweeps once)", minimum=1, maximum=10, type=int),
    Parameter("seed", -1, "", "Seed of the simulated rig (-1: the configuration's)", type=int),
]

BODY_SUFFIXES = {"yaw": "yaw", "back": "pitch_back", "bottom": "pitch_bottom", "end": "pitch_end",
                 "tool": "tool"}


def nominal_lengths() -> dict[str, float]:
    """Table 4.1 quantities of the model (rig.model.psm_kinematics, Table 4.3 completed), m."""
    return {"l1": K.A3, "l2": K.A3, "l12": 0.0, "l2'": K.A3 * math.sin(K.BETA), "l3": K.A4, "l4": K.A4}


def nominal_dh() -> dict[str, float]:
    return {"a3": K.A3, "a4": K.A4, "a5": K.A5, "beta": K.BETA}


# ----------------------------------------------------------------------------- fitting

def true_geometry(world, arm: str, q3: float) -> dict:
    """The simulated arm's true axes and Table 4.1 quantities (world = mocap frame)."""
    base = world.arms[arm].spec.base
    T = {k: base @ v for k, v in K.frames(np.array([0.0, 0.0, q3])).items()}

    def line(f):
        return T[f][:3, 3], T[f][:3, 2]

    rcm = world.rcm_world(arm)
    P1, n1 = line("1")
    P2, n2 = line("2")
    P3, n3 = line("3")
    P4, n4 = line("4")
    u = T["6"][:3, 2]
    m = np.cross(n2, u)
    m /= np.linalg.norm(m)
    lengths = {"l1": distance_in_plane(P2, n2, P3, n3), "l2": distance_in_plane(rcm, n2, P4, n4),
               "l3": distance_in_plane(P3, n3, P4, n4), "l4": distance_in_plane(P2, n2, rcm, n2),
               "l12": common_perpendicular(P1, n1, P2, n2)[0], "l2'": float(abs((P4 - rcm) @ m))}
    axes = {"z1_yaw": n1, "z2_pitch": n2, "zR_rcm_pitch": n2, "z3": n3, "z4": n4, "insertion": u}
    return {"lengths": lengths, "axes": axes, "rcm": rcm}


def compare_truth(result: dict, truth: dict) -> dict:
    """Errors against the simulated truth: lengths (m), axis directions (deg), RCM (m)."""
    out = {"lengths": {k: result["lengths"][k]["value"] - v for k, v in truth["lengths"].items()},
           "axes_deg": {}}
    for k, n in truth["axes"].items():
        d = np.array(result["axes"][k]["direction"])
        # signs are the joints' senses: compare signed where the model's z is the positive
        # sense, unsigned for the passive joints whose z is by convention
        out["axes_deg"][k] = float(np.rad2deg(axis_angle(d, n)))
    out["rcm"] = float(np.linalg.norm(np.array(result["axes"]["rcm"]) - truth["rcm"]))
    return out


# ----------------------------------------------------------------------------- report

def report(result: dict) -> str:
    nom = result["nominal"]["lengths"]
    truth = result.get("truth", {}).get("lengths")
    lines = ["Table 4.1 quantities (m):",
             f"  {'':5} {'fitted':>10} {'+-':>8} {'nominal':>9}" + (f" {'truth':>9} {'error':>9}" if truth else "")]
    for k in ("l1", "l2", "l12", "l2'", "l3", "l4"):
        v = result["lengths"][k]
        row = f"  {k:5} {v['value']:10.5f} {v['std']:8.5f} {nom[k]:9.5f}"
        if truth:
            row += f" {truth[k]:9.5f} {(v['value'] - truth[k]) * 1e3:+8.3f}mm"
        lines.append(row)
    lines.append("DH lengths implied:")
    for k in ("a3", "a4", "a5", "beta"):
        v = result["dh"][k]
        unit = "rad" if k == "beta" else "m"
        lines.append(f"  {k:5} {v['value']:10.5f} {v['std']:8.5f} {result['nominal']['dh'][k]:9.5f} {unit}")
    if "truth" in result:
        err = result["truth"]["errors"]
        worst = max(err["axes_deg"].items(), key=lambda kv: kv[1])
        lines.append(f"simulated truth: worst length error {max(abs(e) for e in err['lengths'].values()) * 1e3:.3f} mm, "
                     f"worst axis direction error {worst[1]:.4f} deg ({worst[0]}), RCM {err['rcm'] * 1e3:.3f} mm")
    return "\n".join(lines)


def figures(result: dict, q1: Capture, q2: Capture, bodies: dict, path) -> None:
    """Pitch-plane picture: marker traces of the q2 sweep and the fitted axes, plus the
    fitted-minus-nominal lengths with their uncertainties."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = np.array(result["axes"]["z2_pitch"]["direction"])
    rcm = np.array(result["axes"]["rcm"])
    u = np.array(result["axes"]["insertion"]["direction"])
    e1 = u - (u @ n) * n
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)

    def proj(X):
        return np.stack([(X - rcm) @ e1, (X - rcm) @ e2], axis=-1)

    fig, (ax, bx) = plt.subplots(1, 2, figsize=(12, 5.5))
    for key, b in bodies.items():
        if b in q2.poses:
            X, _ = body_points(q2, b)
            P = proj(X.reshape(-1, 3))
            ax.plot(P[:, 0], P[:, 1], ".", ms=1, label=b)
    for key, mk in (("z2_pitch", "o"), ("zR_rcm_pitch", "s"), ("z3", "^"), ("z4", "v")):
        P = proj(np.array(result["axes"][key]["point"]))
        ax.plot(P[0], P[1], "k" + mk, ms=8)
        ax.annotate(key, P, textcoords="offset points", xytext=(6, 6))
    ax.plot([0, 0.25], [0, 0], "k--", lw=1)
    ax.set_aspect("equal")
    ax.set_xlabel("along the insertion axis at q2 = 0 (m)")
    ax.set_ylabel("in the pitch plane (m)")
    ax.set_title("q2 sweep: marker traces and fitted axes (pitch plane)")
    ax.legend(fontsize=7, markerscale=6)
    names = ["l1", "l2", "l12", "l2'", "l3", "l4"]
    ref = result.get("truth", {}).get("lengths") or result["nominal"]["lengths"]
    vals = [(result["lengths"][k]["value"] - ref[k]) * 1e3 for k in names]
    errs = [result["lengths"][k]["std"] * 1e3 for k in names]
    bx.errorbar(range(len(names)), vals, yerr=errs, fmt="o", capsize=4)
    bx.axhline(0, color="k", lw=0.8)
    for lim in (-0.3, 0.3):
        bx.axhline(lim, color="r", lw=0.6, ls=":")
    bx.set_xticks(range(len(names)), names)
    bx.set_ylabel("fitted - " + ("truth" if "truth" in result else "nominal") + " (mm)")
    bx.set_title("Table 4.1 quantities (1-sigma bars; dotted: 0.3 mm)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


# ----------------------------------------------------------------------------- procedure

def _symmetric_sweep(joint: int, span: float, passes: int, q3: float) -> list[np.ndarray]:
    goals = []
    for _ in range(passes):
        for s in (-1.0, 1.0):
            q = np.array([0.0, 0.0, q3])
            q[joint] = s * span
            goals.append(q)
    goals.append(np.array([0.0, 0.0, q3]))
    return goals


#: m: one-sigma uncertainty of a Table 4.1 length above which the fit has not measured it:
#: the thesis reports its lengths to the millimetre, and a sound sweep with sub-millimetre
#: marker noise gives a few tenths of a millimetre (bench_calibration_procedures).
LENGTH_STD_BOUND = 0.002


def missed_bound(result: dict) -> str | None:
    """Why the fitted lengths are not usable (an uncertainty not finite or above the
    bound), or None."""
    import math

    high = [f"{k} +-{v['std'] * 1e3:.2f} mm" if v.get("std") is not None and math.isfinite(v["std"]) else f"{k} (no std)"
            for k, v in result["lengths"].items()
            if not (v.get("std") is not None and math.isfinite(v["value"]) and v["std"] <= LENGTH_STD_BOUND)]
    if not high:
        return None
    return (f"length uncertainty {', '.join(high)} above {LENGTH_STD_BOUND * 1e3:g} mm: check the marker bodies' "
            "tracking (occlusion, loose bodies) and sweep again")


def run(cfg, parameters: dict, run_root=None, progress: bool = True) -> dict:
    """The procedure as a function (the CLI and the bench call it). Returns the result."""
    arm_name = parameters["arm"]
    seed = None if parameters["seed"] < 0 else parameters["seed"]
    if arm_name not in cfg.arms:
        raise InputError(f"no arm {arm_name!r} in {cfg.source}; arms: {', '.join(cfg.arms)}")
    dev = open_devices(cfg, seed=seed, arms=[arm_name])
    bodies = {k: f"{arm_name}_{v}" for k, v in BODY_SUFFIXES.items()}
    world_body = "world"
    q3h = parameters["q3"]
    try:
        with Run(PROCEDURE, parameters=parameters, config=cfg.snapshot(), seed=seed, steps=list(STEPS),
                 root=run_root, progress=progress) as run:
            arm = run.claim(dev.arms[arm_name])
            all_bodies = list(bodies.values()) + [world_body]
            with run.step(STEPS[0]):
                dev.person.confirm(f"Mount the marker bodies {', '.join(all_bodies)} and clear the "
                                   f"workspace of {arm_name}")
                dev.person.detach_object()
                arm.power_on()
                home = Collector("home", all_bodies)
                move_capture(dev, run, arm, [np.array([0.0, 0.0, q3h])], home)
            phases = {}
            for idx, (joint, span) in ((1, (0, parameters["q1_range"])), (2, (1, parameters["q2_range"]))):
                goals = _symmetric_sweep(joint, span, parameters["passes"] if joint == 1 else 1, q3h)
                col = Collector(f"q{joint + 1} sweep", all_bodies)
                with run.step(STEPS[idx], total=len(goals)) as st:
                    move_capture(dev, run, arm, goals, col, step=st)
                    settle(dev, run, col, [arm], 0.2)
                phases[joint] = col.capture()
            col = Collector("q3 stroke", all_bodies)
            # three strokes: the insertion direction's noise falls with the frames on it
            goals = [np.array([0.0, 0.0, q3h + f * parameters["q3_stroke"]]) for f in (1, 0) * 3]
            with run.step(STEPS[3], total=len(goals)) as st:
                move_capture(dev, run, arm, goals, col, step=st)
            phases[2] = col.capture()
            with run.step(STEPS[4]):
                fitted = fit_link_lengths(phases[0], phases[1], phases[2], arm_name, bodies, world_body)
            with run.step(STEPS[5]):
                result = {"arm": arm_name, **fitted,
                          "nominal": {"lengths": nominal_lengths(), "dh": nominal_dh()},
                          "frames": {c.name: c.n for c in phases.values()},
                          "bodies": bodies, "world_body": world_body,
                          "tracker": tracker_stats(dev.tracker)}
                if dev.world is not None:
                    truth = true_geometry(dev.world, arm_name, q3h)
                    result["truth"] = {"lengths": truth["lengths"],
                                       "errors": compare_truth(result, truth)}
            with run.step(STEPS[6]):
                figures(result, phases[0], phases[1], bodies, run.dir / "link_lengths.png")
                result.pop("_W2", None)
                result["plot"] = str(run.dir / "link_lengths.png")
                result["summary"] = {k: v["value"] for k, v in result["lengths"].items()}
                result["provenance"] = provenance.live(cfg, [arm_name], run.dir)
                missed = missed_bound(result)
                run.finish(result, "failed" if missed else "completed", missed)
    finally:
        dev.close()
    return run.result


@procedure_command(PROCEDURE, STEPS, PARAMETERS)
def command(ctx, parameters, as_json: bool) -> None:
    """Joint axes and link lengths of a PSM from motion capture (thesis 4.1.1, A.1).

    Sweeps q1 (q2 = 0), q2 (q1 = 0) and a q3 stroke, fits each joint axis between pairs
    of marker bodies (Gamage-Lasenby plain and bias-compensated, SARA for the
    parallelogram's passive joints) and reports Table 4.1's l1, l2, l12, l2', l3, l4 and
    the DH lengths they imply, in m with 1-sigma uncertainties. Saves result.json and
    link_lengths.png in the run folder.
    """
    cfg = config_from_context(ctx)
    try:
        result = run(cfg, parameters)
    except FitError as exc:
        where = f" (run folder {exc.run_dir})" if getattr(exc, "run_dir", None) else ""
        click.echo(f"rig {PROCEDURE}: refused: {exc}{where}", err=True)
        sys.exit(1)
    emit_result(result, as_json, report(result) + f"\nrun folder: {result['run_dir']}")
    exit_for_status(PROCEDURE, result)
