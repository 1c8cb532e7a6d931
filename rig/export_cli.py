"""`rig export`: a run's recorded streams as CSV files a lab loads next.

Two forms:

- `--out DIR`: every recorded topic (or the `--topic`s named, or one `--arm`'s) as one CSV
  file per topic, `DIR/<topic with "." for "/">.csv` (`PSM1.measured_js.csv`,
  `loadcell.force.csv`), every sample as recorded: a header row, then `t` (s, run clock)
  and one column per numeric field of the message (rig.runs.topic_tables). `pandas.read_csv`
  reads each as it is.
- `--csv FILE`: an arm's JointState in the format of the WPI dVRK identification data
  (`data/wpi-psm/`): no header, comma separated, one row per sample on a uniform time grid
  (--rate), columns grouped by quantity: q1..qn | dq1..dqn | tau1..taun for the n joints in
  the recorded JointState messages (rad or m; rad/s or m/s; N m or N).
"""

from __future__ import annotations

from pathlib import Path

import click
import numpy as np

from rig.commands.options import json_option
from rig.commands.report import emit_result
from rig.runs.recorded_run import ExportError, joint_arrays, read_run, resample, resolve_run, unfinalised_warning
from rig.runs.recording import Recording
from rig.runs.topic_tables import TopicError, csv_name, topic_table, write_csv
from rig.sealed_json import result_json


def export_csv(run: str | Path, out: Path, arm: str = "PSM1", rate: float = 200.0,
               topic: str | None = None) -> dict:
    """Write the arm's q | dq | tau at `rate` Hz; returns what was written (and warnings)."""
    run_dir = resolve_run(str(run))
    topic = topic or f"/{arm}/measured_js"
    rec = read_run(run_dir, topics=[topic])
    warnings = unfinalised_warning(rec)
    t, q, dq, tau = joint_arrays(rec, topic)
    n = q.shape[1]
    if n == 0:
        raise ExportError(f"{topic} carries no joint positions")
    _, table = resample(t, np.hstack((q, dq, tau)), rate)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    np.savetxt(out, table, fmt="%.17g", delimiter=",")
    return {"csv": str(out), "topic": topic, "rows": table.shape[0], "joints": n,
            "rate_hz": rate, "samples": len(t), "t_start": float(t[0]), "t_end": float(t[-1]),
            "warnings": warnings}


# ---------------------------------------------------------------------- --out (every topic)
def _selected(rec: Recording, topics: tuple[str, ...], arm: str | None) -> list[str]:
    known = sorted(rec.schemas)
    if topics:
        for topic in topics:
            if topic not in rec.schemas:
                raise ExportError(f"no topic {topic} in {rec.path}; its topics: {', '.join(known) or 'none'}")
        chosen = list(dict.fromkeys(topics))
    else:
        chosen = known
    if arm is not None:
        prefix = f"/{arm}/"
        chosen = [t for t in chosen if t.startswith(prefix)]
        if not chosen:
            arms = sorted({t.split("/")[1] for t in known if t.count("/") >= 2})
            raise ExportError(f"no topic of {arm} in {rec.path}"
                              + (f" among {', '.join(topics)}" if topics else "")
                              + f"; arms and groups recorded: {', '.join(arms) or 'none'}")
    return chosen


def export_topics(run: str | Path, out_dir: Path, topics: tuple[str, ...] = (), arm: str | None = None) -> dict:
    """One CSV per topic into `out_dir` (every topic, or those named, or one arm's).

    A topic named in `topics` that cannot be exported is an ExportError; when exporting
    every topic, such a topic is skipped and named in the warnings."""
    run_dir = resolve_run(str(run))
    rec = read_run(run_dir, topics=list(topics) if topics else None)
    chosen = _selected(rec, tuple(topics), arm)
    if not chosen:
        raise ExportError(f"{rec.path} recorded no streams (a dry run, or a run stopped before it recorded any): "
                          "'rig runs RUN' shows how it ended")
    warnings = unfinalised_warning(rec)
    tables = []
    for topic in chosen:
        try:
            tables.append(topic_table(rec, topic))
        except TopicError as exc:
            if topics:
                raise ExportError(str(exc)) from None
            warnings.append(f"skipped: {exc}")
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise ExportError(f"--out {out_dir} is a file: give a folder (it is created if missing)")
    out_dir.mkdir(parents=True, exist_ok=True)
    files = []
    for table in tables:
        path = out_dir / csv_name(table.topic)
        write_csv(table, path)
        if table.short_samples:
            warnings.append(f"{table.topic}: {table.short_samples} samples had fewer array elements than the "
                            "longest; their missing cells are empty")
        files.append({"topic": table.topic, "type": table.schema, "csv": str(path), "rows": len(table.t),
                      "columns": ["t", *table.columns], "frame_id": table.frame_id,
                      "t_start": float(table.t[0]), "t_end": float(table.t[-1])})
    return {"run_dir": str(run_dir), "out": str(out_dir), "files": files, "warnings": warnings}


def list_topics(run: str | Path) -> dict:
    run_dir = resolve_run(str(run))
    rec = read_run(run_dir)
    return {"run_dir": str(run_dir), "warnings": unfinalised_warning(rec),
            "topics": [{"topic": t, "type": rec.schemas[t], "samples": len(rec.messages.get(t, [])),
                        "csv": csv_name(t)} for t in sorted(rec.schemas)]}


EXPORT_HELP = """Export a run's recorded streams as CSV.

\b
RUN is a run folder or its name under ./logs ($RIG_LOGS); `rig runs` lists them.
\b
--out DIR   one CSV per topic (every topic, or --topic T ..., or --arm's), named
            DIR/<topic, "/" as ".">.csv, e.g. PSM1.measured_js.csv, loadcell.force.csv:
            a header row, then t (s, run clock: the header stamp, else the log time)
            and one column per numeric field, every sample as recorded: JointState
            position_1.. velocity_1.. effort_1.. (joints numbered from 1; rad or m,
            rad/s or m/s, N m or N), PoseStamped position_x.. (m) orientation_x..w,
            WrenchStamped force_x.. (N) torque_x.. (N m), Float64 data.
            The load-cell tension is force_x of /loadcell/force; the cooperative
            tension set-point /cooperative/force_setpoint; tool tips measured and
            planned /<arm>/measured_cp and /<arm>/setpoint_cp (world frame).
--csv FILE  an arm's /<arm>/measured_js (or --topic, a JointState) in the wpi-psm
            format: no header, q | dq | tau, linearly interpolated onto a uniform
            grid at --rate from the first sample.
--list      the recorded topics, their types and sample counts.
"""


@click.command("export", help=EXPORT_HELP)
@click.argument("run")
@click.option("--out", "out_dir", type=click.Path(file_okay=False), default=None,
              help="Folder for one CSV per topic (created if missing; files of the same name are replaced).")
@click.option("--csv", "csv_path", type=click.Path(dir_okay=False), default=None,
              help="Output CSV (wpi-psm format: no header, q | dq | tau).")
@click.option("--list", "list_only", is_flag=True, help="List the recorded topics and exit.")
@click.option("--topic", "topics", multiple=True, metavar="TOPIC",
              help="With --out: only this topic (repeat it). With --csv: the JointState topic to export "
                   "instead of /<arm>/measured_js.")
@click.option("--arm", default=None,
              help="With --csv: the arm whose /<arm>/measured_js to export [default: PSM1]. "
                   "With --out: only that arm's topics (/<arm>/...).")
@click.option("--rate", type=click.FloatRange(min=0.0, min_open=True), default=None,
              help="With --csv: output sample rate [Hz; default: 200].")
@json_option
def export_command(run: str, out_dir: str | None, csv_path: str | None, list_only: bool,
                   topics: tuple[str, ...], arm: str | None, rate: float | None, as_json: bool) -> None:
    chosen = [name for name, given in (("--out", out_dir), ("--csv", csv_path), ("--list", list_only)) if given]
    if len(chosen) != 1:
        raise click.UsageError("give one of --out DIR (every topic, one CSV each), --csv FILE (an arm's joints, "
                               "wpi-psm format) or --list" + (f", not {' and '.join(chosen)}" if chosen else ""))
    if list_only:
        if topics or arm or rate is not None:
            raise click.UsageError("--list takes no --topic, --arm or --rate")
        summary = list_topics(run)
        _warn(summary["warnings"])
        if as_json:
            click.echo(result_json(summary, indent=None))
            return
        width = max((len(t["topic"]) for t in summary["topics"]), default=5)
        for t in summary["topics"]:
            click.echo(f"{t['topic'].ljust(width)}  {t['samples']:>8}  {t['type']}")
        return
    if csv_path is not None:
        if len(topics) > 1:
            raise click.UsageError("--csv writes one JointState topic: give one --topic")
        summary = export_csv(run, Path(csv_path), arm=arm or "PSM1", rate=200.0 if rate is None else rate,
                             topic=topics[0] if topics else None)
        _warn(summary["warnings"])
        lines = [f"wrote {summary['rows']} rows x {3 * summary['joints']} columns "
                 f"({summary['joints']} joints, q|dq|tau) at {summary['rate_hz']:g} Hz from {summary['samples']} "
                 f"samples of {summary['topic']} to {summary['csv']}"]
    else:
        if rate is not None:
            raise click.UsageError("--rate resamples the --csv joint table; --out writes every sample as recorded")
        summary = export_topics(run, Path(out_dir), tuple(topics), arm)
        _warn(summary["warnings"])
        lines = [f"wrote {f['csv']}: {f['rows']} rows, t + {len(f['columns']) - 1} "
                 f"column{'s' if len(f['columns']) != 2 else ''} ({f['type']})" for f in summary["files"]]
        lines.append(f"{len(summary['files'])} topic{'s' if len(summary['files']) != 1 else ''} of "
                     f"{summary['run_dir']} exported to {summary['out']}")
    emit_result(summary, as_json, "\n".join(lines))


def _warn(warnings: list[str]) -> None:
    for w in warnings:
        click.echo(f"warning: {w}", err=True)
