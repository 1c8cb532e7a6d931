"""Shared fixtures: every test writes runs into its own folder."""

import pytest


@pytest.fixture(autouse=True)
def _isolated_logs(tmp_path, monkeypatch):
    monkeypatch.setenv("RIG_LOGS", str(tmp_path / "logs"))
    monkeypatch.delenv("RIG_CONFIG", raising=False)
    monkeypatch.chdir(tmp_path)
