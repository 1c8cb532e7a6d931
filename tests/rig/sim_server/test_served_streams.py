"""rig sim builds a stream only while it has a subscriber, and a client that subscribes late gets its first sample within two periods."""

from __future__ import annotations

import threading
import time

import pytest

import rclpy
from rclpy.context import Context
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.qos import QoSProfile

from drivers.common import cdr
from drivers.common.ros_session import make_executor
from rig import config
from rig.sim.world import world_from_config
from rig.sim_server.crtk_bridge import STREAMS
from rig.sim_server.ros_node import SimServer

pytestmark = pytest.mark.ros

PERIOD = 0.01  # the dVRK console's default


def _wait(pred, timeout=30.0):  # a guard against a hang, not a figure
    deadline = time.monotonic() + timeout
    while not pred():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.001)


@pytest.fixture
def server(ros_env):
    ctx = Context()
    rclpy.init(context=ctx)
    node = rclpy.create_node("rig_sim", context=ctx)
    world = world_from_config(config.load(), arms=["PSM1", "PSM2"], with_object=False)
    srv = SimServer(world, node, ["PSM1", "PSM2"], ros_period=PERIOD)
    yield srv
    srv.close()
    node.destroy_node()
    rclpy.shutdown(context=ctx)


def test_no_stream_is_built_without_a_subscriber(server, monkeypatch):
    built = []
    for psm in server.psms.values():
        for method in ("measured_js", "setpoint_js", "measured_cp", "setpoint_cp", "measured_cv",
                       "body_measured_cf", "spatial_measured_cf", "jacobian"):
            original = getattr(psm, method)
            monkeypatch.setattr(psm, method, lambda *a, _f=original, _m=method, **k: (built.append(_m), _f(*a, **k))[1])
    stats = server.serve(duration=0.3)
    assert stats["ticks"] == 300
    for bridge in server.bridges.values():
        assert bridge.published == 30  # every period served ...
        assert bridge.sent == dict.fromkeys(STREAMS, 0)  # ... to nobody, and nothing built for it
    assert not [m for m in built if m != "measured_js"]
    # the servo loop reads its arm through the world, not through the published sample
    assert built.count("measured_js") == 0


def test_a_late_subscriber_gets_its_first_sample_within_two_periods(server):
    serving = threading.Thread(target=server.serve, kwargs={"duration": 600.0}, daemon=True)
    serving.start()
    ctx = Context()
    rclpy.init(context=ctx)
    client = rclpy.create_node("late_client", context=ctx)
    ex = make_executor("events", ctx)
    ex.add_node(client)
    stop = threading.Event()
    spinning = threading.Thread(target=lambda: [ex.spin_once(timeout_sec=0.01) for _ in iter(stop.is_set, True)],
                                daemon=True)
    spinning.start()
    checked = []
    try:
        _wait(lambda: server.world.t > 0.5)  # serving for a while, to nobody
        cases = [("measured_js", cdr.joint_state), ("setpoint_cp", cdr.pose_stamped),
                 ("jaw/setpoint_js", cdr.joint_state), ("local/measured_cp", cdr.pose_stamped),
                 ("measured_cp", cdr.pose_stamped)]
        for key, read in cases:
            bridge = server.bridges["PSM1"]
            assert bridge.sent[key] == 0
            matched, first = [], []
            client.create_subscription(
                bridge.pub[key].msg_type, f"/PSM1/{key}", lambda raw, read=read: first.append(read(raw)[0]),
                QoSProfile(depth=10), raw=True,
                event_callbacks=SubscriptionEventCallbacks(matched=lambda info: matched.append(info.current_count)))
            # both sides know of each other: the moment from which a sample can reach the client
            _wait(lambda: matched and bridge.pub[key].get_subscription_count() > 0)
            t_both, epoch, slips = server.world.t, server._stamp_ns(0.0), server.slips
            _wait(lambda: first)
            if server.slips != slips or server._stamp_ns(0.0) != epoch:
                continue  # re-anchored to the wall clock meanwhile: stamps and world time no longer line up
            t_first = (first[0] - epoch) / 1e9
            assert t_first - t_both <= 2 * PERIOD + 1e-6, (key, t_first, t_both)
            checked.append(key)
        assert checked, "rig sim re-anchored during every case"
        # the other arm's streams, nobody's, are still not built
        assert set(server.bridges["PSM2"].sent.values()) == {0}
    finally:
        server.stop.set()
        serving.join(timeout=10)
        stop.set()
        spinning.join(timeout=5)
        ex.shutdown()
        client.destroy_node()
        rclpy.shutdown(context=ctx)


def test_a_pose_in_the_base_frame_is_the_local_one_turned_by_the_base():
    import numpy as np

    from drivers.common.quaternion import matrix_to_quat_xyzw
    from rig.sim_server.crtk_bridge import _quat, _turned

    rng = np.random.default_rng(4)
    for _ in range(200):
        A, B = (np.linalg.qr(rng.normal(size=(3, 3)))[0] for _ in range(2))
        A, B = (R * np.sign(np.linalg.det(R)) for R in (A, B))  # rotations
        Ta, Tb = np.eye(4), np.eye(4)
        Ta[:3, :3], Tb[:3, :3] = A, B
        np.testing.assert_allclose(_turned(_quat(Ta), _quat(Tb)), matrix_to_quat_xyzw(A @ B), atol=1e-12)


def test_every_stream_of_one_period_agrees_with_the_arm_it_describes(server):
    """One period's samples, read with rclpy's own message types: the poses, twists, wrenches
    and Jacobians are those of the joints published with the same stamp."""
    import numpy as np

    from drivers.common.quaternion import quat_xyzw_to_matrix

    psm = server.psms["PSM1"]
    server.states["PSM1"].command("enable", 0.0)
    server.states["PSM1"].command("home", 0.0)
    serving = threading.Thread(target=server.serve, kwargs={"duration": 600.0}, daemon=True)
    serving.start()
    ctx = Context()
    rclpy.init(context=ctx)
    client = rclpy.create_node("every_stream", context=ctx)
    ex = make_executor("events", ctx)
    ex.add_node(client)
    stop = threading.Event()
    spinning = threading.Thread(target=lambda: [ex.spin_once(timeout_sec=0.01) for _ in iter(stop.is_set, True)],
                                daemon=True)
    spinning.start()
    got: dict = {}
    bridge = server.bridges["PSM1"]
    keys = [k for k in STREAMS if not k.endswith("jacobian")]
    try:
        for key in STREAMS:
            client.create_subscription(bridge.pub[key].msg_type, f"/PSM1/{key}",
                                       lambda m, key=key: got.setdefault(key, []).append(m), QoSProfile(depth=100))

        def stamp(m):
            return m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec

        def common():  # a stamp every stamped stream has, and some of every stream
            stamps = [set(map(stamp, got.get(k, []))) for k in keys]
            both = set.intersection(*stamps) if all(stamps) else set()
            return min(both) if both and all(len(got.get(k, [])) > 5 for k in STREAMS) else None

        _wait(lambda: common() is not None)
        s = common()
        m = {k: next(x for x in got[k] if stamp(x) == s) for k in keys}
        jac = {k: [np.array(x.data).reshape(6, 6) for x in got[k]] for k in ("body/jacobian", "spatial/jacobian")}
    finally:
        server.stop.set()
        serving.join(timeout=10)
        stop.set()
        spinning.join(timeout=5)
        ex.shutdown()
        client.destroy_node()
        rclpy.shutdown(context=ctx)
    js = m["measured_js"]
    assert list(js.name) == list(psm.joint_names) and list(m["jaw/measured_js"].name) == ["jaw"]
    q, dq, e = (np.array(v) for v in (js.position, js.velocity, js.effort))
    T_local, Jb, Js = psm.kin.forward_and_jacobians(q)

    def pose(msg):
        p, o = msg.pose.position, msg.pose.orientation
        T = np.eye(4)
        T[:3, :3] = quat_xyzw_to_matrix(np.array([o.x, o.y, o.z, o.w]))
        T[:3, 3] = (p.x, p.y, p.z)
        return T

    np.testing.assert_allclose(pose(m["local/measured_cp"]), T_local, atol=1e-12)
    np.testing.assert_allclose(pose(m["measured_cp"]), psm.base_frame @ T_local, atol=1e-12)
    assert m["measured_cp"].header.frame_id == "PSM1_base"
    sp = m["setpoint_js"]
    T_sp = psm.kin.forward(np.array(sp.position))
    np.testing.assert_allclose(pose(m["local/setpoint_cp"]), T_sp, atol=1e-12)
    np.testing.assert_allclose(pose(m["setpoint_cp"]), psm.base_frame @ T_sp, atol=1e-12)

    def six(v3a, v3b):
        return np.array([v3a.x, v3a.y, v3a.z, v3b.x, v3b.y, v3b.z])

    v_local = six(m["local/measured_cv"].twist.linear, m["local/measured_cv"].twist.angular)
    np.testing.assert_allclose(v_local, Jb @ dq, atol=1e-12)
    R = (psm.base_frame @ T_local)[:3, :3]
    v = six(m["measured_cv"].twist.linear, m["measured_cv"].twist.angular)
    np.testing.assert_allclose(v, np.concatenate([R @ v_local[:3], R @ v_local[3:]]), atol=1e-12)
    wb = six(m["body/measured_cf"].wrench.force, m["body/measured_cf"].wrench.torque)
    np.testing.assert_allclose(wb, np.linalg.pinv(Jb.T) @ e, rtol=1e-9, atol=1e-9)
    ws = six(m["spatial/measured_cf"].wrench.force, m["spatial/measured_cf"].wrench.torque)
    np.testing.assert_allclose(ws, np.linalg.pinv(Js.T) @ e, rtol=1e-9, atol=1e-9)
    # the Jacobians carry no stamp: one of those received is that of these joints
    assert any(np.allclose(J, Jb, rtol=0, atol=1e-12) for J in jac["body/jacobian"])
    assert any(np.allclose(J, Js, rtol=0, atol=1e-12) for J in jac["spatial/jacobian"])
