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
   mode). The plain model's rigid body is not fitted again; the friction and rotor inertia
   of an effect's joint (Fc, Fv, Fo, Ia, and joint 3's Stribeck excess) are, beside the
   effect: a plain model fitted without the effect has taken up what it could of it in
   those terms (on the simulated rig an unmodelled position-dependent friction left joint
   3's viscous coefficient and Stribeck excess at 0 and its offset at -0.37 N, where the
   plant has 0.87 N s/m, 0.51 N and 0.12 N). A refitted term below 0 (Fc, Fv, Ia, Fst)
   keeps the plain model's terms on that joint. An effect whose parameters fitted this way
   leave the catalogue's physically plausible range (`calibration.effects`, each effect's
   sanity check: Fs >= Fc >= 0, a positive spring, a payload inside the arm, a lag within
   the catalogue's longest, ...) is dropped.
3. **Confirmed on other motion**, by backward elimination: the effect whose removal costs its
   joint the least prediction accuracy is removed while that cost is under CONFIRM_GAIN
   (1 %) of the joint's relative error or under CONFIRM_ABSOLUTE (0.001) of it, the others
   fitted again each time; of several that fail, the one with the most parameters first. An effect's cost
   is weighed against its joint's friction refitted without it, so that the refit alone is
   never credited to an effect. The accuracy is
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

from calibration.discrepancy.settings import DiscrepancyError, Settings
from calibration.discrepancy.workflow import Discrepancy
from calibration.effects import CATALOGUE, payload_standard_delta
from calibration.effect_reidentification import identified_choice, identified_with
from calibration.plain_model import _relative
from calibration.signals import settling_samples

#: An effect stays only if removing it makes its joint's relative error on other motion
#: at least this share worse (1 %: a smaller change is within what refitting one more
#: parameter set on noise buys).
CONFIRM_GAIN = 0.01
#: ... and by at least this much of the joint's effort (relative error 0.001: a change of
#: 0.1 % of the effort is immaterial to a controller, and on null plants whose joints the
#: plain model already predicts to 0.4 % a friction refit that gained 1 % of that on one
#: motion lost 10 % of it on another).
CONFIRM_ABSOLUTE = 0.001
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
    refit_joints: list = field(default_factory=list)   # 1-based: friction refitted without an effect
    model: object = None   # the workflow's model when it was chosen (see EffectGate.run)


class EffectGate:
    """Steps 2-4 of the module docstring for one plain model and the workflow's effects.

    ``plain``: a `rig.model.model_file.IdentifiedModel`; ``named``: the workflow's added effects
    (`calibration.discrepancy.refinement.Added`); ``motions``: other recordings (empty: cross-validation
    in time); the training arrays and ``settings``/``breaks`` as the workflow had them;
    ``refit``: the workflow's own model (`workflow_model`: its rigid body fitted again with
    all its effects), written instead when another motion is at hand and it predicts that
    motion better than the plain model on every joint and better overall than the plain
    model with the confirmed effects (see `run`). ``training``: the processed training block
    the plain model was identified on (`plain_training_block`); with it and another motion,
    the plain model identified again with the confirmed effects' columns in its regressor
    (`identified_with`) is a candidate too."""

    def __init__(self, plain, named, q, dq, tau, rate: float, settings: Settings | None = None, breaks=(),
                 motions=(), refit=None, training=None):
        from calibration.base_params import base_parameters_of
        from calibration.prediction import extra_effort, standard_parameters
        from rig.model.psm_kinematics import DQ_MAX, Q_MAX, Q_MIN

        self.plain = plain
        self.refit = refit
        self.training = training
        self._arrays = (q, dq, tau, breaks)
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
    def _key(self, subset, joints=()) -> tuple:
        return tuple(next(i for i, o in enumerate(self.all) if o is a) for a in subset), tuple(sorted(joints))

    def _corrections(self, joints, no_stribeck=()) -> tuple[np.ndarray, list]:
        """(3m, k) filtered columns that refit the plain model's friction and rotor inertia of
        ``joints`` (0-based): Fc, Fv, Fo, Ia, and joint 3's Stribeck excess when the plain model
        has one (not on the joints of ``no_stribeck``); and what each column corrects:
        ("standard", index) or ("Fst", joint)."""
        w = self.w
        cols, what = [], []
        Wf = w.W.reshape(w.m, 3, -1)
        for j in sorted(joints):
            for k in range(4):
                c = np.zeros((w.m, 3))
                c[:, j] = Wf[:, j, 70 + 4 * j + k]
                cols.append(c.reshape(-1))
                what.append(("standard", 70 + 4 * j + k))
            st = self.plain.stribeck
            if st is not None and st["vs"][j] > 0 and j == 2 and j not in no_stribeck:
                dq = w.p.dq[:, j]
                raw = np.zeros((w.p.q.shape[0], 3))
                raw[:, j] = np.exp(-(dq / st["vs"][j]) ** 2) * np.tanh(0.5 * w.slope * dq)
                cols.append(w.p.filt_rows(raw).reshape(-1))
                what.append(("Fst", j))
        return (np.column_stack(cols) if cols else np.zeros((3 * w.m, 0))), what

    def _design(self, subset, joints) -> tuple[np.ndarray, list]:
        w = self.w
        blocks = [a.raw_cols.reshape(3 * w.m, -1) for a in subset]
        no_stribeck = {a.joint - 1 for a in subset if a.effect == "stiction"}
        C, what = self._corrections(joints, no_stribeck)
        return np.hstack(blocks + [C]) if blocks or what else np.zeros((3 * w.m, 0)), what

    def _separable(self, subset, j: int) -> bool:
        """Whether joint ``j``'s (0-based) friction can be refitted beside ``subset``'s effects
        on it: not when an effect is a term of the rigid-body and friction model itself (a
        torque offset is Fo, a Coulomb asymmetry Fo and Fc: refitted together, the split is
        arbitrary), nor when their columns are nearly collinear (condition number over 1e6)."""
        on = [a for a in subset if a.joint - 1 == j]
        if any(CATALOGUE[a.effect].in_rigid_body_model for a in on):
            return False
        D, _ = self._design(on, {j})
        rows = self.w.rows_tr[self.w.rows_tr % 3 == j]
        A = D[rows]
        A = A[:, np.linalg.norm(A, axis=0) > 0]
        if not A.shape[1]:
            return False
        s = np.linalg.svd(A / np.linalg.norm(A, axis=0), compute_uv=False)
        return s[-1] > 1e-6 * s[0]

    def _solve(self, D: np.ndarray, rows: np.ndarray, fixed: np.ndarray) -> np.ndarray:
        """Weighted least squares of the plain model's residual on ``rows`` (the workflow's
        per-joint weights)."""
        w = self.w
        if not D.shape[1]:
            return np.zeros(0)
        rw = np.tile(w.w, w.m)[rows]
        A = D[rows] * rw[:, None]
        norms = np.linalg.norm(A, axis=0)
        norms[norms == 0] = 1.0
        return np.linalg.lstsq(A / norms, (w.y - fixed)[rows] * rw, rcond=None)[0] / norms

    def _plain_stribeck(self, j: int) -> np.ndarray:
        """(3m,) the plain model's Stribeck excess of joint ``j`` (0-based), filtered as the
        fits' rows (zero without one)."""
        st = self.plain.stribeck
        w = self.w
        if st is None or not st["Fst"][j]:
            return np.zeros(3 * w.m)
        dq = w.p.dq[:, j]
        raw = np.zeros((w.p.q.shape[0], 3))
        raw[:, j] = st["Fst"][j] * np.exp(-(dq / st["vs"][j]) ** 2) * np.tanh(0.5 * w.slope * dq)
        return w.p.filt_rows(raw).reshape(-1)

    def fit(self, subset, joints=()) -> dict:
        """``subset`` fitted on top of the plain model on the training block, with the
        friction and rotor inertia of the joints it acts on refitted beside it (a plain model
        fitted without an effect has taken up what it could of it in those terms: an
        unmodelled position-dependent friction left joint 3's viscous coefficient at 0 and its
        Stribeck excess at 0 on the simulated rig). A term that would be refitted below 0
        (Fc, Fv, Ia, the Stribeck excess) is held at 0 and the others refitted.
        ``joints`` (1-based): refit these joints' terms too (those of a removed effect, when
        its share is weighed). Cached: {"coef", "standard", "stribeck_fst", "entries",
        "pred", "corrected", "kept_plain", "design"}."""
        key = ("fit",) + self._key(subset, joints)
        if key in self._cache:
            return self._cache[key]
        w = self.w
        joints = {a.joint - 1 for a in subset if a.effect != "payload"} | {j - 1 for j in joints}
        kept_plain = sorted(j + 1 for j in joints if not self._separable(subset, j))
        joints -= {j - 1 for j in kept_plain}
        # A stiction entry is the Stribeck law at its own velocity: it replaces the plain
        # model's excess on its joint rather than adding a second one.
        replaced = sorted({a.joint - 1 for a in subset if a.effect == "stiction"})
        fixed = w.fixed - sum((self._plain_stribeck(j) for j in replaced), np.zeros_like(w.fixed))
        # Terms that would be refitted below 0 (Fc, Fv, Ia, the Stribeck excess) are held at
        # 0 and the others refitted (an active set, as a bounded least squares).
        blocks = [a.raw_cols.reshape(3 * w.m, -1) for a in subset]
        C, what = self._corrections(joints, {a.joint - 1 for a in subset if a.effect == "stiction"})
        st = self.plain.stribeck
        plain_fst = None if st is None else np.asarray(st["Fst"], float).copy()
        if plain_fst is not None:
            plain_fst[replaced] = 0.0

        def plain_value(term):
            kind, idx = term
            return self.pi[idx] if kind == "standard" else plain_fst[idx]

        held: set[int] = set()
        while True:
            free = [k for k in range(len(what)) if k not in held]
            D = np.hstack(blocks + [C[:, free]]) if blocks or free else np.zeros((3 * w.m, 0))
            base = fixed - sum((C[:, k] * plain_value(what[k]) for k in held), np.zeros_like(fixed))
            coef = self._solve(D, w.rows_tr, base)
            ke = D.shape[1] - len(free)
            standard = self.pi.copy()
            fst = None if plain_fst is None else plain_fst.copy()
            for k in held:
                kind, idx = what[k]
                if kind == "standard":
                    standard[idx] = 0.0
                else:
                    fst[idx] = 0.0
            for k, c in zip(free, coef[ke:]):
                kind, idx = what[k]
                if kind == "standard":
                    standard[idx] += c
                else:
                    fst[idx] += c
            bad = [k for k in free if (what[k][0] == "Fst" and fst[what[k][1]] < 0)
                   or (what[k][0] == "standard" and (what[k][1] - 70) % 4 in (0, 1, 3) and standard[what[k][1]] < 0)]
            if not bad:
                break
            held |= set(bad)
        fixed = base
        held_terms = [what[k] for k in sorted(held)]
        w.added = list(subset)
        for a in subset:
            if a.effect == "payload":
                standard = standard + payload_standard_delta(a.params, w.model.body_names)
        entries = []
        if subset:
            for a, prm in zip(subset, w._effect_params(coef, 0, standard)):
                a.params = prm
                entries.append(w._entry(a, dict(prm)))
        out = {"coef": coef, "standard": standard, "stribeck_fst": fst, "entries": entries,
               "pred": fixed + D @ coef if D.shape[1] else fixed.copy(), "fixed": fixed,
               "corrected": sorted(j + 1 for j in joints), "kept_plain": kept_plain, "design": D,
               "held_at_zero": [_term_name(t) for t in held_terms]}
        self._cache[key] = out
        return out

    def model_parts(self, subset) -> tuple[np.ndarray, list[dict]]:
        """Standard parameters (friction refitted, a payload folded in) and the effects'
        entries of ``subset`` fitted on top of the plain model on the training block."""
        f = self.fit(subset)
        return f["standard"], f["entries"]

    def model_file(self, subset, joints=()):
        """The candidate model file (in memory): the plain model with ``subset`` added."""
        f = self.fit(subset, joints)
        doc = copy.deepcopy(self.plain.document)
        doc["effects"] = list(self.plain.effects) + f["entries"]
        doc["standard_parameters"] = dict(doc.get("standard_parameters", {}), values=f["standard"].tolist())
        if f["stribeck_fst"] is not None:
            doc["friction"]["stribeck"]["Fst"] = f["stribeck_fst"].tolist()
        return replace(self.plain, standard=f["standard"], document=doc)

    def errors(self, subset, joints=()) -> np.ndarray:
        """Per joint relative error of the plain model with ``subset`` (and the terms of
        ``joints`` refitted) on the other motions (their mean), or cross-validated over blocks
        in time of the training record."""
        key = self._key(subset, joints)
        if key not in self._cache:
            self._cache[key] = (self._on_motions(subset, joints) if self.motions
                                else self._cross_validated(subset, joints))
        return self._cache[key]

    def _on_motions(self, subset, joints=()) -> np.ndarray:
        from calibration.prediction import predict

        model = self.model_file(subset, joints)
        rel = [predict(model, m.q, m.dq, m.tau, m.rate, self.settings, m.source).figures("all")["relative_error"]
               for m in self.motions]
        return np.mean(np.asarray(rel, float), axis=0)

    def _cross_validated(self, subset, joints=()) -> np.ndarray:
        w = self.w
        m = w.m
        f = self.fit(subset, joints)
        D = f["design"]
        target = w.y - f["fixed"]
        sample = np.arange(3 * m) // 3
        joint = np.arange(3 * m) % 3
        moving = w.moving.reshape(-1)
        guard = settling_samples(self.rate, self.settings.cutoff, self.settings.order)
        num, den = np.zeros(3), np.zeros(3)
        for b in range(CV_BLOCKS):
            lo, hi = b * m // CV_BLOCKS, (b + 1) * m // CV_BLOCKS
            test = moving & (sample >= lo) & (sample < hi)
            train = np.flatnonzero(moving & ((sample < lo - guard) | (sample >= hi + guard)))
            r = target[test]
            if D.shape[1]:
                r = r - D[test] @ self._solve(D, train, f["fixed"])
            for j in range(3):
                sel = joint[test] == j
                num[j] += float(r[sel] @ r[sel])
                den[j] += float(w.y[test][sel] @ w.y[test][sel])
        return np.sqrt(num / np.maximum(den, 1e-300))

    # -- the rigid body identified again with the effects ---------------------------------------
    def identified_with(self, subset):
        """The plain model identified again with ``subset``'s effects in the regressor
        (calibration.effect_reidentification.identified_with). Cached."""
        return identified_with(self, subset)

    def _plain_torque(self):
        """``(q, dq, ddq) -> (n, 3)``: the plain model's rigid-body and friction effort (the
        torque a delay column is built from)."""
        dyn = self.plain.dynamics()
        pi = np.asarray(self.plain.standard, float)

        def torque(q, dq, ddq):
            return (dyn.regressor_batch(q, dq, ddq) @ pi).reshape(-1, 3)

        return torque

    def _identified_choice(self, kept, dropped, plain, written):
        """calibration.effect_reidentification.identified_choice."""
        return identified_choice(self, kept, dropped, plain, written)

    # -- the gate ------------------------------------------------------------------------------
    def run(self) -> GateResult:
        from calibration.prediction import PredictionError

        steps, implausible, not_confirmed = [], [], []
        method = ("another motion: " + "; ".join(m.source for m in self.motions) if self.motions else
                  f"cross-validation over {CV_BLOCKS} blocks in time of the training record (one motion only)")
        kept = []
        # Plausibility of each effect fitted on top of the plain model.
        self.fit(self.all)
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
                # its share beyond its joint's friction refitted without it (an effect that is
                # itself a term of that friction, a torque offset, is weighed against the plain model's)
                separate = a.effect != "payload" and not CATALOGUE[a.effect].in_rigid_body_model
                without = self.errors([o for o in kept if o is not a], {a.joint} if separate else ())
                j = a.joint - 1
                costs.append(((without[j] - current[j]) / max(without[j], 1e-12), a, without[j] - current[j]))
            # Of the effects that do not confirm, the one with the most parameters goes first:
            # two collinear effects (an offset and a spring's constant) each look useless beside
            # the other, and the simpler law should stay.
            weak = [c for c in costs if c[0] < CONFIRM_GAIN or c[2] < CONFIRM_ABSOLUTE]
            if not weak:
                steps.append({"effects": [f"{a.effect}@{a.joint}" for a in kept], "relative_error": current.tolist(),
                              "least_useful": None})
                break
            cost, worst, _ = max(weak, key=lambda c: (c[1].raw_cols.shape[2], -c[0]))
            steps.append({"effects": [f"{a.effect}@{a.joint}" for a in kept], "relative_error": current.tolist(),
                          "least_useful": f"{worst.effect}@{worst.joint}", "its_gain": cost})
            kept = [a for a in kept if a is not worst]
            why = NOT_CONFIRMED
            st = self.plain.stribeck
            if worst.effect == "stiction" and st is not None and st["Fst"][worst.joint - 1] > 0:
                why += (f" beyond the plain model's Stribeck excess on joint {worst.joint} (the same law, "
                        f"{st['Fst'][worst.joint - 1]:.3g} at {st['vs'][worst.joint - 1]:g})")
            not_confirmed.append({"effect": worst.effect, "joint": worst.joint, "gain_on_new_motion": cost,
                                  "why": why})
        # A joint's friction refitted alone (no effect kept on it): kept where it confirms.
        refit: set[int] = set()
        for j in (1, 2, 3):
            if any(a.joint == j for a in kept):
                continue
            current, trial = self.errors(kept, refit), self.errors(kept, refit | {j})
            gain = current[j - 1] - trial[j - 1]
            if self.fit(kept, refit | {j})["corrected"].count(j) and gain >= CONFIRM_ABSOLUTE and \
                    gain / max(current[j - 1], 1e-12) >= CONFIRM_GAIN:
                refit.add(j)
        # Never worse than the plain model on any joint (with nothing kept it is the plain model).
        while kept or refit:
            current = self.errors(kept, refit)
            worse = {j + 1 for j in range(3) if current[j] > plain[j]}
            if not worse:
                break
            drop = [a for a in kept if a.joint in worse or a.effect == "payload"]
            if not drop and not refit & worse:
                drop = list(kept)   # worse through no term of its own: nothing is kept
            refit -= worse
            for a in drop:
                kept = [o for o in kept if o is not a]
                not_confirmed.append({"effect": a.effect, "joint": a.joint,
                                      "why": f"{NOT_CONFIRMED} (joint(s) {sorted(worse)} predicted worse than by the "
                                             "plain model)"})
        written = self.errors(kept, refit)
        final = self.fit(kept, refit)
        standard, entries = final["standard"], final["entries"]
        folded = self._folded(refit, not_confirmed, standard)
        not_confirmed = [d for d in not_confirmed if not any((d["effect"], d["joint"]) == (f["effect"], f["joint"])
                                                             for f in folded)]
        choice = "plain model + confirmed effects"
        whole, passed_over, chosen_model, identified_doc = None, None, None, None
        if self.training is not None and self.motions:
            dropped = [a for a in self.all if any(d["effect"] == a.effect and d["joint"] == a.joint
                                                   and d["why"].startswith(NOT_CONFIRMED) for d in not_confirmed)]
            best, tried = self._identified_choice(kept, dropped, plain, written)
            identified_doc = {"tried": tried}
            if best is not None:
                model, effects, rel, _ = best
                passed_over = {"relative_error": written.tolist(), "kept": [f"{a.effect}@{a.joint}" for a in kept],
                               "friction_refitted_alone_on_joints": sorted(refit),
                               "not_confirmed": not_confirmed, "implausible": implausible}
                choice = IDENTIFIED_CHOICE
                chosen_model, written = model, rel
                standard, entries = model.standard, model.effects
                not_confirmed = [d for d in not_confirmed if not any(d["effect"] == a.effect and d["joint"] == a.joint
                                                                     for a in effects)]
                kept, refit, folded = list(effects), set(), []
                final = {"corrected": [], "kept_plain": []}
                identified_doc.update({"gravity": model.gravity.tolist(), "slope": model.slope,
                                       "stribeck": None if model.stribeck is None else
                                       {k: v.tolist() for k, v in model.stribeck.items()}})
        if self.refit is not None and self.motions and self.all:
            # The rigid body fitted again with the effects (the workflow's own model): on the
            # simulated rig the plain model, fitted without an effect, carries a bias on every
            # joint that only a refit removes; on the real PSM that refit predicted another
            # motion 1.6-1.8 times worse. The other motion decides.
            whole = np.mean([_relative(self.refit, m, self.settings) for m in self.motions], axis=0)
            if np.all(whole <= plain) and whole.sum() < (1.0 - CONFIRM_GAIN) * written.sum():
                choice = "the workflow's model (rigid body refitted with all its effects)"
                passed_over = {"relative_error": written.tolist(), "kept": [f"{a.effect}@{a.joint}" for a in kept],
                               "friction_refitted_alone_on_joints": sorted(refit),
                               "not_confirmed": not_confirmed, "implausible": implausible,
                               "choice": "plain model + confirmed effects" if chosen_model is None
                               else IDENTIFIED_CHOICE}
                chosen_model = None
                written = whole
                standard = self.refit.standard
                entries = [e for e in self.refit.effects if e not in self.plain.effects]
                kept, refit, not_confirmed, implausible, folded = list(self.all), set(), [], [], []
                final = {"corrected": [], "kept_plain": []}
        doc = {"method": method, "confirm_gain": CONFIRM_GAIN, "confirm_absolute": CONFIRM_ABSOLUTE, "choice": choice,
               "refitted_rigid_body_relative_error": None if whole is None else whole.tolist(),
               "guards": ["effects fitted on top of the plain model (its rigid body not fitted again; the friction and "
                          "rotor inertia of an effect's joint refitted beside it, kept >= 0)",
                          "catalogue plausibility ranges per effect (calibration.effects sanity checks)",
                          "backward elimination on " + ("the other motion" if self.motions else
                                                        "blocks in time (cross-validation)")],
               "relative_error": {"plain": plain.tolist(), "written": written.tolist()},
               "kept": [f"{a.effect}@{a.joint}" for a in kept] + [f"{f['effect']}@{f['joint']}" for f in folded],
               "folded_into_friction": folded,
               "friction_refitted_on_joints": final["corrected"],
               "friction_refitted_alone_on_joints": sorted(refit),
               "friction_kept_plain_on_joints": final["kept_plain"],
               "not_confirmed": not_confirmed, "implausible": implausible, "steps": steps,
               "plain_with_confirmed_effects": passed_over, "identified_with_effects": identified_doc}
        if chosen_model is not None:
            doc["guards"].append("the plain model identified again with the confirmed effects in its regressor "
                                 "(gravity, friction slope and Stribeck velocity chosen again), written only where "
                                 "it predicts the other motion better")
        chosen = self.refit if whole is not None and choice.startswith("the workflow") else chosen_model
        return GateResult(kept, standard, entries, doc, sorted(refit), chosen)

    def predicted(self, model) -> np.ndarray:
        """(3m,) ``model``'s efforts (effects included) on the training record's rows, as the
        workflow's figures take them (e.g. for `Discrepancy.heldout_rms`)."""
        q, dq, tau, breaks = self._arrays
        return EffectGate(model, [], q, dq, tau, self.rate, self.settings, breaks).w.fixed

    def _folded(self, refit, not_confirmed, standard) -> list[dict]:
        """Named effects that are terms of a joint's friction (a torque offset is Fo; a
        Coulomb asymmetry dFc is Fo and Fc of dFc / 2 each; a spring's constant part -k q0 is
        an offset), not confirmed as entries of their own but confirmed as that joint's
        friction refitted alone (``refit``, 1-based): the refit moved the joint's Fo by the
        named size within a factor of 2, same sign. They are written, as those terms (a
        spring's stiffness stays "not confirmed")."""
        out = []
        for d in not_confirmed:
            j = d["joint"]
            if j not in refit or d["effect"] not in ("torque_offset", "coulomb_asymmetry", "spring"):
                continue
            a = next(o for o in self.all if (o.effect, o.joint) == (d["effect"], j))
            effect, note = a.effect, None
            if a.effect == "torque_offset":
                named = a.params["offset"]
            elif a.effect == "coulomb_asymmetry":
                named = 0.5 * a.params["dFc"]
            else:
                # A spring k (q - q0) is k q plus the constant -k q0: its stiffness not
                # confirmed, that constant alone is the catalogue's torque offset.
                if a.params.get("q0") is None or any(o.effect == "torque_offset" and o.joint == j for o in self.all):
                    continue
                named, effect = -a.params["k"] * a.params["q0"], "torque_offset"
                note = f"the constant part -k q0 of spring@{j} (its stiffness {a.params['k']:.4g} not confirmed)"
            moved = float(standard[70 + 4 * (j - 1) + 2] - self.pi[70 + 4 * (j - 1) + 2])
            if named != 0.0 and 0.5 <= moved / named <= 2.0:
                out.append({"effect": effect, "joint": j, "as": f"joint{j}.Fo", "named": float(named),
                            "written": moved, "from": note})
        return out

    def written_model(self, result: GateResult):
        """The written model file (in memory) of a `run` result."""
        return result.model if result.model is not None else self.model_file(result.kept, result.refit_joints)


IDENTIFIED_CHOICE = ("the plain model identified again with the confirmed effects (gravity, friction slope, "
                     "Stribeck velocity and rigid body chosen with the effects' columns in the regressor)")


def _term_name(term) -> str:
    kind, idx = term
    if kind == "Fst":
        return f"joint{idx + 1}.Fst"
    return f"joint{(idx - 70) // 4 + 1}." + ("Fc", "Fv", "Fo", "Ia")[(idx - 70) % 4]
