"""Every real driver and its in-process twin against the interface procedures use
(drivers/interfaces.py, docs/fakes.md): the same checks over both, so a twin cannot drift
from its driver (nor a driver from the contract) without a test failing.

Here: every method of every interface on every implementation; the behaviour
(tests/drivers/conformance_checks.py) of the twins (SimArm, SimTracker, SimOperator,
SimForceSensor), of the serial load cell against its emulated firmware, of the NatNet
tracker against its fake Motive and of the console operator. The ROS drivers against
`rig sim --sim-time`: tests/drivers/test_conformance_ros.py."""

from __future__ import annotations

import inspect
import math
import time

import numpy as np
import pytest
import serial

from drivers.arm.dvrk_arm import RosArm
from drivers.interfaces import Arm, ForceSample, ForceSensor, ImpedanceArm, Operator, Tracker
from drivers.loadcell.can import CanLoadCell
from drivers.loadcell.fake_firmware import FakeLoadCellFirmware
from drivers.loadcell.force_calibration import LoadCellCalibration
from drivers.loadcell.serial_driver import LoadCell
from drivers.loadcell.sim import SimForceSensor
from drivers.mocap.ros_tracker import RosMocapTracker
from drivers.mocap.sim import SimTracker
from drivers.natnet.tracker import NatNetTracker
from drivers.operator.driver import ConsoleOperator, RosOperator
from drivers.operator.sim import SimOperator
from drivers.arm.sim import SimArm
from tests.drivers import conformance_checks as checks

#: interface -> the real drivers and the twin that stand for it
IMPLEMENTATIONS = {
    Arm: (RosArm, SimArm),
    ImpedanceArm: (RosArm,),
    ForceSensor: (LoadCell, CanLoadCell, SimForceSensor),
    Tracker: (RosMocapTracker, NatNetTracker, SimTracker),
    Operator: (ConsoleOperator, RosOperator, SimOperator),
}


def _methods(protocol) -> dict[str, inspect.Signature]:
    """The protocol's own methods and properties (not object's), with their signatures."""
    out = {}
    for klass in protocol.__mro__:
        if klass in (object,) or klass.__name__ in ("Protocol", "Generic"):
            continue
        for name, member in vars(klass).items():
            if name.startswith("_"):
                continue
            if isinstance(member, property):
                out.setdefault(name, None)
            elif inspect.isfunction(member):
                out.setdefault(name, inspect.signature(member))
    return out


CASES = [(p, c) for p, classes in IMPLEMENTATIONS.items() for c in classes]


@pytest.mark.parametrize("protocol,cls", CASES, ids=[f"{p.__name__}-{c.__name__}" for p, c in CASES])
def test_each_driver_and_twin_has_every_method_of_its_interface(protocol, cls):
    methods = _methods(protocol)
    assert methods, protocol
    for name, wanted in methods.items():
        assert hasattr(cls, name), f"{cls.__name__} lacks {protocol.__name__}.{name}"
        if wanted is None:  # a property of the interface
            continue
        got = inspect.signature(getattr(cls, name))
        params = got.parameters
        takes_any = any(p.kind is p.VAR_KEYWORD for p in params.values())
        for pname, p in wanted.parameters.items():
            if pname == "self" or p.kind in (p.VAR_KEYWORD, p.VAR_POSITIONAL):
                continue
            assert pname in params or takes_any, \
                f"{cls.__name__}.{name}{got} does not take {pname!r} of {protocol.__name__}.{name}{wanted}"
            if p.default is not inspect.Parameter.empty and pname in params:
                assert params[pname].default is not inspect.Parameter.empty, \
                    f"{cls.__name__}.{name}: {pname!r} is optional in the interface, required here"


# -- the same behaviour from the real load cell (over the emulated firmware) and its twin --------
class _Tension:
    def __init__(self, value: float):
        self.value = value

    def __call__(self) -> float:
        return self.value


def _wait(pred, what: str, timeout: float = 30.0) -> None:
    end = time.monotonic() + timeout
    while not pred():
        assert time.monotonic() < end, f"timed out waiting for {what}"
        time.sleep(0.002)


def _check_force_sensor(sensor, samples: list, truth: float, rate: float) -> None:
    """What a procedure relies on, whichever sensor it holds."""
    assert isinstance(sensor, ForceSensor)
    assert isinstance(sensor.name, str)
    assert len(samples) >= 20
    assert all(isinstance(s, ForceSample) for s in samples)
    t = np.array([s.t for s in samples])
    # oldest first, each once (by the firmware's sequence number): on the wall clock the
    # driver's host-time map never steps back, but a new fit may hold a time for a sample
    # (drivers.loadcell.stream_tracking.ClockMapper), so stamps may repeat, never decrease
    assert np.all(np.diff(t) >= 0), "samples oldest first"
    seq = [s.seq for s in samples[:200]]
    assert len(set(seq)) == len(seq), "each sample once"
    assert np.median(np.diff(t)) == pytest.approx(1.0 / rate, rel=0.2)
    f = np.array([s.force for s in samples])
    assert np.all(np.isfinite(f)) and np.mean(f) == pytest.approx(truth, abs=0.05)
    newest = sensor.read()
    assert newest.t >= t[-1] and math.isfinite(newest.force)
    assert 0.0 <= sensor.stream_age()


def test_the_serial_load_cell_over_its_firmware_and_the_twin_behave_alike(tmp_path):
    fake = FakeLoadCellFirmware(_Tension(2.0), noise=0.005).start()
    port = serial.Serial(fake.port_path, baudrate=250000)
    try:
        cal = LoadCellCalibration(newtons_per_count=1 / fake.model.gain, zero_counts=fake.model.offset)
        lc = LoadCell(port, cal, stale_timeout=0.5)
        got = lc.samples()
        _wait(lambda: got.extend(lc.samples()) or len(got) >= 50, "50 samples")
        _check_force_sensor(lc, got, 2.0, 500.0)
        lc.close()
    finally:
        fake.unplug()
        port.close()

    from rig import config
    from rig.devices.factory import open_rig

    (tmp_path / "rig.toml").write_text("")
    rig = open_rig(config.load(tmp_path / "rig.toml"), ["PSM1", "PSM2"], seed=0, uses=("loadcell",))
    try:
        sensor = rig.forces[0]
        assert isinstance(sensor, SimForceSensor)
        truth = []
        rig.clock.add_listener(lambda t: truth.append(rig.world.tension(0)))
        sensor.samples()
        for _ in range(200):
            rig.clock.tick()
        got = sensor.samples()
        # the twin's samples are the world's tension converted as the firmware would
        _check_force_sensor(sensor, got, float(np.mean(truth)), 500.0)
    finally:
        rig.close()


def test_the_arms_say_what_they_can(tmp_path):
    """The capabilities a procedure asks instead of probing: the in-process arm publishes
    with every tick and runs no Cartesian impedance of its own."""
    from rig import config
    from rig.devices.factory import open_rig

    (tmp_path / "rig.toml").write_text("")
    rig = open_rig(config.load(tmp_path / "rig.toml"), ["PSM1"], seed=0, uses=())
    try:
        arm = rig.arms["PSM1"]
        assert isinstance(arm, Arm)
        assert arm.published_rate() == 0.0 and arm.supports_servo_ci is False
        arm.power_on()
        assert rig.clock.overruns == 0 and rig.clock.skipped == 0
    finally:
        rig.close()


# -- the twins and the drivers that need no ROS, on the simulated world's clock ------------
#: the probability a simulated body is occluded in a frame, in every tracker check
OCCLUSION = 0.2


@pytest.fixture
def sim_rig(tmp_path):
    """The in-process simulated rig of two arms with mocap (occluding bodies), its operator,
    the object off the tool tips and the arms at rest (`checks.settle`)."""
    from rig import config
    from rig.devices.factory import open_rig

    (tmp_path / "rig.toml").write_text(f"[mocap]\nocclusion = {OCCLUSION}\n")
    cfg = config.load(tmp_path / "rig.toml")
    rig = open_rig(cfg, ["PSM1", "PSM2"], seed=0, uses=("mocap",))
    try:
        checks.settle(rig)
        yield cfg, rig
    finally:
        rig.close()


def test_the_in_process_arm_does_what_the_interface_says(sim_rig):
    _, rig = sim_rig
    checks.check_arm_kind(rig.arms["PSM1"], impedance=False)
    checks.check_servo_jp_and_drain(rig, "PSM1")
    checks.check_power_on_and_hold(rig, "PSM2")
    checks.check_move_jp_and_measured_cp(rig, "PSM1")


def test_the_in_process_tracker_does_what_the_interface_says(sim_rig):
    from rig.faults import DeviceFault

    cfg, rig = sim_rig
    tracker = rig.tracker
    assert isinstance(tracker, SimTracker)
    fresh = SimTracker(rig.world, rig.clock, latency=0.01)
    with pytest.raises(DeviceFault, match="no mocap frame"):
        fresh.latest()  # before the first frame, as the drivers
    fresh.close()
    truth = checks.BodyTruth(cfg, list(rig.arms))
    frames = checks.collect_frames(rig, tracker, 1.0, truth)
    checks.check_tracker_frames(tracker, frames, cfg.mocap["rate"], OCCLUSION, truth)
    # its cable pulled (by the operator, as in `rig sim`): stale after the stale timeout
    rig.operator.unplug("mocap")
    checks.run_for(rig, 0.5 * tracker.stale_timeout)
    tracker.frames()  # not yet
    checks.run_for(rig, 0.6 * tracker.stale_timeout + tracker.latency)
    for read in (tracker.frames, tracker.latest):
        with pytest.raises(DeviceFault, match="stale") as err:
            read()
        assert "\n" not in str(err.value)


def test_the_natnet_tracker_over_its_fake_motive_does_what_the_interface_says():
    """The real NatNet driver against the emulated Motive on the loopback, fed by the
    simulated world; the world steps only when this test ticks it."""
    from drivers.natnet.fake_motive import FakeMotiveOnWorld
    from drivers.natnet.udp import UdpTransport
    from rig import config
    from rig.devices.clock import SimClock
    from rig.faults import DeviceFault
    from rig.sim.world import world_from_config

    cfg = config.parse({}, "built-in simulated rig")
    world = world_from_config(cfg, seed=3)
    clock = SimClock(world)
    arms = [SimArm(world, n, clock) for n in world.names]
    for arm in arms:
        arm.hold()
    t_start = clock.now()
    motive = FakeMotiveOnWorld(world, clock, occlusion=OCCLUSION, rate=120.0, seed=11, command_port=0,
                               data_port=0).start()
    # no stale limit while the world is stepped here (however slowly), one of 0.3 s at the end
    tracker = NatNetTracker(UdpTransport("127.0.0.1", motive.motive.command_port, motive.motive.data_port),
                            stale_timeout=1e9)
    try:
        tracker.connect(timeout=30.0)
        assert isinstance(tracker, Tracker)
        truth = checks.BodyTruth(cfg, world.names)
        by_name = {a.name: a for a in arms}
        got = []
        while motive.motive.stats.frames < 150:
            clock.tick()
            truth.record(by_name)
            motive.pump()
            got += tracker.frames()
        _wait(lambda: tracker.stats.frames == motive.motive.stats.frames, "every frame sent")
        got += tracker.frames()
        # The driver maps Motive's clock onto the host's, as a PC's and Motive's run at one
        # rate; this world runs as fast as the test steps it, so a frame's capture time on
        # the world's clock is Motive's own: its first frame's plus the frame's timestamp
        # (its first capture is at the first tick)
        assert got[0].timestamp == 0.0
        t0 = t_start + world.dt
        checks.check_tracker_frames(tracker, got, 120.0, OCCLUSION, truth, stamp=lambda f: t0 + f.timestamp)
        # Motive stops streaming: stale once no frame came for the stale timeout (a lower
        # bound of wall time: the driver counts the silence it saw)
        tracker.stale_timeout = 0.3

        def stale() -> bool:
            try:
                tracker.frames()
            except DeviceFault as exc:
                assert "stale" in str(exc) or "beyond" in str(exc), exc
                return True
            return False

        _wait(stale, "the stale stream")
        with pytest.raises(DeviceFault):
            tracker.latest()
    finally:
        tracker.close()
        motive.close()


def test_the_in_process_operator_does_what_the_interface_says(sim_rig):
    _, rig = sim_rig
    assert isinstance(rig.operator, SimOperator)
    checks.check_touch(rig, ["PSM1", "PSM2"], {n: rig.world.arms[n].rcm_world for n in rig.arms})
    checks.check_operator_refuses(rig.operator)


def test_the_console_operator_refuses_as_the_others_and_answers_each_request(capsys):
    op = ConsoleOperator(yes=True)
    assert isinstance(op, Operator)
    checks.check_operator_refuses(op)
    op.hang_mass(0.5)
    op.attach_object("spring")
    assert "Hang 0.500 kg from the load cell and let it settle: taken as done (--yes)" in capsys.readouterr().err
