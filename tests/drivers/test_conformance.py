"""Every real driver and its in-process twin against the interface procedures use
(drivers/interfaces.py, docs/fakes.md): the same checks over both, so a twin cannot drift
from its driver (nor a driver from the contract) without a test failing."""

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
    assert np.all(np.diff(t) > 0), "samples oldest first, each once"
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
