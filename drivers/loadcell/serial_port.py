"""The load cell's USB serial port: opened with pyserial, and the USB serial number behind it."""

from __future__ import annotations

import os

from drivers.loadcell.errors import LoadCellDisconnected


def open_serial_port(path: str, baudrate: int):
    """The load cell's serial port opened with pyserial; a port that cannot be opened is a
    LoadCellDisconnected naming it and what to check."""
    import serial

    try:
        return serial.Serial(path, baudrate, timeout=0.005)
    except (serial.SerialException, OSError, ValueError) as exc:
        why = getattr(exc, "strerror", None) or str(exc)
        raise LoadCellDisconnected(f"load cell port {path}: cannot open ({why}); check the cable, the "
                                   "port in rig.toml [loadcell] (or `rig sim`'s printed pty)") from None


def usb_serial_number(port: str) -> str:
    """The USB serial number of the device behind `port` (a /dev/serial/by-id link is
    followed), as the operating system reports it; "" for a pty or an unknown port."""
    try:
        from serial.tools import list_ports

        real = os.path.realpath(port)
        for info in list_ports.comports():
            if os.path.realpath(info.device) == real:
                return info.serial_number or ""
    except Exception:  # noqa: BLE001 - no enumeration on this platform: the port names the cell
        return ""
    return ""
