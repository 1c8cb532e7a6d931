"""Every stream's stale limit: its rig.toml key, its default, and the line a stale stream ends a run with.

The keys ([arms.X] watchdog, [loadcell] stale_timeout, [mocap] stale_timeout) default to
ten of the stream's periods, or the floor of its transport if that is longer
(rig.config.stale_default). A stale stream's line says how long it has been silent, in
periods of the rate it had been coming at (from the messages' own stamps), the limit and
its key, and that a starved process looks the same as a stopped device.

The drivers' ages run on clocks the tests set (the load cell's and the trackers' injectable
clocks), so the figures in the lines are exact; the ROS arm's runs on the host's clock, and
its test reads the age back from the line.
"""

from __future__ import annotations

import re
import struct
import time

import pytest

from drivers.arm.crtk import StaleStream
from drivers.loadcell.errors import LoadCellDisconnected
from drivers.loadcell.serial_driver import LoadCell
from drivers.mocap.ros_tracker import MocapStaleError
from rig import config
from rig.faults import rate_of, silence_text
from tests.drivers.loadcell.test_loadcell_protocol import CAL, OPENING, ExpectedProtocolPort, frames
from tests.drivers.loadcell.test_loadcell_protocol import ManualClock as CellClock

STARVED = "A starved process (this one or the publisher, held off the CPU) looks the same as a stopped device"


def _load(tmp_path, text):
    f = tmp_path / "rig.toml"
    f.write_text(text)
    return config.load(f)


def _wait_for(pred, what: str, guard: float = 30.0) -> None:
    end = time.monotonic() + guard  # a guard against a hang, not a figure
    while not pred():
        assert time.monotonic() < end, f"timed out waiting for {what}"
        time.sleep(0.001)


# ------------------------------------------------------------------------- the keys

def test_the_defaults_are_ten_periods_of_the_configured_rate_above_the_floor(tmp_path):
    # slow streams: ten periods, longer than the floor
    cfg = _load(tmp_path, '[arms.PSM1]\ndriver = "ros"\n[ros]\nperiod = 0.5\n'
                          '[loadcell]\ndriver = "serial"\nport = "/dev/ttyACM0"\nrate = 4\n'
                          '[mocap]\ndriver = "ros"\nrate = 2\n')
    assert config.STALE_PERIODS == 10
    assert cfg.arms["PSM1"]["watchdog"] == pytest.approx(10 * 0.5)
    assert cfg.loadcell["stale_timeout"] == pytest.approx(10 / 4)
    assert cfg.mocap["stale_timeout"] == pytest.approx(10 / 2)
    # the dVRK's 100 Hz, a 500 Hz cell, a 120 Hz mocap: the floor of a busy machine
    cfg = _load(tmp_path, '[arms.PSM1]\ndriver = "ros"\n[loadcell]\ndriver = "serial"\nport = "/dev/ttyACM0"\n'
                          '[mocap]\ndriver = "natnet"\n')
    assert cfg.ros["period"] == config.DVRK_DEFAULT_PERIOD == 0.01
    assert cfg.arms["PSM1"]["watchdog"] == config.ROS_STALE_FLOOR > 10 * 0.01
    assert cfg.loadcell["stale_timeout"] == config.SERIAL_STALE_FLOOR > 10 / 500
    assert cfg.mocap["stale_timeout"] == config.ROS_STALE_FLOOR > 10 / 120


def test_simulated_devices_count_periods_of_the_simulated_clock(tmp_path):
    cfg = config.load()  # the built-in rig: no stall on the simulated clock, a 50 ms floor
    assert cfg.arms["PSM1"]["watchdog"] == max(10 / cfg.rig["rate"], config.SIM_STALE_FLOOR) == 0.05
    assert cfg.loadcell["stale_timeout"] == 0.05
    assert cfg.mocap["stale_timeout"] == pytest.approx(10 / 120)
    cfg = _load(tmp_path, '[rig]\nrate = 100\n[loadcell]\nrate = 50\n[mocap]\nrate = 30\n')
    assert cfg.arms["PSM1"]["watchdog"] == pytest.approx(0.1)
    assert cfg.loadcell["stale_timeout"] == pytest.approx(0.2)
    assert cfg.mocap["stale_timeout"] == pytest.approx(10 / 30)


def test_a_limit_the_file_gives_is_taken_as_given(tmp_path):
    cfg = _load(tmp_path, '[arms.PSM1]\ndriver = "ros"\nwatchdog = 0.08\n[ros]\nperiod = 0.5\n'
                          '[loadcell]\ndriver = "can"\nstale_timeout = 2.5\n'
                          '[mocap]\ndriver = "ros"\nstale_timeout = 1.25\n')
    given = (cfg.arms["PSM1"]["watchdog"], cfg.loadcell["stale_timeout"], cfg.mocap["stale_timeout"])
    assert given == (0.08, 2.5, 1.25)


@pytest.mark.parametrize("text, message", [
    ('[mocap]\nstale_timeout = 0\n', "mocap.stale_timeout: must be an interval > 0 s, got 0.0"),
    ('[loadcell]\nstale_timeout = -1\n', "loadcell.stale_timeout: must be an interval > 0 s"),
    ('[arms.PSM1]\nwatchdog = "fast"\n', "arms.PSM1.watchdog: expected a number"),
    ('[ros]\nperiod = 0\n', "ros.period: must be a period > 0 s"),
])
def test_a_bad_limit_is_one_line_naming_the_key(tmp_path, text, message):
    with pytest.raises(config.ConfigError) as err:
        _load(tmp_path, text)
    assert message in str(err.value) and "\n" not in str(err.value)


def test_every_stale_key_says_its_unit_and_how_its_default_is_derived():
    for section, key in (("arm", "watchdog"), ("loadcell", "stale_timeout"), ("mocap", "stale_timeout")):
        text = config.SCHEMA[section][key].help
        floor = config.SERIAL_STALE_FLOOR if section == "loadcell" else config.ROS_STALE_FLOOR
        assert text.startswith("s ") and "10" in text and f"{floor:.1f} s" in text and "period" in text, (section, text)
    assert "dvrk_system -p" in config.SCHEMA["ros"]["period"].help


# ------------------------------------------------------------------------- the lines

def test_rate_of_is_the_median_interval_and_silence_counts_periods():
    assert rate_of([0.0, 0.01, 0.02, 0.5, 0.51]) == pytest.approx(100.0)  # one late message does not move it
    assert rate_of([1.0]) == 0.0 and rate_of([2.0, 2.0]) == 0.0
    assert silence_text(0.412, 100.0) == "no message for 412 ms (41 periods of the 100 Hz it had been coming at)"
    assert silence_text(0.6, 120.0, seconds=True) == ("no message for 0.600 s (72 periods of the 120 Hz it had been "
                                                      "coming at)")
    assert silence_text(float("inf"), 0.0) == "no message ever received"
    assert "rate unknown" in silence_text(0.3, 0.0)


def test_a_stale_load_cell_says_for_how_long_at_what_rate_and_that_a_starved_process_looks_the_same():
    # three samples 2 ms apart on the device's clock (500 Hz), then nothing; the host's
    # clock is the test's, so the silence is exact
    port = ExpectedProtocolPort(OPENING + [(None, frames(0, 3, period_us=2000))])
    clock = CellClock()
    lc = LoadCell(port, CAL, stale_timeout=0.05, clock=clock)
    _wait_for(lambda: lc.stats().samples == 3, "three samples")
    clock.t += 0.1
    _wait_for(lambda: lc.stream_age() == pytest.approx(0.1), "the reader's next look")
    with pytest.raises(LoadCellDisconnected) as exc:
        lc.read()
    line = str(exc.value)
    assert "\n" not in line
    assert line.startswith(f"load cell on {lc.name}: no sample for 100 ms (50 periods of the 500 Hz it had been "
                           "coming at), beyond the stale timeout 50 ms ([loadcell] stale_timeout). ")
    assert STARVED in line
    assert "(free a CPU or raise [loadcell] stale_timeout); if not, check the cable and power" in line
    lc.close()


class _FakeNode:
    """The two things RosMocapTracker asks of its node: subscriptions (the test delivers
    messages to their callbacks, as an executor would: serialized for a raw one) and the
    node's clock (for the latency figure)."""

    def __init__(self) -> None:
        self.callbacks: dict[str, object] = {}

    def create_subscription(self, msg_type, topic, callback, qos, raw=False):
        from rclpy.serialization import serialize_message

        self.callbacks[topic] = (lambda m: callback(serialize_message(m))) if raw else callback
        return topic

    def destroy_subscription(self, sub) -> None:
        self.callbacks.pop(sub, None)

    def get_clock(self):
        class Clock:
            def now(self):
                class T:
                    nanoseconds = time.time_ns()
                return T()
        return Clock()


def _pose(stamp_ns: int):
    from geometry_msgs.msg import PoseStamped

    m = PoseStamped()
    m.header.stamp.sec, m.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
    m.pose.orientation.w = 1.0
    return m


def test_a_stale_mocap_body_says_for_how_long_at_what_rate_and_names_the_key(monkeypatch):
    import geometry_msgs.msg  # noqa: F401  (a declared dependency)
    from drivers.mocap.ros_tracker import RosMocapTracker

    monkeypatch.setenv("ROS_DOMAIN_ID", "42")
    monkeypatch.delenv("ROS_AUTOMATIC_DISCOVERY_RANGE", raising=False)
    t = [100.0]
    node = _FakeNode()
    tr = RosMocapTracker(node, ["tool", "world"], stale_timeout=0.5, clock=lambda: t[0])
    period_ns = 1_000_000_000 // 120
    for k in range(60):  # both bodies at 120 Hz (by their stamps), then 'tool' is lost
        for body in ("tool", "world") if k < 5 else ("world",):
            node.callbacks[f"/mocap/{body}/pose"](_pose(1_700_000_000_000_000_000 + k * period_ns))
        t[0] += 1 / 120
    tr.check_stale()  # 'tool' silent for 55 periods, 0.46 s: not yet
    t[0] = 100.0 + 4 / 120 + 0.6  # 'tool' silent for 0.6 s, 'world' for 0.14 s
    with pytest.raises(MocapStaleError) as exc:
        tr.frames()
    line = str(exc.value)
    assert "\n" not in line
    assert line.startswith("mocap stream stale beyond 0.5 s ([mocap] stale_timeout): 'tool' on /mocap/tool/pose: "
                           "no message for 0.600 s (72 periods of the 120 Hz it had been coming at). ")
    assert "'world'" not in line
    assert STARVED in line
    assert ("if the mocap bridge runs on ROS_DOMAIN_ID=42 and the body is tracked, the machine is too busy for "
            "this stream (free a CPU or raise [mocap] stale_timeout); if not, start the bridge there") in line
    tr.close()


def test_a_stale_natnet_stream_says_for_how_long_at_what_rate():
    from tests.drivers.natnet.test_natnet_protocol import V41, connected, hand_frame
    from tests.drivers.natnet.test_natnet_protocol import ManualClock as MonoClock
    from tests.drivers.natnet.test_natnet_protocol import wait_for

    mono = MonoClock(50.0)
    t, tr = connected(V41, stale_timeout=0.5, monotonic=mono)
    for k in range(4):  # Motive's timestamps 1/240 s apart: 240 Hz
        frame = hand_frame(V41, number=1234 + k).replace(struct.pack("<d", 10.25), struct.pack("<d", 10.25 + k / 240))
        t.inject(frame)
    wait_for(lambda: tr.stats.frames == 4)
    mono.t += 0.75
    wait_for(lambda: tr.stream_age() == pytest.approx(0.75))  # the reader has polled since
    with pytest.raises(MocapStaleError) as exc:
        tr.frames()
    line = str(exc.value)
    assert "\n" not in line
    assert line.startswith(f"NatNet stream from {tr.address}: no frame for 0.750 s (180 periods of the 240 Hz it had "
                           "been coming at), beyond 0.5 s ([mocap] stale_timeout). ")
    assert STARVED in line and "if Motive is streaming to this machine" in line
    tr.close()


class _Quiet:
    """A NatNet transport on which nothing ever arrives (no Motive here)."""

    address = "127.0.0.1:1510"

    def send(self, datagram) -> None:
        pass

    def recv(self, timeout):
        time.sleep(min(timeout, 0.01))

    def close(self) -> None:
        pass


def test_the_natnet_tracker_of_a_config_takes_its_stale_limit(tmp_path, monkeypatch):
    from drivers.natnet import tracker as natnet

    monkeypatch.setattr(natnet, "UdpTransport", lambda *args: _Quiet())
    monkeypatch.setattr(natnet.NatNetTracker, "connect", lambda self, timeout: None)
    cfg = _load(tmp_path, '[mocap]\ndriver = "natnet"\nrate = 2\n')
    tracker = natnet.open_natnet_tracker(cfg.mocap, ["world"], timeout=1.0)
    try:
        assert tracker.stale_timeout == cfg.mocap["stale_timeout"] == pytest.approx(5.0)
    finally:
        tracker.close()


def test_the_stale_arm_line_defaults_its_key_from_the_topic():
    err = StaleStream("/PSM2/measured_js", 0.9, 0.5, rate_hz=1000.0)
    assert str(err).startswith("/PSM2/measured_js: stale stream, no message for 900 ms (900 periods of the 1000 Hz "
                               "it had been coming at), beyond the 500 ms watchdog ([arms.PSM2] watchdog); ")
    assert (err.age, err.watchdog, err.rate_hz, err.setting) == (0.9, 0.5, 1000.0, "[arms.PSM2] watchdog")


@pytest.mark.ros
def test_a_stale_ros_arm_says_for_how_long_at_the_rate_it_was_published(ros_env):
    import rclpy
    from rclpy.context import Context
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import JointState

    from drivers.arm.dvrk_arm import RosArm

    ctx = Context()
    rclpy.init(context=ctx)
    try:
        pub_node = rclpy.create_node("fake_console", context=ctx)
        sub_node = rclpy.create_node("rig_arm", context=ctx)
        pub = pub_node.create_publisher(JointState, "/PSM1/measured_js",
                                        QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
        fired: list[StaleStream] = []
        arm = RosArm(sub_node, "/PSM1", watchdog=0.2, states=False, setting="[arms.left] watchdog",
                     on_stale=fired.append)
        _wait_for(lambda: pub.get_subscription_count() > 0, "the driver's subscription to match")
        for k in range(20):  # stamped 10 ms apart: a console at 100 Hz, whenever they arrive
            m = JointState()
            m.header.stamp.sec, m.header.stamp.nanosec = 1000 + k // 100, (k % 100) * 10_000_000
            m.position = [0.0, 0.0, 0.1]
            n = arm.received
            end = time.monotonic() + 30.0  # a guard against a hang, not a figure
            while arm.received == n:  # the driver reads best effort: a message lost is sent again
                assert time.monotonic() < end, f"message {k} never arrived"
                pub.publish(m)
                resend = time.monotonic() + 0.5
                while arm.received == n and time.monotonic() < resend:
                    time.sleep(0.001)
        assert arm.published_rate() == pytest.approx(100.0)
        with pytest.raises(StaleStream) as exc:
            _wait_for(lambda: arm.measured_js() is None, "the stream to go stale")  # raises once stale
        line = str(exc.value)
        assert "\n" not in line
        found = re.match(r"/PSM1/measured_js: stale stream, no message for (\d+) ms \((\d+) periods of the 100 Hz it "
                         r"had been coming at\), beyond the 200 ms watchdog \(\[arms.left\] watchdog\); the driver "
                         r"commands the arm to hold\. ", line)
        assert found, line
        ms, periods = int(found[1]), int(found[2])
        assert ms >= 200 and periods == pytest.approx(ms / 10, abs=0.51)  # past 200 ms, to the ms
        assert STARVED in line
        assert f"if the dVRK console (or `rig sim`) runs on ROS_DOMAIN_ID={ros_env}" in line
        assert "(free a CPU or raise [arms.left] watchdog); if not, start it there" in line
        # the watchdog thread's callback carries the same figures (on a loaded machine it
        # may also have fired in a pause between two of the messages: once per outage)
        _wait_for(lambda: any(e.rate_hz == pytest.approx(100.0) for e in fired), "the watchdog thread")
        err = next(e for e in fired if e.rate_hz == pytest.approx(100.0))
        assert err.setting == "[arms.left] watchdog" and err.age > 0.2
        arm.close()
    finally:
        rclpy.shutdown(context=ctx)
