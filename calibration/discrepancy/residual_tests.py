"""Tests of a residual: Ljung-Box whiteness, held-out and binned R^2."""

from __future__ import annotations

import numpy as np

LJUNG_BOX_LAGS = 10


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
