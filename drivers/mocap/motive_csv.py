"""OptiTrack Motive CSV exports: reader and writer.

Motive's export layout (format version 1.2x), one line each::

    Format Version,1.23,Take Name,...,Capture Frame Rate,120,Export Frame Rate,120,...,
        Rotation Type,Quaternion,Length Units,Millimeters,Coordinate Space,Global
    <blank>
    ,Type,Rigid Body,Rigid Body,...,Rigid Body Marker,...,Marker,...
    ,Name,Tool,Tool,...,Tool:Marker1,...,Tool:Marker1,...
    ,ID,1,1,...,1:1,...
    ,,Rotation,Rotation,Rotation,Rotation,Position,Position,Position,Mean Marker Error,...
    Frame,Time (Seconds),X,Y,Z,W,X,Y,Z,,X,Y,Z,,...
    0,0.000000,0.012345,...

(newer versions add a ``,Parent,...`` row; it is accepted). Occluded samples are empty
cells. This module returns them as NaN with a boolean validity mask, never as zeros, and
converts lengths to metres. Rotations are quaternions whose component order is read from
the axis row's labels (Motive writes X,Y,Z,W) and returned in (x, y, z, w) order; the
conversion functions live in `drivers.common.quaternion`.

The writer produces the same layout, so the simulated mocap system and the tests create
files that the reader (and Motive-reading tools) accept.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping

import numpy as np

from drivers.interfaces import Pose, TrackerFrame
from drivers.common.quaternion import XYZW, ORDERS, quat_xyzw_to_matrix, reorder_quaternion

LENGTH_SCALE = {"meters": 1.0, "centimeters": 1e-2, "millimeters": 1e-3}
_UNIT_ALIASES = {"m": "Meters", "meters": "Meters", "mm": "Millimeters", "millimeters": "Millimeters"}
HEADER_LABELS = ("Type", "Name", "ID", "Parent")
# A unit quaternion read back from a 6-decimal file has |q| within ~1e-5 of 1; anything
# far from 1 means the columns are not a quaternion (e.g. positions under the wrong label).
QUAT_NORM_TOLERANCE = 1e-2


class MotiveCsvError(ValueError):
    """A Motive CSV that cannot be read; the message names the file and line."""

    def __init__(self, path: str | Path, line: int | None, message: str):
        self.path = str(path)
        self.line = line
        where = f"{self.path}:{line}" if line is not None else self.path
        super().__init__(f"{where}: {message}")


@dataclass
class RigidBodyTrack:
    """One rigid body over a take.

    position: (N, 3) m in the mocap frame; quaternion_xyzw: (N, 4) unit quaternions in
    (x, y, z, w) order; valid: (N,) False where Motive lost the body (position and
    quaternion are NaN there); mean_marker_error: (N,) m, NaN where not exported.
    """

    name: str
    id: str
    time: np.ndarray
    position: np.ndarray
    quaternion_xyzw: np.ndarray
    valid: np.ndarray
    mean_marker_error: np.ndarray

    def rotation(self) -> np.ndarray:
        """Rotation matrices (N, 3, 3); NaN where the body is occluded."""
        return quat_xyzw_to_matrix(self.quaternion_xyzw)

    def pose(self, k: int, frame: str = "mocap") -> Pose | None:
        """The pose at sample k, or None when the body is occluded there."""
        if not self.valid[k]:
            return None
        return Pose(t=float(self.time[k]), position=self.position[k].copy(),
                    rotation=quat_xyzw_to_matrix(self.quaternion_xyzw[k]), frame=frame)


@dataclass
class MarkerTrack:
    """One marker over a take: position (N, 3) m, NaN and valid=False where occluded.

    kind is "Marker" (a measured, labelled marker) or "Rigid Body Marker" (Motive's
    solved position of a body's marker); quality (N,) is Motive's Marker Quality, NaN
    when not exported.
    """

    name: str
    id: str
    kind: str
    time: np.ndarray
    position: np.ndarray
    valid: np.ndarray
    quality: np.ndarray


@dataclass
class MotiveTake:
    """A parsed Motive export. Times in s, lengths in m, quaternions (x, y, z, w)."""

    path: str
    metadata: dict[str, str]
    length_unit: str
    frame_rate: float | None
    frame: np.ndarray
    time: np.ndarray
    rigid_bodies: dict[str, RigidBodyTrack] = field(default_factory=dict)
    rigid_body_markers: dict[str, MarkerTrack] = field(default_factory=dict)
    markers: dict[str, MarkerTrack] = field(default_factory=dict)

    def body(self, name: str) -> RigidBodyTrack:
        """The rigid body called `name`; a clear error listing the bodies present if absent."""
        if name not in self.rigid_bodies:
            present = ", ".join(repr(n) for n in self.rigid_bodies) or "none"
            raise MotiveCsvError(self.path, None,
                                 f"no rigid body named {name!r} in this export; "
                                 f"rigid bodies present: {present}")
        return self.rigid_bodies[name]

    def marker(self, name: str) -> MarkerTrack:
        """The labelled marker called `name` (type "Marker"), with a clear error if absent."""
        if name not in self.markers:
            present = ", ".join(repr(n) for n in self.markers) or "none"
            raise MotiveCsvError(self.path, None,
                                 f"no marker named {name!r} in this export; markers present: {present}")
        return self.markers[name]

    def tracker_frames(self, frame: str = "mocap") -> list[TrackerFrame]:
        """The take as Tracker frames (bodies None and markers None where occluded)."""
        out = []
        for k in range(len(self.time)):
            bodies = {n: b.pose(k, frame) for n, b in self.rigid_bodies.items()}
            markers = {n: (m.position[k].copy() if m.valid[k] else None)
                       for n, m in self.markers.items()}
            out.append(TrackerFrame(t=float(self.time[k]), bodies=bodies, markers=markers))
        return out


# ----------------------------------------------------------------------------- reader

def _canonical_unit(units: str) -> str:
    key = units.strip().lower()
    if key not in _UNIT_ALIASES:
        raise ValueError(f"unknown length unit {units!r}; use 'Meters'/'m' or 'Millimeters'/'mm'")
    return _UNIT_ALIASES[key]


def _parse_metadata(path: Path, row: list[str]) -> dict[str, str]:
    if not row or row[0].strip() != "Format Version":
        first = row[0].strip() if row else ""
        raise MotiveCsvError(path, 1,
                             f"not a Motive CSV export: the first line starts with {first!r}, "
                             "expected 'Format Version,...' (export from Motive with the "
                             "header information switched on)")
    meta: dict[str, str] = {}
    for i in range(0, len(row) - 1, 2):
        key = row[i].strip()
        if key:
            meta[key] = row[i + 1].strip()
    return meta


def read_motive_csv(path: str | Path, quat_order: str | None = None) -> MotiveTake:
    """Read a Motive CSV export.

    quat_order: None reads the quaternion component order from the axis row labels
    (X,Y,Z,W as Motive writes them, or W,X,Y,Z); "xyzw" or "wxyz" forces the order of
    the four rotation columns whatever their labels say (for files from tools that
    mislabel them). Returned quaternions are always (x, y, z, w).
    Raises MotiveCsvError naming the file and line for anything it cannot read.
    """
    path = Path(path)
    if quat_order is not None and quat_order not in ORDERS:
        raise ValueError(f"quat_order must be None or one of {ORDERS}, got {quat_order!r}")
    try:
        with open(path, newline="", encoding="utf-8-sig") as f:
            rows = list(csv.reader(f))
    except UnicodeDecodeError as e:
        raise MotiveCsvError(path, None, f"not a text CSV file ({e})") from None
    if not rows:
        raise MotiveCsvError(path, 1, "empty file, not a Motive CSV export")
    meta = _parse_metadata(path, rows[0])

    rot_type = meta.get("Rotation Type", "")
    if rot_type.lower() != "quaternion":
        raise MotiveCsvError(path, 1,
                             f"Rotation Type is {rot_type!r} (Euler angles), not Quaternion; "
                             "re-export from Motive with Rotation Type = Quaternion, because "
                             "Euler angles are ambiguous in order and singular near gimbal lock")
    unit = meta.get("Length Units", "Meters")
    if unit.lower() not in LENGTH_SCALE:
        raise MotiveCsvError(path, 1, f"unknown Length Units {unit!r}; expected Meters, "
                                      "Centimeters or Millimeters")
    scale = LENGTH_SCALE[unit.lower()]
    frame_rate = None
    for key in ("Export Frame Rate", "Capture Frame Rate"):
        try:
            frame_rate = float(meta[key])
            break
        except (KeyError, ValueError):
            continue

    # Header rows: labelled in the second column, the kind row directly above "Frame".
    axis_idx = next((i for i, r in enumerate(rows[:20]) if r and r[0].strip() == "Frame"), None)
    if axis_idx is None:
        raise MotiveCsvError(path, None,
                             "no column header line 'Frame,Time (Seconds),X,Y,Z,...' in the "
                             "first 20 lines: not a Motive export or a truncated header")
    header: dict[str, list[str]] = {}
    for i in range(1, axis_idx - 1):
        r = rows[i]
        if len(r) > 1 and r[1].strip() in HEADER_LABELS:
            header[r[1].strip()] = r
    for need in ("Type", "Name"):
        if need not in header:
            raise MotiveCsvError(path, axis_idx,
                                 f"header row ',{need},...' missing above the 'Frame' line: "
                                 "not a Motive export layout")
    axis_row = rows[axis_idx]
    kind_row = rows[axis_idx - 1]
    ncol = len(axis_row)
    if ncol < 2 or axis_row[1].strip().lower() != "time (seconds)":
        raise MotiveCsvError(path, axis_idx + 1,
                             f"second column is {axis_row[1] if ncol > 1 else ''!r}, expected "
                             "'Time (Seconds)'")

    def cell(row: list[str], j: int) -> str:
        return row[j].strip() if j < len(row) else ""

    # Group columns: (type, name) -> {(kind, axis): column}
    groups: dict[tuple[str, str], dict[tuple[str, str], int]] = {}
    ids: dict[tuple[str, str], str] = {}
    for j in range(2, ncol):
        typ = cell(header["Type"], j)
        name = cell(header["Name"], j)
        if not typ and not name:
            continue
        key = (typ, name)
        groups.setdefault(key, {})[(cell(kind_row, j), cell(axis_row, j).upper())] = j
        ids.setdefault(key, cell(header.get("ID", []), j))

    # Data
    data_rows = []
    line_numbers = []
    for i in range(axis_idx + 1, len(rows)):
        r = rows[i]
        if not r or all(not c.strip() for c in r):
            continue  # a trailing blank line is not data
        if len(r) < ncol:
            raise MotiveCsvError(path, i + 1,
                                 f"truncated row: {len(r)} cells, the header has {ncol} "
                                 "(the export was cut off or the file is damaged)")
        if any(c.strip() for c in r[ncol:]):
            raise MotiveCsvError(path, i + 1,
                                 f"{len(r)} cells but the header has {ncol}: extra data")
        data_rows.append(r[:ncol])
        line_numbers.append(i + 1)
    if not data_rows:
        raise MotiveCsvError(path, axis_idx + 2, "no data rows after the header")

    n = len(data_rows)
    table = np.full((n, ncol), np.nan)
    for k, r in enumerate(data_rows):
        for j, c in enumerate(r):
            c = c.strip()
            if not c:
                continue
            try:
                table[k, j] = float(c)
            except ValueError:
                if j == 0:
                    col = "Frame"
                elif j == 1:
                    col = "Time (Seconds)"
                else:
                    col = " ".join(x for x in (cell(header["Name"], j), cell(kind_row, j),
                                               cell(axis_row, j)) if x)
                raise MotiveCsvError(path, line_numbers[k],
                                     f"non-numeric cell {c!r} in column {j + 1} ({col})") from None
    if np.any(~np.isfinite(table[:, 1])):
        k = int(np.flatnonzero(~np.isfinite(table[:, 1]))[0])
        raise MotiveCsvError(path, line_numbers[k], "missing time stamp")
    frame = np.where(np.isfinite(table[:, 0]), table[:, 0], -1).astype(int)
    time = table[:, 1].copy()

    def vec(cols: dict[tuple[str, str], int], kind: str, axes: str, what: str) -> np.ndarray:
        missing = [a for a in axes if (kind, a) not in cols]
        if missing:
            raise MotiveCsvError(path, axis_idx + 1,
                                 f"{what}: {kind} columns {','.join(missing)} missing")
        return table[:, [cols[(kind, a)] for a in axes]]

    take = MotiveTake(path=str(path), metadata=meta, length_unit=unit, frame_rate=frame_rate,
                      frame=frame, time=time)
    for (typ, name), cols in groups.items():
        what = f"{typ} {name!r}"
        if typ == "Rigid Body":
            if ("Rotation", "W") not in cols:
                raise MotiveCsvError(path, axis_idx + 1,
                                     f"{what}: no W rotation column; rotations look like Euler "
                                     "angles, re-export with Rotation Type = Quaternion")
            rot_cols = sorted(j for (kind, _), j in cols.items() if kind == "Rotation")
            if quat_order is None:
                q = vec(cols, "Rotation", "XYZW", what)
            else:
                q = reorder_quaternion(table[:, rot_cols], quat_order, XYZW)
            p = vec(cols, "Position", "XYZ", what) * scale
            valid = np.all(np.isfinite(q), axis=1) & np.all(np.isfinite(p), axis=1)
            norms = np.linalg.norm(q[valid], axis=1)
            bad = np.flatnonzero(np.abs(norms - 1.0) > QUAT_NORM_TOLERANCE)
            if bad.size:
                k = int(np.flatnonzero(valid)[bad[0]])
                raise MotiveCsvError(path, line_numbers[k],
                                     f"{what}: rotation is not a unit quaternion (|q| = "
                                     f"{norms[bad[0]]:.4f}); the columns are not a quaternion")
            q = q.copy()
            q[valid] /= norms[:, None]
            q[~valid] = np.nan
            p = p.copy()
            p[~valid] = np.nan
            err_col = next((j for (kind, _), j in cols.items() if kind == "Mean Marker Error"), None)
            err = table[:, err_col] * scale if err_col is not None else np.full(n, np.nan)
            take.rigid_bodies[name] = RigidBodyTrack(name=name, id=ids[(typ, name)], time=time,
                                                     position=p, quaternion_xyzw=q, valid=valid,
                                                     mean_marker_error=err)
        elif typ in ("Marker", "Rigid Body Marker"):
            p = vec(cols, "Position", "XYZ", what) * scale
            valid = np.all(np.isfinite(p), axis=1)
            p = p.copy()
            p[~valid] = np.nan
            qcol = next((j for (kind, _), j in cols.items() if kind == "Marker Quality"), None)
            quality = table[:, qcol] if qcol is not None else np.full(n, np.nan)
            track = MarkerTrack(name=name, id=ids[(typ, name)], kind=typ, time=time,
                                position=p, valid=valid, quality=quality)
            (take.markers if typ == "Marker" else take.rigid_body_markers)[name] = track
        # Other asset types (Skeleton, Bone, Force Plate, ...) are not used by the rig.
    return take


# ----------------------------------------------------------------------------- writer

def _fmt(v: float, decimals: int) -> str:
    return "" if not math.isfinite(v) else f"{v:.{decimals}f}"


def write_motive_csv(path: str | Path, time: np.ndarray,
                     rigid_bodies: Mapping[str, RigidBodyTrack | tuple] | None = None,
                     markers: Mapping[str, np.ndarray | MarkerTrack] | None = None,
                     rigid_body_markers: Mapping[str, np.ndarray | MarkerTrack] | None = None,
                     *, units: str = "Meters", quat_order: str = XYZW,
                     frame_rate: float | None = None, take_name: str = "dvrk-rig",
                     start_frame: int = 0, decimals: int = 6,
                     rotation_type: str = "Quaternion") -> Path:
    """Write a take in Motive's CSV export layout.

    time: (N,) s. rigid_bodies: name -> RigidBodyTrack, or a tuple (position (N, 3) m,
    quaternion_xyzw (N, 4)[, mean_marker_error (N,) m]); rows with NaN are written as
    empty cells (occluded). markers / rigid_body_markers: name -> (N, 3) m or MarkerTrack.
    units: "Meters"/"m" or "Millimeters"/"mm" (lengths are converted on writing).
    quat_order: "xyzw" (Motive's own) or "wxyz": the order of the four rotation columns,
    labelled accordingly in the axis row. rotation_type other than "Quaternion" only
    changes the metadata line (to produce a file the reader must refuse, for tests).
    """
    path = Path(path)
    time = np.asarray(time, dtype=float)
    n = len(time)
    unit = _canonical_unit(units)
    scale = 1.0 / LENGTH_SCALE[unit.lower()]
    if quat_order not in ORDERS:
        raise ValueError(f"quat_order must be one of {ORDERS}, got {quat_order!r}")
    if frame_rate is None:
        frame_rate = 1.0 / float(np.median(np.diff(time))) if n > 1 else 120.0

    # columns: list of (type, name, id, kind, axis, values (N,))
    columns: list[tuple[str, str, str, str, str, np.ndarray]] = []
    for i, (name, b) in enumerate((rigid_bodies or {}).items(), start=1):
        if isinstance(b, RigidBodyTrack):
            p, q, err, bid = b.position, b.quaternion_xyzw, b.mean_marker_error, b.id or str(i)
        else:
            p, q = np.asarray(b[0], float), np.asarray(b[1], float)
            err = np.asarray(b[2], float) if len(b) > 2 else np.full(n, np.nan)
            bid = str(i)
        if p.shape != (n, 3) or q.shape != (n, 4):
            raise ValueError(f"rigid body {name!r}: position must be ({n}, 3) and quaternion "
                             f"({n}, 4), got {p.shape} and {q.shape}")
        q_out = reorder_quaternion(q, XYZW, quat_order)
        for a, col in zip(quat_order.upper(), q_out.T):
            columns.append(("Rigid Body", name, bid, "Rotation", a, col))
        for a, col in zip("XYZ", p.T):
            columns.append(("Rigid Body", name, bid, "Position", a, col * scale))
        columns.append(("Rigid Body", name, bid, "Mean Marker Error", "", err * scale))

    def add_markers(group: Mapping | None, typ: str) -> None:
        for i, (name, m) in enumerate((group or {}).items(), start=1):
            if isinstance(m, MarkerTrack):
                pos, mid, quality = m.position, m.id or str(i), m.quality
            else:
                pos, mid, quality = np.asarray(m, float), str(i), np.full(n, np.nan)
            if pos.shape != (n, 3):
                raise ValueError(f"{typ} {name!r}: position must be ({n}, 3), got {pos.shape}")
            for a, col in zip("XYZ", pos.T):
                columns.append((typ, name, mid, "Position", a, col * scale))
            if typ == "Rigid Body Marker":
                columns.append((typ, name, mid, "Marker Quality", "", quality))

    add_markers(rigid_body_markers, "Rigid Body Marker")
    add_markers(markers, "Marker")

    meta = ["Format Version", "1.23", "Take Name", take_name, "Take Notes", "",
            "Capture Frame Rate", f"{frame_rate:.6f}", "Export Frame Rate", f"{frame_rate:.6f}",
            "Capture Start Time", "2000-01-01 12.00.00.000 AM", "Capture Start Frame", str(start_frame),
            "Total Frames in Take", str(n), "Total Exported Frames", str(n),
            "Rotation Type", rotation_type, "Length Units", unit, "Coordinate Space", "Global"]
    with open(path, "w", newline="", encoding="utf-8") as f:
        w = csv.writer(f, lineterminator="\r\n")  # Motive is a Windows program
        w.writerow(meta)
        w.writerow([])
        w.writerow(["", "Type"] + [c[0] for c in columns])
        w.writerow(["", "Name"] + [c[1] for c in columns])
        w.writerow(["", "ID"] + [c[2] for c in columns])
        w.writerow(["", ""] + [c[3] for c in columns])
        w.writerow(["Frame", "Time (Seconds)"] + [c[4] for c in columns])
        values = np.column_stack([c[5] for c in columns]) if columns else np.zeros((n, 0))
        for k in range(n):
            w.writerow([str(start_frame + k), f"{time[k]:.6f}"]
                       + [_fmt(v, decimals) for v in values[k]])
    return path
