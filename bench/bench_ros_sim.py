"""Achieved measured_js rate of `rig sim`, as a subscriber in another process sees it.

Starts `rig sim` (own ROS_DOMAIN_ID, localhost discovery), subscribes to every arm's
measured_js with a best-effort QoS for `--seconds` (default 10 s) and prints a table:
messages per second per arm, the largest gap between two messages, and the gap
percentiles, against the 1 kHz target and the 50 ms watchdog. Targets: each arm's
measured_js published at >= 98 % of `--rate` (rig sim's own count, its "held" criterion),
and no gap a subscriber sees as long as the driver's stale-data watchdog (which would stop
a run). The share a best-effort Python subscriber receives is reported: on a loaded
2-core machine it is the subscriber's limit as much as the server's.

    .venv/bin/python bench/bench_ros_sim.py [--seconds 10] [--arms PSM1,PSM2]
"""

from __future__ import annotations

import argparse
import inspect
import os
import re
import signal
import subprocess
import sys
import threading
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _table import print_table  # noqa: E402

from drivers.arm.dvrk_arm import RosArm  # noqa: E402

#: RosArm's default stale-data watchdog, s.
WATCHDOG = inspect.signature(RosArm).parameters["watchdog"].default


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--arms", default="PSM1,PSM2")
    ap.add_argument("--rate", type=float, default=1000.0)
    args = ap.parse_args()
    os.environ["ROS_DOMAIN_ID"] = str(100 + os.getpid() % 100)
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    proc = subprocess.Popen([sys.executable, "-m", "rig.cli", "sim", "--arms", args.arms,
                             "--rate", str(args.rate), "--ros-period", str(1.0 / args.rate),
                             "--duration", str(args.seconds + 30)],
                            stdout=subprocess.PIPE, text=True)
    for line in proc.stdout:
        if line.strip() == "ready":
            break
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import JointState

    ctx = Context()
    rclpy.init(context=ctx)
    node = rclpy.create_node("bench_ros_sim", context=ctx)
    arrivals: dict[str, list[float]] = {a: [] for a in args.arms.split(",")}
    recording = threading.Event()

    def cb_for(arm):
        def cb(_msg):
            if recording.is_set():
                arrivals[arm].append(time.monotonic())
        return cb

    qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT)
    for a in arrivals:
        node.create_subscription(JointState, f"/{a}/measured_js", cb_for(a), qos)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    th = threading.Thread(target=ex.spin, daemon=True)
    th.start()
    time.sleep(2.0)  # discovery and warm-up
    recording.set()
    t0 = time.monotonic()
    time.sleep(args.seconds)
    recording.clear()
    wall = time.monotonic() - t0
    proc.send_signal(signal.SIGINT)
    tail = proc.communicate(timeout=10)[0]
    ex.shutdown()
    node.destroy_node()
    rclpy.shutdown(context=ctx)
    said = tail.strip().splitlines()[-1] if tail.strip() else "(nothing)"
    print("rig sim says:", said)
    published = {m[1]: float(m[2]) for m in re.finditer(r"(\w+) ([\d.]+) Hz", said.split("(target")[0])}
    rows = []
    for a, ts in arrivals.items():
        gaps = np.diff(ts) if len(ts) > 1 else np.array([np.inf])
        pub = published.get(a, float("nan"))
        rows += [(f"{a} measured_js published by rig sim [Hz]", f"{pub:.1f}", f">= {0.98 * args.rate:.0f}",
                  bool(pub >= 0.98 * args.rate)),
                 (f"{a} received by a best-effort subscriber in another process [msgs/s]", f"{len(ts) / wall:.1f}",
                  "report", True),
                 (f"{a} largest gap between messages [ms] (p99 {1e3 * np.percentile(gaps, 99):.2f})",
                  f"{1e3 * gaps.max():.2f}", f"< {1e3 * WATCHDOG:.0f} (watchdog)", bool(gaps.max() < WATCHDOG))]
    ok = print_table(f"rig sim over ROS 2 ({args.seconds:.0f} s, {args.arms}, loopback)", rows)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
