"""The newest `rig loadcell-calibrate` result of a load cell, found in the run folders and checked to be of that cell."""

from __future__ import annotations

import json

from drivers.loadcell.errors import LoadCellNotCalibrated
from drivers.loadcell.force_calibration import LoadCellCalibration
from drivers.loadcell.serial_port import usb_serial_number

CALIBRATION_PROCEDURE = "loadcell-calibrate"


def calibration_mismatch(data: dict, device: str | None) -> str | None:
    """Why the calibration run `data` (a result.json) is not of the cell on `device`, or None.

    A cell is its port and, when the operating system knows it, its USB serial number; a
    result edited by hand after it was written (its provenance digest) belongs to no cell.
    """
    from rig import sealed_json

    made_on = str((data.get("calibration") or {}).get("device") or "")
    if device is not None and made_on != device:
        return f"made on {made_on or 'an unnamed port'}, not {device}"
    prov = data.get(sealed_json.KEY)
    if isinstance(prov, dict):
        if not sealed_json.sealed(data):
            return "edited after it was written (its digest does not match)"
        was = (prov.get("cell") or {}).get("usb_serial") or ""
        now = usb_serial_number(device) if device else ""
        if was and now and was != now:
            return f"made on the cell with USB serial {was}; {device} is now the cell with serial {now}"
    return None


def load_latest_calibration(device: str | None = None) -> LoadCellCalibration:
    """The calibration of the newest completed `rig loadcell-calibrate` run of this cell.

    With `device` (the cell's port as rig.toml names it), only a calibration made on that
    port, of the same cell (calibration_mismatch): another cell's calibration is never
    taken. Without it (a CAN cell, which this command does not calibrate), the newest.
    """
    from rig.runs.paths import run_dirs, runs_root

    skipped = []
    for run in reversed(run_dirs(CALIBRATION_PROCEDURE)):
        try:
            data = json.loads((run / "result.json").read_text())
        except (OSError, json.JSONDecodeError):
            continue
        if not isinstance(data, dict) or data.get("status") != "completed" or "calibration" not in data:
            continue
        why = calibration_mismatch(data, device)
        if why is None:
            return LoadCellCalibration.from_dict(data["calibration"], source=str(run / "result.json"))
        if str(data["calibration"].get("device") or "") == (device or ""):  # other ports' cells: not news
            skipped.append(f"{run.name}: {why}")
    if device:
        raise LoadCellNotCalibrated(
            f"no completed '{CALIBRATION_PROCEDURE}' run of the load cell on {device} under {runs_root()}"
            + (f" (skipped {'; '.join(skipped)})" if skipped else "")
            + f"; run `rig loadcell-calibrate --port {device}` (or --element) first")
    raise LoadCellNotCalibrated(
        f"no completed '{CALIBRATION_PROCEDURE}' run under {runs_root()}"
        + (f" (skipped {'; '.join(skipped)})" if skipped else "")
        + "; run `rig loadcell-calibrate` first (or set RIG_LOGS to where it was run)")
