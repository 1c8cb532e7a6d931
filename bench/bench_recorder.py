"""Recorder benchmark: the rig's full stream load for 60 s of simulated time, flat out.

Streams (issue 3): three PSMs' measured_js at 1 kHz (7 joints each, as the dVRK PSM
publishes them), the load cell at 500 Hz (WrenchStamped, force.x = tension), and four
mocap rigid bodies at 120 Hz (PoseStamped). Samples are generated in time order and
handed to the Recorder as fast as it accepts them; the file is then read back and every
channel counted.

Figures:
- samples lost = generated - read back (target 0);
- throughput headroom = samples/s achieved (first write to a finished, closed file)
  divided by the samples/s the rig needs (target >= 10);
- per-call latency of the recorder methods while flat out, for information (the writer
  thread competes for the GIL, so the worst call waits up to a few switch intervals);
- at real rates for --paced-seconds of wall time: the recording cost per 1 ms tick, which
  is what a 1 kHz control loop pays, for information (on a shared machine the worst tick
  includes the OS descheduling either thread for a time slice);
- mcap_ros2's own encoder rate, for information: why rig.runs.ros_messages exists.

Run: .venv/bin/python bench/bench_recorder.py [--seconds 60] [--keep DIR]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from rig.runs.recording import Recorder, read_recording

ARMS = ("PSM1", "PSM2", "PSM3")
JOINTS = 7
ARM_HZ, LOADCELL_HZ, MOCAP_HZ = 1000, 500, 120
BODIES = ("PSM1_base", "PSM1_tool", "PSM2_base", "PSM2_tool")
NAMES = tuple(f"joint_{k}" for k in range(1, JOINTS + 1))


def schedule(seconds: float) -> list[tuple[int, str, int]]:
    """(t_ns, stream, index) for every sample of every stream, in time order."""
    events = []
    for hz, streams in ((ARM_HZ, ARMS), (LOADCELL_HZ, ("loadcell",)), (MOCAP_HZ, BODIES)):
        period_ns = 1_000_000_000 // hz if 1_000_000_000 % hz == 0 else None
        n = int(round(seconds * hz))
        for stream in streams:
            for i in range(n):
                t_ns = i * period_ns if period_ns else (i * 1_000_000_000) // hz
                events.append((t_ns, stream, i))
    events.sort()
    return events


def run(seconds: float, folder: Path) -> dict:
    rng = np.random.default_rng(1)
    n_arm = int(round(seconds * ARM_HZ))
    # Device-like data, made beforehand so the figure is the recorder's, not the generator's.
    q = {arm: rng.normal(size=(n_arm, JOINTS)) for arm in ARMS}
    tension = rng.normal(5.0, 0.1, size=int(round(seconds * LOADCELL_HZ)))
    n_mocap = int(round(seconds * MOCAP_HZ))
    positions = {b: rng.normal(size=(n_mocap, 3)) for b in BODIES}
    quats = {b: (lambda x: x / np.linalg.norm(x, axis=1, keepdims=True))(rng.normal(size=(n_mocap, 4)))
             for b in BODIES}
    events = schedule(seconds)
    generated = {f"/{a}/measured_js": n_arm for a in ARMS}
    generated["/loadcell/force"] = len(tension)
    generated.update({f"/mocap/{b}/pose": n_mocap for b in BODIES})
    assert sum(generated.values()) == len(events)

    path = folder / "run.mcap"
    rec = Recorder(path)
    rec.start("bench-recorder", parameters={"seconds": seconds}, seed=1)
    topics = {a: f"/{a}/measured_js" for a in ARMS}
    topics.update({b: f"/mocap/{b}/pose" for b in BODIES})
    topics["loadcell"] = "/loadcell/force"
    call_ns = np.empty(len(events), dtype=np.int64)
    clock = time.perf_counter_ns
    began = time.perf_counter()
    for k, (t_ns, stream, i) in enumerate(events):
        t = t_ns * 1e-9
        c0 = clock()
        if stream in q:
            row = q[stream][i]
            rec.joint_state(topics[stream], t, row, row, row, NAMES)
        elif stream == "loadcell":
            rec.tension("/loadcell/force", t, tension[i])
        else:
            rec.pose(topics[stream], t, positions[stream][i], quats[stream][i], "mocap")
        call_ns[k] = clock() - c0
    produced = time.perf_counter()
    stop = rec.close("completed")
    finished = time.perf_counter()

    back = read_recording(path, decode=False)
    read_back = back.counts()
    total_generated = len(events)
    total_back = sum(read_back.values())
    lost = sum(max(0, generated[t] - read_back.get(t, 0)) for t in generated)
    needed = ARM_HZ * len(ARMS) + LOADCELL_HZ + MOCAP_HZ * len(BODIES)
    achieved = total_generated / (finished - began)
    return {
        "generated": total_generated, "read_back": total_back, "lost": lost,
        "per_channel_ok": all(read_back.get(t) == n for t, n in generated.items())
        and stop["counts"] == read_back,
        "needed_per_s": needed, "achieved_per_s": achieved, "headroom": achieved / needed,
        "producer_per_s": total_generated / (produced - began),
        "drain_s": finished - produced, "wall_s": finished - began,
        "call_p50_us": float(np.percentile(call_ns, 50)) / 1e3,
        "call_p999_us": float(np.percentile(call_ns, 99.9)) / 1e3,
        "call_max_us": float(call_ns.max()) / 1e3,
        "overflow_events": stop["overflow"]["events"], "max_queue": stop["overflow"]["max_queue"],
        "file_mb": path.stat().st_size / 1e6, "finalised": back.finalised,
    }


def paced(seconds: float, folder: Path) -> np.ndarray:
    """Cost (us) per 1 ms tick of recording the same streams at their real rates.

    What a 1 kHz control loop pays for recording while the writer thread compresses and
    writes in the background; the loop waits for each tick on the wall clock.
    """
    rec = Recorder(folder / "paced.mcap")
    row = np.random.default_rng(3).normal(size=JOINTS)
    ticks = int(seconds * ARM_HZ)
    cost = np.empty(ticks)
    began = time.perf_counter()
    for k in range(ticks):
        wait = began + k / ARM_HZ - time.perf_counter()
        if wait > 0:  # sleep like a paced loop does; the writer thread works meanwhile
            time.sleep(wait)
        t = k / ARM_HZ
        c0 = time.perf_counter_ns()
        for arm in ARMS:
            rec.joint_state(f"/{arm}/measured_js", t, row, row, row, NAMES)
        if k % (ARM_HZ // LOADCELL_HZ) == 0:
            rec.tension("/loadcell/force", t, 5.0)
        if (k * MOCAP_HZ) // ARM_HZ != ((k - 1) * MOCAP_HZ) // ARM_HZ:
            for body in BODIES:
                rec.pose(f"/mocap/{body}/pose", t, (0.0, 0.0, 0.1), (0.0, 0.0, 0.0, 1.0))
        cost[k] = (time.perf_counter_ns() - c0) / 1e3
    rec.close()
    return cost


def mcap_ros2_encoder_rate(n: int = 5000) -> float:
    """JointState messages/s through mcap_ros2's dynamic encoder (for comparison)."""
    from mcap_ros2._dynamic import serialize_dynamic

    from rig.runs import ros_messages as rm

    encode = serialize_dynamic(rm.JOINT_STATE, rm.DEFINITIONS[rm.JOINT_STATE])[rm.JOINT_STATE]
    row = np.random.default_rng(2).normal(size=JOINTS)
    began = time.perf_counter()
    for i in range(n):
        encode({"header": {"stamp": {"sec": i // 1000, "nanosec": (i % 1000) * 1_000_000}, "frame_id": ""},
                "name": list(NAMES), "position": row.tolist(), "velocity": row.tolist(),
                "effort": row.tolist()})
    return n / (time.perf_counter() - began)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0, help="simulated seconds of streams [s]")
    parser.add_argument("--paced-seconds", type=float, default=5.0,
                        help="wall-clock seconds of the real-rate run for the per-tick cost [s]")
    parser.add_argument("--keep", type=Path, default=None, help="folder to keep run.mcap in")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.keep or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        r = run(args.seconds, folder)
        tick = paced(args.paced_seconds, folder)
    ref = mcap_ros2_encoder_rate()

    rows = [
        ("samples generated", f"{r['generated']}", "", None),
        ("samples read back", f"{r['read_back']}", f"{r['generated']}", r["read_back"] == r["generated"]),
        ("samples lost", f"{r['lost']}", "0", r["lost"] == 0),
        ("per-channel counts match (file, run_stop)", str(r["per_channel_ok"]), "True", r["per_channel_ok"]),
        ("file finalised (footer, summary)", str(r["finalised"]), "True", r["finalised"]),
        ("samples/s needed", f"{r['needed_per_s']}", "", None),
        ("samples/s achieved (to closed file)", f"{r['achieved_per_s']:.0f}", "", None),
        ("throughput headroom", f"{r['headroom']:.1f}x", ">= 10x", r["headroom"] >= 10),
        ("producer calls/s", f"{r['producer_per_s']:.0f}", "", None),
        ("drain + finish after last call", f"{r['drain_s']:.2f} s", "", None),
        ("call latency p50 / p99.9 / max", f"{r['call_p50_us']:.1f} / {r['call_p999_us']:.1f} / "
                                           f"{r['call_max_us']:.0f} us", "", None),
        ("at real rates: recording cost per 1 ms tick p50 / p99.9", f"{np.percentile(tick, 50):.1f} / "
                                                                    f"{np.percentile(tick, 99.9):.1f} us", "", None),
        ("at real rates: worst tick cost", f"{tick.max():.0f} us", "", None),
        ("queue overflow events (caller waited)", f"{r['overflow_events']}", "", None),
        ("max queue depth", f"{r['max_queue']}", "", None),
        ("file size", f"{r['file_mb']:.1f} MB", "", None),
        ("mcap_ros2 encoder alone, JointState/s", f"{ref:.0f}", "", None),
        ("  (headroom if it encoded every sample)", f"<= {ref / r['needed_per_s']:.1f}x", "", None),
    ]
    print(f"recorder benchmark: {len(ARMS)} arms x {JOINTS} joints measured_js at {ARM_HZ} Hz, "
          f"load cell at {LOADCELL_HZ} Hz, {len(BODIES)} mocap bodies at {MOCAP_HZ} Hz, "
          f"{args.seconds:g} s simulated, zstd chunks ({sys.platform}, Python {sys.version.split()[0]}, "
          f"{os.cpu_count()} CPUs)")
    w = max(len(x[0]) for x in rows)
    print(f"{'figure'.ljust(w)}  {'value':>24}  {'target':>8}  result")
    for name, value, target, ok in rows:
        verdict = "" if ok is None else ("pass" if ok else "FAIL")
        print(f"{name.ljust(w)}  {value:>24}  {target:>8}  {verdict}")
    failed = [name for name, _, _, ok in rows if ok is False]
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
