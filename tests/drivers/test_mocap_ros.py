"""RosMocapTracker against a real rclpy publisher in the same process.

Each test gets a ROS_DOMAIN_ID of its own (tests/conftest.py's ros_env: claimed across
xdist workers and pytest runs, set before rclpy.init, discovery on localhost only) and its
own rclpy Context, shut down at the end.
"""

from __future__ import annotations

import re
import threading
import time

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from drivers.interfaces import Tracker

import rclpy  # noqa: E402  (a declared dependency: a broken install fails here)
from geometry_msgs.msg import PoseStamped  # noqa: E402
from rclpy.context import Context  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402

from drivers.mocap.ros_tracker import MocapStaleError, RosMocapTracker  # noqa: E402

pytestmark = pytest.mark.ros


@pytest.fixture
def ros(ros_env):
    ctx = Context()
    rclpy.init(context=ctx)
    pub_node = rclpy.create_node("fake_mocap_bridge", context=ctx)
    sub_node = rclpy.create_node("rig_mocap", context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(pub_node)
    ex.add_node(sub_node)
    th = threading.Thread(target=ex.spin, daemon=True)
    th.start()
    yield pub_node, sub_node
    ex.shutdown()
    pub_node.destroy_node()
    sub_node.destroy_node()
    rclpy.shutdown(context=ctx)
    th.join(timeout=2)


def publishers(node, topics):
    qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
    pubs = {t: node.create_publisher(PoseStamped, t, qos) for t in topics}
    deadline = time.monotonic() + 30  # a guard against a hang: discovery is slow on a busy machine
    while any(p.get_subscription_count() == 0 for p in pubs.values()):
        assert time.monotonic() < deadline, "subscriber never matched"
        time.sleep(0.01)
    return pubs


def msg(stamp_ns, pos, quat_xyzw, frame="mocap"):
    m = PoseStamped()
    m.header.stamp.sec, m.header.stamp.nanosec = divmod(int(stamp_ns), 1_000_000_000)
    m.header.frame_id = frame
    m.pose.position.x, m.pose.position.y, m.pose.position.z = map(float, pos)
    o = m.pose.orientation
    o.x, o.y, o.z, o.w = map(float, quat_xyzw)
    return m


def wait(pred, timeout=30.0):  # a guard against a hang, not a figure
    deadline = time.monotonic() + timeout
    while not pred():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.005)


def test_frames_assembled_by_stamp_with_poses_in_si(ros):
    pub_node, sub_node = ros
    tr = RosMocapTracker(sub_node, ["PSM1_tool", "world"], reliable=True)
    assert isinstance(tr, Tracker)
    pubs = publishers(pub_node, tr.topics.values())
    assert set(tr.topics.values()) == {"/mocap/PSM1_tool/pose", "/mocap/world/pose"}
    rot = Rotation.from_euler("xyz", [0.1, -0.4, 1.2])
    for k in range(20):
        stamp = 1_000_000_000 + k * 8_333_333  # 120 Hz
        pubs["/mocap/PSM1_tool/pose"].publish(msg(stamp, [0.1 * k, 0.2, -0.5], rot.as_quat()))
        pubs["/mocap/world/pose"].publish(msg(stamp, [0, 0, 0], [0, 0, 0, 1]))
    assert tr.wait_for_frames(20, timeout=30)
    frames = tr.frames()
    assert len(frames) == 20 and tr.frames() == []
    assert [f.t for f in frames] == pytest.approx([1.0 + k * 0.008333333 for k in range(20)])
    tool = frames[5].bodies["PSM1_tool"]
    np.testing.assert_allclose(tool.position, [0.5, 0.2, -0.5])
    np.testing.assert_allclose(tool.rotation, rot.as_matrix(), atol=1e-12)
    assert tool.frame == "mocap"
    assert tr.latest().t == frames[-1].t
    assert tr.stats.frames == 20 and tr.stats.incomplete == 0 and tr.stats.late == 0
    tr.close()


def test_body_missing_from_frames_is_none_and_counted(ros):
    pub_node, sub_node = ros
    tr = RosMocapTracker(sub_node, ["a", "b"], prefix="vrpn_client_node", reliable=True)
    pubs = publishers(pub_node, tr.topics.values())
    assert "/vrpn_client_node/a/pose" in tr.topics.values()
    for k in range(12):
        stamp = (k + 1) * 10_000_000
        pubs["/vrpn_client_node/a/pose"].publish(msg(stamp, [k, 0, 0], [0, 0, 0, 1]))
        if not 4 <= k <= 7:  # b occluded for 4 frames
            pubs["/vrpn_client_node/b/pose"].publish(msg(stamp, [0, k, 0], [0, 0, 0, 1]))
    assert tr.wait_for_frames(12, timeout=30)
    frames = tr.frames()
    assert [f.bodies["b"] is None for f in frames] == [4 <= k <= 7 for k in range(12)]
    assert all(f.bodies["a"] is not None for f in frames)
    assert tr.stats.missing == {"a": 0, "b": 4} and tr.stats.incomplete == 4


def test_late_and_duplicate_messages_are_counted_and_dropped(ros):
    pub_node, sub_node = ros
    tr = RosMocapTracker(sub_node, ["a", "b"], reliable=True)
    pubs = publishers(pub_node, tr.topics.values())
    pa, pb = pubs["/mocap/a/pose"], pubs["/mocap/b/pose"]
    for k in (1, 2, 3, 4):
        pa.publish(msg(k * 10_000_000, [k, 0, 0], [0, 0, 0, 1]))
        if k != 3:
            pb.publish(msg(k * 10_000_000, [0, k, 0], [0, 0, 0, 1]))
    wait(lambda: tr.stats.frames == 4)  # frame 3 left without b once b reported stamp 4
    pb.publish(msg(3 * 10_000_000, [9, 9, 9], [0, 0, 0, 1]))  # b's stamp-3 message, late
    pa.publish(msg(5 * 10_000_000, [5, 0, 0], [0, 0, 0, 1]))
    pa.publish(msg(5 * 10_000_000, [6, 0, 0], [0, 0, 0, 1]))  # same body, same stamp
    pb.publish(msg(5 * 10_000_000, [0, 5, 0], [0, 0, 0, 1]))
    wait(lambda: tr.stats.frames == 5 and tr.stats.duplicate + tr.stats.late == 2)
    frames = tr.frames()
    assert tr.stats.late == 1 and tr.stats.duplicate == 1
    assert frames[2].bodies["b"] is None  # the late message was never merged
    assert frames[4].bodies["a"].position[0] == 5.0  # the first message kept
    assert tr.stats.received == {"a": 5, "b": 4}


def test_stale_stream_raises_naming_body_and_keeps_frames(ros):
    pub_node, sub_node = ros
    tr = RosMocapTracker(sub_node, ["a", "ghost"], stale_timeout=0.2, assembly_window=0.02,
                         reliable=True)
    pubs = publishers(pub_node, ["/mocap/a/pose"])
    for k in range(1, 6):
        pubs["/mocap/a/pose"].publish(msg(k * 10_000_000, [k, 0, 0], [0, 0, 0, 1]))
    # incomplete frames leave once 'ghost' has been silent for the window (on a read)
    assert tr.wait_for_frames(2, timeout=30)
    time.sleep(0.3)
    # 'ghost' has been silent since the tracker was made: 0.3 s or more (seconds on a loaded
    # machine, where matching the publishers takes longer), past the 0.2 s timeout
    with pytest.raises(MocapStaleError, match=r"'ghost' on /mocap/ghost/pose: no message for \d+\.\d{3} s "
                                              r"\(never received\)") as exc:
        tr.frames()
    assert float(re.search(r"'ghost' on \S+: no message for ([\d.]+) s", str(exc.value))[1]) >= 0.3
    with pytest.raises(MocapStaleError, match="'a' on /mocap/a/pose"):
        tr.latest()
    tr.stale_timeout = 10.0  # recovery: nothing received so far is lost
    tr.flush_pending()
    frames = tr.frames()
    assert len(frames) == 5 and all(f.bodies["ghost"] is None for f in frames)
    assert tr.stats.missing["ghost"] == 5


def test_a_body_taken_late_still_joins_its_frames_and_a_silent_one_is_given_up(ros):
    """A process that takes its messages late may take one topic's backlog before
    another's: frames wait for a body that is still sending, whatever the stamps' distance,
    and leave without it once it has been silent for the window (receive time, here a
    clock the test moves). A message whose quaternion is zero is counted and dropped."""
    pub_node, sub_node = ros
    now = [100.0]
    tr = RosMocapTracker(sub_node, ["a", "b"], reliable=True, assembly_window=0.25,
                         stale_timeout=60.0, clock=lambda: now[0])
    pubs = publishers(pub_node, tr.topics.values())
    pa, pb = pubs["/mocap/a/pose"], pubs["/mocap/b/pose"]
    for k in range(1, 31):   # a's 30 frames (0.29 s of stamps) before any of b's
        pa.publish(msg(k * 10_000_000, [k, 0, 0], [0, 0, 0, 1]))
    wait(lambda: tr.stats.received["a"] == 30)
    assert tr.frames() == []   # b has sent nothing, but the clock has not moved: wait for it
    for k in range(1, 31):
        pb.publish(msg(k * 10_000_000, [0, k, 0], [0, 0, 0, 1]))
    assert tr.wait_for_frames(30, timeout=30)
    frames = tr.frames()
    assert len(frames) == 30 and tr.stats.incomplete == 0
    assert [f.bodies["b"].position[1] for f in frames] == list(range(1, 31))
    # b stops; a goes on: a's frames wait for b until b has been silent for the window
    for k in range(31, 36):
        pa.publish(msg(k * 10_000_000, [k, 0, 0], [0, 0, 0, 1]))
    wait(lambda: tr.stats.received["a"] == 35)
    now[0] += 0.2
    assert tr.frames() == []
    now[0] += 0.1
    frames = tr.frames()
    assert [f.bodies["b"] for f in frames] == [None] * 5 and tr.stats.missing == {"a": 0, "b": 5}
    pa.publish(msg(36 * 10_000_000, [1, 0, 0], [0, 0, 0, 0]))   # not a rotation
    wait(lambda: tr.stats.malformed == 1)
    assert tr.stats.received["a"] == 35
