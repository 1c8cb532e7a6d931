"""The newest `rig loadcell-calibrate` result of a load cell, found in the run folders and checked to be of that cell."""

from __future__ import annotations

import json
import os

from drivers.loadcell.errors import LoadCellNotCalibrated
from drivers.loadcell.force_calibration import LoadCellCalibration
from drivers.loadcell.serial_port import usb_serial_number

CALIBRATION_PROCEDURE = "loadcell-calibrate"


def same_device(a: str, b: str) -> bool:
    """Whether two port names are one device: the same path once every link is followed
    (`/dev/serial/by-id/usb-Arduino...-if00` and the `/dev/ttyACM0` it points to)."""
    if not a or not b:
        return a == b
    return a == b or os.path.realpath(a) == os.path.realpath(b)


def calibration_mismatch(data: dict, device: str | None) -> str | None:
    """Why the calibration run `data` (a result.json) is not of the cell on `device`, or None.

    A cell is its USB serial number when the operating system reports one, now and when it
    was calibrated (the same board on another port, or under its /dev/serial/by-id name, is
    the same cell); else the device its port resolves to (links followed). A result edited
    by hand after it was written (its provenance digest) belongs to no cell.
    """
    from rig import sealed_json

    made_on = str((data.get("calibration") or {}).get("device") or "")
    prov = data.get(sealed_json.KEY)
    if isinstance(prov, dict) and not sealed_json.sealed(data):
        return "edited after it was written (its digest does not match)"
    was = ((prov.get("cell") or {}).get("usb_serial") or "") if isinstance(prov, dict) else ""
    if device is None:
        return None
    now = usb_serial_number(device)
    if was and now:
        if was != now:
            return f"made on the cell with USB serial {was}; {device} is now the cell with serial {now}"
        return None
    if not same_device(made_on, device):
        return f"made on {made_on or 'an unnamed port'}, not {device} (nor the device it resolves to)"
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
        if same_device(str(data["calibration"].get("device") or ""), device or ""):  # other ports' cells: not news
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
