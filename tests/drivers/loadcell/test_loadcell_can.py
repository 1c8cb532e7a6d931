"""The CAN load-cell driver against the firmware fake on python-can's virtual bus.

As in test_loadcell_pty.py, the fake runs on a thread of this process: the tests wait for
what they need instead of sleeping for what an idle machine would deliver, and wall-time
limits only guard against a hang.
"""

from __future__ import annotations

import itertools
import re
import statistics
import time
import uuid

import can
import pytest

from drivers.interfaces import ForceSensor
from drivers.loadcell.can import CanLoadCell, decode_can_sample, encode_can_sample
from drivers.loadcell.fake_can_firmware import FakeCanLoadCellFirmware
from drivers.loadcell.errors import LoadCellCommandError, LoadCellDisconnected
from drivers.loadcell.force_calibration import LoadCellCalibration
from drivers.loadcell.protocol import RawSample


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


def wait_for(pred, what: str, timeout: float = 30.0) -> None:
    """Poll `pred` until true; the limit is a guard against a hang, not a figure."""
    end = time.monotonic() + timeout
    while not pred():
        assert time.monotonic() < end, f"timed out waiting for {what}"
        time.sleep(0.002)


def collect(lc, n: int) -> list:
    """At least `n` samples from now on (every one, in order)."""
    got = lc.samples()
    wait_for(lambda: got.extend(lc.samples()) or len(got) >= n, f"{n} samples")
    return got


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
    end = time.monotonic() + 30.0  # a guard against a hang: the first sample takes 2 ms
    msg = None
    while msg is None or msg.arbitration_id != 0x300:
        assert time.monotonic() < end, "no sample on 0x300"
        msg = bus.recv(timeout=0.1)
    assert msg.dlc == 8
    assert ask(b"\x14") == b"\x94"


def test_stream_tare_and_rate(cell):
    tension = Tension(1.0)
    fake, bus = cell(tension)
    lc = CanLoadCell(bus, cal_of(fake), stale_timeout=0.5)  # (a stalled process is not a dead cell)
    assert isinstance(lc, ForceSensor)
    got = collect(lc, 250)  # 0.5 s on an idle machine
    assert all(s.force == pytest.approx(1.0, abs=3e-3) for s in got)
    assert all(b.t >= a.t for a, b in zip(got, got[1:]))
    # 500 Hz on the device's clock: 2 ms between conversions (a late thread bunches a few;
    # the achieved rate in wall time is a benchmark figure)
    dt = [b.t - a.t for a, b in zip(got, got[1:])]
    assert lc.rate_hz == 500 and statistics.median(dt) == pytest.approx(0.002, abs=0.5e-3)
    lc.tare(conversions=16)
    tension.value = 2.0
    t0 = time.monotonic()
    wait_for(lambda: lc.read().t > t0, "a sample converted after the change")
    assert lc.read().force == pytest.approx(1.0, abs=3e-3)
    with pytest.raises(LoadCellCommandError, match="bad argument"):
        lc.set_rate(5000)
    st = lc.stats()
    assert st.problems() == 0 and st.samples >= len(got)
    lc.close()


def test_gaps_longer_than_the_7_bit_sequence_are_counted_exactly(cell):
    fake, bus = cell(Tension(0.5))
    lc = CanLoadCell(bus, cal_of(fake), stale_timeout=2.0)
    wait_for(lambda: lc.stats().samples >= 5, "samples before the gap")
    fake.inject("skip", 300)  # 0.6 s of silence, more than two wraps of seq mod 128
    wait_for(lambda: fake.injected.get("skip") == 300, "the skipped frames")
    seq = fake.model.seq
    wait_for(lambda: fake.model.seq >= seq + 10, "good frames after the gap")  # then a separate fault
    fake.inject("swap")
    wait_for(lambda: lc.stats().out_of_order >= 1, "the swapped pair")
    st = lc.stats()
    assert (st.gaps, st.out_of_order) == (2, 1)
    assert st.lost == 300 + 1  # the late frame of the swap was first counted missing
    seqs = [s.seq for s in lc.samples()]
    assert len(seqs) == st.samples
    lc.close()


def test_silent_cell_raises_disconnected_once_the_timeout_has_passed(cell):
    received = []  # host time at which the reader took each sample in (the driver's clock)
    fake, bus = cell(Tension(0.5))
    # 250 ms, not the default 50: the fake cell runs in this process, and a stall of the
    # whole process on a loaded machine must not silence it before the test does
    lc = CanLoadCell(bus, cal_of(fake), stale_timeout=0.25, on_sample=lambda s, rx: received.append(rx))
    wait_for(lambda: received, "a first sample")
    lc.read()
    fake.unplug()
    with pytest.raises(LoadCellDisconnected, match="no sample") as exc:
        for _ in itertools.count():
            lc.read()
            assert time.monotonic() - received[-1] < 30.0, "never stale"
            time.sleep(0.0005)
    silent = time.monotonic() - received[-1]
    # Not before the timeout, by the driver's own count and by ours; after it, within the
    # reader's next look (every 5 ms) plus 0.5 s for it to get the CPU on a loaded machine.
    assert int(re.search(r"no sample for (\d+) ms", str(exc.value))[1]) >= 250
    assert lc.stale_timeout < silent < lc.stale_timeout + 0.005 + 0.5
    lc.close()
