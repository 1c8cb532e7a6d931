"""One baud rate for the load cell: the firmware's, taken by the host's default and the
example configuration; and a device that never answers says to check it."""

from __future__ import annotations

import random
import re
import time
import tomllib
from pathlib import Path

import pytest

from drivers.loadcell import errors, protocol, serial_driver
from rig import config

REPO = Path(__file__).resolve().parents[3]


def _firmware_baud() -> int:
    source = (REPO / "drivers/firmware/loadcell/loadcell.ino").read_text()
    defined = re.findall(r"^#define\s+LOADCELL_BAUD\s+(\d+)", source, re.M)
    begins = re.findall(r"Serial\.begin\(\s*([A-Za-z_0-9]+)\s*\)", source)
    assert len(defined) == 1, "the firmware defines LOADCELL_BAUD once"
    assert begins and all(b in ("LOADCELL_BAUD", defined[0]) for b in begins), begins
    return int(defined[0])


def test_the_host_default_is_the_firmwares_rate():
    baud = _firmware_baud()
    assert protocol.BAUDRATE == baud
    assert config.load(None).loadcell["baudrate"] == baud


def test_the_example_configuration_and_the_protocol_notes_say_the_same_rate():
    baud = _firmware_baud()
    example = tomllib.loads((REPO / "examples/real-rig.toml").read_text())
    assert example["loadcell"]["baudrate"] == baud
    assert f"{baud} baud" in (REPO / "drivers/LOADCELL_PROTOCOL.md").read_text()


class _WrongBaudPort:
    """A board at another baud rate: the host reads bytes, none of them a frame."""

    def __init__(self, baudrate: int) -> None:
        self.baudrate = baudrate
        self.port = "/dev/ttyACM9"
        self.timeout = 0.005
        self._rng = random.Random(3)

    @property
    def in_waiting(self) -> int:
        return 4

    def read(self, n: int = 1) -> bytes:
        time.sleep(self.timeout)
        return bytes(self._rng.choice((0x00, 0x80, 0xF8, 0xFE)) for _ in range(min(n, 4)))

    def write(self, data: bytes) -> int:
        return len(data)


def test_a_device_that_never_answers_names_the_baud_rate(monkeypatch):
    monkeypatch.setattr(serial_driver.LoadCell, "connect_timeout", 0.3)
    with pytest.raises(errors.LoadCellCommandError) as info:
        serial_driver.LoadCell(_WrongBaudPort(115200), rate_hz=500)
    text = str(info.value)
    assert "\n" not in text
    assert "/dev/ttyACM9" in text and "at 115200 baud" in text and f"talks at {protocol.BAUDRATE}" in text, text
    assert "[loadcell] baudrate" in text, text
