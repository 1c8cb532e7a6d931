"""`rig runs` (list recorded runs) and `rig export` (an arm's q, dq, tau as CSV).

The CSV is the format of the WPI dVRK identification data (`data/wpi-psm/`): no header,
comma separated, one row per sample on a uniform time grid, columns grouped by quantity:
q1..qn | dq1..dqn | tau1..taun for the n joints in the recorded JointState messages
(rad or m; rad/s or m/s; N m or N).
"""

from __future__ import annotations

import json
from datetime import datetime, timezone
from pathlib import Path

import click
import numpy as np

from rig.paths import RUN_TIME_FORMAT, procedure_of, run_dirs, runs_root
from rig.records import Recording, decode_metadata, read_recording
from rig.run import json_option, result_json


# ---------------------------------------------------------------------- rig runs
def run_time(run_dir: Path) -> datetime | None:
    """UTC start of a run from its folder name (`20261121T050203123456Z-identify`)."""
    stamp = run_dir.name.split("-", 1)[0]
    try:
        return datetime.strptime(stamp[:15], RUN_TIME_FORMAT).replace(
            microsecond=int(stamp[15:21] or 0), tzinfo=timezone.utc)
    except ValueError:
        return None


def _stop_from_mcap(path: Path) -> dict | None:
    """run_stop of a finished recording, from its summary (no scan of the data)."""
    from mcap.reader import make_reader

    try:
        with open(path, "rb") as f:
            reader = make_reader(f)
            if reader.get_summary() is None:
                return None
            for record in reader.iter_metadata():
                if record.name == "run_stop":
                    return decode_metadata(record.metadata)
    except Exception:  # an unfinished or cut file has no readable footer
        return None
    return None


def run_info(run_dir: Path) -> dict:
    """What `rig runs` shows for one run folder."""
    when = run_time(run_dir)
    info = {"run": run_dir.name, "run_dir": str(run_dir),
            "utc_start": when.isoformat() if when else "",
            "procedure": procedure_of(run_dir), "status": "", "duration_s": None,
            "summary": {}, "error": ""}
    result_file = run_dir / "result.json"
    if result_file.exists():
        try:
            result = json.loads(result_file.read_text())
        except (OSError, json.JSONDecodeError) as exc:
            info["status"] = "unreadable"
            info["error"] = f"result.json: {exc}"
            return info
        info["status"] = result.get("status", "completed")
        info["duration_s"] = (result.get("timings") or {}).get("duration_s")
        summary = result.get("summary")
        info["summary"] = summary if isinstance(summary, dict) else {}
        info["error"] = result.get("error") or ""
        return info
    stop = _stop_from_mcap(run_dir / "run.mcap")
    if stop is not None:
        info["status"] = stop.get("status", "")
        info["error"] = stop.get("error", "")
    else:
        # no result and no stop record: still running, or killed without a chance to finish
        info["status"] = "unfinished"
    return info


def _figure(value) -> str:
    if isinstance(value, float):
        return f"{value:.4g}"
    if isinstance(value, dict) and "value" in value:  # {"value": .., "units": ..}
        return f"{_figure(value['value'])} {value.get('units', '')}".rstrip()
    return str(value)


def _key_result(info: dict, width: int = 60) -> str:
    if info["status"] not in ("completed", "") and info["error"]:
        text = info["error"]
    else:
        text = ", ".join(f"{k}={_figure(v)}" for k, v in info["summary"].items())
    return text if len(text) <= width else text[: width - 3] + "..."


@click.command("runs")
@click.option("--procedure", "-p", default=None, help="Only runs of this procedure.")
@click.option("--last", "-n", "last", type=click.IntRange(min=1), default=None,
              help="Only the newest N runs.")
@json_option
def runs_command(procedure: str | None, last: int | None, as_json: bool) -> None:
    """List recorded runs, oldest first: UTC time, procedure, status, key result.

    Runs live in ./logs (or $RIG_LOGS); the key result is the "summary" of result.json.
    """
    infos = [run_info(d) for d in run_dirs(procedure)]
    if last is not None:
        infos = infos[-last:]
    if as_json:
        click.echo(result_json({"runs_root": str(runs_root()), "runs": infos}, indent=None))
        return
    if not infos:
        click.echo(f"no runs under {runs_root()}", err=True)
        return
    rows = [("time (UTC)", "procedure", "status", "duration", "result")]
    for info in infos:
        when = info["utc_start"][:19].replace("T", " ") if info["utc_start"] else info["run"]
        duration = "" if info["duration_s"] is None else f"{info['duration_s']:.1f} s"
        rows.append((when, info["procedure"], info["status"], duration, _key_result(info)))
    widths = [max(len(r[i]) for r in rows) for i in range(4)]
    for r in rows:
        click.echo("  ".join(r[i].ljust(widths[i]) for i in range(4)) + "  " + r[4])


# ---------------------------------------------------------------------- rig export
class ExportError(click.ClickException):
    pass


def resolve_run(run: str) -> Path:
    """A run folder from a path or a folder name under runs_root()."""
    candidates = [Path(run), runs_root() / run]
    for c in candidates:
        if c.is_dir():
            if not (c / "run.mcap").exists():
                raise ExportError(f"{c} has no run.mcap: is it a run folder?")
            return c
        if c.is_file() and c.suffix == ".mcap":
            return c.parent
    raise ExportError(f"no run '{run}': not a folder, and not a run under {runs_root()} "
                      f"(list them with 'rig runs')")


def joint_arrays(rec: Recording, topic: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """t (s, header stamps), q, dq, tau (samples x joints) of a JointState topic."""
    messages = rec.messages.get(topic)
    if not messages:
        available = ", ".join(sorted(t for t, s in rec.schemas.items() if s.endswith("JointState")))
        what = "holds no samples" if messages is not None else "is not in the recording"
        raise ExportError(f"{topic} {what} ({rec.path}); JointState topics: {available or 'none'}")
    n = len(messages[0][1].position)
    t = np.empty(len(messages))
    data = np.empty((len(messages), 3, n))
    for i, (log_ns, msg) in enumerate(messages):
        stamp = msg.header.stamp
        stamp_ns = stamp.sec * 1_000_000_000 + stamp.nanosec
        # the header stamp is when the joint was measured; log time is only a fallback
        t[i] = (stamp_ns or log_ns) * 1e-9
        for k, (label, values) in enumerate((("position", msg.position), ("velocity", msg.velocity),
                                             ("effort", msg.effort))):
            if len(values) != n:
                raise ExportError(f"{topic} sample {i} (t = {t[i]:.6f} s) has {len(values)} {label} "
                                  f"values, the first sample had {n} joints")
            data[i, k] = values
    order = np.argsort(t, kind="stable")
    t, data = t[order], data[order]
    keep = np.concatenate(([True], np.diff(t) > 0))  # a repeated stamp adds nothing to interpolate
    t, data = t[keep], data[keep]
    return t, data[:, 0], data[:, 1], data[:, 2]


def resample(t: np.ndarray, columns: np.ndarray, rate: float) -> tuple[np.ndarray, np.ndarray]:
    """Linear interpolation of `columns` (samples x m) at t[0] + k / rate, k = 0, 1, ..."""
    count = int(np.floor((t[-1] - t[0]) * rate + 1e-9)) + 1
    grid = t[0] + np.arange(count) / rate
    out = np.empty((count, columns.shape[1]))
    for j in range(columns.shape[1]):
        out[:, j] = np.interp(grid, t, columns[:, j])
    return grid, out


def export_csv(run: str | Path, out: Path, arm: str = "PSM1", rate: float = 200.0,
               topic: str | None = None) -> dict:
    """Write the arm's q | dq | tau at `rate` Hz; returns what was written (and warnings)."""
    run_dir = resolve_run(str(run))
    topic = topic or f"/{arm}/measured_js"
    rec = read_recording(run_dir / "run.mcap", topics=[topic])
    warnings = []
    if rec.problem or rec.stop is None:
        why = rec.problem or "it has no run_stop record"
        warnings.append(f"{run_dir / 'run.mcap'} is unfinalised ({why}); exporting the samples it holds")
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


@click.command("export")
@click.argument("run")
@click.option("--csv", "csv_path", required=True, type=click.Path(dir_okay=False),
              help="Output CSV (wpi-psm format: no header, q | dq | tau).")
@click.option("--arm", default="PSM1", show_default=True, help="Arm whose /<arm>/measured_js to export.")
@click.option("--rate", type=click.FloatRange(min=0.0, min_open=True), default=200.0,
              help="Output sample rate [Hz; default: 200].")
@click.option("--topic", default=None, help="JointState topic to export instead of /<arm>/measured_js.")
@json_option
def export_command(run: str, csv_path: str, arm: str, rate: float, topic: str | None,
                   as_json: bool) -> None:
    """Export an arm's joint positions, velocities and efforts from a run as CSV.

    RUN is a run folder or its name under ./logs ($RIG_LOGS). Samples are linearly
    interpolated onto a uniform grid at --rate from the first recorded sample.
    """
    summary = export_csv(run, Path(csv_path), arm=arm, rate=rate, topic=topic)
    for w in summary["warnings"]:
        click.echo(f"warning: {w}", err=True)
    line = (f"wrote {summary['rows']} rows x {3 * summary['joints']} columns "
            f"({summary['joints']} joints, q|dq|tau) at {rate:g} Hz from {summary['samples']} samples "
            f"of {summary['topic']} to {summary['csv']}")
    if as_json:
        click.echo(line, err=True)
        click.echo(result_json(summary, indent=None))
    else:
        click.echo(line)
