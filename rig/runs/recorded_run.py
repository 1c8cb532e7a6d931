"""A recorded run read back: its folder from a name, its recording, an arm's joint arrays on a uniform grid."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rig.commands.exit_codes import InputError
from rig.runs.paths import runs_root
from rig.runs.recording import Recording, read_recording

JOINT_STATE = "sensor_msgs/msg/JointState"


class ExportError(InputError):
    pass


def find_run(run: str, needs: str | None = None) -> Path:
    """The one rule by which every command takes a run: a run folder from its path (or the
    path of its result.json or run.mcap) or its name under runs_root(). `needs`: the file
    the caller reads ("run.mcap"); a run folder without it is refused. Raises ExportError
    (an InputError: exit 5) with one line naming the run and `rig runs`."""
    for c in (Path(run), runs_root() / run):
        if c.is_file() and c.name in ("result.json", "run.mcap"):
            c = c.parent
        if c.is_dir():
            if not ((c / "result.json").exists() or (c / "run.mcap").exists()):
                raise ExportError(f"{c} is not a run folder (no result.json or run.mcap); "
                                  f"'rig runs' lists the runs under {runs_root()}")
            if needs is not None and not (c / needs).exists():
                raise ExportError(f"{c} has no {needs} (the run's recording): 'rig runs' lists the runs that have "
                                  "one")
            return c.resolve()
    raise ExportError(f"no run '{run}' under {runs_root()}, and no such folder; 'rig runs' lists the runs")


def resolve_run(run: str) -> Path:
    """A run folder with its recording (find_run, needing run.mcap)."""
    return find_run(run, needs="run.mcap")


def read_run(run_dir: Path, topics=None) -> Recording:
    """The run's recording, or one line saying why it cannot be read."""
    path = run_dir / "run.mcap"
    from mcap.exceptions import McapError

    try:
        return read_recording(path, topics=topics)
    except (OSError, ValueError, McapError) as exc:
        raise ExportError(f"cannot read {path}: {exc}") from None


def unfinalised_warning(rec: Recording) -> list[str]:
    if rec.problem or rec.stop is None:
        why = rec.problem or "it has no run_stop record"
        return [f"{rec.path} is unfinalised ({why}); exporting the samples it holds"]
    return []


def joint_arrays(rec: Recording, topic: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """t (s, header stamps), q, dq, tau (samples x joints) of a JointState topic."""
    messages = rec.messages.get(topic)
    if messages and rec.schemas.get(topic, JOINT_STATE) != JOINT_STATE:
        raise ExportError(f"{topic} carries {rec.schemas[topic]}, not a JointState: --csv writes the wpi-psm joint "
                          f"table; export it with --out DIR --topic {topic}")
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
