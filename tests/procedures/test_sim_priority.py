"""rig sim asks the OS for the priority of a console's servo loop (`--nice`), and says so
in one line when it is refused."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from procedures import sim


def test_a_lower_priority_is_taken_in_its_own_process():
    # in a child: a nice value, once raised, cannot be lowered again without privileges
    code = ("import os; from procedures.sim import _ask_priority; _ask_priority(7); "
            "print(os.getpriority(os.PRIO_PROCESS, 0))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         cwd=os.path.dirname(os.path.dirname(os.path.dirname(__file__))))
    assert int(out.stdout.strip()) == max(7, os.getpriority(os.PRIO_PROCESS, 0))


def test_a_refused_priority_is_said_in_one_line(monkeypatch, capsys):
    said = []
    monkeypatch.setattr(os, "getpriority", lambda which, who: 0)

    def refuse(which, who, value):
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(os, "setpriority", refuse)
    monkeypatch.setattr(sim, "_say", said.append)
    sim._ask_priority(-10)
    assert len(said) == 1 and "nice 0, not -10" in said[0] and "CAP_SYS_NICE" in said[0], said


@pytest.mark.parametrize("value", ["-21", "20"])
def test_nice_outside_the_range_is_refused(value):
    from click.testing import CliRunner

    out = CliRunner().invoke(sim.command, ["--nice", value, "--duration", "0.1"])
    assert out.exit_code == 2 and "--nice" in out.output, out.output
