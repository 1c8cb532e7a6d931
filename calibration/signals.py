"""Signal processing for identification (thesis 5.5): zero-phase low-pass, differentiation, trimming.

The thesis filters velocities and torques forward and backward with an 8th-order Butterworth
at 3.5 Hz (Matlab ``filtfilt``) and differentiates the filtered velocity to get
accelerations. Here the filter is designed in second-order sections (an 8th-order design in
transfer-function form loses precision at low cutoff/rate ratios) and run with
``scipy.signal.sosfiltfilt``. Forward-backward filtering squares the magnitude response
(-6 dB at the cutoff) and has zero phase: no delay between q, dq, ddq and tau.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import scipy.signal

DEFAULT_CUTOFF_HZ = 3.5
DEFAULT_ORDER = 8


class SignalError(ValueError):
    """A signal cannot be processed as asked (too short, bad cutoff, bad rate)."""


def design_lowpass(rate: float, cutoff: float = DEFAULT_CUTOFF_HZ, order: int = DEFAULT_ORDER) -> np.ndarray:
    """Butterworth low-pass in SOS form; ``rate`` and ``cutoff`` in Hz."""
    return _design_lowpass(float(rate), float(cutoff), order).copy()


@lru_cache(maxsize=64)
def _design_lowpass(rate: float, cutoff: float, order) -> np.ndarray:
    # Designed once per (rate, cutoff, order): the discrepancy workflow filters ~1000 column
    # sets a run, and the design (zpk -> sos) cost more than the filtering.
    if not np.isfinite(rate) or rate <= 0:
        raise SignalError(f"sampling rate must be positive, got {rate} Hz")
    nyquist = 0.5 * rate
    if not (0 < cutoff < nyquist):
        raise SignalError(f"cutoff {cutoff} Hz must lie in (0, {nyquist}) Hz, the Nyquist "
                          f"frequency of a {rate} Hz signal")
    if int(order) != order or order < 1:
        raise SignalError(f"filter order must be a positive integer, got {order}")
    return scipy.signal.butter(int(order), cutoff, btype="low", fs=rate, output="sos")


def _padlen(sos: np.ndarray) -> int:
    # sosfiltfilt's default edge padding (scipy documents it as 3 * (2 * n_sections + 1)
    # minus the zeros at the origin); the signal must be longer than this.
    n_sections = sos.shape[0]
    zeros = min(int((sos[:, 2] == 0).sum()), int((sos[:, 5] == 0).sum()))
    return 3 * (2 * n_sections + 1 - zeros)


def lowpass(x: np.ndarray, rate: float, cutoff: float = DEFAULT_CUTOFF_HZ,
            order: int = DEFAULT_ORDER, axis: int = 0) -> np.ndarray:
    """Zero-phase Butterworth low-pass of ``x`` along ``axis`` (samples at ``rate`` Hz)."""
    sos = design_lowpass(rate, cutoff, order)
    x = np.asarray(x, dtype=float)
    n = x.shape[axis]
    # Shorter than the filter's impulse response, the output would be edge transient only.
    need = max(_padlen(sos) + 1, settling_samples(rate, cutoff, order))
    if n < need:
        raise SignalError(f"signal of {n} samples is too short for an order-{order} {cutoff} Hz "
                          f"zero-phase filter at {rate} Hz: it needs at least {need} samples "
                          f"({need / rate:.2f} s)")
    return scipy.signal.sosfiltfilt(sos, x, axis=axis)


def differentiate(x: np.ndarray, rate: float, method: str = "central", axis: int = 0,
                  window: int = 11, polyorder: int = 3) -> np.ndarray:
    """Time derivative of ``x`` (per second) along ``axis``.

    ``method="central"``: second-order central differences (one-sided at the ends), right for
    an already low-passed signal. ``method="central4"``: fourth-order central differences
    (x[k-2] - 8 x[k-1] + 8 x[k+1] - x[k+2]) / 12 dt, second-order ones on the two samples at
    each end; for a raw signal about to be low-passed, whose derivative must keep its gain up
    to the filter's band: sampled at 200 Hz, central differences read 1.6 % low at 10 Hz and
    6.5 % low at 20 Hz, these 0.03 % and 0.5 %. ``method="savgol"``: Savitzky-Golay
    derivative with the given odd ``window`` (samples) and ``polyorder``, which also smooths.
    """
    x = np.asarray(x, dtype=float)
    dt = 1.0 / rate
    if x.shape[axis] < 3:
        raise SignalError(f"cannot differentiate a signal of {x.shape[axis]} samples (need 3)")
    if method == "central":
        return np.gradient(x, dt, axis=axis, edge_order=2)
    if method == "central4":
        d = np.gradient(x, dt, axis=axis, edge_order=2)
        if x.shape[axis] >= 5:
            y, e = np.moveaxis(x, axis, 0), np.moveaxis(d, axis, 0)
            e[2:-2] = (y[:-4] - 8.0 * y[1:-3] + 8.0 * y[3:-1] - y[4:]) / (12.0 * dt)
        return d
    if method == "savgol":
        if window % 2 == 0 or window <= polyorder:
            raise SignalError(f"Savitzky-Golay window must be odd and > polyorder={polyorder}, got {window}")
        if x.shape[axis] < window:
            raise SignalError(f"signal of {x.shape[axis]} samples is shorter than the "
                              f"Savitzky-Golay window of {window}")
        return scipy.signal.savgol_filter(x, window, polyorder, deriv=1, delta=dt, axis=axis)
    raise SignalError(f"unknown differentiation method {method!r} (use 'central', 'central4' or 'savgol')")


def settling_samples(rate: float, cutoff: float = DEFAULT_CUTOFF_HZ, order: int = DEFAULT_ORDER,
                     fraction: float = 1e-2) -> int:
    """Samples after which the filter's impulse response has decayed: the length of the
    end transients of a forward-backward filter, hence how much to trim at each end.

    Defined as the first sample after which the remaining |impulse response| sums to less
    than ``fraction`` of the total.
    """
    return _settling_samples(float(rate), float(cutoff), order, float(fraction))


@lru_cache(maxsize=64)
def _settling_samples(rate: float, cutoff: float, order, fraction: float) -> int:
    sos = _design_lowpass(rate, cutoff, order)
    n = int(max(64, 40 * rate / cutoff))
    imp = np.zeros(n)
    imp[0] = 1.0
    h = np.abs(scipy.signal.sosfilt(sos, imp))
    tail = np.cumsum(h[::-1])[::-1]
    return int(np.argmax(tail < fraction * tail[0]))


def lowpass_stacked(X: np.ndarray, n_joints: int, rate: float, cutoff: float = DEFAULT_CUTOFF_HZ,
                    order: int = DEFAULT_ORDER) -> np.ndarray:
    """:func:`lowpass` of every column of a stacked sample-major matrix (rows nj*k .. nj*k+nj-1
    are sample k, e.g. a regressor W (n*nj, p) or a torque vector), along time and per joint.

    This is *parallel filtering*: the torques are filtered before the fit, so the regressor
    columns get the same filter. For columns that are smooth functions of the (filtered)
    motion it changes nothing below the cut-off; for the sign-like Coulomb columns it turns
    the step at a velocity reversal into the same smeared step the filtered torque shows.
    tau = W pi survives any linear filter applied to both sides, not the filtered tau
    against W of the filtered motion.
    """
    X = np.asarray(X, dtype=float)
    if X.shape[0] % n_joints:
        raise SignalError(f"{X.shape[0]} rows are not a whole number of samples of {n_joints} joints")
    shape = X.shape
    Y = lowpass(X.reshape(shape[0] // n_joints, n_joints, -1), rate, cutoff, order, axis=0)
    return Y.reshape(shape)


@dataclass
class Processed:
    """Filtered q, dq, ddq, tau (n, nj) and the slice of the input samples they cover;
    ``full``: the untrimmed filtered (q, dq, ddq) when asked for (keep_full)."""

    q: np.ndarray
    dq: np.ndarray
    ddq: np.ndarray
    tau: np.ndarray
    kept: slice
    full: tuple | None = None


def process(q, dq, tau, rate: float, cutoff: float = DEFAULT_CUTOFF_HZ, order: int = DEFAULT_ORDER,
            trim: int | None = None, diff_method: str = "central", keep_full: bool = False) -> Processed:
    """Thesis 5.5 pipeline: zero-phase filter q, dq, tau; ddq = d/dt filtered dq; trim ends.

    Positions are filtered too, with the same filter, so that every quantity has the same
    (zero) delay and the same bandwidth. ``trim`` is the number of samples dropped at each
    end; by default the filter's settling length (:func:`settling_samples`).
    """
    q, dq, tau = (np.asarray(x, dtype=float) for x in (q, dq, tau))
    if trim is None:
        trim = settling_samples(rate, cutoff, order)
    n = q.shape[0]
    if n - 2 * trim < 3:
        raise SignalError(f"signal of {n} samples is too short to trim {trim} samples at each end")
    qf = lowpass(q, rate, cutoff, order)
    dqf = lowpass(dq, rate, cutoff, order)
    tauf = lowpass(tau, rate, cutoff, order)
    ddqf = differentiate(dqf, rate, diff_method)
    kept = slice(trim, n - trim)
    return Processed(qf[kept], dqf[kept], ddqf[kept], tauf[kept], kept,
                     (qf, dqf, ddqf) if keep_full else None)
