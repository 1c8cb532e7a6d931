"""A library's ROS 2 session outliving a SIGKILLed `rig sim`: its participant deleted or parked (issue 44).

Each run: a fresh `rig sim` (built-in rig, `--ros-period 0.001`) on a claimed ROS domain; a
library process (drivers.common.ros_session.RosSession, as a test or a notebook uses it) subscribes
to every stream rig sim publishes; once they flow, rig sim is SIGKILLed after a random 0-0.3 s, and the
session is closed after a further random 0-1.5 s (the listener must first find the dead
peer's port broken: that is the state in which Fast DDS 2.14's shared-memory teardown
crashed, drivers/common/ros_exit.py). A run is clean when the library process printed "closed"
and exited 0 (its interpreter's end included); a crash is a death by a signal the process
raises itself (SIGSEGV, SIGBUS, SIGABRT), counted apart from one sent from outside.

Ways (`--ways`, comma-separated):
  destroy  the library's teardown before issue 44: stop the executors, destroy the nodes,
           shut the context down (the participant is deleted)
  park     `RosSession.close()` now: the participant parked past the interpreter's end
           (drivers/common/ros_exit.py)
A third way, a transport that cannot crash (UDP only), could not be measured: with
ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST rmw_fastrtps 8.4 maps shared memory whatever
FASTDDS_BUILTIN_TRANSPORTS=UDPv4 or a default XML profile (userTransports UDPv4 on
127.0.0.1, useBuiltinTransports false) say (checked in /proc/self/maps), and a library on
ROS_AUTOMATIC_DISCOVERY_RANGE=OFF with ROS_STATIC_PEERS=127.0.0.1 and UDPv4 received nothing
from rig sim in 60 s (nor from a peer set up the same way in 25 s); UDP alone works only
with discovery by multicast on the LAN, which no test may use.

Before the kill, each run measures over `--window` s the library's CPU share, rig sim's,
and the age of each measured_js sample on arrival (receive time minus header stamp; rig
sim stamps in wall time) as median and p99: the two ways share the transport, so these
only show that the runs were alike.

Measured on the 2-core machine loaded 3-18 by others' work (2026-11-29). Round 1, subscribed
to both arms' measured_js and measured_cp, 40 runs each: destroy 1 crash (SIGSEGV in
destroy_node), park 0 (parking then did not yet end the process ahead of the C++ static
destructors). Then a trial with every stream (110) subscribed: the parked session died of
SIGSEGV after its interpreter's end (no Python stack: Fast DDS's participant factory
deleting what was parked), so a library's process now ends ahead of those destructors
(drivers/common/ros_exit.py). Round 2, every stream, 40 runs each: destroy 0, park 0 (one run
ended by a SIGTERM from outside), and 6 more park runs 0. Round 3, every stream, 30 runs
each: destroy 0, park 0. In all: destroyed 1 crash in 110 runs; parked as now 0 in 75. The crash is rare (a kill must land in a write into
this process's port): these counts bound it, they do not measure it well.

    .venv/bin/python bench/bench_session_kill.py [--runs 40] [--ways destroy,park] [--burners 0]
"""

from __future__ import annotations

import argparse
import json
import os
import random
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(REPO))
from _table import print_table  # noqa: E402

from tests.ros_domains import claim_domain  # noqa: E402

#: the library process: a session, both arms' streams, "streaming" once they flow, its
#: measurements as one JSON line, then close() when told
LIBRARY = r"""
import json, os, sys, time
import numpy as np
from drivers.common.ros_session import RosSession
from sensor_msgs.msg import JointState

window = float(sys.argv[1])
session = RosSession("kill_probe")
ages, count = [], [0]
def on_js(msg):
    count[0] += 1
    ages.append(time.time() - (msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec))
# every stream rig sim publishes (raw bytes: the reader costs little), so that its writes into
# this process's port are many and a kill lands in one the more often
deadline = time.monotonic() + 60
while not any(name == "/PSM2/measured_js" for name, _ in session.node.get_topic_names_and_types()):
    if time.monotonic() > deadline:
        print("no stream", flush=True)
        sys.exit(5)
    time.sleep(0.05)
time.sleep(0.5)  # the other topics are announced with it
import importlib
def get_message(kind):  # "pkg/msg/Type"
    pkg, _, typ = kind.split("/")
    return getattr(importlib.import_module(f"{pkg}.msg"), typ)
for name, types in session.node.get_topic_names_and_types():
    if name.endswith("/measured_js") and name.count("/") == 2:
        session.node.create_subscription(JointState, name, on_js, 100)
    elif name not in ("/rosout", "/parameter_events") and "/" in name[1:]:
        session.node.create_subscription(get_message(types[0]), name, lambda m: None, 100, raw=True)
session.start()
deadline = time.monotonic() + 60
while count[0] < 200:
    if time.monotonic() > deadline:
        print("no stream", flush=True)
        sys.exit(5)
    time.sleep(0.01)
ages.clear()
t0, c0 = time.monotonic(), time.process_time()
time.sleep(window)
cpu = (time.process_time() - c0) / (time.monotonic() - t0)
a = np.array(ages) * 1e3
print(json.dumps({"topics": len(list(session.node.subscriptions)), "cpu": cpu, "n": len(a), "age_med": float(np.median(a)), "age_p99": float(np.percentile(a, 99))}),
      flush=True)
print("streaming", flush=True)
sys.stdin.readline()
if sys.argv[2] == "destroy":  # the library teardown before issue 44: the participant deleted
    import rclpy
    assert session.stop()
    for node in (session.control, session.node):
        node.destroy_node()
    rclpy.shutdown(context=session.context)
else:
    session.close()
print("closed", flush=True)
"""


def _cpu_seconds(pid: int) -> float:
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _wait_line(proc, wanted: str, timeout: float) -> list[str]:
    lines, deadline = [], time.monotonic() + timeout
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        if not line:
            break
        lines.append(line.strip())
        if line.strip() == wanted:
            return lines
    raise RuntimeError(f"no {wanted!r}: {lines}")


def one_run(way: str, window: float, rng: random.Random, folder: Path) -> dict:
    with claim_domain() as domain:
        base = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
                    RIG_LOGS=str(folder / "logs"), PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]))
        base.pop("RIG_CONFIG", None)
        sim = subprocess.Popen([sys.executable, "-m", "rig.cli", "sim", "--duration", "120", "--ros-period", "0.001"],
                               cwd=folder, env=base, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                               stderr=subprocess.DEVNULL, text=True)
        lib = None
        try:
            _wait_line(sim, "ready", 90)
            lib = subprocess.Popen([sys.executable, "-c", LIBRARY, str(window), way], cwd=REPO, env=base, text=True,
                                   stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
            s0, t0 = _cpu_seconds(sim.pid), time.monotonic()
            lines = _wait_line(lib, "streaming", 120)
            stats = json.loads(next(ln for ln in lines if ln.startswith("{")))
            # rig sim's share over the library's start and window (its start-up included: a rough figure)
            stats["sim_cpu"] = (_cpu_seconds(sim.pid) - s0) / (time.monotonic() - t0)
            time.sleep(rng.uniform(0.0, 0.3))
            sim.send_signal(signal.SIGKILL)
            sim.wait()
            time.sleep(rng.uniform(0.0, 1.5))
            out, err = lib.communicate("close\n", timeout=120)
            stats.update(code=lib.returncode, closed="closed" in out.split(), err=err.strip().splitlines()[-3:])
            return stats
        finally:
            for p in (sim, lib):
                if p is not None and p.poll() is None:
                    p.kill()
                    p.wait()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=40, help="runs per way")
    ap.add_argument("--ways", default="destroy,park")
    ap.add_argument("--window", type=float, default=2.0, help="s of streaming measured before the kill")
    ap.add_argument("--burners", type=int, default=0, help="CPU-burning processes for the whole bench")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    rng = random.Random(args.seed)
    burners = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(args.burners)]
    results: dict[str, list[dict]] = {t: [] for t in args.ways.split(",")}
    try:
        with tempfile.TemporaryDirectory() as tmp:
            for i in range(args.runs):
                for way in results:  # interleaved: the machine's load falls on both alike
                    r = one_run(way, args.window, rng, Path(tmp))
                    results[way].append(r)
                    bad = "" if r["code"] == 0 and r["closed"] else f"  <- exit {r['code']} {r['err']}"
                    print(f"run {i + 1} {way}: exit {r['code']}, cpu {r['cpu']:.2f}, sim {r['sim_cpu']:.2f}, "
                          f"age {r['age_med']:.1f}/{r['age_p99']:.1f} ms, {r.get('topics', '?')} streams{bad}", flush=True)
    finally:
        for b in burners:
            b.kill()
    import numpy as np

    rows = []
    for way, rs in results.items():
        # a crash is a signal the process raises itself; SIGTERM or SIGKILL came from outside
        crashes = sum(-r["code"] in (signal.SIGSEGV, signal.SIGBUS, signal.SIGABRT, signal.SIGILL) for r in rs)
        unclean = sum(not (r["code"] == 0 and r["closed"]) for r in rs)
        med = {k: float(np.median([r[k] for r in rs])) for k in ("cpu", "sim_cpu", "age_med", "age_p99")}
        rows.append((f"{way}: crashes (SIGSEGV, SIGBUS, SIGABRT)", f"{crashes} of {len(rs)}", "0", crashes == 0))
        rows.append((f"{way}: not closed cleanly", f"{unclean} of {len(rs)}", "0", unclean == 0))
        rows.append((f"{way}: library CPU share (median)", f"{med['cpu']:.3f}", "-", True))
        rows.append((f"{way}: rig sim CPU share (median)", f"{med['sim_cpu']:.3f}", "-", True))
        rows.append((f"{way}: sample age median / p99 (median of runs)",
                     f"{med['age_med']:.2f} / {med['age_p99']:.2f} ms", "-", True))
    print_table(f"a library session outliving a SIGKILLed rig sim ({args.runs} runs per way, "
                f"{args.burners} burners)", rows)


if __name__ == "__main__":
    main()
