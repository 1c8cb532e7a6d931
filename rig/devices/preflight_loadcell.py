"""The load cell's preflight (`rig doctor`): each configured port there, readable, the
board answering at the configured baud rate with the rig's firmware, taking the configured
rate, and streaming it (half a second of samples; the rate from the board's own clock).
"""

from __future__ import annotations

import os

from rig.commands.exit_codes import EXIT_INPUT
from rig.devices.preflight import Check, fail, ok

#: s of samples the rate is counted over
WINDOW = 0.5


def loadcell(cfg) -> list[Check]:
    lc = cfg.loadcell
    if lc["driver"] == "none":
        return [ok("load cell", f"none in {cfg.source} (`rig cooperative` needs one: [loadcell] driver)")]
    if lc["driver"] == "sim":
        return [ok("load cell", "simulated in-process")]
    if lc["driver"] == "can":
        return [ok("load cell", f"CAN on {lc['interface']} {lc['channel']}: not probed (the procedures identify it "
                   "when they open it)")]
    ports = lc["ports"] or [lc["port"]]
    return [_serial(cfg, port, "load cell" if len(ports) == 1 else f"load cell {k}") for k, port in enumerate(ports)]


def _serial(cfg, port: str, what: str) -> Check:
    from drivers.loadcell.errors import LoadCellError
    from drivers.loadcell.protocol import ADC_NAMES
    from drivers.loadcell.serial_driver import LoadCell
    from drivers.loadcell.serial_port import open_serial_port, usb_serial_number

    lc = cfg.loadcell
    if not os.path.exists(port):
        return fail(what, f"{port}: no such device: plug the board in, find it with `ls /dev/serial/by-id/ "
                    "/dev/ttyACM* /dev/ttyUSB*` and set [loadcell] port (the /dev/serial/by-id/... path survives "
                    "replugging)")
    real = os.path.realpath(port)
    shown = port if real == port else f"{port} -> {real}"
    if not os.access(real, os.R_OK | os.W_OK):
        return fail(what, f"{shown}: not readable and writable by this user: `sudo usermod -aG dialout $USER`, "
                    "then log out and in", EXIT_INPUT)
    rate = int(round(lc["rate"]))
    try:
        ser = open_serial_port(port, lc["baudrate"])
    except LoadCellError as exc:
        return fail(what, str(exc))
    cell = None
    try:
        try:
            cell = LoadCell(ser, None, rate_hz=rate, stale_timeout=max(0.5, lc["stale_timeout"]), start=True)
        except LoadCellError as exc:
            text = str(exc)
            if "firmware allows" in text:
                limit = text.rsplit("allows ", 1)[1].split()[0]
                return fail(what, f"{text}: set [loadcell] rate = {limit} in {cfg.source} (or flash the INA build)",
                            EXIT_INPUT)
            return fail(what, text)
        ident = cell.identity
        got = cell.collect_samples(WINDOW)
        # by the board's own clock: a host (or a simulated world) running behind the wall's
        # does not make a healthy board look slow
        counted = cell.device_rate() if len(got) >= 2 else 0.0
        serial = usb_serial_number(port)
        found = (f"{shown} at {lc['baudrate']} baud: firmware {'.'.join(map(str, ident.firmware))}, "
                 f"{ADC_NAMES.get(ident.adc, f'ADC {ident.adc}')} (up to {ident.max_rate_hz} Hz)"
                 + (f", USB serial {serial}" if serial else ""))
        if counted < 0.8 * rate:
            return fail(what, f"{found}; {counted:.0f} samples/s (by its clock) where {rate} Hz was set ([loadcell] rate): the board "
                        "or its cable loses samples; check the build (HX711: 80 Hz at most) and the USB cable")
        return ok(what, f"{found}; streams {counted:.0f} samples/s by its clock ([loadcell] rate {rate} Hz)")
    finally:
        if cell is not None:
            try:
                cell.stop()
            except LoadCellError:
                pass
            cell.close()
        ser.close()
