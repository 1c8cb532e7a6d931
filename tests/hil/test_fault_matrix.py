"""The fault matrix over the wire (issue 37): every procedure x every fault, one test each.

The three-arm triangle runs on a second module `rig sim` (PSM3 too, a cell per element).

A module `rig sim` (tests/hil/fault_matrix.py: the chain's rig.toml, the operator's answer
limit OPERATOR_TIMEOUT) prepared once; a fault that leaves rig sim broken (killed, a cable pulled, an
arm in FAULT, the operator gone) gets the next test a fresh one on the same folder and
domain. Each cell ends cleanly (`fault_matrix.cell`): one line, no traceback, no signal,
the documented exit, the arms it moved held, the recording closed with the reason; or, a
device it no longer uses, completed as if nothing happened. The whole matrix takes about
half an hour on this 2-core machine, so it runs with `-m slow` (and bench/bench_faults.py
prints it as a table); the default run keeps one fault of each kind in tests/hil/test_chain.py,
tests/hil/test_operating_state.py and tests/rig/runs/test_run.py.
"""

from __future__ import annotations

import pytest

import rclpy  # noqa: E402,F401  (a declared dependency: a broken install fails here)

from tests.hil.fault_matrix import FAULTS, PROCEDURES, cell, lab, prepare, sim_args  # noqa: E402
from tests.hil.harness import ServedRig  # noqa: E402

pytestmark = [pytest.mark.ros, pytest.mark.hil, pytest.mark.slow]


def _lab(tmp_path_factory, three_arms: bool):
    folder = tmp_path_factory.mktemp("faults3" if three_arms else "faults")
    with ServedRig(folder, toml=lab(folder, three_arms), sim_args=sim_args(three_arms)) as rig:
        problem = prepare(rig, three_arms)
        assert problem is None, problem
        yield rig


@pytest.fixture(scope="module")
def matrix_rig(tmp_path_factory):
    yield from _lab(tmp_path_factory, False)


@pytest.fixture(scope="module")
def matrix_rig3(tmp_path_factory):
    yield from _lab(tmp_path_factory, True)


@pytest.mark.parametrize("fault", list(FAULTS))
@pytest.mark.parametrize("procedure", list(PROCEDURES))
def test_a_fault_ends_the_procedure_cleanly(request, procedure, fault):
    rig = request.getfixturevalue("matrix_rig3" if PROCEDURES[procedure].three_arms else "matrix_rig")
    if not rig.running or rig.faulted:
        rig.restart()
    try:
        r = cell(rig, procedure, fault)
    finally:
        if FAULTS[fault][2] and rig.running:
            rig.stop(keep_domain=True)  # its cable stays pulled: the next test gets a fresh rig sim
    assert r["ok"], (r["problems"], r["line"])
