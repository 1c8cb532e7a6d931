import numpy as np
import pytest

from rig.model import psm_tool
from rig.model.wrist_plant import ENCODER_RESOLUTION, WristPlant

H = 0.001
TOOLS = [psm_tool.DEFAULT_TOOL, psm_tool.tool("PROGRASP_FORCEPS_400093"),
         psm_tool.tool("MEGA_NEEDLE_DRIVER_400194")]


def _run(w, seconds, h=H, record=False):
    out = []
    for _ in range(int(round(seconds / h))):
        w.step(h)
        if record:
            out.append(w.measured())
    return out


def _joint_stiffness(w):
    Ci = np.linalg.inv(w.coupling)
    return Ci.T @ np.diag(psm_tool.WRIST_PID_P_GAIN) @ Ci


@pytest.mark.parametrize("tool", TOOLS, ids=lambda t: t.name)
def test_step_response_settles_within_the_friction_dead_band(tool):
    w = WristPlant(tool, rng=np.random.default_rng(1))
    w.hold()
    _run(w, 0.01)
    target = np.array([0.3, -0.3, 0.3, 0.5])
    w.servo_jp(target)
    trace = _run(w, 0.25, record=True)
    q = np.array([m[0] for m in trace])
    # equilibrium with Coulomb friction: K e = f with |f_i| <= Fc_i
    band = np.abs(np.linalg.inv(_joint_stiffness(w))) @ w.coulomb + 3 * ENCODER_RESOLUTION * 1.6
    err = np.abs(q[-1] - target)
    assert np.all(err <= band), (err, band)
    # within 2 % of the 0.3 rad step after 0.15 s (measured 0.06-0.125 s), and no overshoot
    assert np.all(np.abs(q[150:] - target) <= np.maximum(0.006, band))
    assert np.all(np.sign(target) * (q - target) <= band)
    assert not w.tracking_error().any()
    assert w.modes == ("position",) * 4


def test_velocity_set_point_removes_the_lag_of_a_ramp():
    v = np.array([1.0, 0.5, -0.5, 0.8])
    lags = []
    for with_velocity in (False, True):
        w = WristPlant(noise=0.0)
        w.hold()
        for k in range(300):
            w.servo_jp(v * k * H, v if with_velocity else None)
            w.step(H)
        lags.append(np.abs(w.measured()[0] - v * 0.299))
    assert np.all(lags[1] < 0.6 * lags[0])
    # what is left is the friction: Coulomb's dead band plus viscous drag over the stiffness
    K_inv = np.linalg.inv(_joint_stiffness(w))
    left = np.abs(K_inv) @ w.coulomb + np.abs(K_inv @ (w.viscous * v)) + 2 * ENCODER_RESOLUTION
    assert np.all(lags[1] <= left), (lags[1], left)


@pytest.mark.parametrize("tool", psm_tool.TOOLS, ids=lambda t: t.name)
def test_effort_saturation_holds(tool):
    w = WristPlant(tool, noise=0.0)
    C = w.coupling
    for sign in (1.0, -1.0):
        w.set_state(np.zeros(4))
        w.servo_jf(sign * 10.0 * np.array([1.0, -1.0, 1.0, 1.0]))
        for _ in range(300):
            w.step(H)
            tau = w.measured()[2]
            assert np.all(np.abs(tau) <= tool.effort4_max + 1e-12)
            assert np.all(np.abs(C.T @ tau) <= psm_tool.DISK_MAX_TORQUE + 1e-12)
    # the roll is bounded by its disc, not by its 0.33 N m rating
    w.set_state(np.zeros(4))
    w.servo_jf([1.0, 0.0, 0.0, 0.0])
    w.step(H)
    assert abs(w.measured()[2][0]) == pytest.approx(psm_tool.DISK_MAX_TORQUE / abs(C[0, 0]))


def test_position_mode_saturates_too():
    w = WristPlant(noise=0.0)
    w.set_state([-3.0, -1.2, 1.2, 0.2])
    w.hold()
    w.servo_jp([4.0, 1.2, -1.2, 1.2])
    for _ in range(50):
        w.step(H)
        tau = w.measured()[2]
        assert np.all(np.abs(tau) <= w.effort_max + 1e-12)


@pytest.mark.parametrize("tool", psm_tool.TOOLS, ids=lambda t: t.name)
def test_full_effort_never_passes_a_stop_by_more_than_a_few_mrad(tool):
    for sign in (1.0, -1.0):
        w = WristPlant(tool, noise=0.0)
        start = np.where(sign > 0, w.q_max - 0.05, w.q_min + 0.05)
        start[3] = tool.jaw_max - 0.05 if sign > 0 else 0.05
        w.set_state(start)
        w.servo_jf(sign * w.effort_max)
        worst = 0.0
        for _ in range(500):
            w.step(H)
            q = w.state[0]
            worst = max(worst, np.max(q - w.stop_max), np.max(w.stop_min - q))
        # arriving at speed (0.1 rad run-up at full effort): a few mrad (measured 0.75-3.7)
        assert 0.0 < worst < 0.005
        # resting on the stops: the effort over the stiffness (1.25 mrad at most)
        q, dq = w.state
        press = np.maximum(q - w.stop_max, w.stop_min - q)
        tau = np.abs(w.measured()[2])
        assert np.allclose(press, tau / w.params.stop_stiffness, atol=2e-4)
        assert np.all(np.abs(dq) < 1e-6)


def test_jaw_closes_on_itself_and_squeezes_at_the_negative_limit():
    tool = psm_tool.DEFAULT_TOOL
    w = WristPlant(tool, noise=0.0)
    w.set_state([0.0, 0.0, 0.0, 0.5])
    w.hold()
    w.servo_jp([0.0, 0.0, 0.0, tool.jaw_min])      # -40 deg: close hard
    _run(w, 0.5)
    q, dq, tau = w.measured()
    assert -0.002 < w.state[0][3] < 0.0               # the blades meet at 0
    assert tau[3] == pytest.approx(-tool.jaw_effort_max)  # grip at the jaw's ftmax
    assert w.setpoint()[0][3] == pytest.approx(tool.jaw_min)


def test_off_with_friction_stays_put():
    w = WristPlant(rng=np.random.default_rng(2))
    q0 = np.array([0.4, -0.2, 0.3, 0.6])
    w.set_state(q0)
    w.off()
    _run(w, 1.0)
    assert np.array_equal(w.state[0], q0)
    assert np.array_equal(w.state[1], np.zeros(4))
    # an outside effort below the Coulomb friction does not move it either; above, it does
    w.set_external_effort(0.9 * w.coulomb)
    _run(w, 0.5)
    assert np.array_equal(w.state[0], q0)
    w.set_external_effort(1.5 * w.coulomb)
    _run(w, 0.05)
    assert np.all(w.state[0] > q0)


def test_energy_decreases_when_unpowered():
    w = WristPlant(noise=0.0)
    w.set_state([0.0, 0.1, -0.1, 0.7], [3.0, -2.0, 2.5, -1.5])
    w.off()
    e = [w.energy()]
    for _ in range(2000):
        w.step(H)
        e.append(w.energy())
    e = np.array(e)
    assert e[0] > 0.0
    assert np.all(np.diff(e) <= 1e-15)
    assert e[-1] == 0.0   # Coulomb friction stops it in finite time


def test_energy_decreases_when_unpowered_against_a_stop():
    w = WristPlant(noise=0.0)
    w.set_state([w.q_max[0] + 0.04, 0.0, 0.0, 0.3], [8.0, 0.0, 0.0, -6.0])
    w.off()
    e = [w.energy()]
    for _ in range(1000):
        w.step(H)
        e.append(w.energy())
    assert np.all(np.diff(e) <= 1e-12)
    assert w.state[0][0] <= w.stop_max[0] + 0.003


def test_no_nan_under_random_commands():
    rng = np.random.default_rng(3)
    w = WristPlant(psm_tool.tool("MARYLAND_BIPOLAR_FORCEPS_400172"), rng=rng)
    for k in range(3000):
        if k % 50 == 0:
            choice = rng.integers(4)
            if choice == 0:
                w.servo_jp(rng.uniform(-6, 6, 4), rng.uniform(-20, 20, 4), rng.uniform(-1, 1, 4))
            elif choice == 1:
                w.servo_jf(rng.uniform(-5, 5, 4))
            elif choice == 2:
                w.off(list(rng.choice(4, size=2, replace=False)))
            else:
                w.hold([int(rng.integers(4))])
            w.set_external_effort(rng.normal(0, 0.3, 4))
        w.step(float(rng.choice([0.001, 0.0005, 0.0025])))
        for x in w.measured() + w.setpoint():
            assert np.all(np.isfinite(x))
    assert np.all(np.isfinite(w.state[0]))


def test_coupling_shows_in_encoders_and_cross_efforts():
    tool = psm_tool.DEFAULT_TOOL
    C = tool.coupling_matrix
    w = WristPlant(tool, noise=0.0)
    # a roll of a little less than one count reads as 0; a count reads as 1.5632 counts' worth
    w.set_state([0.4 * ENCODER_RESOLUTION * abs(C[0, 0]), 0.0, 0.0, 0.0])
    assert w.measured()[0][0] == 0.0
    w.set_state([1.01 * ENCODER_RESOLUTION * abs(C[0, 0]), 0.0, 0.0, 0.0])
    assert w.measured()[0][0] == pytest.approx(ENCODER_RESOLUTION * abs(C[0, 0]))
    # measured positions are always C times whole disc counts
    w.set_state([0.123, -0.456, 0.321, 0.2])
    counts = np.linalg.solve(C, w.measured()[0]) / ENCODER_RESOLUTION
    assert np.allclose(counts, np.round(counts), atol=1e-9)
    # a wrist-pitch error alone makes the disc PID push on wrist yaw as well
    w.set_state(np.zeros(4))
    w.hold()
    w.servo_jp([0.0, 0.01, 0.0, 0.0])
    w.step(H)
    tau = w.setpoint()[2]
    K = _joint_stiffness(w)
    assert tau[1] == pytest.approx(K[1, 1] * 0.01, rel=1e-6)
    assert tau[2] == pytest.approx(K[2, 1] * 0.01, rel=1e-6)
    assert abs(tau[2]) > 0.3 * abs(tau[1])
    assert tau[0] == 0.0


def test_measured_effort_noise_is_per_disc():
    w = WristPlant(rng=np.random.default_rng(4), noise=1.0)
    w.set_state([0.1, 0.1, 0.1, 0.3])
    w.servo_jf([0.05, 0.05, -0.05, 0.05])
    samples = np.array([m[2] for m in _run(w, 4.0, record=True)]) - np.array([0.05, 0.05, -0.05, 0.05])
    Ci = np.linalg.inv(w.coupling)
    expected = w.params.effort_noise * np.sqrt(np.sum(Ci.T ** 2, axis=1))
    assert np.allclose(samples.std(axis=0), expected, rtol=0.1)
    assert np.all(np.abs(samples.mean(axis=0)) < 3 * expected / np.sqrt(len(samples)) + 1e-6)


def test_mixed_modes_and_setpoints():
    w = WristPlant(noise=0.0)
    w.set_state([0.2, 0.1, -0.1, 0.4])
    w.hold()
    w.servo_jf([0.01, np.nan, np.nan, np.nan])       # roll in effort, the rest held
    assert w.modes == ("effort", "position", "position", "position")
    _run(w, 0.2)
    q_sp, dq_sp, tau = w.setpoint()
    assert tau[0] == pytest.approx(0.01)
    assert w.state[0][0] > 0.2                        # pushed past its friction
    assert np.allclose(w.state[0][1:], [0.1, -0.1, 0.4], atol=0.003)
    assert q_sp[0] == w.measured()[0][0]              # mtsPID: the measurement for others
    w.off([3])
    assert w.modes[3] == "off"
    w.servo_jp([np.nan, np.nan, np.nan, 2.0])          # clipped to the jaw's limit
    assert w.setpoint()[0][3] == pytest.approx(psm_tool.DEFAULT_TOOL.jaw_max)


def test_long_steps_are_cut_into_ticks():
    a = WristPlant(noise=0.0)
    b = WristPlant(noise=0.0)
    for w in (a, b):
        w.hold()
        w.servo_jp([0.2, 0.2, 0.2, 0.2])
    _run(a, 0.3, h=0.003)
    _run(b, 0.3, h=0.001)
    assert a.t == pytest.approx(0.3) and b.t == pytest.approx(0.3)
    assert np.allclose(a.state[0], b.state[0], atol=0.003)


def test_tracking_error_reports_a_disc_far_from_its_set_point():
    w = WristPlant(noise=0.0)
    w.hold()
    w.set_state([1.2, 0.0, 0.0, 0.0])                 # the roll knocked 1.2 rad away
    w.step(H)
    flags = w.tracking_error()
    assert flags[0] and not flags[1:].any()
