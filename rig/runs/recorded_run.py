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
