"""How a process of ours lets go of ROS 2: it never deletes a DDS participant; the process's end does.

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

A library's process (a test, a notebook: `end_with_process` never called) parks them too, and
further: a parked node and context are kept past the interpreter's own end (a reference no
finaliser ever drops), so that neither Python's finalisers nor rclpy's destructors delete
the participant; an exit handler removes its shared-memory segments; and the C library's
exit, which ends the process once Python has finished with its own exit status, calls
_exit before the static destructors, among them Fast DDS's participant factory's, which
deletes every participant left (a parked session died there, SIGSEGV after the
interpreter's end, before that was added). Measured (`bench/bench_session_kill.py`: rig sim
SIGKILLed while streaming to a library session, the session closed 0-1.5 s later; a
machine loaded 3-18 by others): with the nodes destroyed 1 run in 110 died of SIGSEGV in
`destroy_node`, parked as here 0 in 75 (the bench's docstring has the rounds). A
transport that cannot crash was no way out: with ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
rmw_fastrtps 8.4 adds shared memory whatever FASTDDS_BUILTIN_TRANSPORTS=UDPv4 or an XML
profile say, and UDP alone discovers nobody on this machine without multicast on the LAN.
The price: a closed session's participant (its threads, sockets and segment) stays until
the process ends, and its peers see it go only then.
"""

from __future__ import annotations

import atexit
import ctypes
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
_exit_prepared = False  # a library's process: its segments removed at exit, its end before the destructors


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
    if _before is None:
        _before = _segments()


def after_node() -> None:
    """Note the segments this process made: new since `before_init` and mapped by this
    process (another process starting at the same moment maps its own, not ours)."""
    global _before
    if _before is None:
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
    """Park `node` (a node, a tuple of the context's nodes, or None) and `context` until the
    process ends: in a command's process for `leave`, in a library's past the interpreter's
    end (see the module docstring). The executors spinning them must have stopped."""
    global _exit_prepared
    _parked.append((node, context))
    if _ending:
        return
    for obj in (*(node if isinstance(node, tuple) else (node,)), context):
        if obj is not None:
            # one reference more than anyone holds: the object is never freed, so no Python
            # finaliser deletes the participant (the crash this module avoids)
            ctypes.pythonapi.Py_IncRef(ctypes.py_object(obj))
    if not _exit_prepared:
        atexit.register(remove_own_segments)
        _end_before_static_destructors()
        _exit_prepared = True


def _end_before_static_destructors() -> None:
    """Make the C library's exit(status), which ends the process once Python has finished,
    call _exit(status) before the destructors registered so far: Fast DDS's
    DomainParticipantFactory, made with the first participant, deletes every participant
    left in its destructor (a parked session's crashed there, SIGSEGV after the
    interpreter's end: bench/bench_session_kill.py). Python's own end (its exit handlers,
    its streams flushed) has run by then; the exit status is kept."""
    try:
        libc = ctypes.CDLL(None)
        libc.on_exit.argtypes = [ctypes.c_void_p, ctypes.c_void_p]
        libc.on_exit(ctypes.cast(libc._exit, ctypes.c_void_p), None)  # _exit(status, arg): arg ignored
    except (AttributeError, OSError):  # not glibc: nothing registered, the destructors run
        pass


def remove_own_segments() -> None:
    """Remove the shared-memory segments this process made for its participants (Fast DDS's
    participant deletion would have): the process is ending, its mappings stay valid."""
    for name in _own_segments:
        for path in (f"{SHM}/{name}", f"{SHM}/{name}_el"):
            try:
                os.unlink(path)
            except OSError:
                pass


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
        remove_own_segments()
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except Exception:  # noqa: BLE001 - a closed pipe: nothing left to say
                pass
        os._exit(code)
