"""Achieved measured_js rate of `rig sim`, as a subscriber in another process sees it.

Starts `rig sim` (own ROS_DOMAIN_ID, localhost discovery), subscribes to every arm's
measured_js with a best-effort QoS for `--seconds` (default 10 s) and prints a table:
messages per second per arm, the largest gap between two messages, and the gap
percentiles, against the 1 kHz target and the 50 ms watchdog.

    .venv/bin/python bench/bench_ros_sim.py [--seconds 10] [--arms PSM1,PSM2]
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import threading
import time

import numpy as np


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--arms", default="PSM1,PSM2")
    ap.add_argument("--rate", type=float, default=1000.0)
    args = ap.parse_args()
    os.environ["ROS_DOMAIN_ID"] = str(100 + os.getpid() % 100)
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    proc = subprocess.Popen([sys.executable, "-m", "rig.cli", "sim", "--arms", args.arms,
                             "--rate", str(args.rate), "--duration", str(args.seconds + 30)],
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
    print(f"{'arm':>6} {'msgs/s':>9} {'target':>7} {'max gap ms':>11} {'p99 gap ms':>11} {'gaps>50ms':>10}")
    for a, ts in arrivals.items():
        gaps = np.diff(ts) * 1e3 if len(ts) > 1 else np.array([np.inf])
        print(f"{a:>6} {len(ts) / wall:9.1f} {args.rate:7.0f} {gaps.max():11.2f} "
              f"{np.percentile(gaps, 99):11.2f} {int(np.sum(gaps > 50)):10d}")
    print("rig sim says:", tail.strip().splitlines()[-1] if tail.strip() else "(nothing)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
