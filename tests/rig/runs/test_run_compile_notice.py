"""A first-use numba compilation inside a run's step is said in its progress lines (issue 36,
point 9: a first `rig cooperative` spent 17 s in "attach the object" with no word: the
simulated rig's kernel, rig.sim.kernel.step, compiling)."""

from __future__ import annotations

import io

import numpy as np
from numba import njit

from rig.runs.run import Run


def _fresh_kernel():
    """A kernel no run has called yet (not cached: it compiles at its first call)."""

    @njit(cache=False)
    def twice_the_sum(x):
        total = 0.0
        for v in x:
            total += v
        return 2.0 * total

    return twice_the_sum


def test_a_compilation_in_a_step_is_named_with_its_time():
    kernel = _fresh_kernel()
    err = io.StringIO()
    with Run("cooperative", stream=err, steps=["power and home the arms", "attach the object"]) as run:
        with run.step("power and home the arms"):
            pass
        with run.step("attach the object"):
            assert kernel(np.ones(3)) == 6.0
            assert kernel(np.ones(4)) == 8.0  # compiled already: no second line
        run.finish({})
    lines = err.getvalue().splitlines()
    start = [line for line in lines if "compiling" in line]
    assert len(start) == 1, lines
    assert start[0].startswith("[2/2] attach the object: compiling ") and "twice_the_sum (numba, first use" in start[0]
    done = [line for line in lines if " compiled " in line]
    assert len(done) == 1 and done[0].startswith("[2/2] attach the object: compiled ") and done[0].endswith(" s")
    # said before the step ends, and the listener goes with the run
    assert lines.index(done[0]) < lines.index(next(line for line in lines if "attach the object done in" in line))
    said = err.getvalue()
    _fresh_kernel()(np.ones(2))
    assert err.getvalue() == said


def test_a_run_without_progress_says_nothing():
    err = io.StringIO()
    with Run("identify", stream=err, progress=False) as run:
        with run.step("fit"):
            _fresh_kernel()(np.ones(3))
        run.finish({})
    assert err.getvalue() == ""
