"""A record prepared for the workflow: filtered, differentiated, trimmed per piece, split into train and held-out."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from calibration.discrepancy.settings import DiscrepancyError, Settings
from calibration.signals import lowpass, settling_samples

#: Velocity deadband (rad/s, rad/s, m/s) on the measured and the filtered velocity: slower, a joint may be
#: stuck, and its effort is then whatever the controller left inside the static friction
#: band, which no function of (q, dq, ddq) predicts (thesis 7.5.1; `rig identify` leaves
#: such samples out too). They are left out of every fit and every figure.
DEADBAND = np.array([0.01, 0.01, 0.002])
#: Shortest continuous recording (piece) of a record, in the filter's settling lengths: each
#: piece loses one at each end, so at least half of it is kept.
MIN_PIECE_TRIMS = 4


def pieces_of(n: int, breaks=()) -> list[tuple[int, int]]:
    """(start, stop) of each continuous recording in ``n`` samples put end to end, a new one
    beginning at every index of ``breaks`` (0 < index < n)."""
    cuts = sorted({int(b) for b in breaks})
    if any(not 0 < b < n for b in cuts):
        raise DiscrepancyError(f"breaks {cuts} must lie inside the {n} samples (0 < index < {n})")
    edges = [0] + cuts + [n]
    return list(zip(edges[:-1], edges[1:]))


@dataclass
class Prepared:
    """Raw (n, 3) and filtered-and-trimmed (m, 3) signals, the kept samples, train/held-out
    index ranges into the kept samples. ``q``, ``dq`` are the measured state ``effort_lag``
    earlier (aligned with the effort); ``qf``, ``dqf``, ``ddqf`` the filtered measured state.

    The raw samples may be several continuous recordings put end to end (``pieces``, raw
    index ranges: an identify run's excitation and validation trajectories, with the arm's
    unrecorded move between them). Filters, derivatives and every state carried along the
    samples (a Dahl state, a play, a delay, the last reversal) restart at each piece, and each
    piece's ends are trimmed: nothing is computed across a join. ``kept`` is then an index
    array (a slice for one piece)."""

    rate: float
    q: np.ndarray
    dq: np.ndarray
    tau: np.ndarray
    qf: np.ndarray
    dqf: np.ndarray
    ddqf: np.ndarray
    tauf: np.ndarray
    kept: slice | np.ndarray
    train: slice
    heldout: slice
    cutoff: float
    order: int
    moving_raw: np.ndarray      # (n, 3) 1.0 where the raw sample's joint moves, 0.0 where it is stuck
    qf_all: np.ndarray          # (n, 3) filtered, untrimmed (for the regressor before masking)
    dqf_all: np.ndarray
    ddqf_all: np.ndarray
    pieces: list = field(default_factory=list)   # [(start, stop)] raw; empty: one piece

    def piecewise(self, fn, x: np.ndarray) -> np.ndarray:
        """``fn`` (raw samples -> as many samples) applied to each piece of ``x`` (n, ...) on its own."""
        return piecewise(fn, x, self.pieces)

    def lowpass(self, x: np.ndarray) -> np.ndarray:
        """The zero-phase filter of raw columns (n, ...), each piece on its own; untrimmed."""
        return self.piecewise(lambda v: lowpass(v, self.rate, self.cutoff, self.order), x)

    def kept_starts(self) -> list[int]:
        """Kept-domain index where each piece after the first begins."""
        if len(self.pieces) < 2:
            return []
        trim = settling_samples(self.rate, self.cutoff, self.order)
        lengths = [b - a - 2 * trim for a, b in self.pieces]
        return np.cumsum(lengths)[:-1].tolist()

    def raw_starts(self) -> list[int]:
        """Raw index where each piece after the first begins."""
        return [a for a, _ in self.pieces[1:]]

    def filt(self, x: np.ndarray) -> np.ndarray:
        """Parallel filter of raw columns (n, ...) -> kept (m, ...)."""
        n = x.shape[0]
        flat = x.reshape(n, -1)
        return self.lowpass(flat)[self.kept].reshape((-1,) + x.shape[1:])

    def filt_rows(self, x: np.ndarray) -> np.ndarray:
        """Masked parallel filter of per-joint rows (n, 3, ...) -> kept (m, 3, ...): each joint's
        stuck raw samples are zeroed before filtering, as the measured effort is."""
        mask = self.moving_raw.reshape(self.moving_raw.shape + (1,) * (x.ndim - 2))
        return self.filt(x * mask)


def piecewise(fn, x: np.ndarray, pieces) -> np.ndarray:
    """``fn`` applied to each piece (raw index ranges) of ``x`` on its own, the results put end
    to end again; ``fn`` of all of ``x`` for one piece (or none given)."""
    if len(pieces) < 2:
        return fn(x)
    return np.concatenate([fn(x[a:b]) for a, b in pieces], axis=0)


def prepare(q, dq, tau, rate: float, settings: Settings, breaks=()) -> Prepared:
    """Filtered, masked and trimmed signals of measured q, dq, tau (n, 3) at ``rate`` Hz.
    ``breaks``: sample indices where another continuous recording begins (see `Prepared`)."""
    q, dq, tau = (np.asarray(x, float) for x in (q, dq, tau))
    if q.ndim != 2 or q.shape[1] != 3 or not (q.shape == dq.shape == tau.shape):
        raise DiscrepancyError(f"expected q, dq, tau of shape (n, 3), got {q.shape}, {dq.shape}, {tau.shape}")
    trim = settling_samples(rate, settings.cutoff, settings.order)
    n = q.shape[0]
    pieces = pieces_of(n, breaks)
    for k, (a, b) in enumerate(pieces if len(pieces) > 1 else []):
        if b - a < MIN_PIECE_TRIMS * trim:
            raise DiscrepancyError(
                f"piece {k + 1} of the record (samples {a}-{b - 1}, {(b - a) / rate:.2f} s) is too short: a continuous "
                f"recording needs at least {MIN_PIECE_TRIMS * trim} samples ({MIN_PIECE_TRIMS * trim / rate:.2f} s) "
                f"at {rate:g} Hz, {trim} of them trimmed at each end for the filter")
    m = n - 2 * trim * len(pieces)
    if m < 6 * trim + 200:
        raise DiscrepancyError(f"{n} samples are too few for the workflow at {rate:g} Hz: it needs at least "
                               f"{8 * trim + 200 + 2 * trim * (len(pieces) - 1)} "
                               f"({(8 * trim + 200 + 2 * trim * (len(pieces) - 1)) / rate:.1f} s) for the filter, "
                               "a training and a held-out block")
    if not 0.0 <= settings.effort_lag < 1.0 / rate:
        raise DiscrepancyError(f"effort_lag {settings.effort_lag:g} s: it must be >= 0 (the effort cannot precede "
                               f"the state) and under one sample ({1.0 / rate:g} s)")

    def filtered(x):
        return piecewise(lambda v: lowpass(v, rate, settings.cutoff, settings.order), x, pieces)

    qf = filtered(q)
    dqf = filtered(dq)
    ddqf = piecewise(lambda v: np.gradient(v, 1.0 / rate, axis=0), dqf, pieces)
    # A stuck joint's effort is whatever the controller left inside the static friction band,
    # no function of (q, dq, ddq). Leaving the stuck samples out after filtering is not
    # enough: the filter has already spread their effort over the moving samples around them
    # (up to ~20 samples at 10 Hz and 200 Hz), where it looks like a Stribeck, Dahl or delay
    # effect on every run. So the effort and every model column are masked (zeroed on the
    # joint's stuck raw samples) before filtering: the equation tau = W theta holds on the
    # moving samples, is 0 = 0 on the stuck ones, and survives the linear filter exactly.
    # The filter starts every breakaway a few samples early (and rings before it): a sample
    # moves only if the measured velocity is outside the deadband as well.
    moving_raw = ((np.abs(dqf) >= DEADBAND) & (np.abs(dq) >= DEADBAND)).astype(float)

    # The measured state effort_lag before each sample (linear interpolation), which the
    # model columns are built on.
    def lagged(x):
        t = np.arange(len(x)) / rate
        return np.column_stack([np.interp(t - settings.effort_lag, t, x[:, j]) for j in range(3)])

    q, dq = piecewise(lagged, q, pieces), piecewise(lagged, dq, pieces)
    tauf = filtered(tau * moving_raw)
    if len(pieces) == 1:
        kept = slice(trim, n - trim)
    else:
        kept = np.concatenate([np.arange(a + trim, b - trim) for a, b in pieces])
    n_ho = int(round(m * settings.heldout))
    train = slice(0, m - n_ho - trim)
    heldout = slice(m - n_ho, m)
    return Prepared(rate, q, dq, tau, qf[kept], dqf[kept], ddqf[kept], tauf[kept], kept, train, heldout,
                    settings.cutoff, settings.order, moving_raw, qf, dqf, ddqf,
                    pieces if len(pieces) > 1 else [])
