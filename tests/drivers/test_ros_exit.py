"""A `rig` command's process leaves its DDS participant to its end (drivers.common.ros_exit, issue 37):
deleting it after a peer died mid-write crashed the procedure in Fast DDS's shared-memory
teardown. The command's process still ends with its code, its words flushed, its exit
handlers run and its own shared-memory segment removed; a library's session is parked past
the interpreter's end, and its process ends with its segment removed (issue 44)."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import pytest

import rclpy  # noqa: E402,F401  (a declared dependency: a broken install fails here)

pytestmark = pytest.mark.ros

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

SCRIPT = textwrap.dedent("""
    import atexit, os, sys
    from drivers.common import ros_exit
    from drivers.common.ros_session import RosSession
    ros_exit.end_with_process()
    atexit.register(lambda: print("exit handler ran", flush=True))
    session = RosSession("ros_exit_test")
    from std_msgs.msg import Float64
    session.node.create_subscription(Float64, "/ros_exit_test/x", lambda m: None, 10)
    session.start()
    mine = sorted(ros_exit._own_segments)
    print("segments", " ".join(mine))
    print("present", all(os.path.exists(f"/dev/shm/{n}") for n in mine))
    session.close()
    print("context ok after close", session.context.ok())
    sys.stderr.write("rig test: aborted: the last line\\n")
    import threading, time
    threading.Thread(target=lambda: (time.sleep(0.5), print("worker done", flush=True))).start()
    ros_exit.leave(3)
    print("not reached")
""")


def test_a_commands_process_parks_its_participant_and_ends_with_its_code(ros_env):
    out = subprocess.run([sys.executable, "-c", SCRIPT], cwd=REPO, env=dict(os.environ), capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 3, out.stderr
    assert "Traceback" not in out.stderr
    assert out.stderr.splitlines()[-1] == "rig test: aborted: the last line"
    lines = out.stdout.splitlines()
    assert "context ok after close True" in lines  # parked, not shut down
    assert "exit handler ran" in lines and "not reached" not in lines
    assert lines.index("worker done") < lines.index("exit handler ran")  # threads end first, as at any exit
    segments = lines[0].split()[1:]
    if os.path.isdir("/dev/shm") and segments:  # Fast DDS made one for its participant: it is gone
        assert "present True" in lines
        for name in segments:
            assert not os.path.exists(f"/dev/shm/{name}") and not os.path.exists(f"/dev/shm/{name}_el")


LIBRARY = textwrap.dedent("""
    import os
    from drivers.common import ros_exit
    from drivers.common.ros_session import RosSession
    session = RosSession("ros_exit_lib")
    from std_msgs.msg import Float64
    session.node.create_subscription(Float64, "/ros_exit_lib/x", lambda m: None, 10)
    session.start()
    session.close()
    mine = sorted(ros_exit._own_segments)
    print("segments", " ".join(mine))
    print("present", all(os.path.exists(f"/dev/shm/{n}") for n in mine))
    print("context ok after close", session.context.ok(), "parked", len(ros_exit._parked))
    raise SystemExit(3)
""")


def test_a_library_session_is_parked_past_the_interpreters_end(ros_env):
    # a library's process (a test, a notebook) ends as any Python program, with its own exit
    # status: the participant outlives the interpreter and the C library's exit ends the
    # process before Fast DDS's destructors, so nothing deletes it; its segment is removed
    out = subprocess.run([sys.executable, "-c", LIBRARY], cwd=REPO, env=dict(os.environ), capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 3, out.stderr
    assert "Traceback" not in out.stderr
    lines = out.stdout.splitlines()
    assert "context ok after close True parked 1" in lines
    segments = lines[0].split()[1:]
    if os.path.isdir("/dev/shm") and segments:
        assert "present True" in lines
        for name in segments:
            assert not os.path.exists(f"/dev/shm/{name}") and not os.path.exists(f"/dev/shm/{name}_el")


def test_leave_without_a_parked_participant_is_sys_exit(monkeypatch):
    from drivers.common import ros_exit

    monkeypatch.setattr(ros_exit, "_parked", [])
    monkeypatch.delitem(sys.modules, "rclpy", raising=False)
    with pytest.raises(SystemExit) as done:
        ros_exit.leave(None)
    assert done.value.code == 0
    with pytest.raises(SystemExit) as done:
        ros_exit.leave(4)
    assert done.value.code == 4
