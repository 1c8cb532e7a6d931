"""`rig runs` (list recorded runs, or show one) and `rig export` (an arm's q, dq, tau as CSV).

The CSV is the format of the WPI dVRK identification data (`data/wpi-psm/`): no header,
comma separated, one row per sample on a uniform time grid, columns grouped by quantity:
q1..qn | dq1..dqn | tau1..taun for the n joints in the recorded JointState messages
(rad or m; rad/s or m/s; N m or N).
"""

from __future__ import annotations

import json
import shutil
from datetime import datetime, timezone
from pathlib import Path

import click
import numpy as np

from rig.paths import RUN_TIME_FORMAT, procedure_of, run_dirs, runs_root
from rig.records import Recording, decode_metadata, read_recording
from rig.run import json_option, result_json


# ---------------------------------------------------------------------- rig runs
#: statuses a run can show: those of result.json and the stop record, "unfinished" (no
#: result and no stop record: running, or killed) and "unreadable" (a broken result.json)
STATUSES = ("completed", "failed", "aborted", "dry-run", "unfinished", "unreadable")

# The figures each procedure's summary leads with in the list (the others follow in their
# order), with the units the procedure computes them in (the summaries carry bare numbers):
# cooperative's force errors in N and times in s (procedures/cooperative.py, _figures),
# friction-ramp's breakaway forces of the prismatic joint 3 in N, identify's relative
# validation errors (no units), discrepancy's verdict and the effects it added.
KEY_FIGURES: dict[str, tuple[tuple[str, str], ...]] = {
    "cooperative": (("rms_error", "N"), ("max_error_during_motion", "N"), ("settling_time", "s"),
                    ("limit_cycle", ""), ("overshoot", "N"), ("hold_peak_to_peak", "N"),
                    ("element_rms_error", "N")),
    "friction-ramp": (("Fs_symmetric", "N"), ("Fs_pos", "N"), ("Fs_neg", "N")),
    "identify": (("validation_sdp", ""), ("validation_ols", "")),
    "discrepancy": (("verdict", ""), ("effects", "")),
}


def run_time(run_dir: Path) -> datetime | None:
    """UTC start of a run from its folder name (`20261121T050203123456Z-identify`)."""
    stamp = run_dir.name.split("-", 1)[0]
    try:
        return datetime.strptime(stamp[:15], RUN_TIME_FORMAT).replace(
            microsecond=int(stamp[15:21] or 0), tzinfo=timezone.utc)
    except ValueError:
        return None


def _metadata_from_mcap(path: Path) -> dict[str, dict]:
    """The metadata records (run_start, run_stop) of a finished recording, from its summary
    (no scan of the data); {} for an unfinished or cut file."""
    from mcap.reader import make_reader

    out = {}
    try:
        with open(path, "rb") as f:
            reader = make_reader(f)
            if reader.get_summary() is None:
                return {}
            for record in reader.iter_metadata():
                out[record.name] = decode_metadata(record.metadata)
    except Exception:  # an unfinished or cut file has no readable footer
        return {}
    return out


def source_arms(provenance) -> list[str]:
    """Names of the arms a result comes from, from its provenance's "arms" (a list of
    {"name": ...} or of names); [] without one."""
    if not isinstance(provenance, dict):
        return []
    arms = provenance.get("arms")
    if isinstance(arms, (str, dict)):
        arms = [arms]
    if not isinstance(arms, list):
        return []
    names = []
    for arm in arms:
        name = arm.get("name") if isinstance(arm, dict) else arm
        if name is not None:
            names.append(str(name))
    return names


def run_info(run_dir: Path, result: dict | None = None) -> dict:
    """What `rig runs` shows for one run folder (`result`: its result.json, if read already)."""
    when = run_time(run_dir)
    info = {"run": run_dir.name, "run_dir": str(run_dir),
            "utc_start": when.isoformat() if when else "",
            "procedure": procedure_of(run_dir), "status": "", "duration_s": None,
            "summary": {}, "error": "", "arms": [], "provenance": None}
    result_file = run_dir / "result.json"
    if result is None and result_file.exists():
        try:
            result = json.loads(result_file.read_text())
            if not isinstance(result, dict):
                raise ValueError(f"a JSON {type(result).__name__}, not an object")
        except (OSError, ValueError) as exc:
            info["status"] = "unreadable"
            info["error"] = f"result.json: {exc}"
            return info
    if result is not None:
        info["status"] = result.get("status", "completed")
        timings = result.get("timings") if isinstance(result.get("timings"), dict) else {}
        info["duration_s"] = timings.get("duration_s")
        summary = result.get("summary")
        info["summary"] = summary if isinstance(summary, dict) else {}
        info["error"] = result.get("error") or ""
        provenance = result.get("provenance")
        if isinstance(provenance, dict):
            info["provenance"] = provenance
            info["arms"] = source_arms(provenance)
        return info
    stop = _metadata_from_mcap(run_dir / "run.mcap").get("run_stop")
    if stop is not None:
        info["status"] = stop.get("status", "")
        info["error"] = stop.get("error", "")
    else:
        # no result and no stop record: still running, or killed without a chance to finish
        info["status"] = "unfinished"
    return info


def _figure(value, units: str = "") -> str:
    """A value as the list and the detail view show it: numbers to 4 significant digits."""
    if isinstance(value, bool):
        text = "yes" if value else "no"
    elif isinstance(value, float):
        text = f"{value:.4g}"
    elif value is None:
        text = "-"
    elif isinstance(value, dict) and "value" in value:  # {"value": .., "units": ..}
        return _figure(value["value"], value.get("units", "") or units)
    elif isinstance(value, dict):
        text = "{" + ", ".join(f"{k}: {_figure(v)}" for k, v in value.items()) + "}"
    elif isinstance(value, (list, tuple)):
        text = "[" + ", ".join(_figure(v) for v in value) + "]"
    elif isinstance(value, str):
        text = _short_path(value)
    else:
        text = str(value)
    return f"{text} {units}" if units and value is not None else text


def _short_path(text: str) -> str:
    """A path inside the runs folder as `<run>/<file>` (the way `rig runs` names runs)."""
    try:
        return str(Path(text).relative_to(runs_root()))
    except ValueError:
        return text


def _ordered_summary(info: dict) -> list[tuple[str, str]]:
    """(name, shown value) of the summary, the procedure's key figures first."""
    summary = info["summary"]
    lead = [(k, units) for k, units in KEY_FIGURES.get(info["procedure"], ()) if k in summary]
    leading = {k for k, _ in lead}
    return ([(k, _figure(summary[k], units)) for k, units in lead]
            + [(k, _figure(v)) for k, v in summary.items() if k not in leading])


def _key_result(info: dict) -> str:
    if info["status"] not in ("completed", "dry-run", "") and info["error"]:
        return info["error"]
    return ", ".join(f"{k}={v}" for k, v in _ordered_summary(info))


def _statuses(ctx, param, values: tuple[str, ...]) -> tuple[str, ...]:
    """--status completed,failed --status aborted -> ("completed", "failed", "aborted")."""
    out = []
    for value in values:
        for status in (s.strip() for s in value.split(",")):
            if not status:
                continue
            if status not in STATUSES:
                raise click.BadParameter(f"{status!r} is not a status; one of {', '.join(STATUSES)}")
            out.append(status)
    return tuple(dict.fromkeys(out))


def find_run(run: str) -> Path:
    """A run folder from its path (or the path of its result.json or run.mcap) or its name
    under runs_root(), like `rig export` and `rig discrepancy` take it."""
    for c in (Path(run), runs_root() / run):
        if c.is_file() and c.name in ("result.json", "run.mcap"):
            c = c.parent
        if c.is_dir():
            if not ((c / "result.json").exists() or (c / "run.mcap").exists()):
                raise click.ClickException(f"{c} is not a run folder (no result.json or run.mcap); "
                                           f"'rig runs' lists the runs under {runs_root()}")
            return c.resolve()
    raise click.ClickException(f"no run '{run}' under {runs_root()}, and no such folder; "
                               f"'rig runs' lists the runs")


def _flatten(value, prefix: str = "") -> list[tuple[str, str]]:
    """Nested dicts and lists of dicts as (`a.b[0].c`, shown value) pairs; a list of plain
    values stays one value."""
    if isinstance(value, dict) and "value" in value:  # a declared parameter: value, units, default, help
        shown = _figure(value["value"], value.get("units") or "")
        if "default" in value and value["default"] != value["value"]:
            shown += f" (default {_figure(value['default'])})"
        return [(prefix, shown)]
    if isinstance(value, dict):
        if not value:
            return [(prefix, "{}")] if prefix else []
        pairs = []
        for k, v in value.items():
            pairs += _flatten(v, f"{prefix}.{k}" if prefix else str(k))
        return pairs
    if isinstance(value, list) and any(isinstance(v, (dict, list)) for v in value):
        pairs = []
        for i, v in enumerate(value):
            pairs += _flatten(v, f"{prefix}[{i}]")
        return pairs
    return [(prefix, _figure(value))]


def _size(n: int) -> str:
    for unit in ("B", "kB", "MB", "GB"):
        if n < 1000 or unit == "GB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.3g} {unit}"
        n /= 1000
    return f"{n} B"


def run_detail(run_dir: Path) -> dict:
    """Everything `rig runs RUN` shows: the list's fields, then the timings, where a run
    stopped, the arms it held, the full provenance, the parameters (from the recording's
    start record) and the folder's files."""
    result = None
    result_file = run_dir / "result.json"
    if result_file.exists():
        try:
            result = json.loads(result_file.read_text())
        except (OSError, ValueError):
            result = None
        if not isinstance(result, dict):
            result = None
    info = run_info(run_dir, result)
    records = _metadata_from_mcap(run_dir / "run.mcap") if (run_dir / "run.mcap").exists() else {}
    start, stop = records.get("run_start") or {}, records.get("run_stop") or {}
    result = result or {}
    timings = result.get("timings") if isinstance(result.get("timings"), dict) else {}
    if not timings and stop:
        timings = {"utc_start": start.get("utc_start"), "utc_stop": stop.get("utc_stop"),
                   "steps": stop.get("steps") or {}}
    info.update({
        "result_file": str(result_file) if result_file.exists() else None,
        "timings": timings,
        "step": result.get("step") or stop.get("step"),
        "held": result.get("held") or stop.get("held") or [],
        "hold_errors": result.get("hold_errors") or stop.get("hold_errors") or [],
        "recording_error": result.get("recording_error"),
        "parameters": start.get("parameters") if isinstance(start.get("parameters"), dict) else None,
        "seed": start.get("seed"),
        "package_version": start.get("package_version"),
        "git_revision": start.get("git_revision"),
        "files": {p.name: p.stat().st_size for p in sorted(run_dir.iterdir()) if p.is_file()},
    })
    return info


def _when(text) -> str:
    """An ISO time as `2026-11-25 13:15:38.557 UTC`."""
    if not text:
        return "-"
    try:
        t = datetime.fromisoformat(str(text)).astimezone(timezone.utc)
    except ValueError:
        return str(text)
    return t.strftime("%Y-%m-%d %H:%M:%S.") + f"{t.microsecond // 1000:03d} UTC"


def format_detail(d: dict) -> str:
    def section(title: str, pairs: list[tuple[str, str]]) -> list[str]:
        if not pairs:
            return []
        width = max(len(k) for k, _ in pairs)
        return [title] + [f"  {k.ljust(width)}  {v}" for k, v in pairs]

    head = [("folder", d["run_dir"]), ("procedure", d["procedure"] or "-"), ("status", d["status"])]
    if d["error"]:
        head.append(("error", d["error"]))
    if d["step"]:
        head.append(("stopped in", f"step '{d['step']}'"))
    if d["held"]:
        head.append(("arms held", ", ".join(map(str, d["held"]))))
    for err in d["hold_errors"]:
        head.append(("hold error", _figure(err)))
    if d["recording_error"]:
        head.append(("recording", d["recording_error"]))
    if d["arms"]:
        head.append(("source arms", ", ".join(d["arms"])))
    lines = [f"run {d['run']}"] + section("", head)[1:]

    t = d["timings"] or {}
    timing = [("started", _when(t.get("utc_start") or d["utc_start"])), ("stopped", _when(t.get("utc_stop")))]
    if t.get("duration_s") is not None:
        timing.append(("duration", _figure(float(t["duration_s"]), "s")))
    steps = t.get("steps") if isinstance(t.get("steps"), dict) else {}
    lines += section("timings", timing)
    lines += section("steps", [(name, _figure(float(s), "s") if isinstance(s, (int, float)) else _figure(s))
                               for name, s in steps.items()])
    lines += section("summary", _ordered_summary(d) if d["summary"] else [])
    if d["provenance"] is not None:
        lines += section("provenance", _flatten(d["provenance"]) or [("(empty)", "")])
    recorded = _flatten(d["parameters"]) if d["parameters"] else []
    if d["seed"] not in (None, ""):
        recorded.append(("seed", _figure(d["seed"])))
    if d["package_version"]:
        recorded.append(("package version", f"{d['package_version']} (git {d['git_revision'] or '-'})"))
    lines += section("parameters (run.mcap start record)", recorded)
    lines += section("files", [(name, _size(size)) for name, size in d["files"].items()])
    return "\n".join(lines)


def _list_table(infos: list[dict]) -> list[str]:
    rows = [("run", "status", "duration", "arms", "result")]
    for info in infos:
        duration = "" if info["duration_s"] is None else f"{info['duration_s']:.1f} s"
        rows.append((info["run"], info["status"], duration, ",".join(info["arms"]), _key_result(info)))
    widths = [max(len(r[i]) for r in rows) for i in range(4)]
    # Fit the result column to a terminal; piped output keeps it whole for grep.
    columns = shutil.get_terminal_size((0, 0)).columns
    room = max(30, columns - sum(widths) - 2 * 4) if columns else None
    lines = []
    for r in rows:
        text = r[4] if room is None or len(r[4]) <= room else r[4][: room - 3] + "..."
        lines.append(("  ".join(r[i].ljust(widths[i]) for i in range(4)) + "  " + text).rstrip())
    return lines


RUNS_HELP = """List recorded runs, oldest first, or show one run in detail.

\b
Without RUN, one line per run:
  run       the run folder's name, <UTC start>-<procedure>: what `rig runs RUN`,
            `rig export RUN`, `rig discrepancy RUN_DIR` and
            `--model logs/<run>/model.json` take
  status    completed, failed (ran but missed its purpose), aborted (a limit, a fault,
            Ctrl-C), dry-run, unfinished (running, or killed) or unreadable
  duration  wall time, s
  arms      the arms the result comes from (its provenance), if it records them
  result    the key figures of its summary (4 significant digits), or the error

With RUN (a run folder's name under ./logs or $RIG_LOGS, or its path): the status, the error
and where it stopped, the timings of every step, the summary, the provenance (where the
result came from: arms, rig, source run or file, version, time), the parameters recorded at
its start and the folder's files.
"""


@click.command("runs", help=RUNS_HELP)
@click.argument("run", required=False)
@click.option("--procedure", "-p", default=None, metavar="NAME",
              help="Only runs of this procedure (e.g. cooperative, identify).")
@click.option("--status", "-s", "statuses", multiple=True, callback=_statuses, metavar="STATUS[,STATUS]",
              help=f"Only runs with this status: {', '.join(STATUSES)}. Repeat it or give a comma list.")
@click.option("--last", "-n", "last", type=click.IntRange(min=1), default=None, metavar="N",
              help="Only the newest N runs (of those the other options select).")
@click.option("--json", "as_json", is_flag=True,
              help="Print the list (or the run) as one JSON document on stdout, figures at full precision.")
def runs_command(run: str | None, procedure: str | None, statuses: tuple[str, ...], last: int | None,
                 as_json: bool) -> None:
    if run is not None:
        if procedure or statuses or last:
            raise click.ClickException("RUN shows one run; --procedure, --status and --last select runs "
                                       "for the list: give one or the other")
        detail = run_detail(find_run(run))
        if as_json:
            click.echo(result_json(detail, indent=None))
        else:
            click.echo(format_detail(detail))
        return
    infos = [run_info(d) for d in run_dirs(procedure)]
    if statuses:
        infos = [i for i in infos if i["status"] in statuses]
    if last is not None:
        infos = infos[-last:]
    if as_json:
        click.echo(result_json({"runs_root": str(runs_root()), "runs": infos}, indent=None))
        return
    if not infos:
        asked = [f"--procedure {procedure}"] if procedure else []
        asked += [f"--status {','.join(statuses)}"] if statuses else []
        line = f"no runs under {runs_root()}" + (f" match {' '.join(asked)}" if asked else "")
        known = sorted({procedure_of(d) for d in run_dirs()})
        if procedure and procedure not in known:
            line += f" (procedures with runs: {', '.join(known) or 'none'})"
        click.echo(line, err=True)
        return
    for line in _list_table(infos):
        click.echo(line)


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
