"""Hardware in the loop without hardware: `rig sim` in one process, procedures in others.

`ServedRig` writes a lab's rig.toml into a folder (ROS arms, the load cell on a serial
port, ROS mocap, `rig sim`'s operator), starts `rig sim` on it with a private
ROS_DOMAIN_ID and localhost discovery, and runs `rig <command> --json` as separate
processes in the same folder, so results pass from one procedure to the next through its
logs/ exactly as in a lab. The tests (tests/hil) and bench/bench_hil.py use it.

Without a `domain`, it claims one for as long as it runs (tests/ros_domains.py: a lock
no other test, xdist worker or pytest run on the machine can take, on a domain nobody's
nodes are on), so tests can run side by side.
"""

from __future__ import annotations

import json
import os
import selectors
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]

PSM2_BASE = "base_xyz = [1.0728, 0.0, 0.0]\nbase_rpy = [0.0, 0.0, 3.141592653589793]\n"


def lab_toml(folder: Path, *, rate: float | None = None, watchdog: float | None = None, extra: str = "",
             three_arms: bool = False, sim_time: bool = False) -> str:
    """A lab's rig.toml for the rig `rig sim` serves: ROS arms, a serial load cell on
    `folder/loadcell` (rig sim links it to its pty), ROS mocap, the simulated operator.
    `three_arms`: PSM3 too, the object a triangle and a cell per element
    (`folder/loadcell`, `loadcell1`, `loadcell2`). `sim_time`: the procedures follow
    `rig sim --sim-time`'s clock in lockstep ([ros] use_sim_time)."""
    arm = 'driver = "ros"\n' + (f"watchdog = {watchdog}\n" if watchdog else "")
    text = ("[rig]\nseed = 0\n" + (f"rate = {rate}\n" if rate else "")
            + f"\n[arms.PSM1]\n{arm}\n[arms.PSM2]\n{arm}{PSM2_BASE}")
    if three_arms:
        # a triangle: a load cell per element, each on its own port
        text += f"\n[arms.PSM3]\n{arm}base_xyz = [0.5364, 0.5730, 0.0]\nbase_rpy = [0.0, 0.0, -1.5707963267948966]\n"
        ports = ", ".join(f'"{folder / name}"' for name in ("loadcell", "loadcell1", "loadcell2"))
        text += (f'\n[object]\narms = ["PSM1", "PSM2", "PSM3"]\nrest_length = 0.099\n'
                 f'\n[loadcell]\ndriver = "serial"\nports = [{ports}]\n')
    else:
        text += f'\n[loadcell]\ndriver = "serial"\nport = "{folder / "loadcell"}"\n'
    text += '\n[mocap]\ndriver = "ros"\n\n[operator]\ndriver = "ros"\n'
    if sim_time:
        text += "\n[ros]\nuse_sim_time = true\n"
    return text + extra


def _ctrl_c_reaches_children() -> None:
    """A procedure started here takes Ctrl-C as a lab's terminal gives it. A process started
    in the background by a shell (`nohup bench &`) has SIGINT ignored, and its children
    inherit that: a procedure would then ignore SIGINT, rightly, as any Unix program
    started that way. Any handler here (not SIG_IGN) makes a child start with the default."""
    if (threading.current_thread() is threading.main_thread()
            and signal.getsignal(signal.SIGINT) is signal.SIG_IGN):
        signal.signal(signal.SIGINT, signal.default_int_handler)


@dataclass
class Outcome:
    """How one `rig` process ended: exit code, its --json document (None if none), stderr, wall
    s, and what `rig sim` said on its stderr meanwhile (its lockstep's joins, leaves and losses)."""

    code: int
    doc: dict | None
    stderr: str
    seconds: float
    sim_said: str = ""

    @property
    def last_line(self) -> str:
        lines = [ln for ln in self.stderr.splitlines() if ln.strip()]
        return lines[-1] if lines else ""


def completed(out: Outcome, what: str) -> dict:
    """The --json document of a run that must have completed, with no traceback (asserts)."""
    assert out.code == 0, f"rig {what} exited {out.code}: {out.stderr[-3000:]}\nrig sim said: {out.sim_said[-2000:]}"
    assert out.doc is not None and out.doc["status"] == "completed", out.stderr[-3000:]
    assert "Traceback" not in out.stderr
    return out.doc


class ServedRig:
    """`rig sim` on `folder/rig.toml` (see the module docstring); a context manager."""

    def __init__(self, folder: Path, domain: int | None = None, toml: str | None = None,
                 sim_args: tuple[str, ...] = (), sim_time: bool = False):
        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        self._claim = None  # the domain this rig claimed (domain=None), held until stop()
        self._domain = domain
        #: simulated time in lockstep (`rig sim --sim-time`, [ros] use_sim_time in the lab's file):
        #: the procedures' figures do not depend on how busy the machine is
        self.sim_time = sim_time
        self.toml = toml if toml is not None else lab_toml(self.folder, sim_time=sim_time)
        # the procedures' 500 Hz loops need the arms' streams at 1 kHz (the dVRK console's
        # default period is 0.01 s; procedures refuse it in one line)
        self.sim_args = tuple(sim_args) if "--ros-period" in sim_args else ("--ros-period", "0.001", *sim_args)
        if sim_time and "--sim-time" not in self.sim_args:
            self.sim_args += ("--sim-time",)
        self.proc: subprocess.Popen | None = None
        self.sim_lines: list[str] = []  # what rig sim printed up to "ready"
        self.sim_err: list[str] = []  # its stderr (ROS log lines: lockstep joins, leaves, losses)
        self._readers: list[threading.Thread] = []
        self._out_rest: list[str] = []  # its stdout after "ready"
        self.runs_since_start = 0  # `run` calls since this rig sim started (its arms start DISABLED)
        #: a procedure run on this rig sim said an arm is in FAULT: it stays so until a person
        #: clears it (as on a dVRK), so a test that needs working arms starts a fresh rig sim
        self.faulted = False

    @property
    def domain(self) -> int:
        """Its ROS_DOMAIN_ID: the one given, else one claimed now for as long as it runs."""
        if self._domain is None:
            from tests.ros_domains import claim_domain

            self._claim = claim_domain()
            self._domain = self._claim.value
        return self._domain

    @property
    def running(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def restart(self, timeout: float = 60.0) -> "ServedRig":
        """A fresh `rig sim` on the same folder and domain (after `kill`, say): the logs stay."""
        self.stop(keep_domain=True)
        return self.start(timeout)

    def env(self, **extra: str) -> dict:
        env = dict(os.environ, ROS_DOMAIN_ID=str(self.domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
                   RIG_LOGS=str(self.folder / "logs"),
                   PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]))
        env.pop("RIG_CONFIG", None)
        env.pop("RIG_DEBUG", None)
        env.update(extra)
        return env

    def start(self, timeout: float = 60.0) -> "ServedRig":
        (self.folder / "rig.toml").write_text(self.toml)
        self.sim_lines, self.runs_since_start, self.faulted = [], 0, False
        self._readers, self._out_rest, self.sim_err = [], [], []
        self.proc = subprocess.Popen([sys.executable, "-m", "rig.cli", "sim", *self.sim_args],
                                     cwd=self.folder, env=self.env(RIG_LOGS=str(self.folder / "sim-logs")),
                                     stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     text=True)
        sel = selectors.DefaultSelector()
        sel.register(self.proc.stdout, selectors.EVENT_READ)
        deadline = time.monotonic() + timeout
        while True:
            if self.proc.poll() is not None:
                raise RuntimeError(f"rig sim exited ({self.proc.returncode}): {self.proc.stderr.read()[-2000:]}")
            if time.monotonic() > deadline:
                self.stop()
                raise RuntimeError(f"rig sim not ready in {timeout} s: {self.sim_lines}")
            if sel.select(0.1):
                line = self.proc.stdout.readline().strip()
                self.sim_lines.append(line)
                if line == "ready":
                    sel.close()
                    self._drain()
                    return self

    def _drain(self) -> None:
        """Read rig sim's stdout and stderr for as long as it runs. A pipe nobody reads fills
        (64 KiB on Linux), and rig sim then blocks in its next write: its world, and the
        /clock every procedure follows, would stand still for a reason that is the
        harness's, not the rig's. What it said is kept (`sim_lines`, `sim_err`)."""
        self.sim_err = []
        self._out_done = threading.Event()

        def read(stream, sink: list[str], done: threading.Event | None) -> None:
            try:
                for line in stream:
                    sink.append(line)
            except (ValueError, OSError):  # closed by _stop
                pass
            if done is not None:
                done.set()

        self._readers = [threading.Thread(target=read, args=(self.proc.stdout, self._out_rest, self._out_done),
                                          daemon=True),
                         threading.Thread(target=read, args=(self.proc.stderr, self.sim_err, None), daemon=True)]
        for r in self._readers:
            r.start()

    def run(self, *args: str, timeout: float = 300.0, json_doc: bool = True, stdin: str | None = None,
            env: dict | None = None, on_start=None, when: tuple[str, object] | None = None) -> Outcome:
        """`rig <args> [--json]` in the folder; `on_start(proc)` is called once it runs.

        when: (text, fn): `fn()` is called, on a thread of its own, the first time a line
        of the procedure's stderr contains `text` (e.g. a step's first progress bar), so a
        fault lands in the step it is meant for however long connecting took.
        """
        argv = [sys.executable, "-m", "rig.cli", *args] + (["--json"] if json_doc else [])
        _ctrl_c_reaches_children()
        self.runs_since_start += 1
        said_from = len(self.sim_err)
        t0 = time.monotonic()
        proc = subprocess.Popen(argv, cwd=self.folder, env=env or self.env(), text=True,
                                stdin=subprocess.PIPE if stdin is not None else subprocess.DEVNULL,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        if on_start is not None:
            on_start(proc)
        try:
            if when is None:
                out, err = proc.communicate(stdin, timeout=timeout)
            else:
                out, err = self._watched(proc, stdin, timeout, *when)
        except subprocess.TimeoutExpired:
            proc.kill()
            out, err = proc.communicate()
            raise RuntimeError(f"rig {' '.join(args)} did not end in {timeout} s: {err[-3000:]}") from None
        on_this_rig = (env or {}).get("ROS_DOMAIN_ID", str(self.domain)) == str(self.domain)
        if on_this_rig and proc.returncode != 0 and "FAULT" in err:
            self.faulted = True
        docs = [ln for ln in out.splitlines() if ln.startswith("{") and ln.rstrip().endswith("}")]
        doc = json.loads(docs[-1]) if docs else None
        return Outcome(proc.returncode, doc, err, time.monotonic() - t0, "".join(self.sim_err[said_from:]))

    @staticmethod
    def _watched(proc: subprocess.Popen, stdin: str | None, timeout: float, text: str, fn) -> tuple[str, str]:
        """communicate(), calling fn() on a thread once a stderr line contains `text`."""
        out: list[str] = []
        err: list[str] = []
        fired = threading.Event()
        calls: list[threading.Thread] = []

        def read(stream, sink: list[str], watch: bool) -> None:
            for line in stream:
                sink.append(line)
                if watch and not fired.is_set() and text in line:
                    fired.set()
                    calls.append(threading.Thread(target=fn, daemon=True))
                    calls[-1].start()

        readers = [threading.Thread(target=read, args=(proc.stdout, out, False), daemon=True),
                   threading.Thread(target=read, args=(proc.stderr, err, True), daemon=True)]
        for r in readers:
            r.start()
        if stdin is not None:
            proc.stdin.write(stdin)
            proc.stdin.close()
        proc.wait(timeout=timeout)
        for r in readers:
            r.join(timeout=10.0)
        # fn may still be at work when the procedure has ended (the fault it injected ended
        # the run before the injecting call had its reply): its caller reads what fn did
        for c in calls:
            c.join(timeout=10.0)
        return "".join(out), "".join(err)

    def kill(self, sig: int = signal.SIGKILL) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(sig)
            self.proc.wait(timeout=10)

    def stop(self, keep_domain: bool = False) -> str:
        """Stop rig sim (SIGINT, as Ctrl-C); returns what it printed at exit. A domain it
        claimed is given back unless `keep_domain`."""
        try:
            return self._stop()
        finally:
            if self._claim is not None and not keep_domain:
                self._claim.release()
                self._claim, self._domain = None, None

    def _stop(self) -> str:
        if self.proc is None or self.proc.stdout is None or self.proc.stdout.closed:
            return ""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        for r in self._readers:
            r.join(timeout=10.0)
        rest = "".join(self._out_rest) if self._readers else self.proc.stdout.read()
        self._readers, self._out_rest = [], []
        self.proc.stdout.close()
        self.proc.stderr.close()
        return rest

    def __enter__(self) -> "ServedRig":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()
