"""The CAN load-cell driver against the firmware fake on python-can's virtual bus."""

from __future__ import annotations

import itertools
import time
import uuid

import can
import pytest

from drivers.interfaces import ForceSensor
from drivers.loadcell import LoadCellCalibration, LoadCellCommandError, LoadCellDisconnected, RawSample
from drivers.loadcell_can import CanLoadCell, FakeCanLoadCellFirmware, decode_can_sample, encode_can_sample


class Tension:
    def __init__(self, value: float = 0.0) -> None:
        self.value = value

    def __call__(self) -> float:
        return self.value


@pytest.fixture
def cell():
    """Makes (fake, host bus) on a fresh virtual channel; shuts both down afterwards."""
    made = []

    def make(tension=None, **kw):
        channel = f"loadcell-{uuid.uuid4().hex[:8]}"
        fake = FakeCanLoadCellFirmware(tension or Tension(), channel=channel, **kw).start()
        bus = can.Bus(interface="virtual", channel=channel)
        made.append((fake, bus))
        return fake, bus

    yield make
    for fake, bus in made:
        fake.unplug()
        bus.shutdown()


def cal_of(fake) -> LoadCellCalibration:
    return LoadCellCalibration(newtons_per_count=1 / fake.model.gain, zero_counts=fake.model.offset)


def test_sample_layout_matches_the_document():
    # LOADCELL_PROTOCOL.md: SAMPLE seq 130, counts -1000, t_us 1000000 -> 300#02 18 FC FF 40 42 0F 00
    data = encode_can_sample(RawSample(130, 1_000_000, -1000))
    assert data == bytes.fromhex("0218FCFF40420F00")
    assert decode_can_sample(data) == RawSample(2, 1_000_000, -1000, 0)
    sat = encode_can_sample(RawSample(5, 0, 1 << 24))  # beyond i24: clipped and flagged
    assert decode_can_sample(sat) == RawSample(5, 0, (1 << 23) - 1, 1)


def test_commands_and_replies_on_the_documented_ids(cell):
    fake, bus = cell()

    def ask(data: bytes) -> bytes:
        bus.send(can.Message(arbitration_id=0x301, data=data, is_extended_id=False))
        for _ in range(50):
            msg = bus.recv(timeout=0.1)
            if msg is not None and msg.arbitration_id == 0x302:
                return bytes(msg.data)
        raise AssertionError("no reply on 0x302")

    assert ask(b"\x10") == bytes.fromhex("9001010000 01E803".replace(" ", ""))
    assert ask(bytes.fromhex("12F401")) == bytes.fromhex("92F401")
    assert ask(bytes.fromhex("120000")) == bytes.fromhex("FF1203")  # bad argument
    assert ask(b"\x42") == bytes.fromhex("FF4201")  # unknown command
    assert ask(bytes.fromhex("12F4")) == bytes.fromhex("FF1204")  # bad length
    assert ask(b"\x13") == b"\x93"
    msg = bus.recv(timeout=0.1)
    while msg.arbitration_id != 0x300:
        msg = bus.recv(timeout=0.1)
    assert msg.dlc == 8
    assert ask(b"\x14") == b"\x94"


def test_stream_tare_and_rate(cell):
    tension = Tension(1.0)
    fake, bus = cell(tension)
    lc = CanLoadCell(bus, cal_of(fake))
    assert isinstance(lc, ForceSensor)
    time.sleep(0.5)
    got = lc.samples()
    assert 230 <= len(got) <= 270
    assert all(s.force == pytest.approx(1.0, abs=3e-3) for s in got)
    assert all(b.t >= a.t for a, b in zip(got, got[1:]))
    lc.tare(conversions=16)
    tension.value = 2.0
    t0 = time.monotonic()
    time.sleep(0.02)
    s = lc.read()
    assert s.t > t0 and s.force == pytest.approx(1.0, abs=3e-3)
    with pytest.raises(LoadCellCommandError, match="bad argument"):
        lc.set_rate(5000)
    st = lc.stats()
    assert st.problems() == 0 and st.samples > 230
    lc.close()


def test_gaps_longer_than_the_7_bit_sequence_are_counted_exactly(cell):
    fake, bus = cell(Tension(0.5))
    lc = CanLoadCell(bus, cal_of(fake), stale_timeout=2.0)
    time.sleep(0.05)
    fake.inject("skip", 300)  # 0.6 s of silence, more than two wraps of seq mod 128
    time.sleep(0.7)
    fake.inject("swap")
    time.sleep(0.05)
    st = lc.stats()
    assert (st.gaps, st.out_of_order) == (2, 1)
    assert st.lost == 300 + 1  # the late frame of the swap was first counted missing
    seqs = [s.seq for s in lc.samples()]
    assert len(seqs) == st.samples
    lc.close()


def test_silent_cell_raises_disconnected_within_100_ms(cell):
    fake, bus = cell(Tension(0.5))
    lc = CanLoadCell(bus, cal_of(fake))
    time.sleep(0.05)
    lc.read()
    t0 = time.monotonic()
    fake.unplug()
    with pytest.raises(LoadCellDisconnected, match="no sample"):
        for _ in itertools.count():
            lc.read()
            time.sleep(0.0005)
    assert time.monotonic() - t0 < 0.1
    lc.close()
