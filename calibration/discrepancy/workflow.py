"""The discrepancy workflow on measured arrays: `Discrepancy`, `run_workflow`, `identify_on_runs`.

It finds where model and measurement disagree, names the missing physical effect from the
catalogue, adds it, re-identifies, and shows the gap shrink on data the fit did not see.

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

import time

import numpy as np

from calibration.discrepancy.augmented_model import AugmentedModel
from calibration.discrepancy.candidates import CandidateSearch
from calibration.discrepancy.detection import Detection
from calibration.discrepancy.preparation import DEADBAND, prepare
from calibration.discrepancy.refinement import Added, Refinement
from calibration.discrepancy.settings import FALLBACK_THRESHOLDS, SLOPES, DiscrepancyError, Settings, load_thresholds
from calibration.effects import CATALOGUE, CATALOGUE_VERSION, EffectContext
from calibration.signals import differentiate


#: A candidate must remove at least this share of what the generic library explains.
LIBRARY_SHARE = 0.5


class Discrepancy(Detection, CandidateSearch, Refinement, AugmentedModel):
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

    def _effect_doc(self, a: Added) -> dict:
        return {"name": a.effect, "joint": a.joint, "params": a.params,
                "units": CATALOGUE[a.effect].units(a.joint), "evidence": a.evidence,
                "heldout_rms_before": a.rms_before, "heldout_rms_after": a.rms_after}


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
