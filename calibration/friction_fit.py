"""Friction of one joint from the tests of thesis 5.6: breakaway detection and curve fits.

Forces in N (insertion joint) or N m, velocities in m/s or rad/s.

* :func:`breakaway`: the first sample of a force ramp after which the joint keeps moving
  faster than a threshold for ``sustain`` samples; the applied force there is the
  breakaway (static friction) force of that direction.
* :func:`fit_viscous_coulomb`: linear least squares of f = Fo + Fv v + Fc sign(v).
* :func:`fit_stribeck`: f = Fo + Fv v + sign(v) (Fc + (Fs - Fc) exp(-(|v|/vs)^2)) by
  bounded non-linear least squares (scipy ``least_squares``), started from the
  viscous-Coulomb fit; one-sigma parameter uncertainties from the Jacobian. The excess
  Fs - Fc is a parameter bounded at 0: a Stribeck effect is a static level above the
  Coulomb one (Fs >= Fc >= 0). Friction that dips below Fc + Fv v at low speed (a
  smooth zero crossing, as the simulated plant's sigmoid has) is then no Stribeck excess,
  not a negative one.
"""

from __future__ import annotations

import numpy as np
import scipy.optimize


class FrictionFitError(ValueError):
    """Too few or degenerate friction data for the fit asked."""


def breakaway(force: np.ndarray, velocity: np.ndarray, threshold: float, sustain: int = 3,
              direction: int = 1, onset_fraction: float = 0.2) -> int | None:
    """Index of the breakaway sample of a ramp, or None if the joint never broke away.

    The joint has broken away once ``direction * velocity`` exceeds ``threshold`` at a
    sample and the ``sustain - 1`` after it (a single noisy sample does not count). Just
    past the breakaway the excess force is small, so the joint accelerates slowly and
    crosses the threshold some time after it started to slide; the index returned is
    therefore the motion's onset: the sample after the last one, before the crossing,
    below ``onset_fraction * threshold`` (keep that above the velocity noise). ``force`` is
    not used for the decision, only returned by the caller.
    """
    v = direction * np.asarray(velocity, float)
    above = v > threshold
    run = 0
    for k, a in enumerate(above):
        run = run + 1 if a else 0
        if run >= sustain:
            first = k - sustain + 1
            slow = np.flatnonzero(v[:first] <= onset_fraction * threshold)
            return int(slow[-1] + 1) if slow.size else first
    return None


def _sign(v):
    return np.sign(np.asarray(v, float))


def fit_viscous_coulomb(v, f) -> dict:
    """f = Fo + Fv v + Fc sign(v) by least squares; returns Fo, Fv, Fc, their std and rms."""
    v, f = np.asarray(v, float), np.asarray(f, float)
    if v.size < 3 or not (np.any(v > 0) and np.any(v < 0)):
        raise FrictionFitError("a viscous-Coulomb fit needs at least 3 points with both directions of motion")
    A = np.column_stack([np.ones_like(v), v, _sign(v)])
    x, *_ = np.linalg.lstsq(A, f, rcond=None)
    r = f - A @ x
    dof = max(v.size - 3, 1)
    cov = np.linalg.pinv(A.T @ A) * float(r @ r) / dof
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    return {"model": "Fo + Fv v + Fc sign(v)", "Fo": float(x[0]), "Fv": float(x[1]), "Fc": float(x[2]),
            "std": {"Fo": float(sd[0]), "Fv": float(sd[1]), "Fc": float(sd[2])},
            "rms": float(np.sqrt(np.mean(r ** 2))), "n": int(v.size)}


def stribeck_curve(p, v):
    """Fo + Fv v + sign(v) (Fc + (Fs - Fc) exp(-(|v|/vs)^2)) for p = (Fo, Fv, Fc, Fs, vs)."""
    fo, fv, fc, fs, vs = p
    v = np.asarray(v, float)
    return fo + fv * v + _sign(v) * (fc + (fs - fc) * np.exp(-(np.abs(v) / vs) ** 2))


def _sd(jac: np.ndarray, r: np.ndarray, dof: int, mix: np.ndarray, rel_tol: float = 1e-8) -> np.ndarray:
    """One-sigma uncertainties of ``mix @ x`` at a least-squares solution x (Jacobian
    ``jac``, residual ``r``): inf for a combination that loads on a direction the data do
    not determine (a singular value of the column-scaled Jacobian below ``rel_tol`` of
    the largest), where a pseudo-inverse would report 0."""
    scale = np.linalg.norm(jac, axis=0)
    scale = np.where(scale > 0, scale, 1.0)
    _, sv, Vt = np.linalg.svd(jac / scale, full_matrices=False)
    good = sv > rel_tol * sv.max() if sv.size and sv.max() > 0 else np.zeros(sv.shape, bool)
    V = Vt[good].T / sv[good] / scale[:, None]
    sd = np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", mix, V @ V.T, mix), 0.0) * float(r @ r) / dof)
    free = np.any(np.abs(Vt[~good]) > 1e-6, axis=0)   # parameters with a part left undetermined
    sd[(np.abs(mix) > 0) @ free] = np.inf
    return sd


def fit_stribeck(v, f, fs_guess: float | None = None, vs_bounds=(1e-4, 1.0)) -> dict:
    """Stribeck fit (module docstring); Fv >= 0, Fs >= Fc >= 0, vs within ``vs_bounds``.

    ``fs_guess`` (e.g. the ramp's breakaway level) starts Fs; else 1.5 Fc of the
    viscous-Coulomb fit. ``success`` is False when the solver failed or the Stribeck
    excess Fs - Fc is not resolved (not above its own one-sigma uncertainty, or not
    determined by these speeds at all): the thesis found exactly that on the real joint 3
    (5.6). ``std`` gives one sigma of each parameter and of the excess ``dFs`` (None where
    the data do not determine it; an undetermined excess is reported as 0, Fs = Fc).
    """
    v, f = np.asarray(v, float), np.asarray(f, float)
    if v.size < 6:
        raise FrictionFitError("a Stribeck fit needs at least 6 points (5 parameters)")
    vc = fit_viscous_coulomb(v, f)
    fc0 = max(vc["Fc"], 1e-3)
    fs0 = max(fs_guess if fs_guess is not None else 1.5 * fc0, fc0)
    vmin = max(np.min(np.abs(v[v != 0])) if np.any(v != 0) else 1e-3, vs_bounds[0])
    # solved in (Fo, Fv, Fc, dFs = Fs - Fc, vs), the excess bounded at 0
    x0 = np.array([vc["Fo"], max(vc["Fv"], 0.0), fc0, fs0 - fc0, np.clip(2 * vmin, *vs_bounds)])
    lo = np.array([-np.inf, 0.0, 0.0, 0.0, vs_bounds[0]])
    hi = np.array([np.inf, np.inf, np.inf, np.inf, vs_bounds[1]])
    x0 = np.clip(x0, lo + 1e-12, hi - 1e-12)
    as_curve = np.array([[1.0, 0, 0, 0, 0], [0, 1.0, 0, 0, 0], [0, 0, 1.0, 0, 0], [0, 0, 1.0, 1.0, 0],
                         [0, 0, 0, 0, 1.0]])   # (Fo, Fv, Fc, dFs, vs) -> (Fo, Fv, Fc, Fs, vs)
    res = scipy.optimize.least_squares(lambda x: stribeck_curve(as_curve @ x, v) - f, x0, bounds=(lo, hi),
                                       x_scale="jac")
    r = res.fun
    # one sigma of (Fo, Fv, Fc, Fs, vs) and of the excess; inf where these data do not
    # determine it (a Stribeck velocity below every swept speed leaves the excess and vs
    # without a trace in the data)
    sd_all = _sd(res.jac, r, max(v.size - 5, 1), np.vstack([as_curve, [0.0, 0, 0, 1.0, 0]]))
    sd_excess = float(sd_all[5])
    p = as_curve @ res.x
    if not np.isfinite(sd_excess):
        # the data carry no trace of the excess (its curve is 0 at every swept speed): any
        # value fits them equally, and the one reported is none, Fs = Fc
        p[3] = p[2]
    names = ("Fo", "Fv", "Fc", "Fs", "vs")
    out = {"model": "Fo + Fv v + sign(v) (Fc + (Fs - Fc) exp(-(|v|/vs)^2))",
           **{n: float(x) for n, x in zip(names, p)},
           "std": {n: (float(s) if np.isfinite(s) else None) for n, s in zip(names + ("dFs",), sd_all)},
           "rms": float(np.sqrt(np.mean(r ** 2))), "n": int(v.size), "solver": res.message}
    resolved = bool(res.x[3] > sd_excess) if np.isfinite(sd_excess) else False
    out["success"] = bool(res.success and resolved)
    out["stribeck_resolved"] = resolved
    return out
