"""A pytest-xdist worker that dies fails the test it was running, and the run goes on to its end.

Why. pytest-xdist 3.8's `--dist loadfile` scheduler (LoadScopeScheduling) keeps every file
a worker was ever given in that worker's workload, finished or not. When the worker dies,
`remove_node` puts its whole workload back in the queue: files it had finished, and the
file it died in with the test it died in still pending. The replacement worker (or the
other one) is then handed a finished file: an empty `runtests`, after which nothing ever
completes on it, so nothing asks the scheduler for more work, and the run waits forever
with idle workers (pytest-xdist issue 1313; seen here after a worker died in
tests/drivers/test_dvrk_arm_ros.py: 16 tests never handed out, stopped at 24 min). The test
it died in is also run again, and dies again, until `--max-worker-restart` is spent.

And when two workers are being replaced at once, the first replacement to finish
collecting makes the scheduler hand work to the other, still collecting, and the run ends
in an INTERNALERROR (KeyError in `_assign_work_unit`; seen in this suite's own test of it on
a loaded machine).

`CrashSafeLoadFile` is the same scheduler with the three mended: on a worker's death only
the files with tests still to run go back in the queue, without the test the worker died in
(xdist reports it failed, "worker 'gwN' crashed while running ..."), so every other test
still runs once; a worker gets work only once it has collected. `pytest_xdist_make_scheduler` gives it for `--dist loadfile` (tests/conftest.py
imports the hook); any other `--dist` keeps xdist's own.
"""

from __future__ import annotations

import pytest

try:
    from xdist.scheduler import LoadFileScheduling
except ImportError:  # pytest-xdist not installed: one process, nothing to schedule
    LoadFileScheduling = None


if LoadFileScheduling is not None:

    class CrashSafeLoadFile(LoadFileScheduling):
        """xdist's loadfile scheduling; a dead worker's finished files are not handed out again."""

        def remove_node(self, node):
            """Requeue the dead (or finished) `node`'s files that still have tests to run; the
            first of those tests is the one it was running: marked done and returned (xdist
            reports it failed)."""
            workload = self.assigned_work.pop(node)
            running = next(((scope, nodeid) for scope, unit in workload.items()
                            for nodeid, done in unit.items() if not done), None)
            if running is None:
                return None
            scope, crashitem = running
            workload[scope][crashitem] = True
            for scope, unit in workload.items():
                if not all(unit.values()):
                    self.workqueue[scope] = unit
            for other in self.assigned_work:
                self._reschedule(other)
            return crashitem

        def _reschedule(self, node):
            """xdist's, for a worker that has collected; one still collecting (a replacement)
            is given work when its collection comes in (`schedule`)."""
            if node in self.registered_collections:
                super()._reschedule(node)


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config, log):
    if LoadFileScheduling is not None and config.getvalue("dist") == "loadfile":
        return CrashSafeLoadFile(config, log)
    return None
