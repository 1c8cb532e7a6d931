"""`rig validate`: how well a model file predicts the efforts of a recording, effects included (issue 26).

The number by which users compare models.

    rig validate --model MODEL.json (RUN_DIR | --csv FILE [--rate 200] [--joints 3])
                 [--compare MODEL2.json] [--block all|heldout] [--json]

Input: a recorded run (its /<arm>/measured_js, resampled to --rate, as `rig export` writes
it) or a CSV in the WPI format (q1..qn, dq1..dqn, tau1..taun; the options of `rig identify
--csv`). The model file is any `rig identify` or `rig discrepancy` model.json: its standard
parameters, friction (with the Stribeck excess when it has one) and its ``effects`` list,
the stateful ones (hysteresis) run through the recording in time order as the controller's
feedforward runs them (`calibration.prediction`).

Figures per joint, on the samples where the joint moves, both efforts zeroed where it is
stuck and low-passed with the same zero-phase Butterworth (10 Hz, order 4) as
`rig discrepancy` does: relative error norm(tau - pred) / norm(tau) and RMS of tau - pred
(N m, N m, N), on the whole recording (ends trimmed by the filter's settling) and on the
held-out block at its end (the last --heldout fraction). For a model without effects and
without a Stribeck excess the held-out figures are those `rig discrepancy --model M`
reports as its baseline on the same recording. --block chooses which block's figures are
the result's top-level ``relative_error`` and ``rms``; the report shows both.

Writes result.json and efforts.png (measured against predicted per joint) to its run folder.

Units: SI (rad, m, rad/s, m/s, N m, N, s, Hz); the effort lag in ms.
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

PROCEDURE = "validate"
STEPS = ("load the recording", "predict the efforts", "compare, plot and report")

PARAMETERS = [
    Parameter("model", "", "", "Model file (model.json of `rig identify` or `rig discrepancy`) whose efforts are "
              "predicted, effects included", type=str),
    Parameter("compare", "", "", "A second model file, predicted on the same recording and shown side by side",
              type=str),
    Parameter("csv", "", "", "Recording in the WPI CSV format (q1..qn, dq1..dqn, tau1..taun: rad|m, rad/s|m/s, "
              "N m|N) instead of RUN_DIR", type=str),
    Parameter("rate", 200.0, "Hz", "Sampling rate of the CSV rows; a run's samples are resampled to it",
              minimum=20.0, maximum=5000.0),
    Parameter("joints", 3, "", "Joints used from the CSV (the model has joints 1-3)", minimum=3, maximum=3, type=int),
    Parameter("time_column", False, "", "The CSV's first column is the sample time (s), followed by the 3n WPI "
              "columns; the rows are resampled to --rate", type=bool),
    Parameter("arm", "PSM1", "", "Arm whose /<arm>/measured_js a RUN_DIR provides", type=str),
    Parameter("block", "all", "", "Block whose figures are the result's relative_error and rms: the whole "
              "recording or the held-out block at its end", type=str, choices=("all", "heldout")),
    Parameter("heldout", 0.25, "", "Fraction of the recording in the held-out block at its end (as `rig "
              "discrepancy`)", minimum=0.1, maximum=0.5),
    Parameter("cutoff", 10.0, "Hz", "Cut-off of the zero-phase Butterworth filter applied to both efforts",
              minimum=1.0, maximum=50.0),
    Parameter("effort_lag", 1.0, "ms", "How much earlier than its sample the reported effort was computed (one "
              "servo period); under one sample", minimum=0.0, maximum=4.0),
    Parameter("plots", True, "", "Write efforts.png (measured against predicted per joint)", type=bool),
]

#: Effort units of joints 1-3.
UNITS = ("N m", "N m", "N")


def load_recording(parameters: dict, run_dir: str | None):
    """(q, dq, tau (n, 3), rate, source) of --csv or RUN_DIR; errors are one line."""
    from calibration.datasets import DataError, load_csv

    rate = parameters["rate"]
    if parameters["csv"]:
        if parameters["time_column"]:
            from calibration.datasets import load_timed_csv

            data = load_timed_csv(parameters["csv"], rate, parameters["joints"])
        else:
            data = load_csv(parameters["csv"], rate, parameters["joints"])
        return data.q, data.dq, data.tau, rate, str(parameters["csv"])
    from mcap.exceptions import McapError

    from rig.runs.recorded_joints import load_run_arrays

    try:
        q, dq, tau, source = load_run_arrays(run_dir, parameters["arm"], rate)
    except (OSError, ValueError, McapError) as exc:
        raise DataError(f"{run_dir}: cannot read its recording ({type(exc).__name__}: {exc})") from None
    if q.shape[1] < 3:
        raise DataError(f"{source}: {q.shape[1]} joints recorded; the model needs joints 1-3")
    return q, dq, tau, rate, source


def _procedure_of(m) -> str | None:
    """The procedure that wrote a model file: its provenance's, else its run folder's name."""
    from rig.runs.paths import procedure_of
    from rig.runs.paths import run_time

    prov = m.provenance
    if prov.get("procedure"):
        return str(prov["procedure"])
    source = prov.get("source")
    run = Path(source["run"]) if isinstance(source, dict) and source.get("run") else Path(m.path).parent
    return procedure_of(run) or None if run_time(run) is not None else None


def _model_doc(m, prediction) -> dict:
    return {"path": str(m.path), "kind": m.kind, "procedure": _procedure_of(m),
            "data_source": m.provenance.get("data_source"), "effects": prediction.effects,
            "stribeck": prediction.stribeck, "friction_slope": m.slope, "gravity": m.gravity.tolist(),
            "inertia_source": prediction.inertia_source, "notes": prediction.notes,
            "prediction_seconds": prediction.seconds}


def _figures(prediction, block: str) -> dict:
    blocks = {b: prediction.figures(b) for b in ("all", "heldout")}
    return {"relative_error": blocks[block]["relative_error"], "rms": blocks[block]["rms"], "block": block,
            "blocks": blocks}


def figures(predictions: list, labels: list[str], path: Path) -> None:
    """Measured against predicted effort per joint on the moving samples (stuck samples
    left as gaps), the held-out block shaded."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ref = predictions[0]
    t = ref.t
    ho = ref.blocks["heldout"]
    fig, axes = plt.subplots(3, 1, figsize=(12, 9), sharex=True)
    for j, ax in enumerate(axes):
        gap = ~ref.moving[:, j]
        ax.plot(t, np.where(gap, np.nan, ref.measured[:, j]), "k-", lw=1.0, label="measured")
        errors = []
        for pr, label, colour in zip(predictions, labels, ("tab:blue", "tab:orange")):
            ax.plot(t, np.where(gap, np.nan, pr.predicted[:, j]), "-", color=colour, lw=0.9, alpha=0.85,
                    label=label)
            f_all, f_ho = pr.figures("all"), pr.figures("heldout")
            errors.append(f"{label.split()[0]} {f_all['relative_error'][j]:.3f} "
                          f"(held-out {f_ho['relative_error'][j]:.3f})")
        ax.axvspan(t[ho.start], t[ho.stop - 1], color="0.9", zorder=0, label="held-out block")
        ax.set_title(f"joint {j + 1}: relative error " + ", ".join(errors), fontsize=9)
        ax.set_ylabel(f"effort joint {j + 1} [{UNITS[j]}]")
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel("time [s]")
    handles, names = axes[0].get_legend_handles_labels()
    fig.legend(handles, names, loc="upper center", ncol=len(names), fontsize=8, frameon=False)
    fig.suptitle("measured and predicted efforts, low-passed alike (gaps: joint stuck)", y=0.965, fontsize=11)
    fig.tight_layout(rect=(0, 0, 1, 0.95))
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _fmt(values, digits: int = 4) -> str:
    return " / ".join("-" if v is None or not np.isfinite(v) else f"{v:.{digits}f}" for v in values)


def report(result: dict) -> str:
    data = result["data"]
    lines = [f"rig validate: {data['source']} ({data['samples']} samples at {data['rate_hz']:g} Hz)"]
    models = [("A", result["model"])] + ([("B", result["compare"]["model"])] if "compare" in result else [])
    for tag, m in models:
        eff = ", ".join(f"{e['name']}@{e['joint']}" for e in m["effects"]) or "none"
        extra = "; Stribeck excess" if m["stribeck"] else ""
        lines.append(f"model {tag}: {m['path']} ({m['kind']}{', ' + m['procedure'] if m['procedure'] else ''}; "
                     f"effects: {eff}{extra})")
    lines.append("figures on the moving samples, both efforts low-passed alike:")
    lines.append(f"  {'block':<36} {'':2}  {'relative error j1 / j2 / j3':<28}  RMS j1 [N m] / j2 [N m] / j3 [N]")
    sources = [("A", result)] + ([("B", result["compare"])] if "compare" in result else [])
    for block in ("all", "heldout"):
        f0 = result["blocks"][block]
        name = (f"whole recording (samples {f0['samples'][0]}-{f0['samples'][1]})" if block == "all" else
                f"held-out block (samples {f0['samples'][0]}-{f0['samples'][1]})")
        for i, (tag, src) in enumerate(sources):
            f = src["blocks"][block]
            mark = "*" if block == result["block"] else " "
            lines.append(f"{mark} {name if i == 0 else '':<36} {tag:2}  {_fmt(f['relative_error']):<28}  "
                         f"{_fmt(f['rms'])}")
    if "compare" in result:
        rel_a = np.array(result["relative_error"], float)
        rel_b = np.array(result["compare"]["relative_error"], float)
        better = ["A" if a < b else "B" if b < a else "=" for a, b in zip(rel_a, rel_b)]
        lines.append(f"better per joint ({'whole recording' if result['block'] == 'all' else 'held-out block'}): "
                     + " / ".join(better))
    lines.append("  (* the block of the result's relative_error and rms, --block " + result["block"] + ")")
    for tag, m in models:
        lines.append(f"model {tag}: inertial term per joint from the {', '.join(m['inertia_source'])} acceleration; "
                     f"prediction {m['prediction_seconds']:.2f} s")
        for e in m["effects"]:
            lines.append(f"    {e['name']}@{e['joint']}: {e['use']}")
        for note in m["notes"]:
            lines.append(f"    {note}")
    if result.get("plots"):
        lines.append("plot: " + ", ".join(result["plots"].values()))
    return "\n".join(lines)


def run(parameters: dict, run_dir: str | None = None, run_root=None, progress: bool = True) -> dict:
    """Validate; the named files are checked first (a missing or unreadable model file, CSV
    or run folder records no run), then the run is recorded. Returns the result."""
    from calibration.datasets import DataError
    from calibration.discrepancy.settings import Settings
    from calibration.prediction import predict
    from rig.model.model_file import load_model
    from rig.runs.recorded_run import resolve_run

    settings = Settings(cutoff=parameters["cutoff"], heldout=parameters["heldout"],
                        effort_lag=parameters["effort_lag"] * 1e-3)
    models = [load_model(parameters["model"])]
    if parameters["compare"]:
        models.append(load_model(parameters["compare"]))
    for m in models:
        m.dynamics()        # raises for a friction-only file: it has no efforts to predict
        _ = m.effects       # raises for an entry that is no catalogue effect on joints 1-3
    if parameters["csv"]:
        if not Path(parameters["csv"]).is_file():
            what = "is a folder, not a CSV file" if Path(parameters["csv"]).is_dir() else "no such file"
            raise DataError(f"{parameters['csv']}: {what}: give a CSV in the WPI format (q1..qn, dq1..dqn, "
                            "tau1..taun)")
    else:
        run_dir = str(resolve_run(str(run_dir)))
    with Run(PROCEDURE, parameters=parameters, config=None, steps=list(STEPS), root=run_root,
             progress=progress) as rn:
        with rn.step(STEPS[0]):
            q, dq, tau, rate, source = load_recording(parameters, run_dir)
        with rn.step(STEPS[1]):
            predictions = [predict(m, q, dq, tau, rate, settings, source) for m in models]
        with rn.step(STEPS[2]):
            block = parameters["block"]
            result = {**_figures(predictions[0], block), "model": _model_doc(models[0], predictions[0])}
            if len(models) > 1:
                result["compare"] = {**_figures(predictions[1], block), "model": _model_doc(models[1], predictions[1])}
            result["data"] = {"source": source, "samples": int(q.shape[0]), "rate_hz": rate}
            result["settings"] = {"cutoff_hz": settings.cutoff, "filter_order": settings.order,
                                  "heldout_fraction": settings.heldout, "effort_lag_s": settings.effort_lag,
                                  "figures": "per joint on the moving samples; relative error norm(tau - pred) / "
                                             "norm(tau), RMS of tau - pred in N m, N m, N"}
            summary = {"block": block, "relative_error": _fmt(result["relative_error"], 3)}
            if "compare" in result:
                summary["compare"] = _fmt(result["compare"]["relative_error"], 3)
            result["summary"] = summary
            if parameters["plots"]:
                path = rn.dir / "efforts.png"
                labels = ["A " + Path(models[0].path).parent.name] + (
                    ["B " + Path(models[1].path).parent.name] if len(models) > 1 else [])
                figures(predictions, labels, path)
                result["plots"] = {"efforts.png": str(path)}
            rn.finish(result)
    return rn.result


@procedure_command(PROCEDURE, STEPS, PARAMETERS, steps_help="List the steps and exit.", yes=False, context=False)
@click.argument("run_dir", required=False)
def command(run_dir, parameters, as_json: bool) -> None:
    """Predict the efforts of a recording (RUN_DIR or --csv FILE) from a model file, effects
    included, and report how well it does: per joint the relative error (dimensionless) and
    the RMS of measured minus predicted effort (N m for joints 1-2, N for joint 3), on the
    whole recording and on its held-out last block; --compare FILE2 side by side. Writes
    result.json and efforts.png to the run folder. Units: SI (rad, m, rad/s, m/s, N m, N, s,
    Hz).
    """

    def usage(line: str) -> None:
        click.echo(f"rig {PROCEDURE}: {line} (rig {PROCEDURE} --help)", err=True)
        sys.exit(2)

    if not parameters["model"]:
        usage("give the model file to validate with --model FILE")
    if bool(run_dir) == bool(parameters["csv"]):
        usage("give either RUN_DIR or --csv FILE, not both" if run_dir else "give either RUN_DIR or --csv FILE")
    from calibration.datasets import DataError
    from calibration.discrepancy.settings import DiscrepancyError
    from calibration.prediction import PredictionError
    from calibration.signals import SignalError
    from rig.model.model_file import ModelFileError
    from rig.runs.recorded_run import ExportError

    try:
        result = run(parameters, run_dir)
    except (DataError, SignalError, DiscrepancyError, PredictionError, ModelFileError, ExportError) as exc:
        text = exc.format_message() if isinstance(exc, click.ClickException) else str(exc)
        where = f" (run folder {exc.run_dir})" if getattr(exc, "run_dir", None) else ""
        click.echo(f"rig {PROCEDURE}: {text}{where}", err=True)
        sys.exit(EXIT_INPUT)  # the recording or the model named cannot be used
    emit_result(result, as_json, report(result))
