"""A fitted model's predictions and its validation figures (thesis 5.5): per-joint relative
error and RMS, over all samples and over the moving ones. Units: N m, N."""

from __future__ import annotations

import numpy as np

from calibration.identification import FitOutcome, equation_rows, moving_mask


def predict(outcome: FitOutcome, data, method: str, parallel: bool | None = None) -> np.ndarray:
    """Predicted efforts (n, 3) on processed ``data``; ``parallel`` (default: as fitted)
    low-passes them like the measured torques (the like-for-like comparison); without it they
    are the model's efforts for the filtered motion (what a controller would compute)."""
    par = outcome.parallel if parallel is None else parallel
    W = equation_rows(data, par)(outcome.model.regressor_batch)
    return outcome.fits[method].predict(outcome.base.regressor(W), 3, outcome.extra_rows(data, par))


def _relative_moving(tau, pred, mask) -> list[float]:
    return [float(np.linalg.norm((tau - pred)[mask[:, j], j]) / np.linalg.norm(tau[mask[:, j], j]))
            if mask[:, j].any() else float("nan") for j in range(3)]


def validation_table(outcome: FitOutcome, data) -> dict:
    """Per method on processed ``data`` (the measured torques are the filtered ones):

    * ``relative_error``, ``rms``: all samples, predictions filtered like the torques when
      the fit used parallel filtering (:func:`predict`);
    * ``moving_relative_error``: the same on the joint samples faster than DEADBAND (a stuck
      joint's effort is anywhere inside its static friction band: no model of the motion
      gives it) -- the figure held against the issue's 5 % target;
    * ``moving_relative_error_unfiltered``: the model's efforts for the filtered motion, not
      low-passed, on the moving samples (the definition before parallel filtering; it also
      counts the filter's smearing of the friction steps as model error).
    """
    from calibration.estimators import validation_errors

    out = {}
    mask = moving_mask(data.dq)
    Wp = outcome.base.regressor(equation_rows(data, outcome.parallel)(outcome.model.regressor_batch))
    Wu = outcome.base.regressor(equation_rows(data, False)(outcome.model.regressor_batch))
    Xp, Xu = outcome.extra_rows(data), outcome.extra_rows(data, False)
    for m in ("ols", "wls", "sdp"):
        pred = outcome.fits[m].predict(Wp, 3, Xp)
        e = validation_errors(data.tau, pred)
        out[m] = {"relative_error": e["relative_error"].tolist(), "rms": e["rms"].tolist(),
                  "moving_relative_error": _relative_moving(data.tau, pred, mask),
                  "moving_relative_error_unfiltered": _relative_moving(data.tau, outcome.fits[m].predict(Wu, 3, Xu),
                                                                       mask)}
    return out


