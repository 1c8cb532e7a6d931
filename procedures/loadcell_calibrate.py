"""`rig loadcell-calibrate`: two-point load-cell calibration with known masses.

Hang mass 1 (usually nothing), average the counts; hang mass 2, average again; the line
through the two points (force = m g, g = 9.80665 m/s^2) is the calibration. It is saved as
`result.json` of a run folder, where `rig.devices.loadcell_calibrations.load_latest_calibration()` finds it.
On the simulated rig the firmware fake is loaded with the masses by the procedure itself,
and the result also reports the fake's true gain so the fit can be judged. On a rig.toml
with `[loadcell] driver = "serial"` the configured port is calibrated and the rig's
operator (drivers.operator.driver) hangs the masses: the person at the console, or `rig sim`'s
simulated operator.
"""

from __future__ import annotations

import math
import statistics
import sys
import time
from datetime import datetime, timezone
from pathlib import Path

import click

from drivers.loadcell.errors import LoadCellError
from drivers.loadcell.fake_firmware import FakeLoadCellFirmware
from drivers.loadcell.force_calibration import STANDARD_GRAVITY, LoadCellCalibration
from drivers.loadcell.protocol import FIRMWARE_MAX_RATE_HZ
from drivers.loadcell.serial_driver import LoadCell
from drivers.loadcell.serial_port import usb_serial_number
from drivers.operator.driver import OperatorError
from rig.commands.exit_codes import EXIT_MISSED, InputError
from rig.commands.options import config_from_context
from rig.commands.procedure import procedure_command
from rig.commands.report import emit_result
from rig.devices.loadcell_calibrations import CALIBRATION_PROCEDURE
from rig.runs.recording import package_version
from rig.runs.run import AbortRun, Run
from rig.sealed_json import result_json

#: The check reads mass 2 through the new calibration: it must agree with m g within
#: 20 mN (the calibration's accuracy target, bench_loadcell) or 1 % of the load, whichever
#: is larger; beyond it the masses were still swinging or the cell drifts.
CHECK_BOUND_N = 0.02
CHECK_BOUND_REL = 0.01

STEPS = (
    "connect to the load cell",
    "tare with mass 1 hanging",
    "average counts with mass 1",
    "average counts with mass 2",
    "fit the two-point calibration",
    "check the force with mass 2",
)


class HangingMass:
    """Tension source for the simulated cell: the weight of whatever hangs from it (N)."""

    def __init__(self) -> None:
        self.kg = 0.0

    def __call__(self) -> float:
        return self.kg * STANDARD_GRAVITY


def _point(mass_kg: float, counts: list[int]) -> dict:
    if len(counts) < 2:
        raise LoadCellError(f"only {len(counts)} samples with {mass_kg} kg; is the cell streaming?")
    std = statistics.stdev(counts)
    return {"mass_kg": mass_kg, "force_n": mass_kg * STANDARD_GRAVITY, "mean_counts": statistics.fmean(counts),
            "std_counts": std, "sem_counts": std / math.sqrt(len(counts)), "n": len(counts)}


@procedure_command("loadcell-calibrate", STEPS, steps_help="List the steps and exit without running.",
                   json_help="Print the result (result.json) on stdout and the report on stderr.",
                   order=("steps", "json", "yes"))
@click.option("--mass1", type=float, default=0.0, show_default=True,
              help="First known mass hanging from the cell (kg); 0 = nothing attached.")
@click.option("--mass2", type=float, default=0.5, show_default=True,
              help="Second known mass (kg); pick one near the working tension (0.5 kg = 4.9 N).")
@click.option("--port", type=click.Path(dir_okay=False), default=None,
              help="Serial port of the load-cell Arduino, e.g. /dev/ttyACM0. Default: rig.toml's [loadcell] port when "
                   "its driver is 'serial', else the simulated cell.")
@click.option("--element", type=click.IntRange(0), default=None,
              help="On a rig with a load cell per object element (rig.toml [loadcell] ports): which element's cell "
                   "to calibrate (0 = PSM1-PSM2, 1 = PSM1-PSM3, 2 = PSM2-PSM3).")
@click.option("--sim", is_flag=True, help="Use the in-process simulated load cell, whatever rig.toml says.")
@click.option("--baud", type=int, default=None, help="Serial speed (baud). Default: rig.toml's [loadcell] baudrate (that of the rig's firmware).")
@click.option("--seconds", type=click.FloatRange(0.1, 60), default=2.0, show_default=True,
              help="Averaging time at each mass (s).")
@click.option("--rate", "rate_hz", type=click.IntRange(1, FIRMWARE_MAX_RATE_HZ), default=None,
              help="Sample rate, Hz. Default: rig.toml's [loadcell] rate (500 Hz unless it says otherwise; the HX711 "
                   "build's limit is 80 Hz).")
def command(ctx, mass1: float, mass2: float, port: str | None, element: int | None, sim: bool, baud: int | None,
            seconds: float, rate_hz: int, as_json: bool) -> None:
    """Two-point load-cell calibration with known masses (kg), stored for later runs.

    Forces are m g with g = 9.80665 m/s^2, in N. The calibration maps ADC counts to
    tension in N and is saved to logs/<UTC time>-loadcell-calibrate/result.json.
    """
    if port and sim:
        raise click.UsageError("give either --port or --sim, not both")
    if mass1 < 0 or mass2 < 0 or mass1 == mass2:
        raise click.UsageError("--mass1 and --mass2 must be non-negative and different (kg)")
    cfg = config_from_context(ctx)
    ports = cfg.loadcell["ports"] if cfg.loadcell["driver"] == "serial" else []
    if element is not None:
        if port or sim:
            raise click.UsageError("give --element, or --port / --sim, not both")
        if element >= len(ports):
            raise click.UsageError(f"--element {element}: {cfg.source} [loadcell] ports names "
                                   f"{len(ports)} cell(s)" + ("" if ports else "; --element needs a cell per element"))
        port = ports[element]
    elif len(ports) > 1 and port is None and not sim:
        raise click.UsageError(f"{cfg.source} names a load cell per object element ({', '.join(ports)}): "
                               f"give --element 0..{len(ports) - 1} (or --port)")
    if port is None and not sim and cfg.loadcell["driver"] == "serial":
        port = cfg.loadcell["port"]
    elif port is None and not sim and cfg.loadcell["driver"] == "can":
        raise InputError(f"{cfg.source}: loadcell.driver = 'can': this command calibrates a serial cell; "
                                   "give --port, or --sim")
    if baud is None:
        baud = cfg.loadcell["baudrate"]
    if rate_hz is None:
        rate_hz = int(round(cfg.loadcell["rate"]))
    simulated = port is None
    params = {"mass1_kg": mass1, "mass2_kg": mass2, "port": port, "element": element, "sim": simulated, "baud": baud,
              "seconds": seconds, "rate_hz": rate_hz}
    # Progress and the end line on stderr and result.json with its timings, as every
    # procedure: the run engine (rig.runs.run) writes them. No arm moves, none is claimed.
    result = run(cfg, params, element)
    if result["status"] != "completed":
        if as_json:  # the document first, as every procedure's --json
            click.echo(result_json(result, indent=None))
        # it ran and missed its bound, or its readings made no calibration: a failed run
        click.echo(f"rig {CALIBRATION_PROCEDURE}: failed: {result['error']} (run folder {result['run_dir']})", err=True)
        sys.exit(EXIT_MISSED)
    emit_result(result, as_json, report(result))


class _Devices:
    """What a calibration opens (the simulated cell's firmware, the port, the driver, the ROS
    session, the operator), closed together however the run ends."""

    def __init__(self):
        self.fake = self.ser = self.lc = self.session = self.operator = None

    def close(self) -> None:
        if self.lc is not None:
            self.lc.close()
        if self.ser is not None:
            self.ser.close()
        if self.fake is not None:
            self.fake.unplug()
        if self.session is not None:
            self.session.time.close()  # leave the lockstep (on the wall clock: nothing to leave)
            self.session.close()


def run(cfg, params: dict, element: int | None) -> dict:
    """The procedure, recorded by the run engine: its result document, "status"
    ("completed", or "failed" with "error") and "run_dir" included. A device or operator
    error aborts the run (AbortRun), recorded; Ctrl-C too."""
    with Run(CALIBRATION_PROCEDURE, parameters=params, config=cfg.snapshot(), steps=list(STEPS)) as rn:
        result = _steps(rn, cfg, params, element)
        rn.finish(result, result.pop("status"), result.get("error"))
    return rn.result


def _steps(run: Run, cfg, params: dict, element: int | None) -> dict:
    """The steps; the result document with its "status" ("completed" or "failed", with
    "error")."""
    simulated = params["sim"]
    mass1, mass2, seconds, rate_hz = params["mass1_kg"], params["mass2_kg"], params["seconds"], params["rate_hz"]
    result: dict = {"status": "failed", "parameters": params}
    weights = HangingMass()
    dev = _Devices()

    def hang(kg: float) -> None:
        if simulated:
            weights.kg = kg  # collect_counts() only takes samples converted from now on
        else:
            dev.operator.hang_mass(kg, element)
            # let it settle: the first conversions may still swing
            (dev.session.time.sleep if dev.session is not None else time.sleep)(0.1)

    try:
        with run.step(STEPS[0]):
            result["device"] = _open(dev, cfg, params, weights)
        lc = dev.lc
        with run.step(STEPS[1]):
            hang(mass1)
            tare = lc.tare_counts(min(255, max(1, int(rate_hz * min(seconds, 0.5)))))
        with run.step(STEPS[2]):
            p1 = _point(mass1, lc.collect_counts(seconds))
        with run.step(STEPS[3]):
            hang(mass2)
            p2 = _point(mass2, lc.collect_counts(seconds))

        with run.step(STEPS[4]):
            cal = LoadCellCalibration.from_two_points(
                mass1, p1["mean_counts"], mass2, p2["mean_counts"], p1["sem_counts"], p2["sem_counts"],
                device=result["device"]["port"])
            lc.calibration = cal

        with run.step(STEPS[5]):
            # through the new calibration from the raw counts of the samples converted from
            # now on, by their conversion time (a pty on a loaded machine delivers them late)
            forces: list[float] = []
            for sample in lc.collect_samples(min(seconds, 0.5)):
                forces.append(cal.newtons(sample.raw))
                run.recorder.tension("/loadcell/force", sample.t, forces[-1])
            if len(forces) < 2:
                raise LoadCellError(f"only {len(forces)} samples in the check with {mass2} kg; is the cell streaming?")
        _result(result, run, dev, params, cal, (p1, p2), tare, forces)
    except (LoadCellError, OperatorError, OSError) as exc:
        # the cell, its port or the operator's channel failed: an abort, as in every procedure
        # (the run engine records it with the reason; exit 3)
        raise AbortRun(str(exc)) from None
    except ValueError as exc:  # masses or readings that cannot make a calibration
        result["status"] = "failed"
        result["error"] = str(exc)
    finally:
        dev.close()
    return result


def _open(dev: _Devices, cfg, params: dict, weights) -> dict:
    """Open the cell (the simulated one's firmware on a pty, or the configured port, with the
    operator and, on ROS, the session); returns what the device says of itself."""
    import serial

    port, simulated, baud = params["port"], params["sim"], params["baud"]
    if simulated:
        dev.fake = FakeLoadCellFirmware(weights, noise=0.005).start()  # 5 mN rms, like a good bridge
        dev.ser = serial.Serial(dev.fake.port_path, baudrate=baud)
    else:
        from drivers.loadcell.serial_port import open_serial_port
        from rig.devices.factory import open_operator

        if cfg.operator["driver"] == "ros" or cfg.ros["use_sim_time"]:
            from drivers.common.ros_session import RosSession

            dev.session = RosSession("rig_loadcell_calibrate", executor=cfg.ros["executor"])
            if cfg.ros["use_sim_time"]:
                from drivers.common.time_base import SimTime

                # the served cell converts on the world's clock: its samples, the
                # windows and the timeouts on the same clock, in lockstep
                dev.session.time = SimTime(dev.session.node, lockstep=cfg.ros["lockstep"],
                                           polled=dev.session.executor_time)
        dev.operator = open_operator(cfg, dev.session)
        session = dev.session
        if session is not None:
            session.start()
            if session.time.simulated and not session.time.wait_heard(cfg.ros["connect_timeout"]):
                from drivers.common.ros_session import domain_text

                raise AbortRun(f"/clock: no simulated time within {cfg.ros['connect_timeout']:g} s on "
                               f"{domain_text()}; [ros] use_sim_time = true follows `rig sim --sim-time`: "
                               "start it so (or set use_sim_time = false)")
        dev.ser = open_serial_port(port, baud)
    # static loads: a scheduling hiccup is harmless here (a pty on a loaded machine
    # delivers up to ~0.35 s late), and a pulled cable still stops us at once
    sim_time = dev.session is not None and dev.session.time.simulated
    # (on simulated time the world waits for the cell's reader: drivers.common.time_base)
    dev.lc = LoadCell(dev.ser, None, rate_hz=params["rate_hz"], stale_timeout=max(0.5, cfg.loadcell["stale_timeout"]),
                      **({"clock": dev.session.time.now, "time_base": dev.session.time} if sim_time else {}))
    ident = dev.lc.identity
    return {"port": port or dev.fake.port_path, "protocol": ident.protocol,
            "firmware": ".".join(map(str, ident.firmware)), "adc": ident.adc,
            "max_rate_hz": ident.max_rate_hz, "simulated": simulated}


def _result(result: dict, run, dev: _Devices, params: dict, cal, points, tare: float, forces: list) -> None:
    """The calibration, its check against the second mass, provenance and (simulated) the
    truth, into `result`; "failed" when the check misses its bound."""
    simulated, mass2, port = params["sim"], params["mass2_kg"], params["port"]
    p1, p2 = points
    measured = statistics.fmean(forces)
    result.update(
        status="completed", calibration=cal.to_dict(), points=[p1, p2],
        tare_counts_mass1=tare, tare_minus_mean_counts=tare - p1["mean_counts"],
        check={"expected_n": p2["force_n"], "measured_n": measured, "error_n": measured - p2["force_n"],
               "std_n": statistics.stdev(forces), "n": len(forces)},
        stats=vars(dev.lc.stats()))
    result["summary"] = {"check_error": result["check"]["error_n"], "check_noise": result["check"]["std_n"],
                         "newtons_per_count": cal.newtons_per_count, "zero_counts": cal.zero_counts,
                         "cell": "simulated" if simulated else result["device"]["port"]}
    result["provenance"] = {
        "cell": {"port": result["device"]["port"], "usb_serial": "" if simulated else usb_serial_number(port),
                 "adc": result["device"]["adc"], "firmware": result["device"]["firmware"], "simulated": simulated},
        "source": {"run": run.dir.name}, "package_version": package_version(),
        "time": datetime.now(timezone.utc).isoformat(timespec="seconds")}
    bound = max(CHECK_BOUND_N, CHECK_BOUND_REL * p2["force_n"])
    if not abs(result["check"]["error_n"]) <= bound:
        result["status"] = "failed"
        result["error"] = (f"check with {mass2} kg read {measured:.4f} N, expected {p2['force_n']:.4f} N: error "
                           f"{result['check']['error_n'] * 1e3:+.1f} mN beyond {bound * 1e3:.0f} mN (the masses "
                           "swinging, or a cell that drifts: calibrate again)")
    if simulated:
        true_k = 1.0 / dev.fake.model.gain
        result["truth"] = {"newtons_per_count": true_k, "zero_counts": dev.fake.model.offset,
                           "gain_error_rel": cal.newtons_per_count / true_k - 1.0,
                           "zero_error_counts": cal.zero_counts - dev.fake.model.offset}


def report(result: dict) -> str:
    """The calibration, its check and the link, one line each (stdout; stderr with --json)."""
    cal, chk, st = result["calibration"], result["check"], result["stats"]
    mass2 = result["parameters"]["mass2_kg"]
    lines = [f"calibration: {cal['newtons_per_count'] * 1e3:.5f} mN/count "
             f"(+- {cal['newtons_per_count_std'] * 1e3:.5f}), zero at {cal['zero_counts']:.1f} counts",
             f"check with {mass2} kg: {chk['measured_n']:.4f} N measured, {chk['expected_n']:.4f} N expected "
             f"(error {chk['error_n'] * 1e3:+.2f} mN, noise {chk['std_n'] * 1e3:.1f} mN rms)"]
    if "truth" in result:
        lines.append(f"simulated cell: gain error {result['truth']['gain_error_rel'] * 100:+.3f} % "
                     "against the fake's truth")
    lines.append(f"link: {st['samples']} samples, {st['lost']} lost, {st['crc_errors']} CRC errors, "
                 f"{st['resyncs']} resyncs")
    lines.append(f"saved {Path(result['run_dir']) / 'result.json'}")
    return "\n".join(lines)
