"""The simulated person's cables: the load cell's, the tracker's and their own presence,
pulled on request (faults for the matrix of tests/hil/test_fault_matrix.py)."""

from __future__ import annotations

import pytest

from drivers.operator.driver import OperatorError
from drivers.operator.sim import CellLoad, SimOperator
from rig import config
from rig.sim.world import world_from_config


@pytest.fixture
def world():
    return world_from_config(config.load(None))


def test_each_cable_is_pulled_by_name(world):
    pulled = []
    op = SimOperator(world, cell=CellLoad(world, cable=lambda: pulled.append("loadcell")))
    op.cables["mocap"] = lambda: pulled.append("mocap")
    op.unplug("loadcell")
    op.unplug("mocap")
    assert pulled == ["loadcell", "mocap"]


def test_an_unknown_cable_is_refused_naming_those_there_are(world):
    op = SimOperator(world, cell=CellLoad(world, cable=lambda: None))
    op.cables["mocap"] = lambda: None
    with pytest.raises(OperatorError, match="can only unplug 'loadcell', 'mocap' here, not 'camera'"):
        op.unplug("camera")


def test_no_load_cell_to_unplug_is_said(world):
    with pytest.raises(OperatorError, match="no load cell to unplug"):
        SimOperator(world).unplug("loadcell")


def test_a_hung_mass_reaches_the_cell_before_the_operator_answers(world):
    """rig sim's world loop writes the cell's load each step; on a loaded machine that step
    comes late. The mass is on the cell when the person says it hangs."""
    from drivers.loadcell.force_calibration import STANDARD_GRAVITY

    felt = []
    op = SimOperator(world, cell=CellLoad(world, sink=felt.append))
    op.hang_mass(0.5)
    assert felt == [0.5 * STANDARD_GRAVITY]
