"""rig sim builds a stream only while it has a subscriber, and a client that subscribes late gets its first sample within two periods."""

from __future__ import annotations

import threading
import time

import pytest

rclpy = pytest.importorskip("rclpy")
from rclpy.context import Context  # noqa: E402
from rclpy.event_handler import SubscriptionEventCallbacks  # noqa: E402
from rclpy.qos import QoSProfile  # noqa: E402

from drivers import cdr  # noqa: E402
from drivers.ros_session import make_executor  # noqa: E402
from rig import config  # noqa: E402
from rig.sim.world import world_from_config  # noqa: E402
from rig.sim_server.crtk_bridge import STREAMS  # noqa: E402
from rig.sim_server.ros_node import SimServer  # noqa: E402

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
