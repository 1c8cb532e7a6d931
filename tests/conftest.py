"""Shared fixtures: every test writes runs into its own folder, Ctrl-C reaches the
processes the tests interrupt, and ROS nodes and local servers get a domain and ports no
other test (in this run, another xdist worker or another pytest run) uses."""

import os
import signal

import pytest

from tests.ros_domains import claim_domain, claim_ports, ros_environment
from tests.xdist_crash import pytest_xdist_make_scheduler  # noqa: F401  (a dead worker fails its test, the run goes on)

#: the files whose tests take longest, longest first. pyproject.toml runs `-n 2 --dist
#: loadfile --no-loadscope-reorder`: the files go to whichever worker is free in this order,
#: so the two workers end together instead of one starting a long file when the other is
#: done. Only the order changes: a file missing here runs all the same, after these.
LONG_FIRST = (
    "tests/calibration/discrepancy/test_discrepancy.py",
    "tests/hil/test_chain.py",
    "tests/procedures/test_cooperative.py",
    "tests/procedures/test_identify.py",
    "tests/procedures/test_discrepancy.py",
    "tests/calibration/test_generalisation.py",
    "tests/drivers/test_dvrk_arm_ros.py",
    "tests/procedures/test_friction_ramp.py",
    "tests/procedures/test_cooperative_ros.py",
    "tests/procedures/test_validate.py",
    "tests/hil/test_dvrk_client.py",
    "tests/procedures/test_provenance_chain.py",
)


#: s a test may take, its fixtures' setup included, before it fails with every thread's
#: stack on stderr: a hang guard (a test that waits on something that never comes would
#: hold CI until CI's own timeout, with no word of where), not a performance bound. The
#: longest test here takes about 3 minutes on a busy 2-core machine.
HANG_GUARD_S = 900.0


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    """The hang guard: SIGALRM raises in the test (it fails, the run goes on); a test stuck
    where no signal reaches Python is ended two minutes later with its worker (faulthandler),
    which then fails as a dead worker's test does while the run goes on (tests/xdist_crash.py)."""
    import faulthandler
    import sys

    guard = float(os.environ.get("RIG_TEST_HANG_GUARD", HANG_GUARD_S))

    def expire(signum, frame):
        faulthandler.dump_traceback(file=sys.__stderr__, all_threads=True)
        raise TimeoutError(f"hang guard: {item.nodeid} still running after {guard:.0f} s (stacks on stderr)")

    previous = signal.signal(signal.SIGALRM, expire)
    signal.setitimer(signal.ITIMER_REAL, guard)
    faulthandler.dump_traceback_later(guard + 120.0, exit=True, file=sys.__stderr__)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0.0)
        signal.signal(signal.SIGALRM, previous)
        faulthandler.cancel_dump_traceback_later()


def pytest_addoption(parser):
    parser.addoption("--test-order", default="declared", choices=("declared", "reverse", "shuffle"),
                     help="order of the tests within each file: reverse or shuffle them to check that no test "
                          "depends on another having run (shuffle: --test-order-seed)")
    parser.addoption("--test-order-seed", type=int, default=0, help="the seed of --test-order shuffle (default 0)")


def pytest_collection_modifyitems(config, items):
    """The long files first (LONG_FIRST); within each file the order --test-order asks for."""
    import random

    root = str(config.rootpath)
    files: dict = {}
    for item in items:
        files.setdefault(item.path, []).append(item)

    def rank(path) -> int:
        rel = os.path.relpath(str(path), root).replace(os.sep, "/")
        return LONG_FIRST.index(rel) if rel in LONG_FIRST else len(LONG_FIRST)

    order = config.getoption("--test-order")
    rng = random.Random(config.getoption("--test-order-seed"))
    ordered = []
    for path in sorted(files, key=rank):  # stable: the others keep their order
        group = files[path]
        if order == "reverse":
            group.reverse()
        elif order == "shuffle":
            rng.shuffle(group)
        ordered.extend(group)
    items[:] = ordered


@pytest.fixture(autouse=True)
def _isolated_logs(tmp_path, monkeypatch):
    monkeypatch.setenv("RIG_LOGS", str(tmp_path / "logs"))
    monkeypatch.delenv("RIG_CONFIG", raising=False)
    monkeypatch.chdir(tmp_path)


@pytest.fixture(autouse=True, scope="session")
def _sigint_delivered():
    """A test run started in the background of a non-interactive shell (``cmd &``, some CI
    runners) inherits SIGINT ignored, and so would every process it starts: the Ctrl-C
    tests would then test a program that rightly ignores Ctrl-C. Give the test process
    Python's own handler for the session; children exec'd from it start with SIGINT at
    its default, which Python turns into KeyboardInterrupt as at a terminal."""
    ignored = signal.getsignal(signal.SIGINT) is signal.SIG_IGN
    if ignored:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    if ignored:
        signal.signal(signal.SIGINT, signal.SIG_IGN)


@pytest.fixture(autouse=True, scope="session")
def _private_ros_domain():
    """Every process of the session (this xdist worker) is on a domain of its own with
    localhost discovery, so a ROS node a test starts without choosing a domain never
    meets another run's nodes, nor the lab's on domain 0."""
    with claim_domain() as domain, ros_environment(domain):
        yield domain


@pytest.fixture
def ros_domain():
    """A ROS domain claimed for this test (tests/ros_domains.py); the environment unchanged."""
    with claim_domain() as domain:
        yield domain


@pytest.fixture
def ros_env(ros_domain):
    """This process on a claimed domain with localhost discovery for the test (set before
    rclpy.init); the domain's number."""
    with ros_environment(ros_domain):
        yield ros_domain


@pytest.fixture
def free_ports():
    """``free_ports(n)``: the first of n consecutive local ports claimed for this test."""
    claims = []

    def claim(count: int = 1) -> int:
        claims.append(claim_ports(count))
        return claims[-1].value

    yield claim
    for c in claims:
        c.release()


@pytest.fixture(autouse=True)
def _no_terminal_size(monkeypatch):
    """Output as a pipe gets it: no test depends on the width of the terminal it runs in
    (pytest-xdist's workers and CI set COLUMNS differently)."""
    monkeypatch.delenv("COLUMNS", raising=False)
    monkeypatch.delenv("LINES", raising=False)
