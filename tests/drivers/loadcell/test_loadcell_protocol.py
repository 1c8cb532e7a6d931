"""Byte-level tests of the load-cell protocol and host driver (no pty, no threads of the fake).

The driver talks to `ExpectedProtocolPort`, a pyserial stand-in holding (bytes the host
must write, bytes the device answers) pairs in order; a write that differs, or a pair left
unused, fails the test.
"""

from __future__ import annotations

import binascii
import json
import random
import re
import struct
import threading
import time
from collections import deque
from pathlib import Path

import pytest

from drivers.interfaces import ForceSensor
from drivers.loadcell.errors import LoadCellCommandError, LoadCellDisconnected, LoadCellNotCalibrated
from drivers.loadcell.force_calibration import LoadCellCalibration
from drivers.loadcell.frame_parser import FrameParser
from drivers.loadcell.protocol import (CMD_IDENTIFY, CMD_SET_RATE, RawSample, crc16_ccitt_false, decode_sample,
                                       encode_frame, sample_frame)
from drivers.loadcell.serial_driver import LoadCell
from drivers.loadcell.stream_tracking import ClockMapper, SequenceTracker
from rig.devices.loadcell_calibrations import load_latest_calibration

DOC = Path(__file__).resolve().parents[3] / "drivers" / "LOADCELL_PROTOCOL.md"


def hx(s: str) -> bytes:
    return bytes.fromhex(s.replace(" ", ""))


# the exchanges of a session, written out from LOADCELL_PROTOCOL.md's examples
IDENTIFY = hx("A5 5A 00 10 3E 0F")
IDENTITY_INA = hx("A5 5A 07 90 01 01 00 00 01 E8 03 65 0A")
SET_RATE_500 = hx("A5 5A 02 12 F4 01 8F 8B")
RATE_500 = hx("A5 5A 02 92 F4 01 D5 B0")
START, STARTED = hx("A5 5A 00 13 5D 3F"), hx("A5 5A 00 93 D5 AE")
STOP, STOPPED = hx("A5 5A 00 14 BA 4F"), hx("A5 5A 00 94 32 DE")
TARE_64 = hx("A5 5A 01 11 40 2A 83")
TARE_REPLY = hx("A5 5A 05 91 2E FB FF FF 40 7B C1")  # mean -1234
SET_RATE_0 = hx("A5 5A 02 12 00 00 AB 44")
ERR_BAD_ARG_RATE = hx("A5 5A 02 FF 12 03 B9 F3")
OPENING = [(IDENTIFY, IDENTITY_INA), (SET_RATE_500, RATE_500), (START, STARTED)]


class ExpectedProtocolPort:
    """A pyserial-like port that plays the device from a list of (sent, replied) pairs.

    A pair whose `sent` is None is output the device produces by itself (samples): it is
    released as soon as every earlier pair has been used.
    """

    def __init__(self, pairs) -> None:
        self._pairs = deque(pairs)
        self._rx = bytearray()
        self._cond = threading.Condition()
        self.timeout = None
        self.port = "expected-protocol"
        self.errors: list[str] = []
        self.dead = False
        self._release()

    def _release(self) -> None:
        while self._pairs and self._pairs[0][0] is None:
            self._rx += self._pairs.popleft()[1]

    def write(self, data: bytes) -> int:
        with self._cond:
            if not self._pairs:
                self.errors.append(f"unexpected write {data.hex(' ')}")
                raise AssertionError(self.errors[-1])
            sent, reply = self._pairs[0]
            if bytes(data) != sent:
                self.errors.append(f"wrote {bytes(data).hex(' ')}, expected {sent.hex(' ')}")
                raise AssertionError(self.errors[-1])
            self._pairs.popleft()
            self._rx += reply
            self._release()
            self._cond.notify_all()
        return len(data)

    @property
    def in_waiting(self) -> int:
        if self.dead and not self._rx:
            raise OSError(5, "Input/output error")
        return len(self._rx)

    def read(self, n: int = 1) -> bytes:
        with self._cond:
            if not self._rx:
                if self.dead:
                    raise OSError(5, "Input/output error")
                self._cond.wait(self.timeout if self.timeout is not None else 1.0)
            out = bytes(self._rx[:n])
            del self._rx[:n]
            return out

    def drained(self) -> bool:
        with self._cond:
            return not self._rx

    def assert_done(self) -> None:
        assert not self.errors, self.errors
        assert not self._pairs, f"unused pairs: {[(s and s.hex(' '), r.hex(' ')) for s, r in self._pairs]}"


def wait_for(pred, timeout=30.0) -> None:  # a guard against a hang, not a figure
    end = time.monotonic() + timeout
    while not pred():
        assert time.monotonic() < end, "timed out"
        time.sleep(0.002)


def frames(first_seq: int, n: int, counts: int = 1000, t0_us: int = 0, period_us: int = 2000) -> bytes:
    return b"".join(sample_frame(RawSample(first_seq + i, t0_us + (first_seq + i) * period_us, counts))
                    for i in range(n))


CAL = LoadCellCalibration(newtons_per_count=0.01, zero_counts=100.0)


# ----------------------------------------------------------------- CRC and framing

def test_crc16_ccitt_false_known_answers():
    assert crc16_ccitt_false(b"123456789") == 0x29B1
    assert crc16_ccitt_false(b"") == 0xFFFF
    assert crc16_ccitt_false(b"\x00\x10") == 0x0F3E  # the IDENTIFY frame's CRC (3E 0F on the wire)
    rng = random.Random(1)
    for _ in range(200):  # binascii.crc_hqx is an independent CCITT implementation
        data = bytes(rng.randrange(256) for _ in range(rng.randrange(40)))
        assert crc16_ccitt_false(data) == binascii.crc_hqx(data, 0xFFFF)


def test_encoders_match_the_documented_bytes():
    assert encode_frame(CMD_IDENTIFY) == IDENTIFY
    assert encode_frame(CMD_SET_RATE, struct.pack("<H", 500)) == SET_RATE_500
    assert sample_frame(RawSample(258, 0x01020304, -1000)) == hx(
        "A5 5A 0D 01 02 01 00 00 04 03 02 01 18 FC FF FF 00 57 C5")
    assert decode_sample(hx("02 01 00 00 04 03 02 01 18 FC FF FF 00")) == RawSample(258, 0x01020304, -1000, 0)


def test_every_serial_example_in_the_protocol_document_is_a_valid_frame():
    text = DOC.read_text()
    examples = re.findall(r"`(A5 5A(?: [0-9A-F]{2})+)`", text)
    assert len(examples) >= 20
    bad_crc = {"A5 5A 00 15 9B A0"}  # documented as the frame with a bad CRC
    incomplete = {"A5 5A 02 12 F4"}  # documented as a command that stops half-way
    for ex in examples:
        p = FrameParser()
        got = p.feed(hx(ex))
        if ex in bad_crc:
            assert (got, p.crc_errors) == ([], 1), ex
        elif ex in incomplete:
            assert (got, p.pending) == ([], 5), ex
        else:
            assert len(got) == 1 and p.pending == 0 and p.crc_errors == 0, ex


# ----------------------------------------------------------------- parser counters

def test_parser_resyncs_after_garbage_and_counts_each_fault_once():
    good = [sample_frame(RawSample(i, i * 2000, i)) for i in range(6)]
    corrupt = bytearray(good[1])
    corrupt[9] ^= 0x04
    truncated = good[3][:11]
    stream = (b"\x00\xff\x13\xa5\x00" + good[0] + bytes(corrupt) + good[2] + truncated + good[4]
              + b"\xa5\x5a\x40\x01" + good[5])
    p = FrameParser()
    out = p.feed(stream)
    assert [decode_sample(f.payload).seq for f in out] == [0, 2, 4, 5]
    assert (p.frames, p.crc_errors, p.truncated, p.bad_length) == (4, 1, 1, 1)
    assert p.resyncs == 2  # the leading garbage, and the bytes after the bogus LEN 0x40
    assert p.pending == 0


def test_parser_gives_the_same_result_fed_byte_by_byte():
    rng = random.Random(7)
    chunks = []
    for i in range(300):
        f = bytearray(sample_frame(RawSample(i, i, rng.randrange(-9000, 9000))))
        r = rng.random()
        if r < 0.05:
            f[rng.randrange(2, len(f))] ^= 1 << rng.randrange(8)
        elif r < 0.08:
            f = f[:rng.randrange(5, len(f) - 1)]
        elif r < 0.1:
            chunks.append(bytes(rng.randrange(256) for _ in range(rng.randrange(1, 9))))
        chunks.append(bytes(f))
    stream = b"".join(chunks)
    whole, single = FrameParser(), FrameParser()
    a = whole.feed(stream)
    b = [f for byte in stream for f in single.feed(bytes((byte,)))]
    assert a == b
    keys = ("frames", "crc_errors", "truncated", "bad_length", "resyncs", "bytes_discarded")
    assert [getattr(whole, k) for k in keys] == [getattr(single, k) for k in keys]
    assert whole.frames > 250


def _spliced_frame_whose_crc_passes() -> tuple[bytes, bytes]:
    """A cut sample frame and its successor such that the cut frame's CRC, read over the
    successor's first bytes, passes (found by search: it happens once in 65536)."""
    for seq in range(1, 1 << 20):
        cut = sample_frame(RawSample(seq, seq * 2000, 464))[:9]  # header and seq survive
        nxt = sample_frame(RawSample(seq + 1, (seq + 1) * 2000, 464))
        spliced = cut + nxt
        end = spliced[2] + 6
        if crc16_ccitt_false(spliced[2:end - 2]) == spliced[end - 2] | spliced[end - 1] << 8:
            return cut, nxt
    raise AssertionError("no CRC collision found")


def test_a_cut_frame_whose_crc_passes_by_chance_is_still_counted_as_cut():
    cut, nxt = _spliced_frame_whose_crc_passes()
    after = sample_frame(RawSample(10**7, 0, 464))
    whole, single = FrameParser(), FrameParser()
    out = whole.feed(cut + nxt + after)
    assert out == [f for byte in cut + nxt + after for f in single.feed(bytes((byte,)))]
    seq_next = struct.unpack_from("<I", nxt, 4)[0]
    assert [decode_sample(f.payload).seq for f in out] == [seq_next, 10**7]
    assert (whole.truncated, whole.crc_errors, whole.resyncs) == (1, 0, 0)


def test_partial_frame_at_end_of_stream_counts_as_truncated():
    p = FrameParser()
    assert p.feed(sample_frame(RawSample(0, 0, 0))[:10]) == []
    assert p.pending == 10
    assert p.flush() == 10 and p.truncated == 1


def test_sequence_tracker_gaps_out_of_order_wrap_and_restart():
    t = SequenceTracker(32)
    for s in (5, 6, 9, 8, 9, 10):
        t.accept(s)
    assert (t.gaps, t.lost, t.out_of_order, t.last) == (1, 2, 2, 10)
    t = SequenceTracker(32)
    assert all(t.accept(s & 0xFFFFFFFF) for s in range(2**32 - 3, 2**32 + 3))
    assert (t.gaps, t.out_of_order) == (0, 0)
    t = SequenceTracker(32)
    for s in range(1000, 1010):
        t.accept(s)
    accepted = [t.accept(s) for s in range(0, 10)]  # the device rebooted
    assert accepted == [False] * 7 + [True] * 3
    assert (t.restarts, t.out_of_order, t.last) == (1, 0, 9)


def test_short_sequence_numbers_unfold_with_the_device_clock():
    t = SequenceTracker(7)
    t.accept(10)
    assert t.accept((10 + 301) % 128, elapsed_periods=301.2)  # 300 lost, > 2 wraps
    assert (t.gaps, t.lost) == (1, 300)
    assert not t.accept((10 + 300) % 128, elapsed_periods=-1.0)
    assert t.out_of_order == 1


def test_clock_mapper_unwraps_micros_and_follows_drift():
    rng = random.Random(3)
    m = ClockMapper()
    host0, ppm = 1000.0, 3000.0  # a resonator 0.3 % fast
    start_us = 2**32 - 1_000_000  # wraps after 1 s
    errors = []
    for i in range(5000):  # 10 s at 500 Hz
        true_t = host0 + i * 0.002
        t_us = int(start_us + i * 2000 * (1 + ppm * 1e-6)) & 0xFFFFFFFF
        delay = 0.0002 + rng.expovariate(1 / 0.0005)
        mapped = m.map(t_us, true_t + delay)
        if i > 1000:
            errors.append(abs(mapped - true_t))
    assert max(errors) < 0.001 and sorted(errors)[len(errors) // 2] < 0.0003


# ----------------------------------------------------------------- driver sessions

def test_session_bytes_samples_tare_and_close():
    stream = frames(0, 10, counts=600)
    port = ExpectedProtocolPort(OPENING + [(None, stream), (TARE_64, TARE_REPLY), (STOP, STOPPED)])
    lc = LoadCell(port, CAL, stale_timeout=10.0)
    assert isinstance(lc, ForceSensor)
    assert lc.identity.max_rate_hz == 1000 and lc.rate_hz == 500
    wait_for(lambda: lc.stats().samples == 10)
    got = lc.samples()
    assert [s.seq for s in got] == list(range(10))
    assert all(s.raw == 600 and s.force == pytest.approx(5.0) for s in got)
    # one burst, one arrival time: the mapping cannot yet tell delays apart, but never reverses
    assert all(b.t >= a.t for a, b in zip(got, got[1:]))
    lc.tare()  # the device says the present load is -1234 counts
    assert lc.calibration.newtons(-1234) == pytest.approx(0.0)
    assert lc.calibration.newtons(-1134) == pytest.approx(1.0)
    lc.close()
    port.assert_done()


def test_faulty_stream_is_counted_and_only_good_samples_delivered():
    f = [sample_frame(RawSample(i, i * 2000, 100 + i)) for i in range(12)]
    bad = bytearray(f[2])
    bad[12] ^= 0x80
    stream = (f[0] + f[1] + bytes(bad) + f[3] + f[4][:9] + f[5] + b"\x01\x02\x03" + f[6]
              + f[8] + f[7] + f[9] + f[9] + f[11])
    port = ExpectedProtocolPort(OPENING + [(None, stream), (STOP, STOPPED)])
    lc = LoadCell(port, CAL, stale_timeout=10.0)
    wait_for(port.drained)
    wait_for(lambda: lc.stats().samples == 8)
    st = lc.stats()
    assert [s.seq for s in lc.samples()] == [0, 1, 3, 5, 6, 8, 9, 11]
    assert (st.crc_errors, st.truncated, st.resyncs) == (1, 1, 1)
    assert (st.gaps, st.lost, st.out_of_order) == (4, 4, 2)  # lost 2, 4, 7, 10; late 7, repeated 9
    assert st.frames_ok == 3 + 10  # three replies, ten intact sample frames
    lc.close()
    port.assert_done()


def test_device_error_reply_raises_a_named_error():
    port = ExpectedProtocolPort([(IDENTIFY, IDENTITY_INA), (SET_RATE_0, ERR_BAD_ARG_RATE)])
    with pytest.raises(LoadCellCommandError, match="SET_RATE refused: bad argument"):
        LoadCell(port, CAL, rate_hz=0)
    port.assert_done()


def test_rate_above_the_firmware_maximum_is_refused_before_sending():
    hx711 = hx("A5 5A 07 90 01 01 00 00 00 50 00 92 9A")  # HX711 build, 80 Hz max
    port = ExpectedProtocolPort([(IDENTIFY, hx711)])
    with pytest.raises(Exception, match="80 Hz"):
        LoadCell(port, CAL, rate_hz=500)
    port.assert_done()


def test_port_failure_raises_disconnected_and_keeps_received_samples():
    port = ExpectedProtocolPort(OPENING + [(None, frames(0, 5))])
    lc = LoadCell(port, CAL, stale_timeout=10.0)
    wait_for(lambda: lc.stats().samples == 5)
    port.dead = True
    with pytest.raises(LoadCellDisconnected, match="disconnected: port read failed"):
        while True:
            lc.read()
            time.sleep(0.001)
    # Found by the reader's read of the port, not by the silence (the stale timeout is 10 s):
    # the port's failure names it ("... disconnected: port read failed"); a stale stream reads
    # "no sample for ..." and would not match. The time it takes is bench_loadcell's row.
    assert len(lc.samples()) == 5  # nothing received is lost
    with pytest.raises(LoadCellDisconnected):
        lc.samples()
    lc.close()
    port.assert_done()


class ManualClock:
    """Host seconds that only move when the test says so."""

    def __init__(self) -> None:
        self.t = 1000.0

    def __call__(self) -> float:
        return self.t


def test_stale_stream_raises_instead_of_returning_old_data():
    # On a clock of its own, so the test sets the silence exactly (a busy machine cannot
    # make fresh data look stale, or stale data fresh).
    port = ExpectedProtocolPort(OPENING + [(None, frames(0, 3))])
    clock = ManualClock()
    lc = LoadCell(port, CAL, stale_timeout=0.05, clock=clock)
    wait_for(lambda: lc.stats().samples == 3)
    assert lc.read().seq == 2
    clock.t += 0.05  # silent for exactly the stale timeout: still usable
    wait_for(lambda: lc.stream_age() == pytest.approx(0.05))  # the reader has looked since
    assert lc.read().seq == 2
    clock.t += 0.001
    wait_for(lambda: lc.stream_age() > 0.05)
    with pytest.raises(LoadCellDisconnected, match="stale timeout 50 ms"):
        lc.read()
    lc.close()  # the device is gone: no STOP is sent
    port.assert_done()


class HeldReaderPort(ExpectedProtocolPort):
    """As ExpectedProtocolPort, and `hold()` makes the reader's next wait for a byte last
    until `release()`: the reader thread that cannot run while the cell goes on sending."""

    def __init__(self, pairs) -> None:
        super().__init__(pairs)
        self._held = threading.Event()
        self._go = threading.Event()
        self.waiting = threading.Event()

    def hold(self) -> None:
        self._go.clear()
        self._held.set()

    def release(self) -> None:
        self._held.clear()
        self._go.set()

    def arrive(self, data: bytes) -> None:
        with self._cond:
            self._rx += data

    def read(self, n: int = 1) -> bytes:
        if self._held.is_set():
            self.waiting.set()
            self._go.wait(30.0)
        return super().read(n)


def test_a_reader_held_up_finds_the_waiting_samples_not_a_silent_cell():
    port = HeldReaderPort(OPENING + [(None, frames(0, 3)), (STOP, STOPPED)])
    clock = ManualClock()
    lc = LoadCell(port, CAL, stale_timeout=0.05, clock=clock)
    wait_for(lambda: lc.stats().samples == 3)
    port.hold()
    wait_for(port.waiting.is_set)  # the reader waits for a byte and cannot run
    port.arrive(frames(3, 100))  # the cell goes on sending meanwhile: 0.2 s of samples
    clock.t += 0.2
    port.release()
    wait_for(lambda: lc.stats().samples == 103)
    assert lc.read().seq == 102  # no stale error: the samples were there
    assert lc.stream_age() == 0.0
    lc.close()
    port.assert_done()


def test_no_calibration_means_no_newtons():
    port = ExpectedProtocolPort(OPENING + [(None, frames(0, 2)), (STOP, STOPPED)])
    lc = LoadCell(port, None, stale_timeout=10.0)
    wait_for(lambda: lc.stats().samples == 2)
    with pytest.raises(LoadCellNotCalibrated, match="loadcell-calibrate"):
        lc.read()
    assert [s.raw for s in lc.raw_samples()] == [1000, 1000]
    lc.close()
    port.assert_done()


# ----------------------------------------------------------------- calibration

def test_two_point_calibration_and_json_round_trip(tmp_path):
    g = 9.80665
    cal = LoadCellCalibration.from_two_points(0.0, 137.0, 0.5, 137.0 + 327.68 * 0.5 * g, 0.3, 0.3)
    assert cal.newtons_per_count == pytest.approx(1 / 327.68)
    assert cal.zero_counts == pytest.approx(137.0)
    assert cal.newtons(137.0 + 327.68 * 2.0) == pytest.approx(2.0)
    assert 0 < cal.newtons_per_count_std < 1e-3 * cal.newtons_per_count
    tared = cal.with_tare(200.0)
    assert tared.newtons(200.0) == 0.0 and tared.newtons(200 + 327.68) == pytest.approx(1.0)
    path = tmp_path / "cal.json"
    tared.save(path)
    assert LoadCellCalibration.load(path) == tared
    with pytest.raises(ValueError, match="check that the mass hangs"):
        LoadCellCalibration.from_two_points(0.0, 100.0, 0.5, 101.0)


def test_bad_calibration_files_name_the_file_and_field(tmp_path):
    p = tmp_path / "cal.json"
    p.write_text('{"newtons_per_count": 0.01,\n "zero_counts": ')
    with pytest.raises(LoadCellNotCalibrated, match=r"cal.json: line 2"):
        LoadCellCalibration.load(p)
    p.write_text(json.dumps({"newtons_per_count": float("nan"), "zero_counts": 1.0}))
    with pytest.raises(LoadCellNotCalibrated, match="newtons_per_count"):
        LoadCellCalibration.load(p)


def test_latest_calibration_is_found_from_the_runs(tmp_path, monkeypatch):
    from rig.runs.paths import run_dir_name

    monkeypatch.setenv("RIG_LOGS", str(tmp_path))
    with pytest.raises(LoadCellNotCalibrated, match="run `rig loadcell-calibrate` first"):
        load_latest_calibration()
    from datetime import datetime, timedelta, timezone

    now = datetime.now(timezone.utc)
    for i, (k, status) in enumerate([(0.01, "completed"), (0.02, "completed"), (0.03, "failed")]):
        run = tmp_path / run_dir_name("loadcell-calibrate", now + timedelta(seconds=i))
        run.mkdir()
        (run / "result.json").write_text(json.dumps(
            {"status": status, "calibration": LoadCellCalibration(k, 5.0).to_dict()}))
    assert load_latest_calibration().newtons_per_count == 0.02


def test_each_port_gets_the_calibration_made_on_it(tmp_path, monkeypatch):
    from datetime import datetime, timedelta, timezone

    from rig.runs.paths import run_dir_name

    monkeypatch.setenv("RIG_LOGS", str(tmp_path))
    now = datetime.now(timezone.utc)
    for i, (k, device) in enumerate([(0.01, "/dev/ttyACM0"), (0.02, "/dev/ttyACM1"), (0.03, "/dev/ttyACM0")]):
        run = tmp_path / run_dir_name("loadcell-calibrate", now + timedelta(seconds=i))
        run.mkdir()
        (run / "result.json").write_text(json.dumps(
            {"status": "completed", "calibration": LoadCellCalibration(k, 5.0, device=device).to_dict()}))
    assert load_latest_calibration("/dev/ttyACM1").newtons_per_count == 0.02
    assert load_latest_calibration("/dev/ttyACM0").newtons_per_count == 0.03
    # a port never calibrated: another cell's calibration is never taken; the error names
    # the port and the command
    with pytest.raises(LoadCellNotCalibrated, match="on /dev/ttyACM2.*--port /dev/ttyACM2"):
        load_latest_calibration("/dev/ttyACM2")


def test_a_calibration_edited_by_hand_or_of_another_usb_cell_is_not_taken(tmp_path, monkeypatch):
    """The sealed provenance of a calibration: a hand edit, or another cell (USB serial)
    now on the same port, makes the procedure refuse it and say why."""
    from datetime import datetime, timedelta, timezone

    import rig.devices.loadcell_calibrations as L
    from rig import sealed_json
    from rig.runs.paths import run_dir_name

    monkeypatch.setenv("RIG_LOGS", str(tmp_path))
    now = datetime.now(timezone.utc)
    old_run = tmp_path / run_dir_name("loadcell-calibrate", now)
    new_run = tmp_path / run_dir_name("loadcell-calibrate", now + timedelta(seconds=1))
    for run, k in ((old_run, 0.01), (new_run, 0.02)):
        run.mkdir()
        doc = {"status": "completed", "calibration": LoadCellCalibration(k, 5.0, device="/dev/ttyACM0").to_dict(),
               "provenance": {"cell": {"port": "/dev/ttyACM0", "usb_serial": "A1"}, "source": {"run": run.name}}}
        (run / "result.json").write_text(json.dumps(sealed_json.seal(doc)))
    monkeypatch.setattr(L, "usb_serial_number", lambda port: "A1")
    assert load_latest_calibration("/dev/ttyACM0").newtons_per_count == 0.02
    # the newest calibration's gain edited by hand: skipped, the older one taken
    doc = json.loads((new_run / "result.json").read_text())
    doc["calibration"]["newtons_per_count"] = 0.05
    (new_run / "result.json").write_text(json.dumps(doc))
    assert load_latest_calibration("/dev/ttyACM0").newtons_per_count == 0.01
    # another cell (serial B7) now on the port: neither calibration is of it
    monkeypatch.setattr(L, "usb_serial_number", lambda port: "B7")
    with pytest.raises(LoadCellNotCalibrated, match=r"edited after.*USB serial A1.*serial B7.*rig loadcell-calibrate"):
        load_latest_calibration("/dev/ttyACM0")


# ----------------------------------------------------------------- the sketch itself

SKETCH = Path(__file__).resolve().parents[3] / "drivers" / "firmware" / "loadcell" / "loadcell.ino"

ARDUINO_STUB = r"""
// host stand-in for the Arduino core: just enough to run the sketch's logic
#pragma once
#include <stdint.h>
#include <string.h>
#include <deque>
#include <vector>
#define HIGH 1
#define LOW 0
#define INPUT 0
#define OUTPUT 1
#define DEFAULT 1
#define A0 14
extern uint32_t fake_us;
extern int fake_analog;
extern uint8_t ADCSRA;
inline uint32_t micros() { return fake_us; }
inline void delay(unsigned long) {}
inline void delayMicroseconds(unsigned int) {}
inline int analogRead(uint8_t) { return fake_analog; }
inline void analogReference(uint8_t) {}
inline void pinMode(uint8_t, uint8_t) {}
inline void digitalWrite(uint8_t, uint8_t) {}
inline int digitalRead(uint8_t) { return HIGH; }
inline void noInterrupts() {}
inline void interrupts() {}
struct FakeSerial {
  std::deque<uint8_t> in;
  std::vector<uint8_t> out;
  void begin(unsigned long) {}
  int available() { return (int)in.size(); }
  int read() { int b = in.front(); in.pop_front(); return b; }
  int availableForWrite() { return 64; }
  size_t write(const uint8_t *b, size_t n) { out.insert(out.end(), b, b + n); return n; }
};
extern FakeSerial Serial;
"""

HARNESS = r"""
#include "Arduino.h"
uint32_t fake_us = 0; int fake_analog = 512; uint8_t ADCSRA = 0x87; FakeSerial Serial;
#include "loadcell.ino"
#include <cstdio>
#include <iostream>
#include <string>
// stdin lines: "w <hex>" bytes to the sketch; "t <us>" run loop() every 10 us for that long;
// "a <0..1023>" the analog reading. After each line, the sketch's output in hex.
int main() {
  setup();
  std::string op;
  while (std::cin >> op) {
    if (op == "w") {
      std::string hx; std::getline(std::cin, hx);
      for (size_t i = 0; i + 1 < hx.size();) {
        if (hx[i] == ' ') { i++; continue; }
        Serial.in.push_back((uint8_t)std::stoi(hx.substr(i, 2), nullptr, 16)); i += 2;
      }
      loop();
    } else if (op == "t") {
      long us; std::cin >> us;
      for (long k = 0; k < us; k += 10) { fake_us += 10; loop(); }
    } else if (op == "a") {
      std::cin >> fake_analog;
    }
    for (uint8_t b : Serial.out) std::printf("%02X", b);
    std::printf("\n");
    Serial.out.clear();
  }
}
"""


@pytest.fixture(scope="module")
def sketch_binary(tmp_path_factory):
    import shutil
    import subprocess

    cxx = shutil.which("g++") or shutil.which("clang++")
    if cxx is None:
        pytest.skip("no host C++ compiler to build the sketch with")
    d = tmp_path_factory.mktemp("sketch")
    (d / "Arduino.h").write_text(ARDUINO_STUB)
    (d / "harness.cpp").write_text(HARNESS)
    (d / "loadcell.ino").write_text(SKETCH.read_text())
    exe = d / "harness"
    res = subprocess.run([cxx, "-std=c++17", "-Wall", "-Wextra", "-Werror", "-I", str(d), "-x", "c++",
                          str(d / "harness.cpp"), "-o", str(exe)], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    return exe


def run_sketch(exe, script: list[str]) -> list[bytes]:
    import subprocess

    out = subprocess.run([str(exe)], input="\n".join(script) + "\n", capture_output=True, text=True,
                         timeout=10, check=True).stdout
    return [bytes.fromhex(line) for line in out.splitlines()]


def test_sketch_speaks_the_documented_protocol(sketch_binary):
    """The .ino compiled for the host against a stub core: the same bytes as the document."""
    pairs = [
        (IDENTIFY, IDENTITY_INA),
        (SET_RATE_500, RATE_500),
        (SET_RATE_0, ERR_BAD_ARG_RATE),
        (hx("A5 5A 00 42 89 75"), hx("A5 5A 02 FF 42 01 44 DD")),  # unknown command
        (hx("A5 5A 00 15 9B A0"), hx("A5 5A 02 FF 15 02 0F 7A")),  # bad CRC
        (hx("A5 5A 01 12 05 18 CE"), hx("A5 5A 02 FF 12 04 5E 83")),  # bad length
    ]
    script = [f"w {s.hex()}" for s, _ in pairs]
    script += ["w A55A0212F4", "t 60000"]  # a command cut short: incomplete after 50 ms
    script += ["w " + START.hex(), "a 700", "t 10000"]  # stream 10 ms at analog 700
    script += ["w " + (TARE_64.hex() * 2), "t 200000", "w " + STOP.hex(), "w A55A00159B5F"]
    out = run_sketch(sketch_binary, script)
    for (sent, reply), got in zip(pairs, out):
        assert got == reply, sent.hex(" ")
    assert out[6] == b"" and out[7] == hx("A5 5A 02 FF 12 06 1C A3")
    assert out[8] == STARTED
    p = FrameParser()
    samples = [decode_sample(f.payload) for f in p.feed(out[10])]
    assert p.crc_errors == p.truncated == p.resyncs == 0 and p.pending == 0
    assert len(samples) == 5  # 10 ms at 500 Hz
    assert [s.seq for s in samples] == [0, 1, 2, 3, 4]
    assert {s.counts for s in samples} == {16 * (700 - 512)}
    assert [b.t_us - a.t_us for a, b in zip(samples, samples[1:])] == [2000] * 4
    assert out[11] == hx("A5 5A 02 FF 11 05 2C C6")  # the second TARE: busy
    frames_after = p.feed(out[12])
    tare = [f for f in frames_after if f.type == 0x91]
    assert tare and struct.unpack("<iB", tare[0].payload) == (16 * 188, 64)
    assert out[13] == STOPPED
    status = p.feed(out[14])[0]
    assert struct.unpack("<HBHH", status.payload) == (500, 0, 4, 0)  # 4 rx errors, none dropped
