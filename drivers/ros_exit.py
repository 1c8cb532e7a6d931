"""How a `rig` process lets go of ROS 2: torn down in a library, left to the process's end in a command.

Why. Fast DDS 2.14 (the middleware of ROS 2 Jazzy's rmw_fastrtps) shares a listening port's
ring buffer and its lock with every process that writes to it (the shared-memory
transport; with ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST rmw_fastrtps always adds it). When
`rig sim` or a dVRK console is SIGKILLed while writing into a procedure's port, the
procedure's listener finds the port broken and opens a new one; deleting the DDS
participant afterwards releases the listener's channel through the old port, whose
segment is no longer mapped, and the process dies of SIGSEGV. A core of such a run
(`bench/bench_kill.py`, 2 CPU burners, 1 run in 33) shows it:
``rcl_node_fini -> rmw_destroy_node -> delete_participant -> ReceiverResource::disable ->
SharedMemChannelResource::release -> interprocess_mutex::lock`` on an address in the gap
a 52 kB port segment had left. The run's own work was done (arms held, recording closed);
only the teardown crashed.

So a `rig` command, whose process ends when the command returns (`rig.cli.run`), never
deletes its participants: `teardown(node, context)` stops at the executor (no callback
runs after it) and parks the node and context, and `leave(code)` ends the process with
`os._exit(code)` after the exit handlers and a flush, so neither Python's finalisers nor
rclpy's destructors delete a participant either. Before it goes, it removes the
shared-memory segment this process created for its own participant (`fastrtps_<16 hex>`
and its `_el` lock in /dev/shm), which Fast DDS's teardown would have removed, so a
lab's day of runs leaves no more in /dev/shm than a clean exit would. A peer sees the
participant go when its lease runs out instead of at once; nothing waits on that.

In a library (tests, a notebook: `end_with_process` never called) `teardown` destroys the
node and shuts the context down as before.
"""

from __future__ import annotations

import atexit
import os
import re
import sys
import threading

#: where Fast DDS keeps its shared-memory segments on Linux
SHM = "/dev/shm"
#: s, longest wait for each thread that is not a daemon before the process ends
THREAD_WAIT = 10.0
_SEGMENT = re.compile(r"fastrtps_[0-9a-f]{16}$")

_ending = False
_parked: list = []  # (node, context) left to the process's end: referenced so no finaliser runs
_own_segments: set[str] = set()
_before: set[str] | None = None


def end_with_process() -> None:
    """Declare that this process ends when its command returns (called by `rig.cli.run`)."""
    global _ending
    _ending = True


def ending() -> bool:
    return _ending


def _segments() -> set[str]:
    try:
        return {n for n in os.listdir(SHM) if _SEGMENT.match(n)}
    except OSError:
        return set()


def before_init() -> None:
    """Note the segments that exist before this process makes a participant (`RosSession`,
    rig sim and the command channel call it before `rclpy.init`)."""
    global _before
    if _ending and _before is None:
        _before = _segments()


def after_node() -> None:
    """Note the segments this process made: new since `before_init` and mapped by this
    process (another process starting at the same moment maps its own, not ours)."""
    global _before
    if not _ending or _before is None:
        return
    new = _segments() - _before
    _before = None
    if not new:
        return
    try:
        with open("/proc/self/maps", encoding="utf-8", errors="replace") as f:
            maps = f.read()
    except OSError:
        return
    _own_segments.update(n for n in new if f"{SHM}/{n}\n" in maps)


def teardown(node, context) -> None:
    """Destroy `node` (a node, a tuple of the context's nodes, or None) and shut `context`
    down, or, in a command's process, park them for `leave` (see the module docstring).
    The executors spinning them must have stopped."""
    import rclpy

    if _ending:
        _parked.append((node, context))
        return
    try:
        for n in node if isinstance(node, tuple) else (node,):
            if n is not None:
                n.destroy_node()
    finally:
        if context.ok():
            rclpy.shutdown(context=context)


def leave(code) -> None:
    """End the process with `code` (an int, None for 0, or a message for 1, as sys.exit):
    with `os._exit` once ROS 2 was loaded (a participant parked, or one whose executor
    would not stop: Python's finalisers would delete it), else with `sys.exit`."""
    if isinstance(code, str):
        print(code, file=sys.stderr)
        code = 1
    code = 0 if code is None else int(code)
    if not _parked and "rclpy" not in sys.modules:
        sys.exit(code)
    try:
        # as the interpreter's own exit: the threads that are not daemons end first (up to
        # THREAD_WAIT s each), then the exit handlers (the recorder's last-chance close)
        for thread in threading.enumerate():
            if thread is not threading.current_thread() and not thread.daemon:
                thread.join(timeout=THREAD_WAIT)
        atexit._run_exitfuncs()
    finally:
        for name in _own_segments:
            for path in (f"{SHM}/{name}", f"{SHM}/{name}_el"):
                try:
                    os.unlink(path)
                except OSError:
                    pass
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except Exception:  # noqa: BLE001 - a closed pipe: nothing left to say
                pass
        os._exit(code)
