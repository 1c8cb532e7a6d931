"""NatNet path benchmark: the fake Motive (its own process) -> UDP loopback -> NatNetTracker.

    .venv/bin/python bench/bench_natnet.py [--seconds 20] [--rates 120,360]

For each mocap rate, a child process steps the simulated rig on the wall clock (1 kHz)
and streams it through `drivers.natnet.fake_motive.FakeMotiveOnWorld` (marker noise, 5 ms of camera
latency, 5 % occlusion) to a `drivers.natnet.tracker.NatNetTracker` in this process. Motive's
clock in the child is `time.monotonic()` (10 MHz ticks), the clock this process reads
too, and each frame's transmit stamp is taken when the frame is ready to go (as Motive
stamps it), just before it is encoded and sent:

* latency fake -> driver: the driver's receipt (after decoding, on its reader thread)
  minus the transmit stamp; median and p99 against one frame period (a frame decoded
  before the next is sent never queues);
* frames lost (sent by the fake, not decoded by the driver), decode errors;
* frame-time error: the driver's `TrackerFrame.t` (mid-exposure mapped onto the host's
  wall clock from receipts alone) minus the true capture time.

Prints a table of figures against their targets and exits non-zero if any fails.
"""

from __future__ import annotations

import multiprocessing
import os
import sys
import time
from pathlib import Path

import click

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench._table import print_table  # noqa: E402


def pct(values: list[float], q: float) -> float:
    if not values:
        return float("nan")
    s = sorted(values)
    return s[min(len(s) - 1, int(q * len(s)))]


def serve(conn, rate: float, seconds: float) -> None:
    """The Motive side: the simulated rig paced to the wall clock, streamed at `rate`."""
    from drivers.natnet.fake_motive import FakeMotiveOnWorld
    from rig.devices.clock import SimClock
    from rig.config import parse
    from rig.sim.world import world_from_config

    world = world_from_config(parse({}, "built-in simulated rig"), seed=0)
    clock = SimClock(world)
    clock.tick()  # the physics kernel loads on the first step
    sm = FakeMotiveOnWorld(world, clock, noise=0.00025, latency=0.005, occlusion=0.05, rate=rate, seed=1,
                           command_port=0, data_port=0, epoch=0.0).start()
    conn.send((sm.motive.command_port, sm.motive.data_port))
    while not sm.motive.clients:  # Motive streams to whoever connects
        clock.tick()
        sm.tracker.frames()
        time.sleep(0.001)
    mono0 = time.monotonic() - world.t  # the sim timeline on the monotonic clock
    t_end = world.t + seconds
    late = 0
    while world.t < t_end:
        clock.tick()
        sm.pump(mono0, sent=time.monotonic)  # stamped when each frame is ready to go
        ahead = mono0 + world.t - time.monotonic()
        if ahead > 0:
            time.sleep(ahead)
        else:
            late += 1
    sm.close()
    conn.send({"frames": sm.motive.stats.frames, "datagrams": sm.motive.stats.datagrams,
               "send_errors": sm.motive.stats.send_errors, "late_ticks": late})


def measure(rate: float, seconds: float) -> tuple[list, dict]:
    from drivers.natnet.tracker import NatNetTracker
    from drivers.natnet.udp import UdpTransport

    ctx = multiprocessing.get_context("spawn")
    here, there = ctx.Pipe()
    child = ctx.Process(target=serve, args=(there, rate, seconds), daemon=True)
    child.start()
    if not here.poll(120.0):
        raise RuntimeError("the fake Motive did not start")
    command_port, data_port = here.recv()
    wall_minus_mono = time.time() - time.monotonic()
    samples: list[tuple[float, int, int, float]] = []

    def on_frame(frame, rx_mono: float) -> None:
        samples.append((rx_mono, frame.transmit_ticks, frame.mid_exposure_ticks, frame.t))

    tracker = NatNetTracker(UdpTransport("127.0.0.1", command_port, data_port), stale_timeout=5.0,
                            on_frame=on_frame)
    tracker.connect(timeout=30.0)
    while not here.poll(0.1):
        tracker.frames()  # as a procedure's loop drains them
    child_stats = here.recv()
    child.join(timeout=30.0)
    end = time.monotonic() + 2.0
    while tracker.stats.frames + tracker.stats.before_handshake < child_stats["datagrams"] and time.monotonic() < end:
        time.sleep(0.01)
    tracker.frames()
    tracker.close()
    st = tracker.stats
    child_stats.update(received=st.frames, gaps=st.gaps, errors=st.truncated + st.trailing + st.malformed,
                       early=st.before_handshake, wall_minus_mono=wall_minus_mono)
    return samples, child_stats


@click.command()
@click.option("--seconds", type=float, default=20.0, show_default=True, help="Streaming time per rate (s).")
@click.option("--rates", default="120,360", show_default=True, help="Comma-separated mocap rates (Hz).")
def main(seconds: float, rates: str) -> None:
    rows = []
    load0 = os.getloadavg()[0]
    for rate in [float(r) for r in rates.split(",")]:
        samples, st = measure(rate, seconds)
        hz = 10_000_000
        lat = [(rx - tx / hz) * 1e3 for rx, tx, _, _ in samples]
        # true capture on the wall clock: the child's monotonic mid-exposure, shifted as this process sees it
        terr = [(t - (mid / hz + st["wall_minus_mono"])) * 1e3 for _, _, mid, t in samples]
        period = 1e3 / rate
        # frames that came before the model definitions cannot be named: counted, not lost
        lost = st["datagrams"] - st["received"] - st["early"]
        r = f"{rate:g} Hz"
        rows += [
            (f"{r}: frames sent / decoded (+ before the handshake)", f"{st['datagrams']} / {st['received']} "
             f"(+ {st['early']})", "equal", lost == 0 and st["datagrams"] > 0.9 * rate * seconds),
            (f"{r}: frames lost, gaps, decode errors", f"{lost}, {st['gaps']}, {st['errors']}", "0, 0, 0",
             lost == 0 and st["gaps"] == 0 and st["errors"] == 0),
            (f"{r}: latency fake -> driver, median", f"{pct(lat, 0.5):.3f} ms", "< 1 ms", pct(lat, 0.5) < 1.0),
            (f"{r}: latency fake -> driver, p99", f"{pct(lat, 0.99):.3f} ms", f"< {period:.2f} ms (1 frame)",
             pct(lat, 0.99) < period),
            (f"{r}: latency fake -> driver, max", f"{pct(lat, 1.0):.3f} ms", "(report)", True),
            (f"{r}: frame time - true capture, median", f"{pct(terr, 0.5):.3f} ms", "|x| < 0.5 ms",
             abs(pct(terr, 0.5)) < 0.5),
            (f"{r}: frame time - true capture, p99", f"{pct(terr, 0.99):.3f} ms", "|x| < 1 ms",
             abs(pct(terr, 0.99)) < 1.0),
            (f"{r}: fake's ticks behind the wall clock", f"{st['late_ticks']}", "(report)", True),
        ]
    ok = print_table(f"NatNet: fake Motive (own process) -> UDP loopback -> NatNetTracker, {seconds:g} s per rate "
                     f"(load average before/after {load0:.2f}/{os.getloadavg()[0]:.2f})", rows)
    sys.exit(0 if ok else 1)


if __name__ == "__main__":
    main()
