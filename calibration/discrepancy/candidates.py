"""Every catalogue effect fitted with the current model and ranked by BIC."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from calibration.effects import EffectContext
from calibration.discrepancy.preparation import DEADBAND
from calibration.effects import CATALOGUE

#: An effect column whose singular value, among the effect's own (normalised) columns outside
#: the model's span, is below this share of the largest carries a parameter these data
#: cannot separate from the effect's other parameters (a payload's mass from its first
#: moments on a parallelogram link): it is fixed at 0.
COLLINEAR = 1e-2

#: A column whose part outside the current model's span is below this fraction of its norm
#: is absorbed by the model (not separately identifiable).
ABSORBED = 1e-3

#: Golden-section steps refining a grid effect's non-linear parameter between grid values.
REFINE_STEPS = 8


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


class CandidateSearch:
    """The catalogue search, a `Discrepancy` mixin: each effect's columns and profile, scored by BIC."""

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
