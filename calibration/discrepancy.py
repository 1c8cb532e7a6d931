"""The discrepancy workflow (issue 7): find where model and measurement disagree, name the
missing physical effect from the catalogue, add it, re-identify, and show the gap shrink on
data the fit did not see.

Method (after Ljung's residual analysis, Kaheman et al. 2019 "SINDy on the model
discrepancy", and BIC selection):

1. **Prepare.** Zero-phase Butterworth (order 4, 10 Hz by default: wider than the thesis'
   3.5 Hz so that friction features at reversals survive) on q, dq; ddq by central
   differences; ends trimmed by the filter's settling length. A joint is stuck on a sample
   where its measured or its filtered velocity is inside its deadband (the zero-phase filter
   starts every breakaway a few samples early): its effort there is whatever the controller
   left inside the static friction band. The model columns are built on the state
   ``effort_lag`` (1 ms) before each sample: the dVRK's 1 kHz PID reports the effort it
   computed from the previous servo cycle's state. The regressor comes from the filtered
   state, except its inertial term, whose source is chosen per joint by the training residual
   (again after each added effect): the filtered acceleration (quiet, but filtered twice by
   the time it meets the effort) or fourth-order central differences of the measured
   velocity, filtered once like the effort (as sharp as the effort at a breakaway; the
   simulated rig's and the WPI PSM's insertion joint, which stick-slips, choose it). The
   effort, the regressor, the smooth-sign Coulomb column and every effect column are zeroed
   on the joint's stuck samples and then filtered with the same filter (masked parallel
   filtering: the equation holds on moving samples, is 0 = 0 on stuck ones, and a linear
   filter keeps it exact; filtering first and dropping the stuck samples afterwards would
   leave their effort smeared over ~20 moving samples on each side, a Stribeck- or
   delay-like pattern on every null run). Train and held-out are contiguous blocks (the
   held-out one at the end) with a guard of one settling length between them. A record may
   be several continuous recordings put end to end (``breaks``: `rig identify`'s excitation
   and validation trajectories); each is filtered, differentiated and trimmed on its own, and
   every state carried along the samples (an effect's, the last reversal) restarts with it.
2. **Baseline.** Without a given model: the thesis model (rigid body + Fc sigma(dq) + Fv dq +
   Fo + Ia ddq) in base parameters, weighted least squares on the training block (weights
   1 / residual std per joint). With a given model: its standard parameters as they are.
3. **Detect**, per joint, on the held-out residual: (a) whiteness, a Ljung-Box Q on the
   residual decimated to the filter's band (rate / (2 cutoff) samples apart, 10 lags);
   (b) predictability, the held-out share of the residual's mean square (a constant part
   counts) a generic library of q, dq, ddq of all joints, the model torque u and its lag
   explains when fitted on the training residual. The thresholds are not textbook chi-square quantiles (filtering and the
   unavoidable friction-switching mismatch make the residual coloured even when nothing is
   missing): they are set on null simulations of the rig, residuals of simulated data
   without any hidden effect, stored in ``discrepancy_thresholds.json`` with how they were
   obtained (``calibration.discrepancy_null`` regenerates them). (c) A joint (a) and (b) call
   white is still structured if its best catalogue candidate (step 5) passes both of its
   null-calibrated tests: isolated bursts, such as the contacts after a play is crossed,
   hardly colour the decimated residual and the generic library cannot place them.
4. **Attribute**: the joint (only structured joints are searched), the variable that best
   explains the residual (binned conditional mean, fitted on train, scored on held-out)
   and the regime (the bin range where the residual's mean is largest).
5. **Name**: every catalogue effect on every joint (for 3c), over its grid, is fitted
   together with the current model (the baseline's parameters re-identified with it, by
   Frisch-Waugh projection: exact joint least squares); the BIC (with the effective number
   of independent samples of the filtered band) ranks them; the best on a structured joint
   must pass its sanity
   check, a BIC gain above the null threshold, and be confirmed on the held-out block: it
   must remove at least the null-calibrated share of the joint's residual variance and at
   least half of what the generic library could explain. Effects whose columns the baseline
   already spans (absorbed) and near-ties (equivalent explanations) are reported, not picked.
   A payload is a point mass (its gravity and its inertia about the body's origin, quadratic
   in its centre): found by variable projection over the centre, the mass linear.
6. **Augment, re-identify, validate**, and repeat from 3 until nothing passes. An accepted
   effort delay d extends the joint's stuck mask d forward (the effort recorded then is still
   the stuck interval's) and is refit on those samples; with an identified baseline the
   smooth-sign slope is chosen again with the effects in the model (an unmodelled spring or
   Dahl state biases the first choice towards a soft sign); then each added effect's
   non-linear parameter (travel, period, Stribeck velocity, delay, width, payload centre) is
   searched again with everything else in the model (one pass of coordinate descent).
   With a given model, its base parameters are finally re-identified together with the
   effects on the training block (when the effects are separable from them), and that is
   kept only if no joint predicts the held-out block more than 5 % worse than the given
   model with the effects (the given model may come from more or richer data).

Verdict: "none" (no joint's held-out residual is structured), "explained" (effects were added
and nothing structured is left), "unexplained" (structure remains that no catalogue effect
explains; effects that were confirmed are still listed, and for each structured joint the
closest catalogue effect and the test it failed are reported as evidence, never added). The
workflow sees only arrays.

Units: SI (rad, m, rad/s, m/s, N m, N, s, Hz).
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from calibration.effects import CATALOGUE, CATALOGUE_VERSION, EffectContext, friction_profile
from calibration.signals import differentiate, lowpass, settling_samples

THRESHOLDS_PATH = Path(__file__).with_name("discrepancy_thresholds.json")

#: Used only when no calibrated file exists (a fresh checkout before calibration): wide,
#: conservative values; the result says which were used.
FALLBACK_THRESHOLDS = {
    "identified": {"ljung_box": [200.0] * 3, "library_r2": [0.5] * 3, "gain": [0.3] * 3, "delta_bic": [50.0] * 3},
    "given_model": {"ljung_box": [200.0] * 3, "library_r2": [0.5] * 3, "gain": [0.3] * 3, "delta_bic": [50.0] * 3},
}
#: A candidate must remove at least this share of what the generic library explains.
LIBRARY_SHARE = 0.5
#: An effect column whose singular value, among the effect's own (normalised) columns outside
#: the model's span, is below this share of the largest carries a parameter these data
#: cannot separate from the effect's other parameters (a payload's mass from its first
#: moments on a parallelogram link): it is fixed at 0.
COLLINEAR = 1e-2
#: Candidates within this BIC of the best are equivalent explanations.
TIE_BIC = 2.0
#: A column whose part outside the current model's span is below this fraction of its norm
#: is absorbed by the model (not separately identifiable).
ABSORBED = 1e-3
LJUNG_BOX_LAGS = 10
#: With a given model, the final joint re-identification (base parameters and effects on the
#: training block) is kept only if no joint's held-out RMS exceeds this multiple of the given
#: model's with the effects added.
REIDENTIFY_TOLERANCE = 1.05
#: Travel scales (fractions of a joint's stroke) of the detection library's after-reversal
#: features.
TRAVEL_SCALES = (0.005, 0.02)
#: Golden-section steps refining a grid effect's non-linear parameter between grid values.
REFINE_STEPS = 8
#: Slopes a (s/rad, s/m) of the Coulomb sign tanh(a dq / 2) tried for an identified baseline.
SLOPES = (100.0, 400.0, 1000.0, 3000.0)
#: Velocity deadband (rad/s, rad/s, m/s) on the measured and the filtered velocity: slower, a joint may be
#: stuck, and its effort is then whatever the controller left inside the static friction
#: band, which no function of (q, dq, ddq) predicts (thesis 7.5.1; `rig identify` leaves
#: such samples out too). They are left out of every fit and every figure.
DEADBAND = np.array([0.01, 0.01, 0.002])
#: Shortest continuous recording (piece) of a record, in the filter's settling lengths: each
#: piece loses one at each end, so at least half of it is kept.
MIN_PIECE_TRIMS = 4


class DiscrepancyError(ValueError):
    """Data the workflow cannot use (too short, not moving)."""


@dataclass
class Settings:
    cutoff: float = 10.0          # Hz
    order: int = 4
    heldout: float = 0.25         # fraction at the end
    max_effects: int = 4
    effort_lag: float = 1e-3      # s: the effort reported with a sample was computed from the state this much earlier
    thresholds: dict | None = None  # {"identified": {...}, "given_model": {...}}; None: the stored file


def load_thresholds(path: Path = THRESHOLDS_PATH) -> tuple[dict, str]:
    """The null-calibrated thresholds and where they came from. The thresholds depend on
    the catalogue (the best null candidate sets the gain and dBIC thresholds): a file
    calibrated with another catalogue version is still used, and its source says so."""
    try:
        doc = json.loads(Path(path).read_text())
        method = doc.get("method", {})
        source = f"{path} ({method.get('summary', 'null simulations')}"
        version = method.get("catalogue_version")
        if version != CATALOGUE_VERSION:
            source += (f"; calibrated with catalogue {version or 'before 1.2'}, this is {CATALOGUE_VERSION}: "
                       "recalibrate with python -m calibration.discrepancy_null")
        return doc["thresholds"], source + ")"
    except (OSError, KeyError, json.JSONDecodeError):
        return FALLBACK_THRESHOLDS, "built-in fallback (no calibrated threshold file)"


# ----------------------------------------------------------------------------- statistics
def ljung_box(r: np.ndarray, lags: int = LJUNG_BOX_LAGS) -> float:
    """Ljung-Box Q of a series (dimensionless; chi-square(lags) for white noise)."""
    r = np.asarray(r, float) - np.mean(r)
    n = len(r)
    c0 = r @ r
    if n <= lags + 1 or c0 == 0:
        return 0.0
    rho = np.array([(r[k:] @ r[:-k]) / c0 for k in range(1, lags + 1)])
    return float(n * (n + 2) * np.sum(rho ** 2 / (n - np.arange(1, lags + 1))))


def heldout_r2(F_tr, r_tr, F_ho, r_ho) -> float:
    """Share of the held-out mean square of r explained by features F (and a constant) fitted
    on train (can be < 0). Mean squares, not variances: a constant part of the residual (an
    offset, an asymmetric Coulomb level against a given model) is a discrepancy too."""
    mu = F_tr.mean(0)
    sd = F_tr.std(0)
    sd[sd == 0] = 1.0
    A = np.column_stack([(F_tr - mu) / sd, np.ones(len(F_tr))])
    coef, *_ = np.linalg.lstsq(A, r_tr, rcond=None)
    pred = np.column_stack([(F_ho - mu) / sd, np.ones(len(F_ho))]) @ coef
    v = np.mean(r_ho ** 2)
    return float(1.0 - np.mean((r_ho - pred) ** 2) / v) if v > 0 else 0.0


def binned_r2(x_tr, r_tr, x_ho, r_ho, bins: int = 16) -> tuple[float, tuple[float, float], float]:
    """Held-out share of the residual's mean square explained by its conditional mean given x
    (quantile bins from train), the bin range with the largest |mean| and that mean."""
    edges = np.unique(np.quantile(x_tr, np.linspace(0, 1, bins + 1)))
    if len(edges) < 3:
        return 0.0, (float(x_tr.min()), float(x_tr.max())), 0.0
    i_tr = np.clip(np.searchsorted(edges, x_tr, side="right") - 1, 0, len(edges) - 2)
    i_ho = np.clip(np.searchsorted(edges, x_ho, side="right") - 1, 0, len(edges) - 2)
    means = np.array([r_tr[i_tr == b].mean() if np.any(i_tr == b) else 0.0 for b in range(len(edges) - 1)])
    means -= r_tr.mean()
    pred = means[i_ho] + r_tr.mean()
    v = np.mean(r_ho ** 2)
    k = int(np.argmax(np.abs(means)))
    return (float(1 - np.mean((r_ho - pred) ** 2) / v) if v > 0 else 0.0, (float(edges[k]), float(edges[k + 1])),
            float(means[k]))


# ----------------------------------------------------------------------------- preparation
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


# ----------------------------------------------------------------------------- the workflow
@dataclass
class Added:
    effect: str
    joint: int
    grid: object
    raw_cols: np.ndarray        # (m, 3, k) filtered (kept-domain) columns, unweighted
    unfiltered: np.ndarray      # (n, 3, k) the same columns on the raw samples
    free: np.ndarray            # (k_all,) bool: which of the effect's columns are in raw_cols
    params: dict = field(default_factory=dict)
    evidence: dict = field(default_factory=dict)
    rms_before: list = field(default_factory=list)
    rms_after: list = field(default_factory=list)


class Discrepancy:
    """One run of the workflow on measured arrays.

    ``model``: a PSMDynamics (gravity, slope) giving the regressor; ``base``: its
    BaseParameters; ``given``: standard parameters (82,) of a given model (None: identify
    the baseline on the training block); ``given_extra``: ``fn(Prepared) -> (n, 3)`` the given
    model's effort beyond what its standard parameters' regressor gives, on the raw samples
    (a model file's Stribeck excess and effects: `calibration.prediction.extra_effort`), so
    that a given model is taken whole.
    """

    def __init__(self, model, base, q, dq, tau, rate: float, given: np.ndarray | None = None,
                 settings: Settings | None = None, breaks=(), given_extra=None):
        self.t0 = time.perf_counter()
        self.model = model
        self.base = base
        self.settings = settings or Settings()
        self.mode = "identified" if given is None else "given_model"
        if self.settings.thresholds is None:
            th, self.threshold_source = load_thresholds()
        else:
            th, self.threshold_source = self.settings.thresholds, "given"
        self.th = th[self.mode]
        self.p = prepare(q, dq, tau, rate, self.settings, breaks)
        p = self.p
        self.given = None if given is None else np.asarray(given, float)
        self.given_extra_raw = None if given_extra is None else np.asarray(given_extra(p), float)
        n = p.q.shape[0]
        # The regressor on every raw sample (unfiltered, unmasked; the model's torque there is
        # what delay and backlash columns are built from) and masked-filtered (the fits).
        # Two sources of the inertial term (the columns multiplying ddq), the rest of the
        # regressor from the filtered state: the filtered state's ddq (quiet, but filtered twice
        # by the time it meets the effort, so smoother than the effort at a breakaway) or the
        # measured velocity's fourth-order central differences, filtered once like the effort
        # (second-order ones read 1.6 % low at the 10 Hz band edge and 6.5 % at 20 Hz, where
        # a stick-slip burst still has its acceleration). Each joint takes the one that leaves
        # the smaller training residual (_choose_inertia).
        z = np.zeros_like(p.dqf_all)
        static = model.regressor_batch(p.qf_all, p.dqf_all, z)
        at_rest = model.regressor_batch(p.qf_all, z, z)
        ddq_measured = p.piecewise(lambda v: differentiate(v, p.rate, "central4"), p.dq)
        self._chains = {"filtered": static + model.regressor_batch(p.qf_all, z, p.ddqf_all) - at_rest,
                        "measured": static + model.regressor_batch(p.qf_all, z, ddq_measured) - at_rest}
        self.inertia = ["filtered"] * 3
        self.W_raw = self._chains["filtered"].copy()
        W = p.filt_rows(self.W_raw.reshape(n, 3, -1))
        W = W.reshape(-1, W.shape[2])
        self.W = W
        self.y = p.tauf.reshape(-1)
        self.m = p.tauf.shape[0]
        self.moving = p.moving_raw[p.kept] > 0
        # Samples per joint by which the stuck mask is extended forward (an accepted effort
        # delay: the measured effort then still carries the stuck interval's effort).
        self.mask_lag = [0, 0, 0]
        # A given model keeps its slope; identified, the slope of the smooth Coulomb sign is
        # chosen on the training block like `rig identify --friction-slope auto` (a wider grid:
        # joint 3 moves in m/s, ten times slower than the rad/s joints).
        slopes = [float(model.slope)] if given is not None else SLOPES
        best = None
        for a in slopes:
            self._set_slope(a)
            res = self.y[self._rows(p.train)] - self.Wb[self._rows(p.train)] @ np.linalg.lstsq(
                self.Wb[self._rows(p.train)], self.y[self._rows(p.train)], rcond=None)[0]
            r = res.reshape(-1)
            score = float(r @ r)
            if best is None or score < best[0]:
                best = (score, a)
        self._set_slope(best[1])
        self._set_fixed()
        self._index_samples()
        for j in range(3):
            if len(self.mov_tr[j]) < 0.2 * (p.train.stop - p.train.start) or len(self.mov_ho[j]) < 50:
                raise DiscrepancyError(f"joint {j + 1} moves faster than its deadband ({DEADBAND[j]:g}) in too "
                                       "few samples: the data do not excite it")
        self.added: list[Added] = []
        self._mass_cache = None
        self.notes: list[str] = []
        self.iterations: list[dict] = []
        self._choose_inertia()   # fits the baseline with each source and keeps the better per joint
        self.baseline_pred = self.pred.copy()

    def _use_inertia(self, choice) -> None:
        """Build the regressor with each joint's inertial term from ``choice[j]``."""
        n = self.p.q.shape[0]
        Wr = self._chains["filtered"].copy()
        for j in range(3):
            if choice[j] == "measured":
                Wr[j::3] = self._chains["measured"][j::3]
        self.inertia = list(choice)
        self.W_raw = Wr
        W = self.p.filt_rows(Wr.reshape(n, 3, -1))
        self.W = W.reshape(-1, W.shape[2])
        self._set_slope(self.slope)
        self._set_fixed()

    def _set_fixed(self) -> None:
        """The given model's effort, filtered (``fixed``, kept rows) and on the raw samples
        (``fixed_raw``); zero without a given model."""
        if self.given is None:
            self.fixed, self.fixed_raw = np.zeros_like(self.y), np.zeros(self.W_raw.shape[0])
            return
        self.fixed, self.fixed_raw = self.W @ self.given, self.W_raw @ self.given
        if self.given_extra_raw is not None:
            self.fixed = self.fixed + self.p.filt_rows(self.given_extra_raw).reshape(-1)
            self.fixed_raw = self.fixed_raw + self.given_extra_raw.reshape(-1)

    def _choose_inertia(self) -> None:
        """Per joint, the inertial term's source with the smaller training residual of the
        current model (chosen again after each added effect: an unmodelled one dominates the
        first choice)."""
        scores = {}
        for c in ("filtered", "measured"):
            self._use_inertia((c,) * 3)
            self._fit_current()
            r = (self.y - self.pred).reshape(-1, 3)
            scores[c] = [float(np.sqrt(np.mean(r[self.mov_tr[j], j] ** 2))) for j in range(3)]
        self.inertia_scores = scores
        choice = tuple(min(scores, key=lambda c: scores[c][j]) for j in range(3))
        if choice != tuple(self.inertia):   # else the last fit above already is this one
            self._use_inertia(choice)
            self._fit_current()

    def _set_slope(self, a: float) -> None:
        """The Coulomb columns as sigma(dq) = tanh(a dq / 2) of the raw velocities, filtered
        like tau (parallel filtering)."""
        self.slope = float(a)
        raw = np.tanh(0.5 * self.slope * self.p.dq)
        sig = self.p.filt_rows(raw)
        for j in range(3):
            self.W[j::3, 70 + 4 * j] = sig[:, j]
            self.W_raw[j::3, 70 + 4 * j] = raw[:, j]
        self.Wb = self.base.regressor(self.W)
        self.Wb_raw = self.base.regressor(self.W_raw)
        self.ctx_raw = EffectContext(self.p.q, self.p.dq, self.p.rate, self.slope)
        self._col_cache = {}

    def _remask(self, joint: int, lag: int) -> None:
        """Extend joint's stuck mask ``lag`` samples forward and rebuild everything filtered
        with the mask (effort, regressor, effect columns, sample sets), then refit.

        With the effort lagging the motion by d, the effort recorded in the d after a stuck
        interval is still the stuck interval's (whatever the controller left inside the static
        friction band): the equation tau(t) = model(t - d) holds only where the joint moved
        at t - d as well as at t."""
        p = self.p
        j = joint - 1
        def grow(stuck):
            grown = stuck.copy()
            for k in range(1, min(lag, len(stuck) - 1) + 1):
                grown[k:] |= stuck[:-k]
            return grown

        p.moving_raw[:, j] = (~p.piecewise(grow, p.moving_raw[:, j] == 0)).astype(float)
        self.mask_lag[j] = lag
        p.tauf = p.lowpass(p.tau * p.moving_raw)[p.kept]
        n = p.q.shape[0]
        W = p.filt_rows(self.W_raw.reshape(n, 3, -1))
        self.W = W.reshape(-1, W.shape[2])
        self.Wb = self.base.regressor(self.W)
        self.y = p.tauf.reshape(-1)
        self.moving = p.moving_raw[p.kept] > 0
        self._set_fixed()
        self._index_samples()
        self._col_cache = {}
        for a in self.added:
            a.raw_cols = p.filt_rows(a.unfiltered)
        added, self.added = self.added, []
        self._fit_current()
        self.baseline_pred = self.pred.copy()
        self.added = added
        self._fit_current()
        self.notes.append(f"joint {joint}: the stuck mask was extended {lag} samples forward for the effort "
                          "delay; baseline and effects are compared on that sample set")

    def _index_samples(self) -> None:
        """Stacked training/held-out rows and per-joint moving samples of the current mask."""
        p = self.p
        self.rows_tr = self._rows(p.train)
        self.rows_ho = self._rows(p.heldout)
        self.mov_tr = [np.flatnonzero(self.moving[p.train, j]) + p.train.start for j in range(3)]
        self.mov_ho = [np.flatnonzero(self.moving[p.heldout, j]) + p.heldout.start for j in range(3)]

    def _rows(self, sl: slice) -> np.ndarray:
        """Stacked rows of the samples in ``sl`` where the joint of the row moves."""
        rows = np.arange(3 * sl.start, 3 * sl.stop)
        return rows[self.moving.reshape(-1)[rows]]

    # -- fitting ----------------------------------------------------------------------------
    def _design(self) -> np.ndarray:
        """Current design (3m, p): baseline base columns (identified mode) and added effects."""
        blocks = [] if self.mode == "given_model" else [self.Wb]
        blocks += [a.raw_cols.reshape(self.m * 3, -1) for a in self.added]
        return np.hstack(blocks) if blocks else np.zeros((3 * self.m, 0))

    def _fit_current(self) -> None:
        D = self._design()
        target = self.y - self.fixed
        tr = self.rows_tr
        # Two passes: OLS for the per-joint residual scale, then weighted by it (the
        # weights stay those of the first pass so that Q, R and the residual agree).
        w = np.ones(3)
        for it in range(2):
            rw = np.tile(w, self.m)
            if D.shape[1]:
                Dw = D[tr] * rw[tr, None]
                norms = np.linalg.norm(Dw, axis=0)
                norms[norms == 0] = 1.0
                Q, R = np.linalg.qr(Dw / norms)
                coef = np.linalg.solve(R, Q.T @ (target[tr] * rw[tr])) / norms
            else:
                Q, R, norms, coef = np.zeros((len(tr), 0)), np.zeros((0, 0)), np.zeros(0), np.zeros(0)
            pred = self.fixed + D @ coef
            if it == 0:
                res = (self.y - pred).reshape(-1, 3)
                w = 1.0 / np.maximum([res[self.mov_tr[j], j].std() for j in range(3)], 1e-9)
        self.w = w
        self.rw = np.tile(w, self.m)
        self.coef = coef
        self.pred = pred
        self.Q, self.R, self.norms = Q, R, norms
        self.D = D
        self.r_w_tr = (self.y - pred)[tr] * self.rw[tr]
        self.tau_model = pred.reshape(-1, 3)   # filtered model torque (kept domain)
        blocks = [] if self.mode == "given_model" else [self.Wb_raw]
        blocks += [a.unfiltered.reshape(-1, a.unfiltered.shape[2]) for a in self.added]
        raw = self.fixed_raw + (np.hstack(blocks) @ coef if blocks else 0.0)
        self.tau_model_raw = raw.reshape(-1, 3)  # the same model on the raw samples

    def residual(self) -> np.ndarray:
        return (self.y - self.pred).reshape(-1, 3)

    def heldout_rms(self, pred=None) -> np.ndarray:
        """Per joint RMS of the held-out residual over the moving samples (N m, N)."""
        r = (self.y - (self.pred if pred is None else pred)).reshape(-1, 3)
        return np.array([np.sqrt(np.mean(r[self.mov_ho[j], j] ** 2)) for j in range(3)])

    def heldout_rel(self, pred=None) -> np.ndarray:
        """Per joint norm(residual) / norm(tau) on the held-out moving samples."""
        r = (self.y - (self.pred if pred is None else pred)).reshape(-1, 3)
        tau = self.p.tauf
        return np.array([np.linalg.norm(r[self.mov_ho[j], j]) / np.linalg.norm(tau[self.mov_ho[j], j])
                         for j in range(3)])

    def n_eff(self) -> float:
        """Independent samples in the training rows: the filtered band's Nyquist spacing."""
        spacing = max(1.0, self.p.rate / (2.0 * self.p.cutoff))
        return len(self.rows_tr) / spacing

    # -- detection --------------------------------------------------------------------------
    def _library(self) -> np.ndarray:
        """(m, k) generic features for the predictability test, kept domain."""
        p = self.p
        raw = []
        for i in range(3):
            v = p.dq[:, i]
            s = np.tanh(0.5 * self.slope * v)
            vs = np.std(v) * 0.05
            raw += [p.q[:, i], p.q[:, i] ** 2, s, v, v * np.abs(v), s * np.exp(-(v / vs) ** 2), s * p.q[:, i]]
            # The regime just after a reversal (pre-sliding, play): the direction fading with
            # the travel since the last reversal, over two scales of the joint's stroke.
            travel = np.abs(p.qf_all[:, i] - _last_reversal_position(p.qf_all[:, i], p.dqf_all[:, i],
                                                                      p.raw_starts()))
            stroke = np.subtract(*np.quantile(p.qf_all[:, i], [0.99, 0.01]))
            raw += [np.sign(p.dqf_all[:, i]) * np.exp(-travel / (f * stroke)) for f in TRAVEL_SCALES]
        F = p.filt(np.column_stack(raw))
        extra = [p.ddqf]
        u = self.tau_model_raw
        lag = int(round(0.02 * p.rate))
        u_lag = p.filt_rows(p.piecewise(lambda v: np.vstack([v[:1].repeat(lag, 0), v[:-lag]]) - v, u))
        return np.column_stack([F] + extra + [self.tau_model, u_lag])

    def detect(self) -> list[dict]:
        """Per joint: Ljung-Box Q and library R^2 of the held-out residual vs thresholds."""
        r = self.residual()
        p = self.p
        spacing = max(1, int(round(p.rate / (2.0 * p.cutoff))))
        F = self._library()
        out = []
        for j in range(3):
            tr, ho = self.mov_tr[j], self.mov_ho[j]
            q_lb = ljung_box(r[ho, j][::spacing])
            r2 = heldout_r2(F[tr], r[tr, j], F[ho], r[ho, j])
            structured = bool(q_lb > self.th["ljung_box"][j] or r2 > self.th["library_r2"][j])
            out.append({"joint": j + 1, "ljung_box": q_lb, "ljung_box_threshold": self.th["ljung_box"][j],
                        "library_r2": r2, "library_r2_threshold": self.th["library_r2"][j],
                        "structured": structured})
        return out

    def attribute(self, joint: int) -> dict:
        """The variable and regime that best explain joint's residual (binned held-out R^2)."""
        p = self.p
        r = self.residual()[:, joint - 1]
        j = joint - 1
        spacing = max(1, int(round(p.rate / (2.0 * p.cutoff))))
        travel = np.abs(p.qf[:, j] - _last_reversal_position(p.qf[:, j], p.dqf[:, j], p.kept_starts()))
        t = np.arange(self.m) / p.rate
        variables = {f"q{j + 1}": p.qf[:, j], f"dq{j + 1}": p.dqf[:, j], f"ddq{j + 1}": p.ddqf[:, j],
                     f"u{j + 1}": self.tau_model[:, j], f"travel since reversal {j + 1}": travel}
        for i in range(3):
            if i != j:
                variables[f"dq{i + 1}"] = p.dqf[:, i]
                variables[f"q{i + 1}"] = p.qf[:, i]
        scores = {}
        tr, ho = self.mov_tr[j], self.mov_ho[j]
        for name, x in variables.items():
            r2, rng, mean = binned_r2(x[tr], r[tr], x[ho], r[ho])
            scores[name] = {"heldout_r2": r2, "regime": list(rng), "regime_mean": mean}
        best = max(scores, key=lambda k: scores[k]["heldout_r2"])
        xc = {}
        for name in (f"dq{j + 1}", f"ddq{j + 1}"):
            x = variables[name][ho][::spacing]
            rr = r[ho][::spacing]
            xc[name] = float(np.max(np.abs(np.correlate((rr - rr.mean()) / (rr.std() * len(rr)),
                                                        (x - x.mean()) / (x.std() + 1e-300), "full"))))
        del t
        return {"variable": best, "regime": scores[best]["regime"], "by_variable": scores,
                "max_cross_correlation": xc}

    # -- naming -----------------------------------------------------------------------------
    def _columns(self, eff, joint: int, g, unfiltered: bool = False) -> np.ndarray:
        """Masked-filtered, kept-domain columns (m, 3, k); or (n, 3, k) on the raw samples."""
        key = (eff.id, joint, g)
        if eff.uses_model:
            # Built from the current model's torque or regressor on the raw samples (they
            # change with every added effect: not cached).
            p = self.p
            ctx = EffectContext(p.q, p.dq, p.rate, self.slope, self.tau_model_raw, self.W_raw,
                                tuple(self.model.body_names), self._inertia())
            if eff.needs_dynamics:
                ctx.mass_diag, ctx.friction = self._mass_diag(), np.nan_to_num(self._friction())
                ctx.ddq, ctx.deadband = p.ddqf_all, DEADBAND
            raw = _effect_columns(eff, ctx, joint, g, p.pieces)
            return raw if unfiltered else p.filt_rows(raw)
        if unfiltered:
            return _effect_columns(eff, self.ctx_raw, joint, g, self.p.pieces)
        if key not in self._col_cache:
            self._col_cache[key] = self.p.filt_rows(_effect_columns(eff, self.ctx_raw, joint, g, self.p.pieces))
        return self._col_cache[key]

    def _score(self, E: np.ndarray) -> dict | None:
        """Joint fit of current design + E on train (Frisch-Waugh); None if absorbed."""
        tr = self.rows_tr
        Ef = E.reshape(3 * self.m, -1)
        Ew = Ef[tr] * self.rw[tr, None]
        enorm = np.linalg.norm(Ew, axis=0)
        nonzero = enorm > 0
        if not nonzero.any():
            return None
        enorm[~nonzero] = 1.0
        Ew = Ew / enorm
        proj = self.Q.T @ Ew if self.Q.shape[1] else np.zeros((0, Ew.shape[1]))
        Ep = Ew - self.Q @ proj if self.Q.shape[1] else Ew
        # Columns the current model spans carry a parameter these data cannot separate from
        # the model's own (a spring's rest position from the offset Fo): fixed at 0. So are
        # columns that are zero (a mass on the yaw axis) or collinear with the effect's others.
        free = nonzero & (np.linalg.norm(Ep, axis=0) >= ABSORBED)
        while free.sum() > 1:
            u, sv, vt = np.linalg.svd(Ep[:, free] / np.linalg.norm(Ep[:, free], axis=0), full_matrices=False)
            if sv[-1] >= COLLINEAR * sv[0]:
                break
            # The column that carries most of the near-null direction goes.
            free[np.flatnonzero(free)[int(np.argmax(np.abs(vt[-1])))]] = False
        if not free.any():
            return None
        theta = np.zeros(Ew.shape[1])
        theta[free], *_ = np.linalg.lstsq(Ep[:, free], self.r_w_tr, rcond=None)
        rss0 = float(self.r_w_tr @ self.r_w_tr)
        rss1 = float(np.sum((self.r_w_tr - Ep @ theta) ** 2))
        if self.Q.shape[1]:
            dcoef = np.linalg.solve(self.R, proj @ theta) / self.norms
        else:
            dcoef = np.zeros(0)
        th = theta / enorm
        pred = self.pred - self.D @ dcoef + Ef @ th
        return {"theta": th, "rss0": rss0, "rss1": rss1, "pred": pred, "coef": self.coef - dcoef,
                "fixed_columns": np.flatnonzero(~free).tolist()}

    def _profile(self, eff, joint: int):
        """(grid value, score) minimising the residual over the effect's non-linear parameter:
        the catalogue grid, then a golden-section search (in log) between the best grid
        value's neighbours, inside the grid's range (a period or a Stribeck velocity between
        two grid values fits much better at the right value, which the BIC should see). An
        effect with options (a second, discrete parameter) is profiled for each option; its
        grid value is then (value, option), and the option is chosen by the information
        criterion (an option may change the number of columns: a friction profile's
        harmonics)."""
        if eff.point_mass:
            return self._profile_point_mass(eff, joint)
        if eff.options is None:
            return self._profile_grid(eff, joint, None)
        n_eff = self.n_eff()

        def crit(rss, k):
            return n_eff * np.log(rss) + k * np.log(n_eff)

        def bic(r):
            return crit(r[1]["rss1"], len(r[1]["theta"]) - len(r[1]["fixed_columns"]))

        if not eff.nested_options:
            scored = [r for r in (self._profile_grid(eff, joint, o) for o in eff.options(joint)) if r is not None]
            return min(scored, key=bic) if scored else None
        # Nested options (a friction profile's harmonics: option K's columns are the first of
        # the largest option's): on the grid the largest option's columns are filtered once
        # and sliced. The smallest option and the grid's best by the criterion are refined: on
        # the grid alone a single ripple between two grid periods loses to three harmonics of
        # a period three times as long, which holds it as its third.
        options = list(eff.options(joint))
        top, grid = max(options), set(eff.grid(joint))

        def sliced(o):
            def cols(g):
                if g in grid:
                    return self._columns(eff, joint, (g, top))[:, :, :len(eff.linear_names_at((g, o)))]
                return self._columns(eff, joint, (g, o))
            return cols

        # The grid's criterion for every option from one projection of the largest option's
        # columns (the residual after each leading block of them, by one QR).
        sizes = [len(eff.linear_names_at((None, o))) for o in options]
        coarse = {}
        for g in sorted(grid):
            for o, k, rss in zip(options, sizes, self._nested_rss(self._columns(eff, joint, (g, top)), sizes)):
                coarse[o] = min(coarse.get(o, np.inf), crit(rss, k))
        refine = sorted({min(options), min(coarse, key=coarse.get)})
        scored = [r for r in (self._profile_grid(eff, joint, o, cols=sliced(o)) for o in refine) if r is not None]
        return min(scored, key=bic) if scored else None

    def _nested_rss(self, E: np.ndarray, sizes: list[int]) -> list[float]:
        """Training residual sums of squares (weighted, as ``_score``'s rss1) of the current
        model plus the first k columns of E, for each k in ``sizes``: one projection and one QR
        of all of them."""
        tr = self.rows_tr
        Ew = E.reshape(3 * self.m, -1)[tr] * self.rw[tr, None]
        Ew = Ew / np.maximum(np.linalg.norm(Ew, axis=0), 1e-300)
        Ep = Ew - self.Q @ (self.Q.T @ Ew) if self.Q.shape[1] else Ew
        Qe = np.linalg.qr(Ep)[0]
        gain = np.cumsum((Qe.T @ self.r_w_tr) ** 2)
        rss0 = float(self.r_w_tr @ self.r_w_tr)
        return [max(rss0 - float(gain[k - 1]), 1e-300) for k in sizes]

    def _profile_grid(self, eff, joint: int, option, cols=None):
        """(grid value, score) of the effect at ``option`` (None: no options) over its grid,
        then a golden-section search next to the best grid value. ``cols`` (grid value ->
        columns) replaces the effect's own columns at (value, option)."""
        if cols is None:
            def cols(g):
                return self._columns(eff, joint, g if option is None else (g, option))

        def value(g):
            return g if option is None else (g, option)

        grid = list(eff.grid(joint))
        scored = [(g, self._score(cols(g))) for g in grid]
        ok = [(i, g, s) for i, (g, s) in enumerate(scored) if s is not None]
        if not ok:
            return None
        i, g, s = min(ok, key=lambda t: t[2]["rss1"])
        if len(grid) < 3 or not all(isinstance(x, float) and x > 0 for x in grid):
            return value(g), s
        lo, hi = np.log(grid[max(i - 1, 0)]), np.log(grid[min(i + 1, len(grid) - 1)])
        best = (g, s)
        cache = {}

        def f(x):
            if x not in cache:
                gg = float(np.exp(x))
                cache[x] = (gg, self._score(cols(gg)))
            r = cache[x][1]
            return np.inf if r is None else r["rss1"]

        ratio = (np.sqrt(5.0) - 1.0) / 2.0
        a, b = lo, hi
        c, d = b - ratio * (b - a), a + ratio * (b - a)
        for _ in range(REFINE_STEPS):
            if f(c) < f(d):
                b, d = d, c
                c = b - ratio * (b - a)
            else:
                a, c = c, d
                d = a + ratio * (b - a)
        for gg, r in cache.values():
            if r is not None and r["rss1"] < best[1]["rss1"]:
                best = (gg, r)
        return value(best[0]), best[1]

    def _profile_point_mass(self, eff, joint: int):
        """(centre, score) of a point mass on the joint's body by variable projection: the
        body's ten standard columns are projected out of the current model once; for a centre
        c the mass column is those columns times the unit point mass's parameters v(c) (first
        moments and inertia about the origin, quadratic in c), so the residual after the best
        mass is rss0 - (b.v)^2 / (v.G v) with G, b the projected columns' Gram matrix and
        correlation with the residual: a 10 x 10 problem per centre. A coarse lattice of
        centres, then Nelder-Mead from the best few, inside the arm's box; the mass must be
        positive."""
        from scipy.optimize import minimize

        from calibration.effects import COM_BOX, point_mass_parameters

        tr = self.rows_tr
        E = self._columns(eff, joint, None).reshape(3 * self.m, -1)
        Ew = E[tr] * self.rw[tr, None]
        Ep = Ew - self.Q @ (self.Q.T @ Ew) if self.Q.shape[1] else Ew
        G = Ep.T @ Ep
        b = Ep.T @ self.r_w_tr
        rss0 = float(self.r_w_tr @ self.r_w_tr)
        floor = 1e-12 * float(np.max(np.diag(G)) or 1.0)

        def rss(c):
            c = np.asarray(c, float)
            if np.any(np.abs(c) >= COM_BOX):
                return rss0 + float(np.sum(np.maximum(np.abs(c) - COM_BOX, 0.0))) * rss0
            v = point_mass_parameters(c)
            den = float(v @ G @ v)
            num = float(b @ v)
            if den <= floor or num <= 0.0:      # no mass, or a negative one
                return rss0
            return rss0 - num * num / den

        axis = np.array([-0.4, -0.2, -0.05, 0.05, 0.2, 0.4])
        lattice = np.array(np.meshgrid(axis, axis, axis, indexing="ij")).reshape(3, -1).T
        values = np.array([rss(c) for c in lattice])
        best_c, best_v = None, rss0
        for i in np.argsort(values)[:4]:
            r = minimize(rss, lattice[i], method="Nelder-Mead",
                         options={"xatol": 1e-4, "fatol": 1e-9 * rss0, "maxiter": 600})
            if r.fun < best_v:
                best_c, best_v = r.x, float(r.fun)
        if best_c is None:
            return None
        c = tuple(float(x) for x in best_c)
        s = self._score(self._columns(eff, joint, c))
        if s is None:
            return None
        # Which components of the centre the data determine: moving one by 2 cm must cost at
        # least one unit of the information criterion.
        step = 0.02 * np.eye(3)
        s["com_determined"] = [bool(min(rss(best_c + d), rss(best_c - d)) - best_v > best_v / self.n_eff())
                               for d in step]
        return c, s

    def candidates(self, joints: list[int]) -> list[dict]:
        """Best grid value of every (effect, joint) on the given joints, with figures."""
        out = []
        n_eff = self.n_eff()
        before = self.heldout_rms()
        have = {(a.effect, a.joint) for a in self.added}
        for eff in CATALOGUE.values():
            for joint in joints:
                if (eff.id, joint) in have:
                    continue
                best = self._profile(eff, joint)
                if best is None:
                    out.append({"effect": eff.id, "joint": joint, "absorbed": True})
                    continue
                g, s = best
                k = eff.n_params(g) - len(s["fixed_columns"])
                dbic = n_eff * np.log(s["rss0"] / s["rss1"]) - k * np.log(n_eff)
                after = self.heldout_rms(s["pred"])
                # On the joint it is attributed to (also for a payload, whose columns load
                # other joints too: the weighted sum would be dominated by joints it leaves
                # alone, their noise weighted up by the per-joint weights).
                gain = float(1 - (after[joint - 1] / before[joint - 1]) ** 2)
                params = eff.params(s["theta"], g, joint, self._baseline_terms(s["coef"], joint))
                if "com_determined" in s:
                    params["com_determined"] = s["com_determined"]
                out.append({"effect": eff.id, "joint": joint, "absorbed": False, "grid": g, "delta_bic": float(dbic),
                            "heldout_gain": gain, "heldout_rms_after": after, "params": params,
                            "sanity": eff.sanity(params, joint), "score": s})
        return out

    def _baseline_terms(self, coef: np.ndarray, joint: int) -> dict:
        """The joint's Coulomb level Fc in the current fit (for Fs >= Fc checks), and for the
        backlash crossing its viscous coefficient Fv, its inertia and its stuck velocity."""
        inertia = float(self._inertia(coef)[joint - 1])
        fc, fv = self._friction(coef)[joint - 1]
        return ({"Fc": float(fc)} if np.isfinite(fc) else {}) | {"Fv": float(np.nan_to_num(fv)), "inertia": inertia,
                                                                 "stuck_velocity": float(DEADBAND[joint - 1])}

    def _friction(self, coef: np.ndarray | None = None) -> np.ndarray:
        """(3, 2): each joint's Coulomb level Fc and viscous coefficient Fv in the current fit
        (NaN where the base parameters do not carry it alone)."""
        coef = self.coef if coef is None else coef
        out = np.full((3, 2), np.nan)
        for j in range(3):
            for k, idx in enumerate((70 + 4 * j, 71 + 4 * j)):
                if self.mode == "given_model":
                    out[j, k] = self.given[idx]
                else:
                    pos = np.flatnonzero(self.base.independent == idx)
                    if pos.size:
                        out[j, k] = coef[pos[0]]
        return out

    def _mass_diag(self, coef: np.ndarray | None = None) -> np.ndarray:
        """(n, 3): the diagonal of the current model's mass matrix on every sample's filtered
        configuration (for the backlash crossing; kept for the last parameters asked)."""
        coef = self.coef if coef is None else coef
        key = None if self.mode == "given_model" else coef[:self.Wb.shape[1]].tobytes()
        if self._mass_cache is None or self._mass_cache[0] != key:
            self._mass_cache = (key, self._mass_diagonal_at(self.p.qf_all, coef))
        return self._mass_cache[1]

    def _mass_diagonal_at(self, q: np.ndarray, coef: np.ndarray) -> np.ndarray:
        """(len(q), 3): M_jj of the model (the given one, or the base parameters ``coef``) at
        configurations q: the regressor's change for a unit acceleration of each joint, times
        the parameters."""
        z = np.zeros_like(q)
        Y0 = self.model.regressor_batch(q, z, z)
        out = np.empty_like(q)
        for j in range(3):
            e = z.copy()
            e[:, j] = 1.0
            dY = (self.model.regressor_batch(q, z, e) - Y0)[j::3]
            out[:, j] = dY @ self.given if self.mode == "given_model" else \
                self.base.regressor(dY) @ coef[:self.Wb.shape[1]]
        return out

    def _inertia(self, coef: np.ndarray | None = None) -> np.ndarray:
        """Diagonal of the current model's mass matrix (3,) at the data's median configuration."""
        coef = self.coef if coef is None else coef
        return self._mass_diagonal_at(np.median(self.p.qf_all, axis=0)[None], coef)[0]

    # -- the loop ---------------------------------------------------------------------------
    def run(self) -> dict:
        unexplained_joints: set[int] = set()
        closest: dict[int, dict | None] = {}   # per joint: the best candidate that was not enough
        det = self.detect()
        first_detection = det
        for _ in range(self.settings.max_effects):
            cands = self.candidates([1, 2, 3])
            eligible = [c for c in cands if not c["absorbed"] and c["sanity"] is None]
            eligible.sort(key=lambda c: -c["delta_bic"])
            self._catalogue_detection(det, eligible)
            joints = [d["joint"] for d in det if d["structured"] and d["joint"] not in unexplained_joints]
            if not joints:
                break
            lib = {d["joint"]: d["library_r2"] for d in det}
            record = {"structured_joints": joints,
                      "ranking": [{k: c[k] for k in ("effect", "joint", "delta_bic", "heldout_gain", "sanity")}
                                  for c in sorted((c for c in cands if not c["absorbed"]),
                                                  key=lambda c: -c["delta_bic"])[:8]],
                      "absorbed": [f"{c['effect']}@{c['joint']}" for c in cands if c["absorbed"]]}
            accepted = None
            for joint in joints:
                on_joint = [c for c in eligible if c["joint"] == joint]
                if not on_joint:
                    unexplained_joints.add(joint)
                    closest[joint] = None
                    continue
                best = on_joint[0]
                gain_needed = max(self.th["gain"][joint - 1], LIBRARY_SHARE * lib[joint])
                ok = best["delta_bic"] > self.th["delta_bic"][joint - 1] and best["heldout_gain"] >= gain_needed
                best["gain_needed"] = gain_needed
                if ok and (accepted is None or best["delta_bic"] > accepted["delta_bic"]):
                    accepted = best
                elif not ok:
                    unexplained_joints.add(joint)
                    # Kept as evidence for the report, never added: the verdict stays
                    # "unexplained" rather than the nearest guess.
                    closest[joint] = {"effect": best["effect"], "params": best["params"],
                                      "delta_bic": best["delta_bic"],
                                      "delta_bic_needed": self.th["delta_bic"][joint - 1],
                                      "heldout_variance_removed": best["heldout_gain"],
                                      "heldout_gain_needed": gain_needed, "library_r2": lib[joint]}
            record["accepted"] = None if accepted is None else f"{accepted['effect']}@{accepted['joint']}"
            self.iterations.append(record)
            if accepted is None:
                break
            unexplained_joints.discard(accepted["joint"])
            self._accept(accepted, eligible, det)
            det = self.detect()
        structured_left = [d["joint"] for d in det if d["structured"]]
        if not self.added and not any(d["structured"] for d in first_detection):
            verdict = "none"
        elif structured_left:
            verdict = "unexplained"
        else:
            verdict = "explained"
        reid = self._reidentify()
        # The baseline on the final sample set (an effort delay extends the stuck mask).
        baseline_rms = self.heldout_rms(self.baseline_pred)
        baseline_rel = self.heldout_rel(self.baseline_pred)
        return {"mode": self.mode, "baseline": {"heldout_rms": baseline_rms.tolist(),
                                                "heldout_rel_error": baseline_rel.tolist()},
                "final": {"heldout_rms": self.heldout_rms(reid["pred"]).tolist(),
                          "heldout_rel_error": self.heldout_rel(reid["pred"]).tolist()},
                "effects": [self._effect_doc(a) for a in self.added], "verdict": verdict,
                "detection": {"initial": first_detection, "final": det, "structured_left": structured_left},
                "closest_rejected": [{"joint": j, "candidate": closest.get(j)} for j in structured_left],
                "iterations": self.iterations, "reidentification": reid["doc"], "notes": self.notes,
                "thresholds": {"source": self.threshold_source, **self.th},
                "catalogue_version": CATALOGUE_VERSION,
                "settings": {"cutoff_hz": self.settings.cutoff, "filter_order": self.settings.order,
                             "heldout_fraction": self.settings.heldout, "rate_hz": self.p.rate,
                             "samples": int(self.p.q.shape[0]), "train_samples": self.p.train.stop - self.p.train.start,
                             "heldout_samples": self.p.heldout.stop - self.p.heldout.start,
                             "pieces": [list(r) for r in self.p.pieces] or [[0, int(self.p.q.shape[0])]]},
                "coulomb_slope": self.slope, "inertia_source": self.inertia, "seconds": time.perf_counter() - self.t0, "_reid": reid}

    def _catalogue_detection(self, det: list[dict], eligible: list[dict]) -> None:
        """Marks as structured a joint the generic tests call white whose best catalogue
        candidate passes both null-calibrated tests (information criterion and held-out
        gain). Isolated bursts, such as the contacts after a play is crossed, leave a residual
        whose autocorrelation at the decimated lags is small and which the generic library
        cannot predict, yet a component placed at the right events removes most of it."""
        for d in det:
            if d["structured"]:
                continue
            on = [c for c in eligible if c["joint"] == d["joint"]]
            if on and on[0]["delta_bic"] > self.th["delta_bic"][d["joint"] - 1] \
                    and on[0]["heldout_gain"] >= self.th["gain"][d["joint"] - 1]:
                d["structured"] = True
                d["catalogue"] = {"effect": on[0]["effect"], "delta_bic": on[0]["delta_bic"],
                                  "heldout_gain": on[0]["heldout_gain"]}

    def _accept(self, c: dict, eligible: list[dict], det: list[dict]) -> None:
        eff = CATALOGUE[c["effect"]]
        for _ in range(3 if eff.id == "time_delay" else 0):
            lag = int(np.ceil(c["params"]["delay"] * self.p.rate))
            if lag > self.mask_lag[c["joint"] - 1]:
                # Refit the delay on the samples where the equation holds (again if the refit
                # delay is longer).
                self._remask(c["joint"], lag)
                best = self._profile(eff, c["joint"])
                if best is not None:
                    g, s = best
                    c = c | {"grid": g, "score": s,
                             "params": eff.params(s["theta"], g, c["joint"],
                                                  self._baseline_terms(s["coef"], c["joint"]))}
        before = self.heldout_rms()
        free = np.ones(len(c["score"]["theta"]), bool)
        free[c["score"]["fixed_columns"]] = False
        cols = self._columns(eff, c["joint"], c["grid"])[:, :, free]
        unfiltered = self._columns(eff, c["joint"], c["grid"], unfiltered=True)[:, :, free]
        ties = [f"{o['effect']}@{o['joint']}" for o in eligible
                if o is not c and o["joint"] == c["joint"] and c["delta_bic"] - o["delta_bic"] < TIE_BIC]
        ties += [f"{e}@{c['joint']} (identical while moving)" for e in eff.equivalent_to]
        evidence = {"detection": next(d for d in det if d["joint"] == c["joint"]),
                    "attribution": self.attribute(c["joint"]),
                    "delta_bic": c["delta_bic"], "delta_bic_threshold": self.th["delta_bic"][c["joint"] - 1],
                    "heldout_variance_removed": c["heldout_gain"], "heldout_gain_needed": c["gain_needed"],
                    "grid": {"name": eff.grid_name if eff.option_name is None else [eff.grid_name, eff.option_name],
                             "value": c["grid"]}, "sanity": "pass",
                    "equivalent_explanations": ties}
        if not free.all():
            evidence["not_separable"] = [eff.linear_names_at(c["grid"])[i] for i in np.flatnonzero(~free)]
        self.added.append(Added(eff.id, c["joint"], c["grid"], cols, unfiltered, free, c["params"], evidence,
                                before.tolist(), []))
        self._fit_current()
        if self.mode == "identified":
            self._reselect_slope()
        self._choose_inertia()
        self._refine_added()
        self.added[-1].rms_after = self.heldout_rms().tolist()
        # Parameters from the joint fit now holding every added effect.
        self._refresh_params()

    def _reselect_slope(self) -> None:
        """Choose the smooth-sign slope again with the added effects in the model (the same
        grid and criterion as for the baseline: the training residual). An unmodelled effect
        biases the first choice (a spring or a Dahl state near reversals looks like a soft
        sign); the effects' columns that use the sign are rebuilt with it (those built from
        the model's torque keep the columns they were chosen with)."""
        saved = [(a.raw_cols, a.unfiltered) for a in self.added]

        def rebuild():
            for a in self.added:
                eff = CATALOGUE[a.effect]
                if not eff.uses_model:
                    a.raw_cols = self._columns(eff, a.joint, a.grid)[:, :, a.free]
                    a.unfiltered = self._columns(eff, a.joint, a.grid, unfiltered=True)[:, :, a.free]
            self._fit_current()

        first = self.slope
        scores = {}
        for a in SLOPES:
            self._set_slope(a)
            rebuild()
            r = (self.y - self.pred)[self.rows_tr]
            scores[a] = float(r @ r)
        best = min(scores, key=scores.get)
        self._set_slope(best)
        if best == first:
            for a, (cols, unf) in zip(self.added, saved):
                a.raw_cols, a.unfiltered = cols, unf
            self._fit_current()
        else:
            rebuild()
            self.notes.append(f"smooth-sign slope re-chosen after adding {self.added[-1].effect}@"
                              f"{self.added[-1].joint}: {first:g} -> {best:g} s/rad")

    def _refine_added(self) -> None:
        """Re-fit each added effect's non-linear parameter (travel, period, Stribeck velocity,
        delay, width, payload centre) with everything else now in the model: one pass of
        coordinate descent, so that "re-identify all parameters together" includes them.

        A value chosen before a later effect or a new smooth-sign slope was in the model is
        biased by what the model then lacked (a Dahl travel found with a soft sign came out
        15 % long, and the held-out residual of a Dahl state is steep in its travel)."""
        added = list(self.added)
        for a in added:
            eff = CATALOGUE[a.effect]
            if not eff.point_mass and len(list(eff.grid(a.joint))) < 2:
                continue   # nothing non-linear to refit (offset, spring, asymmetry)
            self.added = [o for o in added if o is not a]
            self._fit_current()
            best = self._profile(eff, a.joint)
            self.added = added
            if best is None:
                continue
            g, s = best
            free = np.ones(len(s["theta"]), bool)
            free[s["fixed_columns"]] = False
            # Keep the parameters that were free (a number of harmonics may change when all are).
            if not (np.array_equal(free, a.free) or (free.all() and a.free.all())):
                continue
            if not np.allclose(g, a.grid, rtol=0.01, atol=0.0):
                self.notes.append(f"{a.effect}@{a.joint}: {eff.grid_name} refit with the model as it now "
                                  f"stands: {np.round(a.grid, 6).tolist()} -> {np.round(g, 6).tolist()}")
            a.grid = g
            a.free = free   # all free, but as many as the refit's: a friction profile's harmonics may change
            a.raw_cols = self._columns(eff, a.joint, g)[:, :, free]
            a.unfiltered = self._columns(eff, a.joint, g, unfiltered=True)[:, :, free]
            a.evidence["grid"]["value"] = g
        self._fit_current()

    def _refresh_params(self, coef: np.ndarray | None = None, k0: int | None = None,
                        standard: np.ndarray | None = None) -> None:
        """Each added effect's parameters from a fit's coefficients: the current fit by
        default, or ``coef`` whose effect columns start at ``k0`` with the baseline's Coulomb
        levels taken from ``standard`` (a re-identified model's standard parameters)."""
        if coef is None:
            coef, k0 = self.coef, (0 if self.mode == "given_model" else self.Wb.shape[1])
        for a, params in zip(self.added, self._effect_params(coef, k0, standard)):
            a.params = params

    def add_named(self, named) -> None:
        """Add effects named by another run of the workflow (each an `Added` of it, or anything
        with its effect, joint, grid, free and params) at their non-linear parameters, and fit
        their linear ones with the current model: with a given model, on top of it, which
        stays as it is. An effort delay extends the joint's stuck mask first, as when accepted."""
        for a in named:
            eff = CATALOGUE[a.effect]
            if eff.id == "time_delay":
                lag = int(np.ceil(a.params["delay"] * self.p.rate))
                if lag > self.mask_lag[a.joint - 1]:
                    self._remask(a.joint, lag)
            free = np.asarray(a.free, bool)
            cols = self._columns(eff, a.joint, a.grid)[:, :, free]
            unfiltered = self._columns(eff, a.joint, a.grid, unfiltered=True)[:, :, free]
            before = self.heldout_rms().tolist()
            self.added.append(Added(eff.id, a.joint, a.grid, cols, unfiltered, free, dict(a.params),
                                    {"grid": {"name": eff.grid_name, "value": a.grid}}, before, []))
            self._fit_current()
            self.added[-1].rms_after = self.heldout_rms().tolist()
        self._refresh_params()

    def _reidentify(self) -> dict:
        """Identified mode: the loop's fits are already joint. Given model: re-identify the
        baseline's base parameters with the effects when the effects are separable from them."""
        if self.mode == "identified" or not self.added:
            return {"pred": self.pred, "doc": {"done": self.mode == "identified",
                                               "note": "baseline and effects fitted together"
                                               if self.mode == "identified" else "no effect added"}}
        blocks = [self.Wb] + [a.raw_cols.reshape(3 * self.m, -1) for a in self.added]
        D = np.hstack(blocks)
        tr = self.rows_tr
        Dw = D[tr] * self.rw[tr, None]
        norms = np.linalg.norm(Dw, axis=0)
        norms[norms == 0] = 1.0
        s = np.linalg.svd(Dw / norms, compute_uv=False)
        absorbed = [a.effect for a in self.added if CATALOGUE[a.effect].in_rigid_body_model]
        if s[-1] / s[0] < 1e-6 or absorbed:
            return {"pred": self.pred, "doc": {"done": False, "note": (
                f"{', '.join(absorbed) or 'an effect'} is spanned by the rigid-body/friction parameters: "
                "re-identifying them would absorb it, so the given model is kept and the effect added")}}
        x, *_ = np.linalg.lstsq(Dw / norms, self.y[tr] * self.rw[tr], rcond=None)
        coef = x / norms
        pred = D @ coef
        fixed_rms, reid_rms = self.heldout_rms(), self.heldout_rms(pred)
        rms = {"heldout_rms_fixed_model": fixed_rms.tolist(), "heldout_rms_reidentified": reid_rms.tolist()}
        worse = [j + 1 for j in range(3) if reid_rms[j] > REIDENTIFY_TOLERANCE * fixed_rms[j]]
        if worse:
            # Validation: re-identified on the training block alone, the base parameters
            # generalise worse than the given model (identified on more or richer data).
            return {"pred": self.pred, "doc": {"done": False, "note": (
                f"re-identified on the training block, the model predicts the held-out block worse on joint(s) "
                f"{worse} than the given model with the effects: the given model is kept and the effects added"),
                **rms}}
        # The effects' parameters from the joint fit, with the re-identified Coulomb levels.
        k0 = self.Wb.shape[1]
        self._refresh_params(coef, k0, self.base.standard_from_base(coef[:k0], self.given))
        return {"pred": pred, "coef": coef, "doc": {
            "done": True, "note": "base parameters and effects re-identified together on the training block", **rms}}

    def _effect_doc(self, a: Added) -> dict:
        return {"name": a.effect, "joint": a.joint, "params": a.params,
                "units": CATALOGUE[a.effect].units(a.joint), "evidence": a.evidence,
                "heldout_rms_before": a.rms_before, "heldout_rms_after": a.rms_after}

    # -- the augmented model ------------------------------------------------------------------
    def augmented(self, result: dict) -> tuple[np.ndarray, list[dict]]:
        """The augmented model as a model file holds it: 82 standard parameters (a payload
        folded in) and the added effects' entries (name, joint, params, units).

        The standard parameters are physically consistent (every body's pseudo-inertia
        positive semi-definite, masses, Fc, Fv, Ia >= 0), so that a controller's M(q) and a
        simulated plant built from them are well posed. When the fit's inverse map is
        consistent, it and the effects are written as fitted. Otherwise the consistent rigid
        body and the effects are fitted again together on the training block (`_consistent`),
        and the effects' parameters are those of that fit, so that each goes with the rigid
        body it was fitted beside. ``result["standard_consistency"]`` says which, how much the
        model's training-block torques changed and the held-out RMS of the model as written
        (per joint, N m, N m, N)."""
        from calibration.effects import payload_standard_delta
        from calibration.estimators import check_physical, model_nominal

        reid = result["_reid"]
        entries = [self._entry(a, a.params) for a in self.added]
        if self.mode == "identified":
            coef, nominal = self.coef, model_nominal(self.model)
        elif reid["doc"].get("done"):
            coef, nominal = reid["coef"], self.given
        else:
            pi = self.given.copy()
            for a in self.added:
                if a.effect == "payload":
                    pi = pi + payload_standard_delta(a.params, self.model.body_names)
            return pi, entries
        r = self.Wb.shape[1]
        pi = self.base.standard_from_base(coef[:r], nominal)
        doc = {"projected": False, "training_torque_change_rms": [0.0, 0.0, 0.0],
               "heldout_rms": list(result["final"]["heldout_rms"])}
        if not check_physical(pi, self.model)["all_pass"]:
            coef_c, pi = self._consistent(nominal)
            D = self._joint_design()
            change = (D @ (coef_c - coef)).reshape(-1, 3)
            tr = slice(self.p.train.start, self.p.train.stop)
            moving = self.moving[tr]
            doc = {"projected": True,
                   "training_torque_change_rms": [float(np.sqrt(np.mean(change[tr][moving[:, j], j] ** 2)))
                                                  for j in range(3)],
                   "heldout_rms": self.heldout_rms(D @ coef_c).tolist(),
                   "effects_refitted": bool(self.added)}
            entries = [self._entry(a, prm) for a, prm in zip(self.added, self._effect_params(coef_c, r, pi))]
        result["standard_consistency"] = doc
        return pi, entries

    def _entry(self, a: Added, params: dict) -> dict:
        entry = {"name": a.effect, "joint": a.joint, "params": params, "units": CATALOGUE[a.effect].units(a.joint)}
        if a.effect == "payload":
            entry["applied_to"] = "standard_parameters"
        return entry

    def _joint_design(self) -> np.ndarray:
        """(3m, r + k): the base regressor and every added effect's (filtered) columns."""
        return np.hstack([self.Wb] + [a.raw_cols.reshape(3 * self.m, -1) for a in self.added])

    def _effect_params(self, coef: np.ndarray, k0: int, standard: np.ndarray | None = None) -> list[dict]:
        """Each added effect's parameters from ``coef`` (its columns from ``k0``); the baseline
        terms are the current fit's (those its column was built with: a backlash's Fv and
        inertia), with the Coulomb levels of ``standard`` when given."""
        out = []
        for a in self.added:
            n_cols = a.raw_cols.shape[2]
            theta = np.zeros(len(a.free))
            theta[a.free] = coef[k0:k0 + n_cols]
            k0 += n_cols
            extra = {k: a.params[k] for k in ("com_determined",) if k in a.params}
            terms = self._baseline_terms(self.coef, a.joint)
            if standard is not None:
                terms["Fc"] = float(standard[70 + 4 * (a.joint - 1)])
            out.append(CATALOGUE[a.effect].params(theta, a.grid, a.joint, terms) | extra)
        return out

    def _consistent(self, nominal) -> tuple[np.ndarray, np.ndarray]:
        """The best physically consistent model on the training block, with the effects:
        minimise the (weighted, moving-sample) training residual of base parameters and
        effect coefficients together, the base parameters those of consistent standard ones.
        The effects' coefficients enter linearly and unconstrained, so they are projected out
        (Frisch-Waugh): `Identification.sdp` fits the consistent rigid body to what the effect
        columns cannot explain, pulled toward ``nominal`` where the data do not see, and the
        effects are then the least-squares fit given that rigid body. Returns the coefficients
        (base, then effects) and the standard parameters."""
        from calibration.estimators import Identification

        tr = self.rows_tr
        r = self.Wb.shape[1]
        rw = self.rw[tr]
        D = self._joint_design()[tr] * rw[:, None]
        A, E, t = D[:, :r], D[:, r:], self.y[tr] * rw
        if E.shape[1]:
            norms = np.linalg.norm(E, axis=0)
            norms[norms == 0] = 1.0
            U, s, _ = np.linalg.svd(E / norms, full_matrices=False)
            U = U[:, s > s[0] * 1e-10]
            A_p, t_p = A - U @ (U.T @ A), t - U @ (U.T @ t)
        else:
            A_p, t_p = A, t
        fit = Identification(A_p, t_p[:, None], self.base, self.model, nominal=nominal,
                             max_condition=np.inf).sdp(weighting="none", tol=1e-8)
        beta = np.asarray(fit.beta, float)
        theta = np.zeros(E.shape[1])
        if E.shape[1]:
            theta, *_ = np.linalg.lstsq(E, t - A @ beta, rcond=None)
        return np.concatenate([beta, theta]), np.asarray(fit.pi, float)

    def residual_pairs(self, result: dict) -> list[dict]:
        """For the plots: per added effect, the held-out residual before/after against the
        variable that explains it (time-ordered arrays)."""
        out = []
        p = self.p
        final = result["_reid"]["pred"]
        for a in self.added:
            j = a.joint - 1
            var = a.evidence["attribution"]["variable"]
            x = _variable(self, var)
            ho = self.mov_ho[j]
            pair = {"effect": a.effect, "joint": a.joint, "variable": var, "x": x[ho],
                    "before": (self.y - self.baseline_pred).reshape(-1, 3)[ho, j],
                    "after": (self.y - final).reshape(-1, 3)[ho, j]}
            if a.effect == "position_friction":
                # The friction level against position: the residual times the direction of
                # motion, and the fitted profile f(q) less its mean (the model's Fc holds it).
                grid = np.linspace(p.qf[ho, j].min(), p.qf[ho, j].max(), 300)
                f = friction_profile(a.params, grid)
                pair["profile"] = {"q": p.qf[ho, j], "direction": np.sign(p.dqf[ho, j]), "grid": grid,
                                   "f": f - np.mean(friction_profile(a.params, p.qf[ho, j]))}
            out.append(pair)
        return out


def _effect_columns(eff, ctx: EffectContext, joint: int, g, pieces) -> np.ndarray:
    """The effect's columns (n, 3, k) on the raw samples, each piece of the record on its own:
    a state an effect carries along the samples (a Dahl state, a play's side, a delay's
    history) starts afresh with each recording instead of running across the join."""
    if len(pieces) < 2:
        return eff.columns(ctx, joint, g)

    def part(a, b):
        cut = {"q": ctx.q[a:b], "dq": ctx.dq[a:b]}
        for name in ("tau_model", "mass_diag", "ddq"):
            if getattr(ctx, name) is not None:
                cut[name] = getattr(ctx, name)[a:b]
        if ctx.W_standard is not None:
            cut["W_standard"] = ctx.W_standard[3 * a:3 * b]
        return replace(ctx, **cut)

    return np.concatenate([eff.columns(part(a, b), joint, g) for a, b in pieces], axis=0)


def _variable(w: Discrepancy, name: str) -> np.ndarray:
    p = w.p
    j = int(name[-1]) - 1
    if name.startswith("travel"):
        return np.abs(p.qf[:, j] - _last_reversal_position(p.qf[:, j], p.dqf[:, j], p.kept_starts()))
    return {"q": p.qf, "dq": p.dqf, "ddq": p.ddqf, "u": w.tau_model}[name[:-1]][:, j]


def _last_reversal_position(q: np.ndarray, dq: np.ndarray, starts=()) -> np.ndarray:
    """Position at the last velocity reversal before each sample; a recording that begins at
    an index of ``starts`` begins as if it reversed there (what came before is unknown)."""
    s = np.sign(dq)
    out = np.empty_like(q)
    last = q[0]
    starts = set(starts)
    for k in range(len(q)):
        if k in starts or (k and s[k] != 0 and s[k] != s[k - 1]):
            last = q[k]
        out[k] = last
    return out


def run_workflow(model, base, q, dq, tau, rate: float, given=None, settings: Settings | None = None, breaks=(),
                 given_extra=None):
    """Run the workflow; returns (result dict, the Discrepancy object for plots and the model).
    ``breaks``: sample indices where another continuous recording begins (see `Prepared`);
    ``given_extra``: see `Discrepancy`."""
    w = Discrepancy(model, base, q, dq, tau, rate, given, settings, breaks, given_extra)
    return w.run(), w


def identify_on_runs(model, base, runs, settings: Settings | None = None) -> tuple[np.ndarray, float]:
    """The thesis model identified on every moving sample of several recorded runs together
    (each ``(q, dq, tau, rate)``): a lab's earlier `rig identify`, to be given to the workflow
    as ``given``. Each run is prepared as the workflow prepares data (masked parallel
    filtering, trimmed ends); their equations are stacked, and the Coulomb sign's slope (one
    for all runs, from SLOPES) is the one with the least squares residual; then one weighted
    pass (1 / residual std per joint), as the baseline fit. Returns the standard parameters
    (82,) and the slope."""
    # Detection thresholds play no part in an identification: the fallback ones spare a file read.
    base_settings = settings or Settings()
    ws = [Discrepancy(model, base, *run, settings=Settings(**(vars(base_settings) | {"thresholds": FALLBACK_THRESHOLDS})))
          for run in runs]
    best = None
    for a in SLOPES:
        rows, A, b = [], [], []
        for w in ws:
            w._set_slope(a)
            r = np.concatenate([w.rows_tr, w.rows_ho])
            rows.append(r % 3)
            A.append(w.Wb[r])
            b.append(w.y[r])
        joint, A, b = np.concatenate(rows), np.vstack(A), np.concatenate(b)
        coef = np.linalg.lstsq(A, b, rcond=None)[0]
        res = b - A @ coef
        if best is None or res @ res < best[0]:
            best = (float(res @ res), a, joint, A, b, res)
    _, a, joint, A, b, res = best
    wt = 1.0 / np.maximum([res[joint == j].std() for j in range(3)], 1e-9)
    coef = np.linalg.lstsq(A * wt[joint, None], b * wt[joint], rcond=None)[0]
    model.slope = a
    return base.standard_from_base(coef, model.standard_params()), a
