"""`rig runs`: list the recorded runs, or show one.

`rig export` and `rig plot` take a run the way this finds it.
"""

from __future__ import annotations

import json
import os
import shutil
import sys
import textwrap
from datetime import datetime, timezone
from pathlib import Path

import click

from rig.commands.exit_codes import InputError
from rig.runs import run_owner
from rig.runs.paths import procedure_of, run_dirs, run_time, runs_root
from rig.runs.recorded_run import find_run
from rig.runs.recording import decode_metadata
from rig.runs_setup import arms_of, cooperative_setup, setup_text, source_arms
from rig.sealed_json import result_json


# ---------------------------------------------------------------------- rig runs
#: statuses a run can show: those of result.json and the stop record; with neither,
#: "running" (its process lives), "interrupted" (its process died without closing it:
#: SIGKILL, a power cut) or, for a run from before owner files, "unfinished"; and
#: "unreadable" (a broken result.json)
STATUSES = ("completed", "failed", "aborted", "dry-run", "running", "interrupted", "unfinished", "unreadable")

# The figures each procedure's summary leads with in the list (the others follow in their
# order), with the units the procedure computes them in (the summaries carry bare numbers):
# cooperative's force errors in N and times in s (procedures/cooperative_report.py, force_error_figures),
# friction-ramp's breakaway forces of the prismatic joint 3 in N, identify's relative
# validation errors (no units), discrepancy's verdict and the effects it added.
KEY_FIGURES: dict[str, tuple[tuple[str, str], ...]] = {
    "cooperative": (("rms_error", "N"), ("max_error_during_motion", "N"), ("settling_time", "s"),
                    ("limit_cycle", ""), ("overshoot", "N"), ("hold_peak_to_peak", "N"),
                    ("element_rms_error", "N")),
    "friction-ramp": (("Fs_symmetric", "N"), ("Fs_pos", "N"), ("Fs_neg", "N")),
    "identify": (("validation_sdp", ""), ("validation_ols", "")),
    "discrepancy": (("verdict", ""), ("effects", "")),
    "loadcell-calibrate": (("check_error", "N"), ("check_noise", "N"), ("newtons_per_count", "N/count"),
                           ("zero_counts", "counts")),
}

#: the list's lines are cut to the terminal's width, or to this many columns when the
#: output is not a terminal (a pipe, a log); --wide keeps them whole
LIST_WIDTH = 120


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


def _loadcell_calibrate_figures(result: dict, info: dict) -> None:
    """Duration and key figures of a loadcell-calibrate result written before it ran as a
    recorded run (no timings, no summary: "started" and "finished" times, "check" and
    "calibration")."""
    if info["duration_s"] is None and result.get("started") and result.get("finished"):
        try:
            info["duration_s"] = (datetime.fromisoformat(result["finished"])
                                  - datetime.fromisoformat(result["started"])).total_seconds()
        except (TypeError, ValueError):
            pass
    check = result.get("check") if isinstance(result.get("check"), dict) else {}
    cal = result.get("calibration") if isinstance(result.get("calibration"), dict) else {}
    if not info["summary"] and (check or cal):
        info["summary"] = {k: v for k, v in (("check_error", check.get("error_n")), ("check_noise", check.get("std_n")),
                                             ("newtons_per_count", cal.get("newtons_per_count")),
                                             ("zero_counts", cal.get("zero_counts"))) if v is not None}


def run_info(run_dir: Path, result: dict | None = None) -> dict:
    """What `rig runs` shows for one run folder (`result`: its result.json, if read already).

    "arms": the arms the run used (see arms_of); "setup": what a cooperative run held and
    did (cooperative_setup), {} for the other procedures."""
    when = run_time(run_dir)
    info = {"run": run_dir.name, "run_dir": str(run_dir),
            "utc_start": when.isoformat() if when else "",
            "procedure": procedure_of(run_dir), "status": "", "duration_s": None,
            "summary": {}, "error": "", "arms": [], "setup": {}, "provenance": None}
    start: dict | None = None

    def start_record() -> dict:
        nonlocal start
        if start is None:
            start = _metadata_from_mcap(run_dir / "run.mcap").get("run_start") or {}
        return start

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
        if info["procedure"] == "loadcell-calibrate":
            _loadcell_calibrate_figures(result, info)
    else:
        records = _metadata_from_mcap(run_dir / "run.mcap")
        start, stop = records.get("run_start") or {}, records.get("run_stop")
        if stop is not None:
            info["status"] = stop.get("status", "")
            info["error"] = stop.get("error", "")
            result = {"held": stop.get("held"), "hold_errors": stop.get("hold_errors")}
        else:
            # no result and no stop record: still running, or killed without a chance to
            # finish; its owner file (rig.runs.run_owner) tells which, for runs that have one
            owner = run_owner.state(run_dir)
            info["status"] = {"running": "running", "interrupted": "interrupted"}.get(owner, "unfinished")
            if owner == "interrupted":
                info["error"] = ("interrupted (no stop record): its process ended without closing the run; "
                                 "the recording holds the samples up to its last chunk")
            result = {}
    if info["procedure"] == "cooperative":
        info["setup"] = cooperative_setup(result, start_record())
        info["arms"] = info["setup"]["arms"]
    else:
        info["arms"] = arms_of(result, {})
        if not info["arms"] and (run_dir / "run.mcap").exists():
            info["arms"] = arms_of(result, start_record())
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


def _key_parts(info: dict) -> tuple[str, str]:
    """(a cooperative run's setup or "", the error of a run that did not complete or the
    key figures of its summary)."""
    if info["status"] not in ("completed", "dry-run", "") and info["error"]:
        figures = info["error"]
    else:
        figures = ", ".join(f"{k}={v}" for k, v in _ordered_summary(info))
    return setup_text(info.get("setup") or {}), figures


def _key_result(info: dict) -> str:
    """The list's result field: a cooperative run's setup, then the error of a run that did
    not complete, or the key figures of its summary."""
    setup, figures = _key_parts(info)
    return f"{setup}: {figures}" if setup and figures else setup or figures


def _result_lines(info: dict, room: int | None) -> list[str]:
    """The result field in `room` columns (None: any): one line, cut to the room; a
    cooperative run's (its setup, then its figures) wraps onto a second line first."""
    text = _key_result(info)
    if room is None or len(text) <= room:
        return [text]
    if not setup_text(info.get("setup") or {}):
        return [_cut(text, room)]
    lines = textwrap.wrap(text, room) or [""]
    return lines if len(lines) <= 2 else [lines[0], _cut(" ".join(lines[1:]), room)]


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
    held, hold_errors = _holds(result.get("held") or stop.get("held") or [],
                               result.get("hold_errors") or stop.get("hold_errors") or [],
                               result.get("fault") or stop.get("fault"))
    info.update({
        "result_file": str(result_file) if result_file.exists() else None,
        "timings": timings,
        "step": result.get("step") or stop.get("step"),
        "held": held,
        "hold_errors": hold_errors,
        "recording_error": result.get("recording_error"),
        "parameters": start.get("parameters") if isinstance(start.get("parameters"), dict) else None,
        "seed": start.get("seed"),
        "package_version": start.get("package_version"),
        "git_revision": start.get("git_revision"),
        "files": {p.name: p.stat().st_size for p in sorted(run_dir.iterdir()) if p.is_file()},
    })
    return info


#: an arm's operating states in which it obeys no command (drivers.arm.crtk.OperatingState)
_DISOBEYING = ("FAULT", "DISABLED", "PAUSED")


def _holds(held: list, hold_errors: list, fault: dict | None) -> tuple[list[str], list[dict]]:
    """(arms held, arms not held) of a run. The run engine records an arm that obeys no
    command (FAULT, DISABLED, PAUSED) among the hold errors with its state; where the
    fault that ended the run (its structured fields: arm, state) names an arm that obeyed
    no command and the run still lists it as held, it is moved to the errors here."""
    held = [str(a) for a in held]
    errors = [e if isinstance(e, dict) else {"arm": "", "error": str(e)} for e in hold_errors]
    fault = fault if isinstance(fault, dict) else {}
    arm, state = fault.get("arm"), fault.get("state")
    if arm in held and state in _DISOBEYING:
        held.remove(arm)
        errors.append({"arm": arm, "state": state,
                       "error": f"{arm} is {state} (the fault that ended the run): it obeyed no command, the hold "
                                "included"})
    return held, errors


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
        if err.get("state"):  # the arm obeyed no command: its error says what it was
            head.append(("not held", str(err.get("error"))))
        else:
            head.append(("hold error", f"{err.get('arm') or '?'}: {err.get('error')}"))
    if d["recording_error"]:
        head.append(("recording", d["recording_error"]))
    setup = d.get("setup") or {}
    setup = setup if setup_text(setup) else {}  # a setup nothing recorded is no section
    if d["arms"] and not setup:
        # "source arms": where the result comes from (its provenance); else the arms it used
        head.append(("source arms" if source_arms(d["provenance"]) else "arms", ", ".join(d["arms"])))
    lines = [f"run {d['run']}"] + section("", head)[1:]
    if setup:
        move, turn = setup.get("move_m"), setup.get("rotate_rad")
        lines += section("setup", [
            ("object", f"{setup.get('object') or '-'}"
                       + (f", {setup['force_n']:g} N of tension" if setup.get("force_n") is not None else "")),
            ("mode", setup.get("mode") or "-"),
            ("arms", ", ".join(setup.get("arms") or []) or "-"),
            ("master", setup.get("master") or "-"),
            ("move", "-" if move is None else ", ".join(f"{1000 * v:g}" for v in move) + " mm (world frame)"),
            ("rotate", "-" if turn is None else ", ".join(f"{v:g}" for v in turn) + " rad (x-y-z Euler)"),
            ("loop rate", "-" if not setup.get("rate_hz") else f"{setup['rate_hz']:g} Hz")])

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


def _cut(text: str, room: int | None) -> str:
    return text if room is None or len(text) <= room else text[: max(room - 3, 0)] + "..."


def list_width() -> int:
    """Columns a list line may take: $COLUMNS when set, else the terminal's width when
    stdout is a terminal, else LIST_WIDTH."""
    try:
        columns = int(os.environ.get("COLUMNS", ""))
    except ValueError:
        columns = 0
    if columns > 0:
        return columns
    if getattr(sys.stdout, "isatty", lambda: False)():
        return shutil.get_terminal_size((LIST_WIDTH, 24)).columns
    return LIST_WIDTH


def _list_table(infos: list[dict], width: int | None = None) -> list[str]:
    """The list's lines, each at most `width` columns (None: whole). The result field is
    cut first (the whole of it is in `rig runs RUN`), then the arms, never the run's name."""
    rows = [("run", "status", "duration", "arms", "result")]
    for info in infos:
        duration = "" if info["duration_s"] is None else f"{info['duration_s']:.1f} s"
        rows.append((info["run"], info["status"], duration, ",".join(info["arms"]), info))
    widths = [max(len(r[i]) for r in rows) for i in range(4)]
    if width is not None:
        # arms past 14 columns (three arms) are cut when the result would get fewer than 30
        fixed = sum(widths[:3]) + 2 * 4
        widths[3] = min(widths[3], max(14, width - fixed - 30))
    room = None if width is None else max(1, width - sum(widths) - 2 * 4)
    lines = []
    for r in rows:
        cells = [r[0], r[1], r[2], _cut(r[3], None if width is None else widths[3])]
        results = [r[4]] if isinstance(r[4], str) else _result_lines(r[4], room)
        lead = "  ".join(c.ljust(w) for c, w in zip(cells, widths)) + "  "
        lines.append((lead + results[0]).rstrip())
        lines += [(" " * len(lead) + more).rstrip() for more in results[1:]]
    return lines


RUNS_HELP = """List recorded runs, oldest first, or show one run in detail.

\b
Without RUN, a line per run (a cooperative run's result may take a second):
  run       the run folder's name, <UTC start>-<procedure>: what `rig runs RUN`,
            `rig export RUN`, `rig discrepancy RUN_DIR` and
            `--model logs/<run>/model.json` take
  status    completed, failed (ran but missed its purpose), aborted (a limit, a fault,
            Ctrl-C), dry-run, running, interrupted (its process killed before it could close
            the run: no stop record), unfinished (an older run: running, or killed) or unreadable
  duration  wall time, s
  arms      the arms the run used: those its result comes from (its provenance), else
            those it names or held
  result    a cooperative run's setup (object and tension set-point, mode, the master
            and its move in the world frame, the loop rate), then the key figures of its
            summary (4 significant digits) or the error

Lines fit the terminal (120 columns when not a terminal): a cooperative run's figures go
on a second line when they do not fit after its setup, and a field still too long ends in
"..."; --wide keeps each run on one whole line, `rig runs RUN` and --json show all of it.

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
@click.option("--wide", "-w", is_flag=True,
              help="Keep every line whole, however long (for grep), instead of cutting it to the terminal.")
@click.option("--json", "as_json", is_flag=True,
              help="Print the list (or the run) as one JSON document on stdout, figures at full precision.")
def runs_command(run: str | None, procedure: str | None, statuses: tuple[str, ...], last: int | None,
                 wide: bool, as_json: bool) -> None:
    if run is not None:
        if procedure or statuses or last:
            raise InputError("RUN shows one run; --procedure, --status and --last select runs "
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
    for line in _list_table(infos, None if wide else list_width()):
        click.echo(line)
