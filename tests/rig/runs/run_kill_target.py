"""A recording procedure to be killed by tests/rig/runs/test_run.py (not a test itself).

Usage: python run_kill_target.py MODE MARKER_DIR  (RIG_LOGS chooses where the run goes)
MODE: "wait" records until a signal arrives; "raise" raises RuntimeError after the
first READY_AFTER samples. Prints "READY <run_dir>" once READY_AFTER samples are queued.
The claimed fake arm writes MARKER_DIR/held-<name> when held, so the parent can see that
the engine made it safe.
"""

import sys
import time
from pathlib import Path

import click

from rig.commands.abort import exit_on_abort
from rig.commands.parameters import Parameter, with_parameters
from rig.runs.run import Run

READY_AFTER = 500


class MarkerArm:
    def __init__(self, name: str, marker_dir: Path):
        self.name = name
        self.marker_dir = marker_dir

    def hold(self) -> None:
        (self.marker_dir / f"held-{self.name}").write_text("held\n")


@click.command("killtarget")
@click.argument("mode", type=click.Choice(["wait", "raise"]))
@click.argument("marker_dir", type=click.Path(file_okay=False))
@with_parameters([Parameter("rate", 1000.0, "Hz", "Sample rate of the fake stream", minimum=1.0)])
@exit_on_abort
def main(mode: str, marker_dir: str, parameters) -> None:
    marker = Path(marker_dir)
    with Run("killtest", parameters=parameters, seed=11, progress=False) as run:
        run.claim(MarkerArm("PSM1", marker))
        run.claim(MarkerArm("PSM2", marker))
        with run.step("stream"):
            i = 0
            while True:
                t = i / parameters["rate"]
                run.recorder.joint_state("/PSM1/measured_js", t, [t, 2 * t, 3 * t], [1.0, 2.0, 3.0],
                                         [float(i), 0.0, 0.0], ("j1", "j2", "j3"))
                run.recorder.tension("/loadcell/force", t, 0.5 * t)
                i += 1
                if i == READY_AFTER:
                    if mode == "raise":
                        raise RuntimeError("simulated driver fault")
                    print(f"READY {run.dir}", flush=True)
                if i > READY_AFTER:
                    time.sleep(0.0005)


if __name__ == "__main__":
    sys.exit(main())
