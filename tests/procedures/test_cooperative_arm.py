"""The cooperative loop with the slaves' impedance in the arm (servo_ci): the goal it sends
(rig.control.arm_impedance) against the dVRK's semantics, and the loop over a wire emulated in
sim time (tests/procedures/wire_emulation.py) against the simulated object's tension."""

from __future__ import annotations

import numpy as np
import pytest

from rig.control.arm_impedance import cartesian_inertia, force_frame, servo_ci_goal
from rig.model import psm_kinematics as K
from rig.model.psm_arm_kinematics import PSMKinematics


@pytest.mark.parametrize("u", [(1.0, 0.0, 0.0), (0.0, 0.0, 1.0), (0.3, -0.5, 0.81)])
def test_force_frame_is_right_handed_with_x_along_u(u):
    R = force_frame(np.array(u))
    assert np.allclose(R.T @ R, np.eye(3), atol=1e-12) and np.isclose(np.linalg.det(R), 1.0)
    assert np.allclose(R[:, 0], np.array(u) / np.linalg.norm(u))


def test_feedforward_reaches_joints_1_to_3_and_nothing_reaches_the_wrist():
    """The dVRK applies the servo_ci wrench through the body Jacobian (J_b^T w): with no
    spring or damper the bias alone must give the feedforward torques on joints 1-3 and
    zero on the wrist (drivers.arm.fake_psm.Impedance is rig sim's run of the same message)."""
    from crtk_msgs.msg import CartesianImpedance

    from drivers.arm.dvrk_arm import impedance_message
    from rig.sim_server.crtk_bridge import impedance_from_msg

    kin = PSMKinematics()
    q6 = np.array([0.2, -0.15, 0.13, 0.4, -0.3, 0.25])
    tau = np.array([0.3, 1.8, -1.6])
    shaft = K.tip_in_rcm(q6[:3])
    g = servo_ci_goal(kin, q6, shaft, np.zeros(3), np.array([0.0, 1.0, 0.0]), np.zeros(3), np.zeros(3), tau)
    m = impedance_message(CartesianImpedance(), g.position, g.orientation, g.stiffness, g.damping, g.bias,
                          torque_stiffness=g.torque_stiffness * 0, torque_damping=g.torque_damping * 0,
                          force_orientation=g.force_orientation, torque_bias=g.torque_bias)
    T, Jb, _ = kin.forward_and_jacobians(q6)
    w = impedance_from_msg(m).wrench(T, np.zeros(3), np.zeros(3))
    R = T[:3, :3]
    applied = Jb.T @ np.concatenate([R.T @ w[:3], R.T @ w[3:]])
    assert np.allclose(applied[:3], tau, atol=1e-9), applied
    assert np.allclose(applied[3:], 0.0, atol=1e-9), applied


def test_goal_moves_the_tool_tip_by_the_shaft_end_error():
    kin = PSMKinematics()
    q6 = np.array([0.1, 0.05, 0.12, 0.0, 0.3, -0.2])
    target = K.tip_in_rcm(q6[:3]) + np.array([0.002, -0.001, 0.003])
    g = servo_ci_goal(kin, q6, target, np.zeros(3), np.array([1.0, 0.0, 0.0]), np.ones(3), np.ones(3), np.zeros(3))
    assert np.allclose(g.position - kin.forward(q6)[:3, 3], [0.002, -0.001, 0.003], atol=1e-12)


def test_cartesian_inertia_is_the_mass_a_force_accelerates():
    from rig.model.psm_dynamics import PSMDynamics

    q = np.array([0.1, -0.2, 0.14])
    M = PSMDynamics().mass_matrix(q)
    J = K.tip_jacobian_rcm(q)
    a = np.array([0.0, 0.6, 0.8])
    lam = cartesian_inertia(M, J, a)
    # a force f a on the tip accelerates it along a by f / lam
    acc = J @ np.linalg.solve(M, J.T @ a)
    assert np.isclose(a @ acc, 1.0 / lam)


def test_arm_control_needs_ros_arms():
    """--slave-control arm on the in-process simulated rig is refused before anything moves."""
    from click.testing import CliRunner

    from rig.cli import main

    out = CliRunner().invoke(main, ["cooperative", "--slave-control", "arm", "--duration", "0.5"])
    assert out.exit_code != 0 and "needs ROS arms" in out.output, out.output
    assert "Traceback" not in out.output


@pytest.mark.parametrize("kind,period,ceiling", [("spring", 0.01, 0.25), ("string", 0.01, 0.5)])
def test_the_tension_holds_over_an_emulated_wire(kind, period, ceiling):
    """The loop at the rate the arms publish, the state a period old when it acts, holds 5 N
    during a 3 cm move (the simulated object's tension): the spring at the dVRK's default
    100 Hz within issue 35's 0.25 N; the string, taken up from slack by force, at 100 Hz
    (the loop's most, procedures.cooperative.ARM_LOOP_MAX_RATE) within the thesis' 0.5 N
    (0.35 N here, short of 0.25: bench/bench_cooperative_arm.py)."""
    from tests.procedures.wire_emulation import emulate

    r = emulate(kind, period, settle=2.0)
    assert r["max_error_during_motion"] <= ceiling, r
    assert r["overshoot"] <= 0.5, r
    assert abs(r["final"] - 5.0) < 0.25, r


def test_a_loop_slower_than_asked_holds_on_its_samples_times():
    """Over the wire a loop asked for 200 Hz ran at 120-160 Hz. Given the samples' times,
    the controller steps its filters and integrators by them; taken as 5 ms apart, samples
    6.4 ms apart read rates 28 % too fast (0.36 N while moving here instead of 0.14 N)."""
    from tests.procedures.wire_emulation import emulate

    r = emulate("spring", period=0.002, loop_rate=156.0, controller_rate=200.0)
    assert r["max_error_during_motion"] <= 0.25, r
    assert r["overshoot"] <= 0.5, r


def test_old_master_samples_do_not_drag_the_slaves():
    """A master sample 50 ms old (rig sim behind the clock on a loaded machine) is compared
    with the plan of its own time: against the plan of now, the slaves trailed the master
    by its speed times the age (0.45 N while moving here instead of 0.21 N)."""
    from tests.procedures.wire_emulation import emulate

    r = emulate("spring", period=0.002, delay=25.0, loop_rate=100.0)
    assert r["max_error_during_motion"] <= 0.25, r


def test_gaps_in_the_arms_stream_are_ridden_through():
    """Gaps of 140 ms twice a second in the arms' state while the load cell streams on (as
    rig sim's stream came in bursts on a loaded machine): the loop acts on the fresh
    tension and the last state it has (holding the force loop through them instead was
    worse here, 0.25 N against 0.18 N)."""
    from tests.procedures.wire_emulation import emulate

    r = emulate("spring", period=0.002, loop_rate=100.0, gap_every=0.5, gap=0.14)
    assert r["max_error_during_motion"] <= 0.25, r


def test_the_consoles_each_object_needs():
    """The spring runs from the dVRK's default 100 Hz streams; the string and the triangle
    aborted on the tension ceiling at 100 Hz over the wire and need 500 Hz (`-p 0.002`)."""
    from procedures.cooperative import arm_loop_min_rate

    assert arm_loop_min_rate("spring", 2) == 100.0
    assert arm_loop_min_rate("string", 2) == 500.0
    assert arm_loop_min_rate("spring", 3) == 500.0
