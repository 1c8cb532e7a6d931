"""Effects kept only where they predict motion the fit has not seen (issue 26).

The discrepancy workflow (`calibration.discrepancy`) names effects on one recording: it fits
them, together with a rigid body fitted again on the workflow's 10 Hz band, on the first
three quarters, and confirms them on the last quarter of the same motion. On the real PSM
that rigid body, fitted again beside four effects, predicted another motion 1.6-1.8 times
worse than `rig identify`'s model of the same data: the held-out block of one excitation is
no test of another motion. So the model file is built and judged here, not there:

1. **The plain model** is the one `rig identify --csv` writes for the training data (its
   defaults: gravity direction and friction slope chosen by the fit, the thesis' 3.5 Hz
   filter, moving samples only, Stribeck excess on joint 3, physically consistent SDP), or
   the model the user gave (`--model`), whole: its Stribeck excess and its effects too.
2. **The named effects are fitted on top of it**: the workflow's effects at the non-linear
   parameters it chose (travel, period, delay, centre), their linear parameters fitted on the
   training block to what the plain model leaves (`Discrepancy.add_named` in the given-model
   mode); the plain model is not fitted again. An effect whose parameters fitted this way
   leave the catalogue's physically plausible range (`calibration.effects`, each effect's
   sanity check: Fs >= Fc >= 0, a positive spring, a payload inside the arm, a lag within the
   catalogue's longest, ...) is dropped.
3. **Confirmed on other motion**, by backward elimination: the effect whose removal costs its
   joint the least prediction accuracy is removed while that cost is under CONFIRM_GAIN
   (1 %) of the joint's relative error, the others fitted again each time. The accuracy is
   measured, in order of preference, on
   * another motion: a second recording (`--validate-csv`), or the last continuous piece of a
     run recorded as several (`rig identify`'s validation trajectory after its excitation):
     the candidate model file, effects and all, predicts its efforts
     (`calibration.prediction`);
   * with only one motion, cross-validation over CV_BLOCKS blocks in time of the training
     record: each block predicted by the effects' parameters fitted on the others (a guard
     of one filter settling length on each side), the plain model fixed.
4. **Never worse than the plain model**: effects on a joint the kept set predicts worse than
   the plain model are removed too. With nothing confirmed the written model is the plain
   model.

Effects removed in 3 are reported "seen in training, not confirmed on new motion".

Units: SI (rad, m, rad/s, m/s, N m, N, s, Hz).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field, replace

import numpy as np

from calibration.discrepancy import Discrepancy, DiscrepancyError, Settings
from calibration.effects import CATALOGUE, payload_standard_delta
from calibration.signals import settling_samples

#: An effect stays only if removing it makes its joint's relative error on other motion
#: at least this share worse (1 %: a smaller change is within what refitting one more
#: parameter set on noise buys).
CONFIRM_GAIN = 0.01
#: Blocks in time of the cross-validation used when there is one motion only.
CV_BLOCKS = 4
NOT_CONFIRMED = "seen in training, not confirmed on new motion"


@dataclass
class Motion:
    """A recording other than the training one: q, dq, tau (n, 3) at ``rate`` Hz and what it is."""

    q: np.ndarray
    dq: np.ndarray
    tau: np.ndarray
    rate: float
    source: str


@dataclass
class GateResult:
    """What the gate kept and why (``doc`` for result.json) and the model file it writes
    (``standard`` (82,), ``entries`` the effects' entries to add to the plain model's)."""

    kept: list
    standard: np.ndarray
    entries: list
    doc: dict = field(default_factory=dict)


def plain_training_block(q, dq, tau, rate: float, heldout: float, breaks=(), source: str = "the data"):
    """The training block as `rig identify --csv` takes it, processed with its filter: the
    first 1 - ``heldout`` of the record less a guard of one settling length (several pieces:
    each filtered on its own, the first share of their samples)."""
    from calibration.datasets import JointData, processed, split_blocks
    from calibration.identification import CUTOFF_HZ, FILTER_ORDER

    data = JointData(np.arange(len(q)) / rate, np.asarray(q, float), np.asarray(dq, float),
                     np.asarray(tau, float), rate, source)
    if len(breaks):
        from calibration.datasets import pieces_training_block

        return pieces_training_block(data, breaks, CUTOFF_HZ, FILTER_ORDER, heldout)
    train_all, _ = split_blocks(processed(data, CUTOFF_HZ, FILTER_ORDER), heldout)
    guard = min(settling_samples(rate, CUTOFF_HZ, FILTER_ORDER), train_all.n_samples // 4)
    return train_all.rows(slice(0, train_all.n_samples - guard), f"minus a {guard}-sample guard")


def plain_fit(train):
    """`rig identify --csv`'s fit at its defaults on processed training data: a FitOutcome."""
    from calibration.identification import DEADBAND, fit_identification

    return fit_identification(train, "auto", "auto", deadband=DEADBAND, parallel=True, stribeck=True)


class EffectGate:
    """Steps 2-4 of the module docstring for one plain model and the workflow's effects.

    ``plain``: a `rig.model_file.IdentifiedModel`; ``named``: the workflow's added effects
    (`calibration.discrepancy.Added`); ``motions``: other recordings (empty: cross-validation
    in time); the training arrays and ``settings``/``breaks`` as the workflow had them."""

    def __init__(self, plain, named, q, dq, tau, rate: float, settings: Settings | None = None, breaks=(),
                 motions=()):
        from calibration.base_params import base_parameters_of
        from calibration.prediction import extra_effort, standard_parameters
        from rig.psm_kinematics import DQ_MAX, Q_MAX, Q_MIN

        self.plain = plain
        self.settings = settings or Settings()
        self.motions = list(motions)
        self.rate = rate
        self.pi = standard_parameters(plain)
        dyn = plain.dynamics()
        base = base_parameters_of(dyn.regressor_batch, dyn, Q_MIN, Q_MAX, DQ_MAX)
        self.w = Discrepancy(dyn, base, q, dq, tau, rate, self.pi, self.settings, breaks,
                             given_extra=lambda p: extra_effort(plain, p))
        self.w.add_named(named)
        self.all = list(self.w.added)
        self._cache: dict = {}

    # -- a subset of the effects -------------------------------------------------------------
    def _use(self, subset: list) -> None:
        self.w.added = list(subset)
        self.w._fit_current()
        if subset:
            self.w._refresh_params()

    def _key(self, subset) -> tuple:
        return tuple(self.all.index(a) for a in subset)

    def model_parts(self, subset) -> tuple[np.ndarray, list[dict]]:
        """Standard parameters (a payload folded in) and the effects' entries of ``subset``
        fitted on top of the plain model on the training block."""
        self._use(subset)
        pi = self.pi.copy()
        entries = []
        for a in subset:
            entries.append(self.w._entry(a, dict(a.params)))
            if a.effect == "payload":
                pi = pi + payload_standard_delta(a.params, self.w.model.body_names)
        return pi, entries

    def model_file(self, subset):
        """The candidate model file (in memory): the plain model with ``subset`` added."""

        pi, entries = self.model_parts(subset)
        doc = copy.deepcopy(self.plain.document)
        doc["effects"] = list(self.plain.effects) + entries
        doc["standard_parameters"] = dict(doc.get("standard_parameters", {}), values=pi.tolist())
        return replace(self.plain, standard=pi, document=doc)

    def errors(self, subset) -> np.ndarray:
        """Per joint relative error of the plain model with ``subset`` on the other motions
        (their mean), or cross-validated over blocks in time of the training record."""
        key = self._key(subset)
        if key not in self._cache:
            self._cache[key] = self._on_motions(subset) if self.motions else self._cross_validated(subset)
        return self._cache[key]

    def _on_motions(self, subset) -> np.ndarray:
        from calibration.prediction import predict

        model = self.model_file(subset)
        rel = [predict(model, m.q, m.dq, m.tau, m.rate, self.settings, m.source).figures("all")["relative_error"]
               for m in self.motions]
        return np.mean(np.asarray(rel, float), axis=0)

    def _cross_validated(self, subset) -> np.ndarray:
        w = self.w
        m = w.m
        target = w.y - w.fixed
        D = (np.hstack([a.raw_cols.reshape(3 * m, -1) for a in subset]) if subset else np.zeros((3 * m, 0)))
        sample = np.arange(3 * m) // 3
        joint = np.arange(3 * m) % 3
        moving = w.moving.reshape(-1)
        rw = np.tile(w.w, m)
        guard = settling_samples(self.rate, self.settings.cutoff, self.settings.order)
        num, den = np.zeros(3), np.zeros(3)
        for b in range(CV_BLOCKS):
            lo, hi = b * m // CV_BLOCKS, (b + 1) * m // CV_BLOCKS
            test = moving & (sample >= lo) & (sample < hi)
            train = moving & ((sample < lo - guard) | (sample >= hi + guard))
            r = target[test]
            if D.shape[1]:
                A = D[train] * rw[train, None]
                norms = np.linalg.norm(A, axis=0)
                norms[norms == 0] = 1.0
                coef = np.linalg.lstsq(A / norms, target[train] * rw[train], rcond=None)[0] / norms
                r = r - D[test] @ coef
            for j in range(3):
                sel = joint[test] == j
                num[j] += float(r[sel] @ r[sel])
                den[j] += float(w.y[test][sel] @ w.y[test][sel])
        return np.sqrt(num / np.maximum(den, 1e-300))

    # -- the gate ------------------------------------------------------------------------------
    def run(self) -> GateResult:
        from calibration.prediction import PredictionError

        steps, implausible, not_confirmed = [], [], []
        method = ("another motion: " + "; ".join(m.source for m in self.motions) if self.motions else
                  f"cross-validation over {CV_BLOCKS} blocks in time of the training record (one motion only)")
        kept = []
        # Plausibility of each effect fitted on top of the plain model.
        self._use(self.all)
        for a in self.all:
            why = CATALOGUE[a.effect].sanity(a.params, a.joint)
            if why is None:
                kept.append(a)
            else:
                implausible.append({"effect": a.effect, "joint": a.joint, "why": why})
        try:
            plain = self.errors([])
        except PredictionError as exc:
            raise DiscrepancyError(f"the other motion cannot be used: {exc}") from None
        # Backward elimination on the other motion.
        while kept:
            current = self.errors(kept)
            costs = []
            for a in kept:
                without = self.errors([o for o in kept if o is not a])
                j = a.joint - 1
                costs.append(((without[j] - current[j]) / max(without[j], 1e-12), a, without))
            cost, worst, without = min(costs, key=lambda c: c[0])
            steps.append({"effects": [f"{a.effect}@{a.joint}" for a in kept], "relative_error": current.tolist(),
                          "least_useful": f"{worst.effect}@{worst.joint}", "its_gain": cost})
            if cost >= CONFIRM_GAIN:
                break
            kept.remove(worst)
            not_confirmed.append({"effect": worst.effect, "joint": worst.joint, "gain_on_new_motion": cost,
                                  "why": NOT_CONFIRMED})
        # Never worse than the plain model on any joint.
        while kept:
            current = self.errors(kept)
            worse = [j for j in range(3) if current[j] > plain[j]]
            if not worse:
                break
            drop = [a for a in kept if a.joint - 1 in worse or a.effect == "payload"] or kept[:1]
            for a in drop:
                kept.remove(a)
                not_confirmed.append({"effect": a.effect, "joint": a.joint,
                                      "why": f"{NOT_CONFIRMED} (the joint(s) {[j + 1 for j in worse]} predicted "
                                             "worse than the plain model)"})
        written = self.errors(kept)
        standard, entries = self.model_parts(kept)
        doc = {"method": method, "confirm_gain": CONFIRM_GAIN,
               "guards": ["effects fitted on top of the plain model (its rigid body and friction not fitted again)",
                          "catalogue plausibility ranges per effect (calibration.effects sanity checks)",
                          "backward elimination on " + ("the other motion" if self.motions else
                                                        "blocks in time (cross-validation)")],
               "relative_error": {"plain": plain.tolist(), "written": written.tolist()},
               "kept": [f"{a.effect}@{a.joint}" for a in kept], "not_confirmed": not_confirmed,
               "implausible": implausible, "steps": steps}
        return GateResult(kept, standard, entries, doc)
