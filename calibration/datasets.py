"""Recorded joint data for identification: loading, validation, train/held-out split.

The CSV format is that of the WPI dVRK identification data (``shared/data/wpi-psm``): no
header, comma separated, 3n columns grouped by quantity (q1..qn, dq1..dqn, tau1..taun),
one row per sample at a fixed rate (t = row / rate). Units SI: rad or m, rad/s or m/s,
N m or N.

Every error names the file and the line (1-based, as an editor shows it) and column
(1-based, with the quantity it holds), and says what to do.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np


class DataError(ValueError):
    """Recorded data that cannot be used for identification."""


class EmptyDataError(DataError):
    """No samples (empty or truncated file)."""


class ColumnCountError(DataError):
    """The number of columns is not 3 * n joints, or fewer joints than asked."""


class NonFiniteError(DataError):
    """A NaN or infinite value, or a field that is not a number."""


class NonMonotonicTimeError(DataError):
    """Time stamps that do not strictly increase."""


class ConstantSignalError(DataError):
    """A joint whose position or torque never changes: it cannot be identified."""


@dataclass(frozen=True)
class FilterContext:
    """The untrimmed filtered motion a processed block was cut from, and its filter.

    Parallel filtering (:func:`calibration.signals.lowpass_stacked`) of a regressor must run
    over the same samples as the torque filter did, so that its end transients fall where
    the torques' did (in the trimmed ends), not inside the block. ``start`` is the block's
    first sample in these arrays; q, dq, ddq (N, nj) SI; rate, cutoff in Hz.
    """

    q: np.ndarray
    dq: np.ndarray
    ddq: np.ndarray
    rate: float
    cutoff: float
    order: int
    start: int
    #: The measured (unfiltered) q and dq (N, nj) the filtered motion came from, for the
    #: functions a model evaluates on raw samples (a hysteresis state runs on them).
    raw_q: np.ndarray | None = None
    raw_dq: np.ndarray | None = None

    def rows_raw(self, fn, n: int) -> np.ndarray:
        """As `rows`, with ``fn(q, dq, ddq)`` of the measured q and dq (and the filtered
        ddq): what a model computes on raw samples, low-passed like the torques. Without the
        raw motion, `rows`."""
        if self.raw_q is None:
            return self.rows(fn, n)
        from calibration.signals import lowpass_stacked

        nj = self.q.shape[1]
        X = lowpass_stacked(fn(self.raw_q, self.raw_dq, self.ddq), nj, self.rate, self.cutoff, self.order)
        return X[nj * self.start:nj * (self.start + n)]

    def rows(self, fn, n: int) -> np.ndarray:
        """``fn(q, dq, ddq) -> (N * nj, p)`` stacked sample-major on the untrimmed motion,
        low-passed like the torques, and cut to the block's ``n`` samples."""
        from calibration.signals import lowpass_stacked

        nj = self.q.shape[1]
        X = lowpass_stacked(fn(self.q, self.dq, self.ddq), nj, self.rate, self.cutoff, self.order)
        return X[nj * self.start:nj * (self.start + n)]


@dataclass
class JointData:
    """Joint samples: t (n,) in s; q, dq, tau (n, nj) SI; ddq (n, nj) once processed.

    ``rate`` is the nominal sampling rate in Hz; ``source`` a description of where the data
    came from (a file path and the rows kept) for error messages and provenance.
    ``context``: once processed, the untrimmed filtered motion (see :class:`FilterContext`).
    """

    t: np.ndarray
    q: np.ndarray
    dq: np.ndarray
    tau: np.ndarray
    rate: float
    source: str = "<memory>"
    ddq: np.ndarray | None = None
    context: FilterContext | None = None

    @property
    def n_samples(self) -> int:
        return self.q.shape[0]

    @property
    def n_joints(self) -> int:
        return self.q.shape[1]

    def rows(self, sl: slice, note: str = "") -> "JointData":
        """The samples in ``sl`` (a contiguous block)."""
        start, _, step = sl.indices(self.n_samples)
        if step != 1:
            raise ValueError(f"rows() takes a contiguous block, got a slice with step {step}")
        ctx = None if self.context is None else replace(self.context, start=self.context.start + start)
        return replace(self, t=self.t[sl], q=self.q[sl], dq=self.dq[sl], tau=self.tau[sl],
                       ddq=None if self.ddq is None else self.ddq[sl], context=ctx,
                       source=self.source + (f" [{note}]" if note else ""))

    @classmethod
    def from_arrays(cls, q, dq, tau, rate: float | None = None, t=None, source: str = "<memory>",
                    check_constant: bool = True) -> "JointData":
        """Build and validate from arrays (e.g. a recorded run); ``t`` must strictly increase.

        When ``t`` is given and ``rate`` is not, the rate is the median sampling rate.
        """
        q, dq, tau = (np.atleast_2d(np.asarray(x, dtype=float)) for x in (q, dq, tau))
        if q.shape[0] == 0:
            raise EmptyDataError(f"{source}: no samples")
        if not (q.shape == dq.shape == tau.shape):
            raise ColumnCountError(f"{source}: q {q.shape}, dq {dq.shape} and tau {tau.shape} "
                                   "must have the same shape (samples, joints)")
        for name, x in (("q", q), ("dq", dq), ("tau", tau)):
            _check_finite(x, source, name, first_line=0)
        if t is None:
            if rate is None:
                raise DataError(f"{source}: give a sampling rate or time stamps")
            t = np.arange(q.shape[0]) / float(rate)
        else:
            t = np.asarray(t, dtype=float)
            if t.shape != (q.shape[0],):
                raise DataError(f"{source}: {t.shape[0]} time stamps for {q.shape[0]} samples")
            _check_finite(t[:, None], source, "t", first_line=0)
            steps = np.diff(t)
            bad = np.flatnonzero(steps <= 0)
            if bad.size:
                k = int(bad[0]) + 1
                raise NonMonotonicTimeError(
                    f"{source}: time does not increase at sample {k} "
                    f"(t[{k - 1}] = {t[k - 1]:.6f} s, t[{k}] = {t[k]:.6f} s); "
                    f"{bad.size} such step(s): re-record or sort and de-duplicate the samples")
            if rate is None:
                rate = 1.0 / float(np.median(steps)) if steps.size else 1.0
        data = cls(t, q, dq, tau, float(rate), source)
        if check_constant:
            _check_not_constant(data, source)
        return data


_QUANTITIES = ("q", "dq", "tau")


def _check_finite(x: np.ndarray, source: str, name: str, first_line: int):
    bad = ~np.isfinite(x)
    if bad.any():
        r, c = np.argwhere(bad)[0]
        raise NonFiniteError(f"{source}: {name}{c + 1} at sample {r + first_line} is {x[r, c]}; "
                             f"{int(bad.sum())} non-finite value(s) in {name}: drop or repair them")


def _check_not_constant(data: JointData, source: str):
    for name in ("q", "tau"):
        x = getattr(data, name)
        span = np.ptp(x, axis=0)
        for j in np.flatnonzero(span == 0.0):
            raise ConstantSignalError(
                f"{source}: {name}{j + 1} is constant ({x[0, j]}) over all {x.shape[0]} samples: "
                f"joint {j + 1} did not move or was not recorded, so it cannot be identified")


def load_csv(path, rate: float = 200.0, joints: int | None = None) -> JointData:
    """Load a WPI-format joint CSV (no header, 3n columns q|dq|tau) as :class:`JointData`.

    ``joints`` keeps the first ``joints`` joints of each group (e.g. 3 of the PSM's 7);
    ``rate`` in Hz gives t = row / rate.
    """
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as e:
        raise DataError(f"{path}: cannot read ({e.strerror})") from None
    except UnicodeDecodeError:
        raise DataError(f"{path}: not a text CSV file (binary content): expected rows of 3n "
                        "comma-separated numbers (q1..qn, dq1..dqn, tau1..taun)") from None
    lines = text.splitlines()
    # A trailing blank line is normal; blank lines inside are not skipped silently.
    while lines and not lines[-1].strip():
        lines.pop()
    if not lines:
        raise EmptyDataError(f"{path}: file is empty: expected rows of 3n comma-separated numbers "
                             "(q1..qn, dq1..dqn, tau1..taun)")
    rows = [ln.split(",") for ln in lines]
    ncol = len(rows[0])
    if ncol % 3 != 0:
        raise ColumnCountError(f"{path}, line 1: {ncol} columns is not a multiple of 3: expected "
                               "3n columns grouped as q1..qn, dq1..dqn, tau1..taun")
    n_file = ncol // 3
    for i, r in enumerate(rows):
        if len(r) != ncol:
            what = "truncated" if i == len(rows) - 1 and len(r) < ncol else "inconsistent"
            raise ColumnCountError(f"{path}, line {i + 1}: {len(r)} columns where line 1 has "
                                   f"{ncol} ({what} row): repair or remove the line")
    if joints is None:
        joints = n_file
    if joints < 1 or joints > n_file:
        raise ColumnCountError(f"{path}: {joints} joints asked but the file has {ncol} columns "
                               f"= {n_file} joints x (q, dq, tau)")
    try:
        arr = np.array(rows, dtype=float)
    except ValueError:
        arr = None
    if arr is None:
        for i, r in enumerate(rows):
            for c, field in enumerate(r):
                try:
                    float(field)
                except ValueError:
                    raise NonFiniteError(
                        f"{path}, line {i + 1}, column {c + 1} ({_column_name(c, n_file)}): "
                        f"{field.strip()!r} is not a number") from None
    keep = np.concatenate([np.arange(joints) + g * n_file for g in range(3)])
    sub = arr[:, keep]
    bad = ~np.isfinite(sub)
    if bad.any():
        r, c = np.argwhere(bad)[0]
        fc = int(keep[c])
        raise NonFiniteError(f"{path}, line {r + 1}, column {fc + 1} ({_column_name(fc, n_file)}): "
                             f"{arr[r, fc]}; {int(bad.sum())} non-finite value(s) in the joints used: "
                             "drop or repair them")
    source = str(path)
    q, dq, tau = sub[:, :joints], sub[:, joints:2 * joints], sub[:, 2 * joints:]
    data = JointData(np.arange(arr.shape[0]) / float(rate), q, dq, tau, float(rate), source)
    _check_not_constant(data, source)
    return data


def load_timed_csv(path, rate: float, joints: int):
    """A CSV whose first column is time (s) and the rest the WPI columns, checked and
    resampled to a uniform grid at ``rate`` Hz (linear interpolation) as JointData.

    Raises the calibration.datasets errors naming the line (column count, non-numbers,
    non-finite values) or the sample (time that does not increase).
    """
    path = Path(path)
    try:
        lines = [ln for ln in path.read_text().splitlines()]
    except OSError as exc:
        raise DataError(f"{path}: cannot read ({exc.strerror})") from None
    except UnicodeDecodeError:
        raise DataError(f"{path}: not a text CSV file (binary content): expected rows of "
                        "t, q1..qn, dq1..dqn, tau1..taun") from None
    while lines and not lines[-1].strip():
        lines.pop()
    if not lines:
        raise EmptyDataError(f"{path}: file is empty: expected rows of t, q1..qn, dq1..dqn, tau1..taun")
    rows = [ln.split(",") for ln in lines]
    ncol = len(rows[0])
    if ncol < 4 or (ncol - 1) % 3:
        raise ColumnCountError(f"{path}, line 1: {ncol} columns: with --time-column expected 1 + 3n columns "
                               "(t, q1..qn, dq1..dqn, tau1..taun)")
    for i, r in enumerate(rows):
        if len(r) != ncol:
            raise ColumnCountError(f"{path}, line {i + 1}: {len(r)} columns where line 1 has {ncol}")
    try:
        arr = np.array(rows, dtype=float)
    except ValueError:
        for i, r in enumerate(rows):
            for c, f in enumerate(r):
                try:
                    float(f)
                except ValueError:
                    raise NonFiniteError(f"{path}, line {i + 1}, column {c + 1}: {f.strip()!r} is not a number") from None
        raise
    n_file = (ncol - 1) // 3
    if joints > n_file:
        raise ColumnCountError(f"{path}: {joints} joints asked but the file has {n_file}")
    t = arr[:, 0]
    q, dq, tau = (arr[:, 1 + g * n_file:1 + g * n_file + joints] for g in range(3))
    data = JointData.from_arrays(q, dq, tau, t=t, source=str(path))  # checks finite and increasing time
    grid = np.arange(t[0], t[-1] + 0.5 / rate, 1.0 / rate)
    grid = grid[grid <= t[-1]]

    def resample(x):
        return np.column_stack([np.interp(grid, data.t, x[:, j]) for j in range(x.shape[1])])

    return JointData.from_arrays(resample(data.q), resample(data.dq), resample(data.tau), rate=rate,
                                 t=grid, source=f"{path} [resampled to {rate:g} Hz]")


def _column_name(c: int, n_joints: int) -> str:
    return f"{_QUANTITIES[c // n_joints]}{c % n_joints + 1}"


def split_blocks(data: JointData, heldout_fraction: float = 0.25,
                 heldout: str = "end") -> tuple[JointData, JointData]:
    """Split into contiguous (train, held-out) blocks; the held-out block at the ``"end"``
    or ``"start"``. Contiguous blocks (not random rows) because neighbouring samples of a
    filtered signal are strongly correlated: a random split would validate on the training data.
    """
    if not (0.0 < heldout_fraction < 1.0):
        raise ValueError(f"heldout_fraction must lie in (0, 1), got {heldout_fraction}")
    n = data.n_samples
    n_out = int(round(n * heldout_fraction))
    if n_out < 1 or n - n_out < 1:
        raise DataError(f"{data.source}: {n} samples cannot be split {1 - heldout_fraction:.2f}/"
                        f"{heldout_fraction:.2f}")
    if heldout == "end":
        return (data.rows(slice(0, n - n_out), f"train rows 1-{n - n_out}"),
                data.rows(slice(n - n_out, n), f"held-out rows {n - n_out + 1}-{n}"))
    if heldout == "start":
        return (data.rows(slice(n_out, n), f"train rows {n_out + 1}-{n}"),
                data.rows(slice(0, n_out), f"held-out rows 1-{n_out}"))
    raise ValueError(f"heldout must be 'end' or 'start', got {heldout!r}")


def processed(data: JointData, cutoff: float = 3.5, order: int = 8, trim: int | None = None,
              diff_method: str = "central") -> JointData:
    """Filtered copy with accelerations (thesis 5.5), ends trimmed; see ``calibration.signals.process``."""
    from calibration.signals import process

    p = process(data.q, data.dq, data.tau, data.rate, cutoff, order, trim, diff_method, keep_full=True)
    k = p.kept
    ctx = FilterContext(p.full[0], p.full[1], p.full[2], data.rate, cutoff, order, k.start,
                        np.asarray(data.q, float), np.asarray(data.dq, float))
    return replace(data, t=data.t[k], q=p.q, dq=p.dq, tau=p.tau, ddq=p.ddq, context=ctx,
                   source=f"{data.source} [filtered {order}th-order {cutoff} Hz, rows "
                          f"{k.start + 1}-{k.stop}]")


class PiecesContext:
    """Parallel filtering over several processed pieces (each its own
    `calibration.datasets.FilterContext`): a function of the motion becomes each piece's
    filtered rows, put end to end."""

    def __init__(self, pieces):
        self.pieces = pieces   # [(FilterContext, samples used)]

    def rows(self, fn, n: int) -> np.ndarray:
        out = np.vstack([ctx.rows(fn, k) for ctx, k in self.pieces])
        return out[:n * self.pieces[0][0].q.shape[1]]

    def rows_raw(self, fn, n: int) -> np.ndarray:
        out = np.vstack([ctx.rows_raw(fn, k) for ctx, k in self.pieces])
        return out[:n * self.pieces[0][0].q.shape[1]]


def pieces_training_block(data, breaks, cutoff: float, order: int, heldout: float):
    """The training block of pieces put end to end: each piece processed (filtered, trimmed)
    on its own, and the first 1 - ``heldout`` of their samples kept, as `split_blocks` keeps
    of one processed record. Pieces too short for the identification filter are left out."""
    from dataclasses import replace

    from calibration.signals import settling_samples

    trim = settling_samples(data.rate, cutoff, order)
    edges = [0] + sorted(int(b) for b in breaks) + [data.n_samples]
    parts = [processed(data.rows(slice(a, b)), cutoff, order) for a, b in zip(edges[:-1], edges[1:])
             if b - a > 4 * trim]
    if not parts:
        raise DataError(f"{data.source}: no piece lasts {4 * trim / data.rate:.1f} s, the shortest the "
                               f"{cutoff:g} Hz identification filter needs to estimate the gravity direction; "
                               "give an identified model with --model (its gravity is used)")
    total = sum(p.n_samples for p in parts)
    keep = total - int(round(total * heldout))
    used = []
    for p in parts:
        k = min(p.n_samples, keep - sum(u.n_samples for u in used))
        if k <= 0:
            break
        used.append(p.rows(slice(0, k)))
    cat = {name: np.concatenate([getattr(u, name) for u in used]) for name in ("t", "q", "dq", "tau", "ddq")}
    return replace(used[0], **cat, source=f"{data.source} [{len(used)} pieces, filtered each on its own]",
                   context=PiecesContext([(u.context, u.n_samples) for u in used]))
