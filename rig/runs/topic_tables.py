"""A recorded topic as a table: a time column in seconds and one numeric column per field.

What `rig export --out` writes and `rig plot` draws. Any ROS 2 message the recording holds
is flattened the same way, from its decoded fields (so a message type the recorder does
not write today exports all the same):

- `t`: the sample time (s, run clock): the header stamp where the message has one, else
  the MCAP log time (the recorder writes the same time to both).
- the header is left out; a stamped message's one body (PoseStamped.pose,
  WrenchStamped.wrench) gives its fields without its name: `position_x ... orientation_w`,
  `force_x ... torque_z`;
- nested fields are joined with "_" (`linear_x`), a numeric array gives one column per
  element numbered from 1 (`position_1 ... position_7` of a JointState, as joints are
  numbered in this package), a plain number its field's name (`data`);
- text (frame_id, joint names) and arrays of messages are not columns: the frame is kept
  beside the table (`frame_id`), joint names in `names`.

A topic whose messages have no numeric field, or that the file holds no decodable samples
of, is refused with a `TopicError` that says so in one line.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from operator import attrgetter
from pathlib import Path

import numpy as np

from rig.runs.recording import Recording


class TopicError(ValueError):
    """A topic cannot be made a table (missing, empty, undecodable, nothing numeric)."""


@dataclass
class TopicTable:
    topic: str
    schema: str                 # e.g. "geometry_msgs/msg/WrenchStamped"
    t: np.ndarray               # s, run clock, sorted (stable)
    columns: list[str]          # names of data's columns (t excluded)
    data: np.ndarray            # samples x columns; NaN where a sample lacked an element
    frame_id: str = ""          # the header's frame, if one frame for every sample
    names: list[str] = field(default_factory=list)  # JointState joint names, if any
    short_samples: int = 0      # samples with fewer array elements than the longest one

    def column(self, name: str) -> np.ndarray:
        return self.data[:, self.columns.index(name)]

    def has(self, name: str) -> bool:
        return name in self.columns


def _fields(msg) -> tuple[str, ...]:
    return tuple(getattr(type(msg), "__slots__", ()) or ())


def _is_message(value) -> bool:
    return bool(_fields(value))


def _is_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, str)


def _plan(msg, prefix: str = "", path: tuple[str, ...] = ()) -> list[tuple[str, str, bool]]:
    """(column name, dotted attribute path, is an array) of every numeric leaf of a decoded
    message, in field order. An array empty in this message is taken as numeric (a
    JointState's effort may be empty in one sample and not in the next)."""
    fields = _fields(msg)
    names = [f for f in fields if not (prefix == "" and f == "header")]
    # the one body of a stamped message: its fields without its name
    collapse = (prefix == "" and "header" in fields and len(names) == 1
                and _is_message(getattr(msg, names[0])))
    out = []
    for name in names:
        value = getattr(msg, name)
        key = prefix if collapse else (f"{prefix}_{name}" if prefix else name)
        where = path + (name,)
        if _is_message(value):
            out += _plan(value, key, where)
        elif _is_number(value):  # bool is an int: 0 or 1
            out.append((key, ".".join(where), False))
        elif isinstance(value, (list, tuple)) or hasattr(value, "tolist"):
            seq = value.tolist() if hasattr(value, "tolist") else value
            if not len(seq) or _is_number(seq[0]):
                out.append((key, ".".join(where), True))
        # strings and arrays of strings or messages are not columns
    return out


def topic_table(rec: Recording, topic: str) -> TopicTable:
    """The table of one topic of a recording read with `read_recording(..., decode=True)`."""
    messages = rec.messages.get(topic)
    schema = rec.schemas.get(topic, "")
    if messages is None:
        raise TopicError(f"{topic} is not in {rec.path}; its topics: {', '.join(sorted(rec.schemas)) or 'none'}")
    if not messages:
        raise TopicError(f"{topic} ({schema}) holds no samples in {rec.path}")
    first = messages[0][1]
    if not _is_message(first):
        raise TopicError(f"{topic} carries {schema or 'an unnamed schema'}, which the recording gives no "
                         "definition to decode")
    plan = _plan(first)
    n = len(messages)
    # attrgetter walks the dotted paths in C: a 1 kHz stream of a long run is 10^5 samples
    scalars = [(key, where) for key, where, array in plan if not array]
    get_scalars = attrgetter(*[where for _, where in scalars]) if scalars else None
    arrays = {key: attrgetter(where) for key, where, array in plan if array}
    values = np.empty((n, len(scalars)))
    array_values: dict[str, list] = {key: [None] * n for key in arrays}
    times = np.empty(n)
    stamped = _is_message(getattr(first, "header", None))
    get_stamp = attrgetter("header.stamp.sec", "header.stamp.nanosec", "header.frame_id") if stamped else None
    frames: set[str] = set()
    for i, (log_ns, msg) in enumerate(messages):
        if get_scalars is not None:
            values[i] = get_scalars(msg)
        for key, get in arrays.items():
            array_values[key][i] = get(msg)
        stamp_ns = 0
        if get_stamp is not None:
            sec, nanosec, frame = get_stamp(msg)
            stamp_ns = sec * 1_000_000_000 + nanosec
            frames.add(frame)
        # the header stamp is when the sample was taken; the log time only stands in
        times[i] = (stamp_ns or log_ns) * 1e-9
    columns: list[str] = []
    blocks: list[np.ndarray] = []
    short = np.zeros(n, bool)
    scalar_index = {key: j for j, (key, _) in enumerate(scalars)}
    for key, _, array in plan:
        if not array:
            columns.append(key)
            blocks.append(values[:, scalar_index[key]:scalar_index[key] + 1])
            continue
        seqs = array_values[key]
        if any(len(s) and not _is_number(s[0]) for s in seqs):
            continue  # text after all (joint names given in later samples)
        lengths = np.array([len(s) for s in seqs])
        width = int(lengths.max())
        if width == 0:
            continue
        if (lengths == width).all():
            block = np.array(seqs, float).reshape(n, width)
        else:
            block = np.full((n, width), np.nan)
            for i, s in enumerate(seqs):
                block[i, :len(s)] = s
            short |= lengths < width
        columns += [f"{key}_{j + 1}" for j in range(width)]
        blocks.append(block)
    if not columns:
        raise TopicError(f"{topic} carries {schema}, which has no numeric fields to export")
    data = np.hstack(blocks)
    order = np.argsort(times, kind="stable")
    names = getattr(first, "name", None)
    return TopicTable(topic, schema, times[order], columns, data[order],
                      frame_id=frames.pop() if len(frames) == 1 else "",
                      names=[str(x) for x in names] if isinstance(names, list) else [],
                      short_samples=int(short.sum()))


def csv_name(topic: str) -> str:
    """File name of a topic's CSV: `/PSM1/measured_js` -> `PSM1.measured_js.csv`. ROS 2 names
    never hold a ".", so two topics never share a file."""
    parts = [p for p in topic.split("/") if p]
    return (".".join(parts) or "root") + ".csv"


def _cell(value: float) -> str:
    # repr: the shortest text that reads back to the same double; an empty cell reads as NaN
    return "" if math.isnan(value) else repr(value)


def write_csv(table: TopicTable, path: Path) -> None:
    """Header row `t,<columns>`, comma separated, one row per sample."""
    path = Path(path)
    lines = [",".join(["t", *table.columns])]
    for t, row in zip(table.t.tolist(), table.data.tolist()):
        lines.append(",".join([repr(t), *map(_cell, row)]))
    path.write_text("\n".join(lines) + "\n")
