"""Where runs and their results live, and how later procedures find earlier results.

Runs go to `logs/` under the current directory (or `$RIG_LOGS`). A later procedure finds
an earlier result (RCM, registration, identified model, load-cell calibration) as the
newest completed run of that procedure, so nobody copies numbers by hand.
"""

from __future__ import annotations

import json
import os
from datetime import datetime, timezone
from pathlib import Path


def runs_root() -> Path:
    return Path(os.environ.get("RIG_LOGS", "logs")).resolve()


RUN_TIME_FORMAT = "%Y%m%dT%H%M%S"  # then microseconds and "Z", no dash: the procedure follows the first dash


def run_dir_name(procedure: str, when=None) -> str:
    """`<UTC time>-<procedure>`, e.g. `20261121T050203123456Z-identify`."""
    when = when or datetime.now(timezone.utc)
    return f"{when.strftime(RUN_TIME_FORMAT)}{when.microsecond:06d}Z-{procedure}"


def procedure_of(run_dir: Path) -> str:
    return run_dir.name.split("-", 1)[1] if "-" in run_dir.name else ""


def run_dirs(procedure: str | None = None) -> list[Path]:
    """Run folders, oldest first (folder names start with a sortable UTC time)."""
    root = runs_root()
    if not root.is_dir():
        return []
    dirs = [p for p in root.iterdir()
            if p.is_dir() and ((p / "result.json").exists() or (p / "run.mcap").exists())]
    if procedure is not None:
        dirs = [p for p in dirs if procedure_of(p) == procedure]
    return sorted(dirs, key=lambda p: p.name)


def latest_result(procedure: str, status: str = "completed") -> tuple[Path, dict] | None:
    """The newest run of `procedure` whose result.json has the given status, or None."""
    for run in reversed(run_dirs(procedure)):
        f = run / "result.json"
        if not f.exists():
            continue
        try:
            data = json.loads(f.read_text())
        except (OSError, json.JSONDecodeError):
            continue
        if data.get("status", "completed") == status:
            return run, data
    return None


def run_time(run_dir: Path) -> datetime | None:
    """UTC start of a run from its folder name (`20261121T050203123456Z-identify`)."""
    stamp = run_dir.name.split("-", 1)[0]
    try:
        return datetime.strptime(stamp[:15], RUN_TIME_FORMAT).replace(
            microsecond=int(stamp[15:21] or 0), tzinfo=timezone.utc)
    except ValueError:
        return None
