"""Shared fixtures: every test writes runs into its own folder, and Ctrl-C reaches the
processes the tests interrupt."""

import signal

import pytest


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
