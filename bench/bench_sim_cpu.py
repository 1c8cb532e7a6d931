"""CPU share of `rig sim` (process CPU time / wall time), with and without a dVRK client subscribed.

For 2 arms (the default configuration) and 3 arms (`examples/three-arms.toml`), at
`--ros-period` 0.01, 0.002 and 0.001 s: `rig sim --duration S` is started on a private
ROS_DOMAIN_ID (the hand-run range 150-169, claimed as the tests claim theirs) with localhost
discovery; with a client, a second process subscribes right after 'ready' (reliable, depth
10, as crtk's ral does) to every stream and event the dVRK's Python client (`dvrk.psm`)
subscribes to, for every arm (`CLIENT_TOPICS`; `bench/probe_dvrk_client.py` lists them from
the client itself). rig sim's CPU time (utime + stime of every thread) from 'ready'
(/proc/<pid>/stat) to its exit (wait4's rusage) over the wall time between: the share (1.0
= one core). Also over the simulated time: on a loaded machine rig sim falls behind the
clock, and its share of the wall then says how much CPU it got more than what it needs.
The client reads raw bytes on rclpy's EventsExecutor and counts messages: its count per second of measured_js is
printed as a check that the streams reached it. Targets (issue 44): 2 arms at 0.002 s
with the client under 30 % of a core, 3 arms under 45 %.

    .venv/bin/python bench/bench_sim_cpu.py [--seconds 12] [--only 2@0.002] [--code CHECKOUT]
"""

from __future__ import annotations

import argparse
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "bench"))
from _table import print_table  # noqa: E402

#: what `dvrk.psm(ral, name)` subscribes to under /<arm> (dvrk/arm.py, dvrk/psm.py, crtk/utils.py)
CLIENT_TOPICS = ("measured_js", "setpoint_js", "measured_cp", "setpoint_cp", "measured_cv", "local/measured_cp",
                 "local/setpoint_cp", "body/measured_cf", "body/jacobian", "spatial/measured_cf",
                 "spatial/jacobian", "jaw/measured_js", "jaw/setpoint_js", "operating_state", "error", "warning",
                 "status", "trajectory_j/ratio")
CONFIGS = {2: None, 3: str(REPO / "examples" / "three-arms.toml")}
ARMS = {2: ("PSM1", "PSM2"), 3: ("PSM1", "PSM2", "PSM3")}
PERIODS = (0.01, 0.002, 0.001)
#: (arms, ros period) -> the share of a core not to exceed with the client subscribed
TARGETS = {(2, 0.002): 0.30, (3, 0.002): 0.45}
TICKS = os.sysconf("SC_CLK_TCK")


def cpu_seconds(pid: int) -> float:
    """utime + stime of a process (all its threads), s."""
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICKS


def client(arms: list[str]) -> int:
    """The subscriber process: every dVRK-client topic of `arms`, raw; prints measured_js counts on SIGTERM."""
    import importlib

    import rclpy
    from rclpy.qos import QoSProfile

    from drivers.common.ros_session import make_executor

    types = {"measured_cp": "geometry_msgs.msg.PoseStamped", "setpoint_cp": "geometry_msgs.msg.PoseStamped",
             "measured_cv": "geometry_msgs.msg.TwistStamped", "measured_cf": "geometry_msgs.msg.WrenchStamped",
             "jacobian": "std_msgs.msg.Float64MultiArray", "measured_js": "sensor_msgs.msg.JointState",
             "setpoint_js": "sensor_msgs.msg.JointState", "operating_state": "crtk_msgs.msg.OperatingState",
             "error": "std_msgs.msg.String", "warning": "std_msgs.msg.String", "status": "std_msgs.msg.String",
             "ratio": "std_msgs.msg.Float64"}

    def msg_type(topic):
        module, name = types[topic.rsplit("/", 1)[-1]].rsplit(".", 1)
        return getattr(importlib.import_module(module), name)

    rclpy.init()
    node = rclpy.create_node("bench_sim_cpu_client")
    counts = {a: 0 for a in arms}
    stop, mark = [], []
    signal.signal(signal.SIGTERM, lambda *_: stop.append(1))
    signal.signal(signal.SIGUSR1, lambda *_: mark.append((time.monotonic(), dict(counts))))

    def counter(arm):
        def cb(_raw):
            counts[arm] += 1
        return cb

    def ignore(_raw):
        pass

    qos = QoSProfile(depth=10)
    subs = [node.create_subscription(msg_type(topic), f"/{a}/{topic}",
                                     counter(a) if topic == "measured_js" else ignore, qos, raw=True)
            for a in arms for topic in CLIENT_TOPICS]
    ex = make_executor("events", node.context)  # the lightest reader: a client that keeps up
    ex.add_node(node)
    deadline = time.monotonic() + 60.0
    while any(s.get_publisher_count() == 0 for s in subs) and time.monotonic() < deadline:
        ex.spin_once(timeout_sec=0.05)  # every topic matched before the measurement starts
    print("subscribed", flush=True)
    while not stop:
        ex.spin_once(timeout_sec=0.05)
    if mark:
        t0, c0 = mark[0]
        dt = time.monotonic() - t0
        print(" ".join(f"{a}={(counts[a] - c0[a]) / dt:.1f}" for a in arms), flush=True)
    os._exit(0)  # noqa: SLF001 - no participant teardown (drivers/common/ros_exit.py says why)


def measure(n_arms: int, period: float, with_client: bool, seconds: float, env: dict, code: Path) -> dict:
    """Serve `seconds` of simulated time; rig sim's CPU from 'ready' to its exit over the wall and the simulated time."""
    argv = [sys.executable, "-m", "rig.cli"]
    if CONFIGS[n_arms]:
        argv += ["--config", CONFIGS[n_arms]]
    argv += ["sim", "--ros-period", str(period), "--duration", str(seconds)]
    sim = subprocess.Popen(argv, cwd=code, env=env, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    sub = None
    try:
        for line in sim.stdout:
            if line.strip() == "ready":
                break
        else:
            raise RuntimeError(f"rig sim ({n_arms} arms, --ros-period {period}) exited before 'ready'")
        cpu0, wall0 = cpu_seconds(sim.pid), time.monotonic()
        if with_client:
            sub = subprocess.Popen([sys.executable, __file__, "--client", ",".join(ARMS[n_arms])], cwd=REPO, env=env,
                                   stdout=subprocess.PIPE, text=True)
            sub.stdout.readline()  # "subscribed": every topic matched
            sub.send_signal(signal.SIGUSR1)
        rest = sim.stdout.read()
        _, status, usage = os.wait4(sim.pid, 0)
        sim.returncode = os.waitstatus_to_exitcode(status)
        wall = time.monotonic() - wall0
        cpu = usage.ru_utime + usage.ru_stime - cpu0
        simulated = re.search(r"([0-9.]+) s simulated in", rest)
        if simulated is None:
            raise RuntimeError(f"rig sim ({n_arms} arms, --ros-period {period}) said no simulated time at exit")
        received = ""
        if sub is not None:
            sub.send_signal(signal.SIGTERM)
            received = sub.communicate(timeout=30)[0].strip()
        return {"share": cpu / wall, "per_sim_s": cpu / float(simulated.group(1)),
                "realtime": float(simulated.group(1)) / wall, "received": received}
    finally:
        for p in (sub, sim):
            if p is not None and p.poll() is None:
                p.send_signal(signal.SIGINT if p is sim else signal.SIGTERM)
                try:
                    p.wait(timeout=15)
                except subprocess.TimeoutExpired:
                    p.kill()
                    p.wait()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=12.0, help="simulated time served per case (default 12)")
    ap.add_argument("--only", default=None, help="cases as ARMS@PERIOD, comma-separated (e.g. 2@0.002,3@0.002)")
    ap.add_argument("--code", type=Path, default=REPO, help="the checkout whose `rig sim` runs (default: this one)")
    ap.add_argument("--client", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.client:
        return client(args.client.split(","))

    from tests.ros_domains import claim_domain

    cases = [(n, p) for n in (2, 3) for p in PERIODS]
    if args.only:
        cases = [(int(c.split("@")[0]), float(c.split("@")[1])) for c in args.only.split(",")]
    with claim_domain(list(range(150, 170))) as domain:
        env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
                   PYTHONPATH=str(args.code.resolve()))
        rows = []
        for n, p in cases:
            for with_client in (True, False):
                r = measure(n, p, with_client, args.seconds, env, args.code.resolve())
                target = TARGETS.get((n, p)) if with_client else None
                figure = f"rig sim CPU share, {n} arms, --ros-period {p:g}, {'dVRK client' if with_client else 'no client'}"
                # beside the share of the wall clock: the share per simulated second (what it
                # would take at real time; the same as the first when rig sim kept time), the
                # real-time factor reached, and the client's measured_js per wall second
                value = (f"{100 * r['share']:.1f} % (per sim s {100 * r['per_sim_s']:.1f} %, rt {r['realtime']:.2f}"
                         + (f"; measured_js/s {r['received']})" if r["received"] else ")"))
                rows.append((figure, value, f"< {100 * target:.0f} %" if target else "(reported)",
                             r["share"] < target if target else True))
                print(f"{figure}: {value}", file=sys.stderr, flush=True)
    ok = print_table(f"rig sim's CPU share of the wall clock from 'ready' to its exit (one core = 100 %; "
                     f"{args.code.resolve()}, ROS_DOMAIN_ID={domain}, {args.seconds:g} s simulated each; "
                     f"load average {os.getloadavg()[0]:.1f})", rows)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
