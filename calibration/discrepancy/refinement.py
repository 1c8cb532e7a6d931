"""An accepted effect added to the model, its non-linear parameters refined, the model re-identified."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from calibration.discrepancy.settings import SLOPES
from calibration.effects import CATALOGUE

#: Candidates within this BIC of the best are equivalent explanations.
TIE_BIC = 2.0

#: With a given model, the final joint re-identification (base parameters and effects on the
#: training block) is kept only if no joint's held-out RMS exceeds this multiple of the given
#: model's with the effects added.
REIDENTIFY_TOLERANCE = 1.05


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


class Refinement:
    """An effect accepted, a `Discrepancy` mixin: added, refined, the model re-identified."""

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
