"""The workflow's model with its effects, physically consistent, and the residual pairs for plots."""

from __future__ import annotations

import numpy as np

from calibration.discrepancy.detection import detection_variable
from calibration.discrepancy.refinement import Added
from calibration.effects import CATALOGUE, friction_profile


class AugmentedModel:
    """The augmented model, a `Discrepancy` mixin: standard parameters and effects as a model file holds them."""

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
            x = detection_variable(self, var)
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
