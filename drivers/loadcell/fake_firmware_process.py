"""The load-cell firmware fake in a process of its own, for `rig sim`.

`FakeLoadCellFirmware` runs on a thread; inside `rig sim` that thread would share the
interpreter lock with the loop that steps the world, and every time the loop was
preempted holding it (other programs on the CPUs) the "Arduino" would stop sending for
tens of milliseconds, which no real Arduino does. Here the firmware runs in a child
process on its own pty: the parent writes the tension (N) into shared memory every step
(`set_tension`), the child samples it at its own rate.

The child dies with its parent (PR_SET_PDEATHSIG, and a check of the parent's pid), so a
killed `rig sim` closes the pty at once and the host sees the cable go. `unplug()` pulls
the cable on purpose (the fault a test or the simulated operator injects).
"""

from __future__ import annotations

import multiprocessing as mp
import os
import signal
import threading
import time


def _die_with_parent(parent: int) -> None:
    try:
        import ctypes

        PR_SET_PDEATHSIG = 1
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
    except (OSError, AttributeError):  # not Linux: the pid check below still ends the child
        pass

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(0.02)
        os._exit(0)

    threading.Thread(target=watch, name="parent-watch", daemon=True).start()


def _child(tension, conn, parent: int, kwargs: dict) -> None:
    from drivers.loadcell.fake_firmware import FakeLoadCellFirmware

    _die_with_parent(parent)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent stops us (Ctrl-C reaches the group)
    fw = FakeLoadCellFirmware(lambda: tension.value, **kwargs)
    fw.start()
    conn.send(fw.port_path)
    while True:
        try:
            what = conn.recv()
        except (EOFError, OSError):
            what = "stop"
        if what == "unplug":
            fw.unplug()
            conn.send("unplugged")
        elif what == "stop":
            fw.close()
            return


class FakeFirmwareProcess:
    """`FakeLoadCellFirmware(**kwargs)` in a child process (see the module docstring)."""

    def __init__(self, **kwargs):
        ctx = mp.get_context("spawn")
        self._tension = ctx.Value("d", 0.0, lock=False)
        self._conn, child_conn = ctx.Pipe()
        self._proc = ctx.Process(target=_child, args=(self._tension, child_conn, os.getpid(), kwargs),
                                 name="loadcell-firmware", daemon=True)
        self._proc.start()
        if not self._conn.poll(30.0):
            self._proc.kill()
            raise RuntimeError("the load-cell firmware process did not start")
        self.port_path: str = self._conn.recv()

    def set_tension(self, newtons: float) -> None:
        self._tension.value = float(newtons)

    def unplug(self, wait: bool = False) -> None:
        """Pull the cable: the firmware stops and its pty closes. Without `wait` it returns at
        once: `rig sim` pulls it from the loop that steps the world, and waiting for the
        child there (it was seen to take over 0.25 s) would stop the arms' streams too."""
        self._conn.send("unplug")
        if wait:
            self._conn.poll(5.0) and self._conn.recv()

    def close(self) -> None:
        if self._proc.is_alive():
            try:
                self._conn.send("stop")
            except OSError:
                pass
            self._proc.join(timeout=2.0)
            if self._proc.is_alive():
                self._proc.kill()
                self._proc.join()
