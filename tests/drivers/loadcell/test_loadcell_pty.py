"""The host driver against the firmware fake over a real pseudo-terminal, opened by pyserial.

The fake runs on a thread of this process, so on a loaded machine its conversions come
late and in bunches. The tests wait for what they need (samples, faults sent) instead of
sleeping for what an idle machine would deliver; the wall-time limits of those waits only
guard against a hang. Rates and latencies on an idle machine are bench/bench_loadcell.py's.
"""

from __future__ import annotations

import re
import statistics
import time

import pytest
import serial

from drivers.loadcell.errors import LoadCellCommandError, LoadCellDisconnected
from drivers.loadcell.fake_firmware import FakeLoadCellFirmware
from drivers.loadcell.force_calibration import STANDARD_GRAVITY, LoadCellCalibration
from drivers.loadcell.protocol import ADC_HX711
from drivers.loadcell.serial_driver import LoadCell


class Tension:
    """A settable tension source (N), like the simulated object's spring."""

    def __init__(self, value: float = 0.0) -> None:
        self.value = value

    def __call__(self) -> float:
        return self.value


def truth_calibration(fake: FakeLoadCellFirmware) -> LoadCellCalibration:
    return LoadCellCalibration(newtons_per_count=1 / fake.model.gain, zero_counts=fake.model.offset)


@pytest.fixture
def rig():
    """(fake, open serial port) pairs; everything is unplugged and closed afterwards."""
    made = []

    def make(tension=None, **kw):
        fake = FakeLoadCellFirmware(tension or Tension(), **kw).start()
        port = serial.Serial(fake.port_path, baudrate=250000)
        made.append((fake, port))
        return fake, port

    yield make
    for fake, port in made:
        fake.unplug()
        port.close()


def wait_for(pred, what: str, timeout: float = 30.0) -> None:
    """Poll `pred` until true; the limit is a guard against a hang, not a figure."""
    end = time.monotonic() + timeout
    while not pred():
        assert time.monotonic() < end, f"timed out waiting for {what}"
        time.sleep(0.002)


def collect(lc: LoadCell, n: int) -> list:
    """At least `n` samples from now on (every one, in order)."""
    got = lc.samples()
    wait_for(lambda: got.extend(lc.samples()) or len(got) >= n, f"{n} samples")
    return got


def fresh(lc: LoadCell, timeout: float = 30.0):
    """The first sample converted after this call (s.t is the conversion time)."""
    wait_for(lambda: lc.stats().samples > 0, "a first sample")
    t0 = time.monotonic()
    while time.monotonic() < t0 + timeout:
        s = lc.read()
        if s.t > t0:
            return s
        time.sleep(0.001)
    raise AssertionError("no fresh sample")


def exchange(port: serial.Serial, sent: bytes, n_reply: int) -> bytes:
    port.reset_input_buffer()
    port.write(sent)
    port.timeout = 5.0  # read() returns once n_reply bytes are in; the limit guards a hang
    return port.read(n_reply)


def hx(s: str) -> bytes:
    return bytes.fromhex(s.replace(" ", ""))


def test_fake_answers_commands_and_errors_byte_for_byte(rig):
    fake, port = rig()
    pairs = [
        ("A5 5A 00 10 3E 0F", "A5 5A 07 90 01 01 00 00 01 E8 03 65 0A"),  # IDENTIFY
        ("A5 5A 02 12 F4 01 8F 8B", "A5 5A 02 92 F4 01 D5 B0"),  # SET_RATE 500
        ("A5 5A 02 12 00 00 AB 44", "A5 5A 02 FF 12 03 B9 F3"),  # SET_RATE 0: bad argument
        ("A5 5A 00 42 89 75", "A5 5A 02 FF 42 01 44 DD"),  # unknown command
        ("A5 5A 00 15 9B A0", "A5 5A 02 FF 15 02 0F 7A"),  # bad CRC
        ("A5 5A 01 12 05 18 CE", "A5 5A 02 FF 12 04 5E 83"),  # bad length
        ("A5 5A 00 14 BA 4F", "A5 5A 00 94 32 DE"),  # STOP
    ]
    for sent, reply in pairs:
        assert exchange(port, hx(sent), len(hx(reply))) == hx(reply), sent
    # a command that stops half-way is answered after 50 ms
    assert exchange(port, hx("A5 5A 02 12 F4"), 8) == hx("A5 5A 02 FF 12 06 1C A3")
    # two tares at once: the second is refused, the first answers with the mean counts
    port.write(hx("A5 5A 01 11 40 2A 83") * 2)
    port.timeout = 10.0
    busy, tare = port.read(8), port.read(11)
    assert busy == hx("A5 5A 02 FF 11 05 2C C6")
    assert tare[:4] == hx("A5 5A 05 91") and int.from_bytes(tare[4:8], "little", signed=True) == 137
    assert fake.model.rx_errors == 4  # unknown, bad CRC, bad length, incomplete (not argument/busy)
    assert not fake.model.streaming


def test_samples_arrive_at_500_hz_with_mapped_times(rig):
    fake, port = rig(Tension(2.0), record_write_times=True)
    lc = LoadCell(port, truth_calibration(fake), stale_timeout=0.5)
    assert lc.rate_hz == 500 and fake.model.rate_hz == 500  # the device was set to 500 Hz
    wait_for(lambda: lc.stats().samples >= 500, "500 samples")  # 1 s on an idle machine
    lc.stop()  # everything sent before the STOP reply has been received
    got = lc.samples()
    assert len(got) == fake.frames_sent  # every sample the device sent, once, in order
    assert [s.seq for s in got] == list(range(got[0].seq, got[0].seq + len(got)))
    assert all(b.t >= a.t for a, b in zip(got, got[1:]))
    # 500 Hz on the device's clock: conversions 2 ms apart, except where the fake's thread,
    # late on a loaded machine, caught up with a bunch (the achieved rate in wall time is
    # bench/bench_loadcell.py's figure)
    times = list(fake.sample_times.values())
    assert statistics.median(b - a for a, b in zip(times, times[1:])) == pytest.approx(0.002, abs=0.5e-3)
    # the mapped time is the fake's conversion time (host clock), to within a millisecond
    err = [abs(s.t - fake.sample_times[s.seq]) for s in got[100:]]
    assert statistics.median(err) < 0.5e-3 and max(err) < 5e-3
    assert all(s.force == pytest.approx(2.0, abs=2e-3) for s in got)  # quantisation 3 mN
    st = lc.stats()
    assert st.problems() == 0 and st.samples == len(got)
    lc.close()


def test_two_point_calibration_recovers_the_true_gain(rig):
    tension = Tension(0.0)
    fake, port = rig(tension, noise=0.02, seed=4)
    lc = LoadCell(port, None, stale_timeout=0.5)
    m1, m2 = 0.0, 0.5
    c1 = lc.collect_counts(0.4)
    tension.value = m2 * STANDARD_GRAVITY
    # Settle, as an operator does after hanging the mass: collect_counts selects samples by
    # their mapped conversion time, which runs late by the shortest delivery delay seen
    # (ms, more on a loaded machine), so a sample converted just before the change could
    # fall into a window opened at once (one such sample shifts the gain by 0.5 %).
    time.sleep(0.1)
    c2 = lc.collect_counts(0.4)
    sem = lambda c: statistics.stdev(c) / len(c) ** 0.5  # noqa: E731
    cal = LoadCellCalibration.from_two_points(m1, statistics.fmean(c1), m2, statistics.fmean(c2), sem(c1), sem(c2))
    assert cal.newtons_per_count == pytest.approx(1 / fake.model.gain, rel=3e-3)
    assert abs(cal.newtons_per_count - 1 / fake.model.gain) < 4 * cal.newtons_per_count_std + 1e-6
    lc.calibration = cal
    tension.value = 3.0
    time.sleep(0.1)  # settle (see above)
    forces = [cal.newtons(c) for c in lc.collect_counts(0.3)]
    assert statistics.fmean(forces) == pytest.approx(3.0, abs=0.01)
    assert statistics.stdev(forces) == pytest.approx(0.02, rel=0.25)  # the fake's noise, N rms
    lc.close()


def test_tare_zeroes_the_present_load(rig):
    tension = Tension(1.0)
    fake, port = rig(tension)
    lc = LoadCell(port, truth_calibration(fake), stale_timeout=0.5)
    assert fresh(lc).force == pytest.approx(1.0, abs=3e-3)
    lc.tare(conversions=32)
    assert fresh(lc).force == pytest.approx(0.0, abs=3e-3)
    tension.value = 2.5
    assert fresh(lc).force == pytest.approx(1.5, abs=3e-3)
    lc.close()


def test_unplug_raises_disconnected_from_the_port(rig):
    # A stale timeout far longer than the test, so only the closed port can raise
    # ("disconnected"; silence would say "no sample for ..."). On an idle machine this
    # takes a few ms (bench/bench_loadcell.py: < 100 ms); the bound leaves the reader
    # (which looks every 5 ms) up to 1 s to get the CPU, and fails a driver that waits
    # for the stale timeout.
    fake, port = rig(Tension(1.0))
    lc = LoadCell(port, truth_calibration(fake), stale_timeout=10.0)
    wait_for(lambda: lc.stats().samples >= 40, "40 samples")
    lc.read()
    fake.unplug()  # returns once the pty is closed
    # Found from the port (its closed pty), not from the silence: the stale timeout is 10 s
    # and a stale stream reads "no sample for ...". How fast is bench_loadcell's row.
    with pytest.raises(LoadCellDisconnected, match="disconnected") as exc:
        for _ in range(200_000):  # a guard against a hang, not a time bound
            lc.read()
            time.sleep(0.0005)
        pytest.fail("the unplug was never noticed")
    assert "no sample for" not in str(exc.value)
    st = lc.stats()
    assert st.samples >= 40 and st.lost == 0
    lc.close()


def test_silent_device_is_stale_once_the_timeout_has_passed(rig):
    received = []  # host time at which the reader took each sample in (the driver's clock)
    fake, port = rig(Tension(1.0))
    # 250 ms, not the default 50: the fake device runs in this process, and a stall of the
    # whole process on a loaded machine must not silence it before the test does
    lc = LoadCell(port, truth_calibration(fake), stale_timeout=0.25,
                  on_sample=lambda s, rx: received.append(rx))
    fresh(lc)
    wait_for(lambda: received, "on_sample")
    fake.inject("skip", 100_000)  # the firmware keeps counting but sends nothing
    with pytest.raises(LoadCellDisconnected, match="stale timeout 250 ms") as exc:
        while True:
            lc.read()
            assert time.monotonic() - received[-1] < 30.0, "never stale"
            time.sleep(0.0005)
    silent = time.monotonic() - received[-1]
    # Not before the timeout, by the driver's own count and by ours; after it, within the
    # reader's next look (every 5 ms) plus 0.5 s for it to get the CPU on a loaded machine.
    assert int(re.search(r"no sample for (\d+) ms", str(exc.value))[1]) >= 250
    assert lc.stale_timeout < silent < lc.stale_timeout + 0.005 + 0.5
    lc.close()


def test_injected_faults_are_each_counted(rig):
    fake, port = rig(Tension(1.0), seed=2)
    lc = LoadCell(port, truth_calibration(fake), stale_timeout=0.5)
    fresh(lc)

    for kind, n in [("crc", 5), ("truncate", 3), ("garbage", 4), ("skip", 6), ("swap", 2)]:
        fake.inject(kind, n)
        wait_for(lambda: fake.injected.get(kind, 0) == n, f"{n} {kind} faults to be sent")
        seq = fake.model.seq  # then 30 conversions (60 ms) of good frames before the next kind
        wait_for(lambda: fake.model.seq >= seq + 30, "30 more conversions")
    fake.corrupt_probability = 0.05
    wait_for(lambda: fake.injected["crc"] - 5 > 3, "random CRC faults")
    fake.corrupt_probability = 0.0
    seq = fake.model.seq
    wait_for(lambda: lc.read().seq > seq, "a good frame after the last fault")  # every gap is closed
    st = lc.stats()
    random_crc = fake.injected["crc"] - 5
    assert random_crc > 3
    assert st.crc_errors == fake.injected["crc"]
    assert st.truncated == 3
    assert st.resyncs == 4
    assert st.out_of_order == 2  # each swapped pair delivers its late frame out of order
    # lost = skipped + corrupt + truncated + the two late frames counted as gaps first
    assert st.lost == 6 + fake.injected["crc"] + 3 + 2
    lc.read()  # still healthy
    lc.close()


def test_saturation_is_flagged_and_clipped(rig):
    tension = Tension(1.0)
    fake, port = rig(tension, adc_limits=(-1000, 1000))
    lc = LoadCell(port, truth_calibration(fake), stale_timeout=0.5)
    fresh(lc)
    tension.value = 10.0  # 137 + 3277 counts, past the 1000-count limit
    s = fresh(lc)
    assert s.raw == 1000
    wait_for(lambda: lc.stats().saturated > 10, "saturated samples")
    lc.close()


def test_drift_and_noise_are_settable(rig):
    fake, port = rig(Tension(0.0), seed=5)
    lc = LoadCell(port, truth_calibration(fake), stale_timeout=0.5)
    fake.drift = 10.0  # N/s, since the fake started
    got = collect(lc, 150)[10:]  # 0.3 s on an idle machine
    slope = (got[-1].force - got[0].force) / (got[-1].t - got[0].t)
    assert slope == pytest.approx(10.0, rel=0.05)
    fake.noise = 0.05
    fake.drift = 0.0
    fresh(lc)  # converted after the change
    lc.samples()
    assert statistics.stdev(s.force for s in collect(lc, 150)) == pytest.approx(0.05, rel=0.25)
    lc.close()


def test_micros_wraparound_keeps_sample_times_continuous(rig):
    fake, port = rig(Tension(0.5), micros_start=2**32 - 200_000, record_write_times=True)  # wraps 0.2 s in
    lc = LoadCell(port, truth_calibration(fake), stale_timeout=0.5)
    wait_for(lambda: 100_000 < fake.model.micros() < 2**31, "the device clock to wrap")  # 0.3 s in
    got = collect(lc, 1)
    wait_for(lambda: fake.model.seq > got[-1].seq + 10, "conversions after the wrap")
    got += collect(lc, 10)
    dt = [b.t - a.t for a, b in zip(got, got[1:])]
    # a wrong unwrap would jump by 71.6 minutes or run backwards; a thread late on a loaded
    # machine leaves gaps of a fraction of a second at most
    assert len(got) > 20 and max(dt) < 1.0 and min(dt) >= 0
    # the mapped times follow the device's true conversion times across the wrap
    # (to within the mapping's error: the shortest delivery delay seen so far, which is ms
    # on an idle machine and can be tens of ms on a loaded one; a wrong wrap is 71.6 min)
    truth = fake.sample_times
    assert got[-1].t - got[10].t == pytest.approx(truth[got[-1].seq] - truth[got[10].seq], abs=0.05)
    lc.close()


def test_hx711_build_refuses_500_hz(rig):
    fake, port = rig(Tension(0.5), adc=ADC_HX711, max_rate_hz=80)
    with pytest.raises(Exception, match="allows 80 Hz"):
        LoadCell(port, truth_calibration(fake), rate_hz=500)
    lc = LoadCell(port, truth_calibration(fake), rate_hz=80, stale_timeout=0.5)
    with pytest.raises(LoadCellCommandError, match="bad argument"):
        lc.set_rate(81)
    got = collect(lc, 20)
    # 80 Hz on the device's clock: 12.5 ms between conversions (a late thread bunches a few)
    dt = [b.t - a.t for a, b in zip(got, got[1:])]
    assert lc.rate_hz == 80 and statistics.median(dt) == pytest.approx(1 / 80, abs=1e-3)
    lc.close()


def test_calibrate_command_on_the_simulated_cell_is_found_by_later_runs(tmp_path, monkeypatch):
    import json

    from click.testing import CliRunner

    from rig.devices.loadcell_calibrations import load_latest_calibration
    from procedures.loadcell_calibrate import command

    monkeypatch.setenv("RIG_LOGS", str(tmp_path))
    res = CliRunner().invoke(command, ["--mass2", "0.5", "--seconds", "0.3", "--json"])
    assert res.exit_code == 0, res.output
    result = json.loads(res.stdout)
    assert result["status"] == "completed"
    assert abs(result["truth"]["gain_error_rel"]) < 2e-3
    assert abs(result["check"]["error_n"]) < 0.01  # N, with 5 mN rms noise
    cal = load_latest_calibration()
    assert cal.newtons_per_count == result["calibration"]["newtons_per_count"]
    assert (tmp_path / next(tmp_path.iterdir()).name / "result.json").exists()
