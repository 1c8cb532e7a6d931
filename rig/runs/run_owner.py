"""Who is writing a run folder: the process that owns it.

A run with no stop record can so be told apart as still running or interrupted (its process
killed with no chance to close it).

`Run` writes `run.owner` (the process id, its start time since boot and the host) when it
starts and removes it when the run has ended and its files are written. A run folder that
still has one, whose process is gone, was interrupted: SIGKILL, a power cut, the machine's
out-of-memory killer. The process's start time guards against a reused process id.
"""

from __future__ import annotations

import json
import os
import socket
from pathlib import Path

OWNER_FILE = "run.owner"


def _start_ticks(pid: int) -> int | None:
    """The process's start time in clock ticks since boot (Linux /proc), None if unknown."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    # the command name (field 2) is in parentheses and may hold spaces: fields after it
    return int(stat.rsplit(")", 1)[1].split()[19])


def claim(run_dir: Path) -> None:
    """Mark `run_dir` as written by this process."""
    pid = os.getpid()
    doc = {"pid": pid, "start_ticks": _start_ticks(pid), "host": socket.gethostname()}
    (Path(run_dir) / OWNER_FILE).write_text(json.dumps(doc) + "\n")


def release(run_dir: Path) -> None:
    """The run has ended and its files are written: nobody owns it any more."""
    try:
        (Path(run_dir) / OWNER_FILE).unlink()
    except FileNotFoundError:
        pass


def state(run_dir: Path) -> str | None:
    """"running" (its process lives, or runs on another host: it cannot be told from here),
    "interrupted" (its process is gone) or None (no owner file: the run ended, or it was
    written before owner files existed)."""
    try:
        doc = json.loads((Path(run_dir) / OWNER_FILE).read_text())
        pid, ticks, host = int(doc["pid"]), doc.get("start_ticks"), str(doc.get("host", ""))
    except FileNotFoundError:
        return None
    except (OSError, ValueError, KeyError, TypeError):
        return "interrupted"  # a cut owner file: its writer died as it wrote it
    if host and host != socket.gethostname():
        return "running"
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return "interrupted"
    except PermissionError:
        pass  # alive, another user's
    if ticks is not None and _start_ticks(pid) not in (None, ticks):
        return "interrupted"  # the id now belongs to another process
    return "running"
