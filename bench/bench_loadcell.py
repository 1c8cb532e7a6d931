"""Load-cell path benchmark: firmware fake on a pty -> pyserial -> LoadCell at 500 Hz.

    .venv/bin/python bench/bench_loadcell.py [--seconds 60] [--rate 500]

Prints a table of figures against their targets (issue 3: zero frames lost; latency from
the fake's write to the driver's sample, median < 2 ms; a silent or unplugged cell
reported within 100 ms, serial and CAN, which the unit tests check only as "after the
timeout" and "before a generous bound") and exits non-zero if any fails.
The fake runs in a child process. Latency uses a side channel: the fake records time.monotonic() right after each frame's
write to the pty (by sequence number), the driver's `on_sample` hook records
time.monotonic() when the reader thread has decoded it. The fake also records each
sample's true conversion time, which checks the driver's device-to-host time mapping.
"""

from __future__ import annotations

import multiprocessing
import os
import sys
import time
from pathlib import Path

import click
import serial

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from drivers.loadcell.can import CanLoadCell  # noqa: E402
from drivers.loadcell.fake_can_firmware import FakeCanLoadCellFirmware  # noqa: E402
from drivers.loadcell.errors import LoadCellError  # noqa: E402
from drivers.loadcell.fake_firmware import FakeLoadCellFirmware  # noqa: E402
from drivers.loadcell.force_calibration import LoadCellCalibration  # noqa: E402
from drivers.loadcell.serial_driver import LoadCell  # noqa: E402


def pct(values: list[float], q: float) -> float:
    if not values:
        return float("nan")
    s = sorted(values)
    return s[min(len(s) - 1, int(q * len(s)))]


def run_fake(conn, rate_hz: int) -> None:
    """The device side, in its own process as the Arduino is its own machine (and so the
    fake's thread and the driver's reader do not share one interpreter lock)."""
    fake = FakeLoadCellFirmware(lambda: 2.0, record_write_times=True, noise=0.005, rate_hz=rate_hz).start()
    conn.send((fake.port_path, fake.model.gain, fake.model.offset))
    conn.recv()  # the host is done
    fake.unplug()
    conn.send((fake.write_times, fake.sample_times, fake.model.tx_dropped))


def _wait(pred, timeout: float = 10.0) -> None:
    end = time.monotonic() + timeout
    while not pred():
        if time.monotonic() > end:
            raise RuntimeError("timed out")
        time.sleep(0.002)


def _until_error(lc) -> LoadCellError:
    """Poll like a procedure's loop until the driver raises; the error."""
    end = time.monotonic() + 10.0
    while time.monotonic() < end:
        try:
            lc.read()
        except LoadCellError as exc:
            return exc
        time.sleep(0.0005)
    raise RuntimeError("the driver never raised")


def detection_ms(repeats: int) -> dict[str, list[float]]:
    """ms until the driver raises, with the fakes in this process (as in the unit tests):
    silence (default 50 ms stale timeout) from the last sample taken in; unplug (the
    stale timeout out of the way) from the moment the pty is closed; CAN silence."""
    out: dict[str, list[float]] = {"stale": [], "unplug": [], "can_stale": []}
    for k in range(repeats):
        fake = FakeLoadCellFirmware(lambda: 1.0).start()
        port = serial.Serial(fake.port_path, baudrate=250000)
        cal = LoadCellCalibration(newtons_per_count=1 / fake.model.gain, zero_counts=fake.model.offset)
        last: list[float] = []
        lc = LoadCell(port, cal, on_sample=lambda s, rx: last.append(rx))
        _wait(lambda: len(last) >= 20)
        fake.inject("skip", 100_000)  # the firmware keeps converting, sends nothing
        _until_error(lc)
        out["stale"].append((time.monotonic() - last[-1]) * 1e3)
        lc.close()
        fake.unplug()
        port.close()

        fake = FakeLoadCellFirmware(lambda: 1.0).start()
        port = serial.Serial(fake.port_path, baudrate=250000)
        lc = LoadCell(port, cal, stale_timeout=10.0)
        _wait(lambda: lc.stats().samples >= 20)
        fake.unplug()
        t0 = time.monotonic()
        _until_error(lc)
        out["unplug"].append((time.monotonic() - t0) * 1e3)
        lc.close()
        port.close()

        channel = f"bench-loadcell-{os.getpid()}-{k}"
        cfake = FakeCanLoadCellFirmware(lambda: 1.0, channel=channel).start()
        import can
        bus = can.Bus(interface="virtual", channel=channel)
        last = []
        clc = CanLoadCell(bus, cal, on_sample=lambda s, rx: last.append(rx))
        _wait(lambda: len(last) >= 20)
        cfake.unplug()
        _until_error(clc)
        out["can_stale"].append((time.monotonic() - last[-1]) * 1e3)
        clc.close()
        bus.shutdown()
    return out


@click.command()
@click.option("--seconds", type=float, default=60.0, show_default=True, help="Streaming time (s).")
@click.option("--rate", "rate_hz", type=int, default=500, show_default=True, help="Sample rate (Hz).")
@click.option("--repeats", type=int, default=5, show_default=True,
              help="Repeats of each fault-detection figure (the worst is the figure).")
def main(seconds: float, rate_hz: int, repeats: int) -> None:
    load0 = os.getloadavg()[0]
    ctx = multiprocessing.get_context("fork")
    conn, child_conn = ctx.Pipe()
    child = ctx.Process(target=run_fake, args=(child_conn, rate_hz), daemon=True)
    child.start()
    port_path, gain, offset = conn.recv()
    port = serial.Serial(port_path, baudrate=250000)
    rx: dict[int, float] = {}
    mapped: dict[int, float] = {}

    def on_sample(sample, rx_time):
        rx[sample.seq] = time.monotonic()  # CLOCK_MONOTONIC: the same clock in both processes
        mapped[sample.seq] = sample.t

    cal = LoadCellCalibration(newtons_per_count=1 / gain, zero_counts=offset)
    lc = LoadCell(port, cal, rate_hz=rate_hz, on_sample=on_sample)
    t0 = time.monotonic()
    n_read = 0
    error = None
    while time.monotonic() - t0 < seconds:  # a consumer, like a procedure's loop
        time.sleep(0.01)
        try:
            n_read += len(lc.samples())
            lc.read()
        except LoadCellError as exc:  # a stale stream ends the run, as it would a procedure
            error = exc
            break
    elapsed = time.monotonic() - t0
    if error is None:
        lc.stop()
        time.sleep(0.05)
        n_read += len(lc.samples())
    st = lc.stats()
    lc.close()
    port.close()
    conn.send("stop")
    write_times, sample_times, tx_dropped = conn.recv()
    child.join(timeout=5)

    sent = write_times
    lost = len(set(sent) - set(rx)) + tx_dropped
    lat = [(rx[s] - sent[s]) * 1e3 for s in sent if s in rx]
    map_err = [abs(mapped[s] - sample_times[s]) * 1e3 for s in mapped if s in sample_times][rate_hz:]
    achieved = len(rx) / elapsed
    det = detection_ms(repeats)
    rows = [
        # (figure, value, unit, target, pass)
        ("duration", f"{elapsed:.1f}", "s", f"{seconds:g}", error is None),
        ("stale / disconnect errors", "0" if error is None else "1", "", "0", error is None),
        ("frames written by the fake", f"{len(sent)}", "", "", True),
        ("samples received by the driver", f"{len(rx)}", "", "", True),
        ("samples handed to the consumer", f"{n_read}", "", f"= {len(rx)}", n_read == len(rx)),
        ("frames lost", f"{lost}", "", "0", lost == 0),
        ("CRC errors + truncated + resyncs", f"{st.crc_errors + st.truncated + st.resyncs}", "", "0",
         st.crc_errors + st.truncated + st.resyncs == 0),
        ("sequence gaps / out of order", f"{st.gaps} / {st.out_of_order}", "", "0 / 0",
         st.gaps == 0 and st.out_of_order == 0),
        ("achieved rate", f"{achieved:.1f}", "Hz", f"{rate_hz} +- 1 %", abs(achieved / rate_hz - 1) < 0.01),
        ("latency write -> sample, median", f"{pct(lat, 0.5):.3f}", "ms", "< 2", pct(lat, 0.5) < 2),
        ("latency write -> sample, p99", f"{pct(lat, 0.99):.3f}", "ms", "(report)", True),
        ("latency write -> sample, max", f"{pct(lat, 1.0):.3f}", "ms", "< 50 (stale timeout)", pct(lat, 1.0) < 50),
        ("sample time error (mapped - true), median", f"{pct(map_err, 0.5):.3f}", "ms", "< 1",
         pct(map_err, 0.5) < 1),
        ("sample time error, p99", f"{pct(map_err, 0.99):.3f}", "ms", "(report)", True),
        (f"silent cell -> stale error, from last sample, worst of {repeats}", f"{max(det['stale']):.1f}", "ms",
         "< 100 (timeout 50)", max(det["stale"]) < 100),
        (f"unplug -> disconnected error, worst of {repeats}", f"{max(det['unplug']):.1f}", "ms", "< 100",
         max(det["unplug"]) < 100),
        (f"CAN: silent cell -> stale error, worst of {repeats}", f"{max(det['can_stale']):.1f}", "ms",
         "< 100 (timeout 50)", max(det["can_stale"]) < 100),
    ]
    w = max(len(r[0]) for r in rows)
    print(f"load-cell path: pty fake -> pyserial -> LoadCell, {rate_hz} Hz, {seconds:g} s "
          f"(load average before/after {load0:.2f}/{os.getloadavg()[0]:.2f})")
    if error is not None:
        print(f"stopped early: {error}")
    print(f"{'figure':<{w}}  {'value':>14}  {'unit':<4}  {'target':<22}  result")
    for name, value, unit, target, ok in rows:
        print(f"{name:<{w}}  {value:>14}  {unit:<4}  {target:<22}  {'pass' if ok else 'FAIL'}")
    sys.exit(0 if all(r[4] for r in rows) else 1)


if __name__ == "__main__":
    main()
