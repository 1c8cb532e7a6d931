"""The load cell on a lab's first day (issue 45, item 5): the calibration's rate from
rig.toml, `[loadcell] rate` bounded by the firmware, a calibration found under any name of
the same device."""

from __future__ import annotations

import json
import os
import re
from pathlib import Path

import pytest
from click.testing import CliRunner

from drivers.loadcell import protocol
from drivers.loadcell.errors import LoadCellNotCalibrated
from drivers.loadcell.force_calibration import LoadCellCalibration
from rig import config
from rig.cli import main
from rig.devices.loadcell_calibrations import load_latest_calibration
from rig.runs.paths import run_dir_name

REPO = Path(__file__).resolve().parents[2]


def test_the_firmware_limits_are_the_sketchs():
    """MAX_RATE_HZ of each front end as the sketch defines it (HX711 first, then the INA)."""
    sketch = (REPO / "drivers/firmware/loadcell/loadcell.ino").read_text()
    limits = [int(x) for x in re.findall(r"static const uint16_t MAX_RATE_HZ = (\d+);", sketch)]
    assert limits == [protocol.MAX_RATE_HZ[protocol.ADC_HX711], protocol.MAX_RATE_HZ[protocol.ADC_INA]]


def test_a_rate_beyond_the_firmware_is_refused_in_one_line():
    with pytest.raises(config.ConfigError) as err:
        config.parse({"loadcell": {"rate": 2000.0}}, "lab.toml")
    text = str(err.value)
    assert "loadcell.rate" in text and "[1, 1000] Hz" in text and "80 for the HX711 build" in text
    assert config.parse({"loadcell": {"rate": 80.0}}, "lab.toml").loadcell["rate"] == 80.0


def test_calibrate_takes_its_rate_from_rig_toml(tmp_path):
    """An HX711 build's rig.toml says 80 Hz: the calibration runs at 80 Hz without --rate."""
    toml = tmp_path / "rig.toml"
    toml.write_text("[loadcell]\nrate = 80\n")
    res = CliRunner().invoke(main, ["--config", str(toml), "loadcell-calibrate", "--seconds", "0.3", "--json"])
    assert res.exit_code == 0, res.output
    doc = json.loads(res.stdout)
    assert doc["parameters"]["rate_hz"] == 80
    # the samples of the check came at 80 Hz (by the device's clock: 0.3 s holds about 24)
    assert 15 <= doc["check"]["n"] <= 30, doc["check"]


def _calibrated_on(root: Path, device: str, k: float) -> None:
    from datetime import datetime, timezone

    run = root / run_dir_name("loadcell-calibrate", datetime.now(timezone.utc))
    run.mkdir(parents=True)
    (run / "result.json").write_text(json.dumps(
        {"status": "completed", "calibration": LoadCellCalibration(k, 5.0, device=device).to_dict()}))


def test_a_calibration_is_found_under_the_by_id_name_of_its_device(tmp_path, monkeypatch):
    """Calibrated on /dev/ttyACM0, then rig.toml moved to the /dev/serial/by-id link the guide
    recommends (a link to the same device): the calibration is still this cell's. A link to
    another device is not."""
    monkeypatch.setenv("RIG_LOGS", str(tmp_path / "logs"))
    device = tmp_path / "ttyACM0"
    device.write_text("")
    other = tmp_path / "ttyACM1"
    other.write_text("")
    by_id = tmp_path / "usb-Arduino_Uno_7513-if00"
    by_id.symlink_to(device)
    elsewhere = tmp_path / "usb-Arduino_Uno_9999-if00"
    elsewhere.symlink_to(other)
    _calibrated_on(tmp_path / "logs", str(device), 0.0125)
    assert load_latest_calibration(str(by_id)).newtons_per_count == 0.0125
    with pytest.raises(LoadCellNotCalibrated, match=f"on {re.escape(str(elsewhere))}"):
        load_latest_calibration(str(elsewhere))
    # and the other way round: calibrated on the link, found on the device's own name
    _calibrated_on(tmp_path / "logs", str(elsewhere), 0.02)
    assert load_latest_calibration(os.path.realpath(elsewhere)).newtons_per_count == 0.02
