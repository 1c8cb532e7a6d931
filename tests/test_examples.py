"""The example configurations the README names: each loads, and the simulated ones run."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from click.testing import CliRunner

from rig import config
from rig.cli import main

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


@pytest.mark.parametrize("name", ["three-arms.toml", "real-rig.toml"])
def test_each_example_loads_and_the_readme_names_it(name):
    cfg = config.load(EXAMPLES / name)
    assert f"examples/{name}" in (EXAMPLES.parent / "README.md").read_text()
    assert len(cfg.arms) >= 2


def test_three_arms_runs_the_triangle(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("RIG_LOGS", str(tmp_path / "logs"))
    res = CliRunner().invoke(main, ["--config", str(EXAMPLES / "three-arms.toml"), "cooperative", "--arms",
                                    "PSM1,PSM2,PSM3", "--force", "5", "--move", "0.02,0,0", "--duration", "1",
                                    "--settle", "1", "--hold-after", "0.2", "--json"])
    assert res.exit_code == 0, res.output
    doc = json.loads(res.stdout.strip().splitlines()[-1])
    assert doc["status"] == "completed" and doc["arms"] == ["PSM1", "PSM2", "PSM3"]
    assert doc["max_error_during_motion"] <= 0.25


def test_real_rig_is_a_lab_with_hardware_and_rig_sim_can_serve_it():
    from procedures.sim import served_config

    cfg = config.load(EXAMPLES / "real-rig.toml")
    assert not cfg.simulated
    assert {a["driver"] for a in cfg.arms.values()} == {"ros"}
    assert cfg.loadcell["driver"] == "serial" and cfg.mocap["driver"] == "ros"
    assert cfg.rig["rate"] == config.ROS_DEFAULT_RATE
    served = served_config(cfg)
    assert {a["driver"] for a in served.arms.values()} == {"sim"}
