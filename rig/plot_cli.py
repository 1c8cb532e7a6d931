"""`rig plot RUN`: draw a run's figures again from its recording, aborted runs included.

Every run gets time-series figures of every recorded stream (rig.runs.stream_figures); a
cooperative run also gets its own figures (procedures.cooperative_figures: tension and
tips, Cartesian tracking) and its tracking numbers, up to where it stopped. The CLI layer
may import a procedure's figure module; procedures never import this.
"""

from __future__ import annotations

from pathlib import Path

import click

from rig.commands.exit_codes import InputError
from rig.commands.options import json_option
from rig.commands.report import emit_result
from rig.runs.recorded_run import read_run, resolve_run

PLOT_HELP = """Draw a run's figures again from its recording (run.mcap), aborted runs included.

\b
RUN is a run folder or its name under ./logs ($RIG_LOGS); `rig runs` lists them.
Writes PNG files into the run folder (or --out DIR), replacing those of the same name:
\b
  every run    plot-<arm>-joints.png  (position, velocity, effort per joint;
               rad or m, rad/s or m/s, N m or N), plot-<group>-poses.png (mm),
               plot-forces.png (N), plot-signals.png (set-points, timings)
  cooperative  cooperative.png (tips x, y, z in the world frame, tension and
               set-point, error F - F_d) and cooperative-tracking.png (each tip
               against its plan, and the error, mm), with the tracking numbers
\b
A run that did not end (aborted, unfinished) is drawn up to its last sample, marked
by a dotted red line.
"""


def _status(rec) -> tuple[str, str]:
    """(status, how a run cut short ended or "") from the recording's stop record."""
    stop = rec.stop or {}
    status = stop.get("status") or "unfinished"
    if status in ("completed", "failed", "dry-run"):
        return status, ""
    error = stop.get("error") or (rec.problem if status == "unfinished" else "")
    return status, f"{status}: {error}" if error else status


def plot_run(run: str | Path, out: Path | None = None) -> dict:
    """Draw the figures of a run; returns what was written (and notes)."""
    from rig.runs.stream_figures import stream_figures

    run_dir = resolve_run(str(run))
    rec = read_run(run_dir)
    out_dir = Path(out) if out is not None else run_dir
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError(f"--out {out_dir} is a file: give a folder (it is created if missing)")
    out_dir.mkdir(parents=True, exist_ok=True)
    status, stopped = _status(rec)
    procedure = (rec.start or {}).get("procedure") or run_dir.name.split("-", 1)[-1]
    title = f"{run_dir.name} ({stopped or status})"
    if len(title) > 110:
        title = title[:107] + "..."
    notes: list[str] = []
    figures: list[Path] = []
    summary: dict = {"run_dir": str(run_dir), "procedure": procedure, "status": status, "out": str(out_dir)}
    if rec.problem and status != "unfinished":
        notes.append(f"{rec.path}: {rec.problem}; drawn from the samples it holds")
    if procedure == "cooperative":
        from procedures import cooperative_figures as cf

        try:
            trace = cf.trace_from_recording(rec, title)
        except cf.FigureDataError as exc:
            notes.append(f"no cooperative figures: {exc}")
        else:
            figures.append(cf.draw_force_figure(trace, out_dir / "cooperative.png"))
            tracked = cf.draw_tracking_figure(trace, out_dir / "cooperative-tracking.png")
            if tracked is None:
                notes.append("no Cartesian tracking figure: this recording holds no /<arm>/measured_cp and "
                             "/<arm>/setpoint_cp (recorded before the cooperative loop recorded its tips)")
            else:
                figures.append(tracked)
                summary["cartesian_tracking"] = cf.cartesian_tracking(trace)
    streams, skipped = stream_figures(rec, out_dir, title, stopped)
    figures += streams
    notes += [f"not drawn: {s}" for s in skipped]
    if not figures:
        raise InputError(f"{rec.path} holds no samples to draw (status {status}: a dry run, or a run "
                                   "stopped before it recorded any); 'rig runs RUN' shows how it ended")
    summary["figures"] = [str(p) for p in figures]
    summary["notes"] = notes
    return summary


@click.command("plot", help=PLOT_HELP)
@click.argument("run")
@click.option("--out", "out_dir", type=click.Path(file_okay=False), default=None,
              help="Folder for the figures (created if missing) [default: the run folder].")
@json_option
def plot_command(run: str, out_dir: str | None, as_json: bool) -> None:
    summary = plot_run(run, Path(out_dir) if out_dir else None)
    lines = [f"note: {n}" for n in summary["notes"]]
    if summary.get("cartesian_tracking"):
        from procedures.cooperative_figures import tracking_lines

        lines += [line[2:] for line in tracking_lines(summary["cartesian_tracking"])]
    lines += [f"wrote {p}" for p in summary["figures"]]
    lines.append(f"{len(summary['figures'])} figures of {summary['run_dir']} ({summary['status']}) "
                 f"in {summary['out']}")
    emit_result(summary, as_json, "\n".join(lines))
