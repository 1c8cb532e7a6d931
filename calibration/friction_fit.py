"""Friction of one joint from the tests of thesis 5.6: breakaway detection and curve fits.

Forces in N (insertion joint) or N m, velocities in m/s or rad/s.

* :func:`breakaway`: the first sample of a force ramp after which the joint keeps moving
  faster than a threshold for ``sustain`` samples; the applied force there is the
  breakaway (static friction) force of that direction.
* :func:`fit_viscous_coulomb`: linear least squares of f = Fo + Fv v + Fc sign(v).
* :func:`fit_stribeck`: f = Fo + Fv v + sign(v) (Fc + (Fs - Fc) exp(-(|v|/vs)^2)) by
  bounded non-linear least squares (scipy ``least_squares``), started from the
  viscous-Coulomb fit; one-sigma parameter uncertainties from the Jacobian.
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


def fit_stribeck(v, f, fs_guess: float | None = None, vs_bounds=(1e-4, 1.0)) -> dict:
    """Stribeck fit (module docstring); Fc, Fs, Fv >= 0, vs within ``vs_bounds``.

    ``fs_guess`` (e.g. the ramp's breakaway level) starts Fs; else 1.5 Fc of the
    viscous-Coulomb fit. ``success`` is False when the solver failed or the Stribeck
    term is not resolved (its uncertainty exceeds its size): the thesis found exactly
    that on the real joint 3 (5.6).
    """
    v, f = np.asarray(v, float), np.asarray(f, float)
    if v.size < 6:
        raise FrictionFitError("a Stribeck fit needs at least 6 points (5 parameters)")
    vc = fit_viscous_coulomb(v, f)
    fc0 = max(vc["Fc"], 1e-3)
    fs0 = max(fs_guess if fs_guess is not None else 1.5 * fc0, fc0)
    vmin = max(np.min(np.abs(v[v != 0])) if np.any(v != 0) else 1e-3, vs_bounds[0])
    x0 = np.array([vc["Fo"], max(vc["Fv"], 0.0), fc0, fs0, np.clip(2 * vmin, *vs_bounds)])
    lo = np.array([-np.inf, 0.0, 0.0, 0.0, vs_bounds[0]])
    hi = np.array([np.inf, np.inf, np.inf, np.inf, vs_bounds[1]])
    x0 = np.clip(x0, lo + 1e-12, hi - 1e-12)
    res = scipy.optimize.least_squares(lambda p: stribeck_curve(p, v) - f, x0, bounds=(lo, hi), x_scale="jac")
    r = res.fun
    dof = max(v.size - 5, 1)
    try:
        cov = np.linalg.pinv(res.jac.T @ res.jac) * float(r @ r) / dof
        sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    except np.linalg.LinAlgError:
        sd = np.full(5, np.inf)
    names = ("Fo", "Fv", "Fc", "Fs", "vs")
    out = {"model": "Fo + Fv v + sign(v) (Fc + (Fs - Fc) exp(-(|v|/vs)^2))",
           **{n: float(x) for n, x in zip(names, res.x)}, "std": {n: float(s) for n, s in zip(names, sd)},
           "rms": float(np.sqrt(np.mean(r ** 2))), "n": int(v.size), "solver": res.message}
    resolved = bool(abs(res.x[3] - res.x[2]) > sd[3]) if np.isfinite(sd[3]) else False
    out["success"] = bool(res.success and resolved)
    out["stribeck_resolved"] = resolved
    return out
