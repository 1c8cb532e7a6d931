"""`rig estimate-force`: the force at a PSM's tool tip over a recording, from its joints,
efforts and identified model alone (issue 47).

    rig estimate-force --csv FILE --model MODEL.json [--rate 200] [--bandwidth 5] [--json]
    rig estimate-force RUN [--arm PSM1] [--model MODEL.json]

Input: a CSV in the WPI joint-state format (q, dq, tau of n joints, grouped by quantity:
3n columns, no header; the PSM's 21 columns at 200 Hz; joints 1-3 are used), or a recorded
run (its /<arm>/measured_js resampled to --rate). The model file is any `rig identify` or
`rig discrepancy` model.json: its standard parameters, friction and effects; a run
without --model takes the nominal model (the simulated rig's plant).

The estimate (`calibration.momentum_observer`, `calibration.tip_force`): a generalized-
momentum observer (bandwidth --bandwidth, its only filter; no acceleration is used) gives
the external joint torque, J^-T maps it to the tip in the arm's base frame 0. Its spread
comes from the model file's held-out RMS error per joint; samples where joint 3 is slower
than 5 mm/s (static friction band), a joint is at a limit or the Jacobian is near singular
are flagged.

Writes force.csv (t, Fx, Fy, Fz in N, base frame; their spread; the flags), force.png and
result.json to its run folder. `--json`: ``mean_force`` (N, base frame), ``mean_magnitude``
(N, the norm of that vector), ``spread`` (standard deviation per axis over time, N),
``sigma_model`` (the model's median spread per axis, N), the flagged shares, and the same on
the unflagged samples.

Units: SI (m, N, rad, s, Hz).
"""

from __future__ import annotations

import sys
from pathlib import Path

import click
import numpy as np

from rig.commands.exit_codes import EXIT_INPUT
from rig.commands.parameters import Parameter
from rig.commands.procedure import procedure_command
from rig.commands.report import emit_result
from rig.runs.run import Run

PROCEDURE = "estimate-force"
STEPS = ("load the recording and the model", "estimate the tip force", "write, plot and report")

PARAMETERS = [
    Parameter("model", "", "", "Model file (model.json of `rig identify` or `rig discrepancy`); a RUN without it "
              "takes the nominal model", type=str),
    Parameter("csv", "", "", "Recording in the WPI CSV format (q1..qn, dq1..dqn, tau1..taun: rad|m, rad/s|m/s, "
              "N m|N) instead of RUN", type=str),
    Parameter("rate", 200.0, "Hz", "Sampling rate of the CSV rows; a run's samples are resampled to it",
              minimum=20.0, maximum=5000.0),
    Parameter("joints", 7, "", "Joints in each group of the CSV (the PSM's 7; joints 1-3 are used)", minimum=3,
              maximum=7, type=int),
    Parameter("arm", "PSM1", "", "Arm whose /<arm>/measured_js a RUN provides", type=str),
    Parameter("bandwidth", 3.0, "Hz", "Bandwidth of the momentum observer (its first-order filter)",
              minimum=0.2, maximum=50.0),
    Parameter("plots", True, "", "Write force.png (the force per axis over time, its spread, the flags)", type=bool),
]


def checked_model(parameters: dict):
    """The --model file (or None), checked: a friction-only file or a bad effect entry is one line."""
    from rig.model.model_file import load_model

    if not parameters["model"]:
        return None
    model = load_model(parameters["model"])
    model.dynamics()
    _ = model.effects
    return model


def check_csv(parameters: dict) -> None:
    from calibration.datasets import DataError

    path = Path(parameters["csv"])
    if not path.is_file():
        raise DataError(f"{path}: {'is a folder, not a CSV file' if path.is_dir() else 'no such file'}: give a "
                        "CSV in the WPI format (q1..qn, dq1..dqn, tau1..taun)")


def load(parameters: dict, run_dir: str | None):
    """(q, dq, tau (n, 3), rate, source) of --csv or RUN; errors are one line."""
    from calibration.datasets import DataError, load_csv

    rate = parameters["rate"]
    if parameters["csv"]:
        data = load_csv(parameters["csv"], rate, parameters["joints"])
        return data.q[:, :3], data.dq[:, :3], data.tau[:, :3], rate, str(parameters["csv"])
    from mcap.exceptions import McapError

    from rig.runs.recorded_joints import load_run_arrays

    try:
        q, dq, tau, source = load_run_arrays(run_dir, parameters["arm"], rate)
    except (OSError, ValueError, McapError) as exc:
        raise DataError(f"{run_dir}: cannot read /{parameters['arm']}/measured_js from its recording "
                        f"({type(exc).__name__}: {exc})") from None
    return q, dq, tau, rate, source


def summary(forces, flags_names) -> dict:
    """The figures of a `calibration.tip_force.RecordingForces`."""
    F = forces.force
    clean = ~forces.flags.any(axis=1)

    def block(mask) -> dict:
        if not mask.any():
            return {"samples": 0}
        m = F[mask].mean(axis=0)
        return {"samples": int(mask.sum()), "mean_force": m.tolist(), "mean_magnitude": float(np.linalg.norm(m)),
                "spread": F[mask].std(axis=0).tolist(),
                "rms_magnitude": float(np.sqrt(np.mean(np.sum(F[mask] ** 2, axis=1))))}

    out = block(np.ones(len(F), bool))
    out["sigma_model"] = (np.nanmedian(forces.sigma, axis=0).tolist() if np.isfinite(forces.sigma).any() else None)
    out["flagged_share"] = {name: float(forces.flags[:, i].mean()) for i, name in enumerate(flags_names)}
    out["unflagged"] = block(clean)
    return out


def write_csv(path: Path, forces, flag_names) -> None:
    head = "t,Fx,Fy,Fz,sigma_x,sigma_y,sigma_z," + ",".join(flag_names)
    table = np.column_stack([forces.t, forces.force, forces.sigma, forces.flags.astype(int)])
    np.savetxt(path, table, delimiter=",", header=head, comments="",
               fmt=["%.4f"] + ["%.6g"] * 6 + ["%d"] * len(flag_names))


def figures(path: Path, forces, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(3, 1, figsize=(12, 8), sharex=True)
    flagged = forces.flags.any(axis=1)
    for i, (ax, name) in enumerate(zip(axes, "xyz")):
        f, s = forces.force[:, i], forces.sigma[:, i]
        ax.plot(forces.t, f, "k-", lw=0.8, label="estimate")
        if np.isfinite(s).any():
            ax.fill_between(forces.t, f - s, f + s, color="tab:blue", alpha=0.2, lw=0, label="+-1 spread (model)")
        ax.fill_between(forces.t, 0, 1, where=flagged, transform=ax.get_xaxis_transform(), color="tab:red",
                        alpha=0.08, lw=0, label="flagged")
        ax.set_ylabel(f"F{name} [N]")
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper right", fontsize=8, ncol=3)
    axes[-1].set_xlabel("time [s]")
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def report(result: dict) -> str:
    def vec(v):
        return "(" + ", ".join(f"{x:+.3f}" for x in v) + ")"

    lines = [f"rig estimate-force: {result['data']['source']} ({result['data']['samples']} samples at "
             f"{result['data']['rate_hz']:g} Hz)",
             f"model: {result['model']['path']} ({result['model']['note']})",
             f"observer: generalized momentum, bandwidth {result['estimator']['bandwidth_hz']:g} Hz; spread from "
             f"{result['estimator']['sigma_source']}",
             f"mean force (base frame) {vec(result['mean_force'])} N, magnitude {result['mean_magnitude']:.3f} N; "
             f"spread over time {vec(result['spread'])} N",
             "flagged: " + ", ".join(f"{k} {100 * v:.1f} %" for k, v in result["flagged_share"].items())]
    u = result["unflagged"]
    if u.get("samples"):
        lines.append(f"unflagged samples ({u['samples']}): mean {vec(u['mean_force'])} N, magnitude "
                     f"{u['mean_magnitude']:.3f} N")
    if result.get("sigma_model"):
        lines.append(f"model's spread (median per axis) {vec(result['sigma_model'])} N")
    lines.append(f"force over time: {result['files']['csv']}")
    return "\n".join(lines)


def run(parameters: dict, run_dir: str | None = None, run_root=None, progress: bool = True) -> dict:
    from calibration.tip_force import FLAGS, estimate_recording, heldout_sigma
    from rig.model.psm_dynamics import PSMDynamics

    """Estimate; the named files are checked first (a missing or unusable model file, CSV or
    run folder records no run), then the run is recorded. Returns the result."""
    model = checked_model(parameters)
    if parameters["csv"]:
        check_csv(parameters)
    else:
        from rig.runs.recorded_run import resolve_run

        run_dir = str(resolve_run(str(run_dir)))
    with Run(PROCEDURE, parameters=parameters, config=None, steps=list(STEPS), root=run_root,
             progress=progress) as rn:
        with rn.step(STEPS[0]):
            q, dq, tau, rate, source = load(parameters, run_dir)
        with rn.step(STEPS[1]):
            if model is None:
                dyn, effects, stick, sigma = PSMDynamics(), [], None, None
                model_doc = {"path": None, "note": "nominal model (no --model): the simulated rig's plant"}
                sigma_source = "none (the nominal model has no held-out figures)"
            else:
                dyn, effects, stick = model.dynamics(), model.effects, model.stick_slip()
                sigma, sigma_source = heldout_sigma(model)
                model_doc = {"path": str(model.path), "note": (", ".join(f"{e['name']}@{e['joint']}" for e in effects)
                                                                or "no effects")}
            forces = estimate_recording(dyn, effects, q, dq, tau, rate, 2 * np.pi * parameters["bandwidth"],
                                        sigma, stick)
        with rn.step(STEPS[2]):
            result = summary(forces, FLAGS)
            result["model"] = model_doc
            result["data"] = {"source": source, "samples": int(len(q)), "rate_hz": rate}
            result["estimator"] = {"kind": "generalized-momentum observer", "bandwidth_hz": parameters["bandwidth"],
                                   "sigma_source": sigma_source, "frame": "the arm's base frame 0",
                                   "flags": list(FLAGS)}
            path = rn.dir / "force.csv"
            write_csv(path, forces, FLAGS)
            result["files"] = {"csv": str(path)}
            if parameters["plots"]:
                png = rn.dir / "force.png"
                figures(png, forces, f"tip force estimate: {source}")
                result["files"]["png"] = str(png)
            result["summary"] = {"mean_magnitude": round(result["mean_magnitude"], 4)}
            rn.finish(result)
    return rn.result


@procedure_command(PROCEDURE, STEPS, PARAMETERS, steps_help="List the steps and exit.", yes=False, context=False)
@click.argument("run_dir", required=False)
def command(run_dir, parameters, as_json: bool) -> None:
    """The force at the tool tip over a recording (RUN or --csv FILE), from the arm's joints,
    efforts and model: momentum observer, J^-T, in the arm's base frame (N). Writes force.csv
    and force.png to the run folder; --json gives mean_force (N, base frame), mean_magnitude
    (N) and the spread (N). Units: SI (m, N, rad, s, Hz).
    """
    def usage(line: str) -> None:
        click.echo(f"rig {PROCEDURE}: {line} (rig {PROCEDURE} --help)", err=True)
        sys.exit(2)

    if bool(run_dir) == bool(parameters["csv"]):
        usage("give either RUN or --csv FILE, not both" if run_dir else "give either RUN or --csv FILE")
    if parameters["csv"] and not parameters["model"]:
        usage("a CSV needs the arm's model: give --model FILE")
    from calibration.datasets import DataError
    from rig.model.model_file import ModelFileError
    from rig.runs.recorded_run import ExportError

    try:
        result = run(parameters, run_dir)
    except (DataError, ModelFileError, ExportError) as exc:
        where = f" (run folder {exc.run_dir})" if getattr(exc, "run_dir", None) else ""
        click.echo(f"rig {PROCEDURE}: {exc}{where}", err=True)
        sys.exit(EXIT_INPUT)
    emit_result(result, as_json, report(result))
