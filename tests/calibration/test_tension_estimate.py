"""The object's tension from both arms' joints and efforts (issue 47), against the simulated
spring's own tension."""

import numpy as np
import pytest

from calibration.momentum_observer import DEFAULT_GAIN
from calibration.tension_estimate import TensionSource, tension_figures, tension_source
from rig.model import psm_kinematics as K
from rig.model.psm_dynamics import PSMDynamics
from tests.force_truth import facing, motion, world


class _JS:
    def __init__(self, position, velocity, effort, t):
        self.position, self.velocity, self.effort, self.t = position, velocity, effort, t


def _frames():
    return {"PSM1": np.eye(4) @ K.RCM_FRAME, "PSM2": facing(1.0728) @ K.RCM_FRAME}


def test_both_arms_give_the_springs_tension_while_one_moves():
    w = world(stretch=0.002)
    src = tension_source(PSMDynamics(), [], None, _frames(), ["PSM1", "PSM2"], [("PSM1", "PSM2")])
    est, true, t = [], [], []
    for k in range(int(3.0 / w.dt)):
        if k * w.dt >= 0.5:
            w.servo_jp("PSM1", *motion(k * w.dt - 0.5))
        w.step()
        if k % 2:
            continue
        js = {n: _JS(*w.measured_js(n), w.t) for n in ("PSM1", "PSM2")}
        est.append(src.update(js, 0.002)[0])
        true.append(w.tension(0))
        t.append(w.t)
    est, true, t = np.array(est), np.array(true), np.array(t)
    moving = t > 1.0
    assert np.ptp(true[moving]) > 10.0        # the spring swings through 20 N
    # against the truth through the observers' own first-order filter (5 Hz)
    seen = np.empty_like(true)
    seen[0] = true[0]
    a = 1.0 - np.exp(-DEFAULT_GAIN * 0.002)
    for k in range(1, len(true)):
        seen[k] = seen[k - 1] + a * (true[k] - seen[k - 1])
    # (PSM2 holds still: its joints stick, within the static friction its model cannot know)
    assert np.sqrt(np.mean((est[moving] - seen[moving]) ** 2)) < 0.3
    # the tips come from the registration's frames: both arms' tips where the world has them
    np.testing.assert_allclose(src.tip_world("PSM2", w.measured_js("PSM2")[0]), w.tip_world("PSM2"), atol=1e-4)
    assert np.isfinite(src.spread).all() and src.spread[0] > 0


def test_a_sample_seen_twice_is_not_fed_twice_and_elements_need_both_arms():
    src = tension_source(PSMDynamics(), [], None, _frames(), ["PSM1", "PSM2"], [("PSM1", "PSM2")])
    q = np.array([0.0, 0.0, 0.12])
    js = {n: _JS(q, np.zeros(3), np.zeros(3), 1.0) for n in ("PSM1", "PSM2")}
    a = src.update(js, 0.001)
    b = src.update(js, 0.001)
    np.testing.assert_array_equal(a, b)
    # at rest every joint sticks: the spread is the static friction's, over a newton here
    assert src.spread[0] > 0.5 and src.flags["PSM1"]["joint3_static"]
    with pytest.raises(ValueError, match="PSM3"):
        TensionSource({"PSM1": None, "PSM2": None}, _frames(), [("PSM1", "PSM3")])


def test_figures_compare_the_estimate_with_the_cell_in_the_window():
    t = np.linspace(0.0, 10.0, 1001)
    cell = np.full((len(t), 1), 5.0)
    est = cell + 0.1
    est[t > 8.0] += 2.0               # outside the window: not counted
    f = tension_figures(t, est, cell, 2.0, 7.0)
    assert f["rms_difference"] == pytest.approx(0.1) and f["max_difference"] == pytest.approx(0.1)
    assert f["bias"] == pytest.approx(0.1) and f["ticks"] == 501
    assert tension_figures(t, est, cell, 20.0, 30.0) is None
