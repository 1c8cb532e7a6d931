"""Zero-phase filtering, differentiation, trimming, and their errors."""

import numpy as np
import pytest

from calibration.signals import (SignalError, design_lowpass, differentiate, lowpass, process,
                                 settling_samples)

RATE = 200.0


def sine(f, n=6000, phase=0.3):
    t = np.arange(n) / RATE
    w = 2 * np.pi * f
    return t, np.sin(w * t + phase), w * np.cos(w * t + phase), -w * w * np.sin(w * t + phase)


def test_zero_phase_no_delay():
    t, x, _, _ = sine(0.5)
    y = lowpass(x, RATE)
    k = settling_samples(RATE)
    # Delay from the phase of the fitted sinusoid: zero-phase means < 1 microsecond.
    w = 2 * np.pi * 0.5
    A = np.column_stack([np.sin(w * t), np.cos(w * t)])[k:-k]
    cx = np.linalg.lstsq(A, x[k:-k], rcond=None)[0]
    cy = np.linalg.lstsq(A, y[k:-k], rcond=None)[0]
    delay = (np.arctan2(cx[1], cx[0]) - np.arctan2(cy[1], cy[0])) / w
    assert abs(delay) < 1e-6
    # A one-pass filter of the same order would lag by tens of milliseconds.
    import scipy.signal
    y1 = scipy.signal.sosfilt(design_lowpass(RATE), x)
    c1 = np.linalg.lstsq(A, y1[k:-k], rcond=None)[0]
    assert (np.arctan2(cx[1], cx[0]) - np.arctan2(c1[1], c1[0])) / w > 0.05


def test_passband_and_stopband():
    _, x, _, _ = sine(0.5)
    _, noise, _, _ = sine(20.0)
    k = settling_samples(RATE)
    y = lowpass(x + 0.5 * noise, RATE)
    assert np.abs(y - x)[k:-k].max() < 2e-3


@pytest.mark.parametrize("method", ["central", "central4", "savgol"])
def test_derivative_of_sine(method):
    _, x, dx, _ = sine(0.65)
    d = differentiate(x, RATE, method)
    assert np.abs(d - dx)[10:-10].max() < 1e-3 * np.abs(dx).max()


@pytest.mark.parametrize("f, central, central4", [(10.0, 0.0164, 0.0003), (20.0, 0.0645, 0.0050)])
def test_derivative_gain_in_the_band(f, central, central4):
    # The relative shortfall of each stencil's gain on a sine at f Hz, sampled at 200 Hz:
    # 1 - sin(x) / x and 1 - (8 sin(x) - sin(2 x)) / 6 x, x = 2 pi f / 200.
    t = np.arange(2000) / 200.0
    x = np.sin(2 * np.pi * f * t)
    for method, shortfall in (("central", central), ("central4", central4)):
        d = differentiate(x, 200.0, method)[10:-10]
        gain = np.sqrt(2.0 * np.mean(d ** 2)) / (2 * np.pi * f)
        assert abs((1.0 - gain) - shortfall) < 2e-4, (method, gain)


def test_central4_on_2d_along_an_axis():
    _, x, dx, _ = sine(0.65)
    X = np.stack([x, 2 * x])                    # (2, n): time on axis 1
    d = differentiate(X, RATE, "central4", axis=1)
    np.testing.assert_allclose(d[1], 2 * d[0])
    assert np.abs(d[0] - dx)[10:-10].max() < 1e-3 * np.abs(dx).max()


def test_process_gives_accelerations_and_trims():
    t, q, dq, ddq = sine(0.4)
    tau = 2.0 * ddq + 0.5
    noisy = dq + 0.05 * np.random.default_rng(0).normal(size=dq.shape)
    p = process(q[:, None], noisy[:, None], tau[:, None], RATE)
    k = settling_samples(RATE)
    assert p.kept == slice(k, 6000 - k)
    assert p.q.shape == (6000 - 2 * k, 1)
    ref = ddq[p.kept]
    assert np.sqrt(np.mean((p.ddq[:, 0] - ref) ** 2)) < 0.02 * np.abs(ref).max()
    np.testing.assert_allclose(p.tau[:, 0], tau[p.kept], atol=1e-3 * np.abs(tau).max())


def test_errors():
    with pytest.raises(SignalError, match="Nyquist"):
        lowpass(np.zeros(1000), RATE, cutoff=150.0)
    with pytest.raises(SignalError, match="too short.*order-8"):
        lowpass(np.zeros(200), RATE)
    with pytest.raises(SignalError, match="rate"):
        design_lowpass(0.0)
    with pytest.raises(SignalError, match="order"):
        design_lowpass(RATE, order=0)
    with pytest.raises(SignalError, match="method"):
        differentiate(np.zeros(10), RATE, "spline")
    with pytest.raises(SignalError, match="trim"):
        process(np.zeros((100, 1)), np.zeros((100, 1)), np.zeros((100, 1)), RATE, trim=60)


def test_settling_grows_with_order_and_rate():
    assert settling_samples(RATE, order=4) < settling_samples(RATE, order=8)
    assert settling_samples(1000.0) > settling_samples(RATE)


def _friction_data(n=4000, seed=0):
    """One joint reversing at 0.3 Hz with Coulomb + viscous friction (exact, noise-free)."""
    from calibration.datasets import JointData

    t = np.arange(n) / RATE
    q = 0.2 * np.sin(2 * np.pi * 0.3 * t)
    dq = 0.2 * 2 * np.pi * 0.3 * np.cos(2 * np.pi * 0.3 * t)
    tau = 0.5 * np.sign(dq) + 0.8 * dq
    return JointData.from_arrays(q[:, None], dq[:, None], tau[:, None], rate=RATE), (0.5, 0.8)


def test_parallel_filtering_matches_the_filtered_friction_step():
    """The filtered torque's friction step is smeared: the model of the filtered motion misses
    it at every reversal; the same model low-passed like the torques (parallel filtering,
    over the untrimmed samples) reproduces it."""
    from calibration.datasets import processed

    data, (fc, fv) = _friction_data()
    p = processed(data)

    def friction(q, dq, ddq):
        return (fc * np.sign(dq) + fv * dq).reshape(-1, 1)

    plain = friction(p.q, p.dq, p.ddq)[:, 0]
    parallel = p.context.rows(friction, p.n_samples)[:, 0]
    tau = p.tau[:, 0]
    e_plain = np.linalg.norm(tau - plain) / np.linalg.norm(tau)
    e_parallel = np.linalg.norm(tau - parallel) / np.linalg.norm(tau)
    assert e_plain > 0.05
    assert e_parallel < 0.1 * e_plain


def test_filter_context_follows_row_blocks():
    """A block cut from processed data keeps its place in the untrimmed motion: its parallel-
    filtered rows are the whole record's rows at that place (no new end transients)."""
    from calibration.datasets import processed, split_blocks
    from calibration.signals import lowpass_stacked

    data, _ = _friction_data()
    p = processed(data)

    def fn(q, dq, ddq):
        return np.column_stack([np.sign(dq).reshape(-1), dq.reshape(-1)])

    whole = p.context.rows(fn, p.n_samples)
    train, held = split_blocks(p, 0.25)
    inner = train.rows(slice(30, train.n_samples - 30))
    assert np.array_equal(held.context.rows(fn, held.n_samples), whole[-held.n_samples:])
    assert np.array_equal(inner.context.rows(fn, inner.n_samples), whole[30:train.n_samples - 30])
    with pytest.raises(ValueError, match="contiguous"):
        p.rows(slice(0, 100, 2))
    with pytest.raises(SignalError, match="whole number of samples"):
        lowpass_stacked(np.zeros((7, 2)), 3, RATE)
