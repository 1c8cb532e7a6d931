"""`rig doctor`: the lab's preflight, from its rig.toml, before any procedure.

One line per check, "ok", "todo" or "fail" first, then what was found and, unless ok, what
to do: this machine (Python, the ROS 2 packages, crtk_msgs, the domain and discovery
range), each arm's console (measured_js heard and its published rate against what each
procedure needs, the clock, the operating state, servo_ci subscribed, the console's power
and home topics), the load cell (port, access, baud rate, firmware, rate, streaming), every
mocap body (heard, rate, whole frames), the operator channel, and the results found for
this rig (rig.runs.preflight_results). Nothing moves: the devices are listened to and the
load cell streams for half a second.

Exit status (rig.commands.exit_codes): 0 when every device answers as the procedures need
(results not made yet are "todo", listed with the command that makes them, not
failures); 3 when a device does not (no console, a slow console, no servo_ci, no load cell
answer ...); 5 when only this machine's or rig.toml's set-up is wrong (crtk_msgs, the
domain, [ros] period, [loadcell] rate above the firmware's ...).
"""

from __future__ import annotations

import json
import time

import click

from rig.commands.exit_codes import EXIT_ABORTED, EXIT_COMPLETED, EXIT_INPUT
from rig.commands.options import config_from_context
from rig.commands.procedure import procedure_command

STEPS = ("this machine", "the ROS devices (arms' consoles, mocap, operator)", "the load cell",
         "the results found for this rig")


def exit_code(checks) -> int:
    """0 when nothing failed; EXIT_ABORTED when a device failed; else EXIT_INPUT."""
    codes = {c.code for c in checks if c.status == "fail"}
    if not codes:
        return EXIT_COMPLETED
    return EXIT_ABORTED if EXIT_ABORTED in codes else EXIT_INPUT


def run(cfg, timeout: float, say=None) -> dict:
    """Every check of `cfg`'s rig, in order, as the result document ("status", "exit_code",
    "checks"); `say(line)` is called as each check's line is known. Records no run."""
    from rig.devices import preflight, preflight_loadcell
    from rig.runs import preflight_results

    checks = []

    def add(found):
        for c in found:
            checks.append(c)
            if say is not None:
                say(c.line())

    env = preflight.environment(cfg)
    add(env)
    if not any(c.what == "ROS 2" and c.status == "fail" for c in env):
        add(preflight.ros_devices(cfg, timeout))
    add(preflight_loadcell.loadcell(cfg))
    add(preflight_results.results(cfg))
    code = exit_code(checks)
    return {"status": "completed" if code == 0 else "failed", "exit_code": code,
            "checks": [c.__dict__ for c in checks]}


def report(result: dict, source: str, seconds: float) -> str:
    """The summary line of a doctor's `result`: `source` the rig.toml, `seconds` its time."""
    checks = result["checks"]
    failed = [c for c in checks if c["status"] == "fail"]
    todo = [c for c in checks if c["status"] == "todo"]
    return (f"rig doctor: {len(checks) - len(failed) - len(todo)} ok, {len(todo)} to do, {len(failed)} failed "
            f"({source}, {seconds:.1f} s)")


@procedure_command("doctor", STEPS, steps_help="List what is checked and exit.", yes=False)
@click.option("--timeout", type=click.FloatRange(min=0.5, max=60.0), default=3.0, show_default=True,
              help="Seconds each device is listened for before it is reported silent (the ROS devices share one "
                   "wait; the load cell's board is given 2.5 s more to come out of its reset).")
def command(ctx, timeout: float, as_json: bool) -> None:
    """Check this rig from its rig.toml before any procedure: one line per check.

    Lines start with ok, todo (a result not made yet, with the command that makes it) or
    fail (what to do). Exit 0 when every device answers as the procedures need, 3 when a
    device does not, 5 when this machine's or rig.toml's set-up is wrong. Nothing moves.
    """
    cfg = config_from_context(ctx)
    t0 = time.monotonic()
    result = run(cfg, timeout, say=None if as_json else click.echo)
    summary = report(result, cfg.source, time.monotonic() - t0)
    if as_json:
        click.echo(json.dumps(result))
    click.echo(summary, err=True)
    ctx.exit(result["exit_code"])
