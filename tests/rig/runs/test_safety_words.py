"""The safety limits' words: an effort beyond its limit says by how much, in its unit,
whichever its sign."""

import numpy as np
import pytest

from rig.runs.run import AbortRun
from rig.runs.safety import SafetyLimits


@pytest.mark.parametrize("effort, words", [
    ([0.0, 0.0, -19.76], "joint 3 commanded effort -19.76 N, beyond its limit +/-15.00 N"),
    ([0.0, 5.5, 0.0], "joint 2 commanded effort +5.50 N m, beyond its limit +/-5.00 N m"),
])
def test_an_effort_beyond_its_limit_is_said_with_sign_and_unit(effort, words):
    with pytest.raises(AbortRun) as info:
        SafetyLimits().check_effort("PSM1", np.array(effort))
    assert str(info.value.reason if hasattr(info.value, "reason") else info.value) == f"PSM1: {words}"
    assert "above the ceiling" not in str(info.value)


def test_an_effort_within_its_limit_passes():
    SafetyLimits().check_effort("PSM1", np.array([-4.9, 4.9, -14.9]))
