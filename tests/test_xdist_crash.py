"""A worker that dies fails the test it ran, and the run goes on to its end (tests/xdist_crash.py).

A pytest run in a subprocess, as the README's command runs (`-n 2 --dist loadfile
--no-loadscope-reorder`), on six files of three tests with this suite's scheduler hook.
Both workers die at once in the first two files (os._exit, SIGSEGV), and their replacements
collect slowly, one 2 s longer than the other: the state in which xdist's scheduler handed work to a
worker still collecting (INTERNALERROR). A third dies by SIGSEGV in the last file, once its
worker has finished other files and nothing is left in the queue: the state in which xdist's
loadfile scheduler handed a finished file to the replacement and waited forever.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest


REPO = Path(__file__).resolve().parents[1]

#: s: a guard against the hang this test is about (the run takes a few seconds), not a bound
HANG_GUARD = 300

FILE = textwrap.dedent("""
    import os, signal

    def _ran(name):
        with open(os.environ["RAN"], "a") as f:
            f.write(f"{__name__.rsplit('.', 1)[-1]}::{name}\\n")

    def test_1():
        _ran("test_1")

    def test_2():
        _ran("test_2")
        {death}

    def test_3():
        _ran("test_3")
""")

DEATHS = {"test_a": "os._exit(1)", "test_b": "os.kill(os.getpid(), signal.SIGSEGV)",
          "test_f": "os.kill(os.getpid(), signal.SIGSEGV)"}

#: the replacements of the first two dead workers, gw2 and gw3, collect 2 s and 4 s: gw3 is
#: started and known to the scheduler, still collecting, when gw2's collection comes in
CONFTEST = textwrap.dedent("""
    import os, time
    from tests.xdist_crash import pytest_xdist_make_scheduler  # noqa: F401

    def pytest_collection_modifyitems(items):
        time.sleep({"gw2": 2.0, "gw3": 4.0}.get(os.environ.get("PYTEST_XDIST_WORKER"), 0.0))
""")


def test_a_dead_worker_fails_its_test_and_every_other_test_runs_once(tmp_path):
    (tmp_path / "pytest.ini").write_text("[pytest]\n")
    (tmp_path / "conftest.py").write_text(CONFTEST)
    names = ("test_a", "test_b", "test_c", "test_d", "test_e", "test_f")
    for name in names:
        (tmp_path / f"{name}.py").write_text(FILE.replace("{death}", DEATHS.get(name, "pass")))
    ran = tmp_path / "ran.txt"
    env = dict(os.environ, RAN=str(ran), PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]))
    env.pop("PYTEST_ADDOPTS", None)
    proc = subprocess.Popen([sys.executable, "-m", "pytest", "-p", "no:cacheprovider", "-n", "2", "--dist", "loadfile",
                             "--no-loadscope-reorder", "-rA", *(f"{n}.py" for n in names)],
                            cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            start_new_session=True)
    try:
        out, _ = proc.communicate(timeout=HANG_GUARD)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        out, _ = proc.communicate()
        pytest.fail(f"the run did not end after a worker died:\n{out[-3000:]}")
    assert proc.returncode == 1, out[-3000:]
    for name in DEATHS:
        assert f"crashed while running '{name}.py::test_2'" in out, out[-3000:]
    runs = ran.read_text().split()
    expected = sorted(f"{n}::test_{i}" for n in names for i in (1, 2, 3))
    assert sorted(runs) == expected, out[-3000:]  # each once: the dead ones not again, none left out
    assert "15 passed" in out and "3 failed" in out, out[-3000:]
