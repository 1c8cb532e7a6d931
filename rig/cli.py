"""The `rig` command line.

Commands are imported only when invoked so that `rig --help` stays fast (ROS 2 and
Pinocchio take a second or more to import). Each entry maps a command name to the
`module:attribute` of its click command and a one-line summary for the listing.
"""

from __future__ import annotations

import importlib
import os

# One BLAS thread per process, unless the user says otherwise: the rig's matrices are small
# (3x3 to a few hundred rows), and OpenBLAS's worker threads spin on a core while they wait:
# on a 2-core machine running `rig sim` and a procedure side by side they starved both (an
# SVD of identify's regressor took 0.28 s with the default threads, 0.0026 s with one).
# Set before numpy is first imported (every command imports it after this).
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import click  # noqa: E402

from rig import __version__

# name -> (module:attribute, summary shown by `rig --help`)
COMMANDS: dict[str, tuple[str, str]] = {
    "link-lengths": ("procedures.link_lengths:command", "Mocap link-length and joint-axis fit of a PSM (thesis 4.1.1, A.1)."),
    "calibrate-rcm": ("procedures.calibrate_rcm:command", "Remote-centre-of-motion pivot calibration from mocap (A.2, Table 6.1)."),
    "register": ("procedures.register:command", "Arm-to-arm base registration for cooperative work (7.7.1)."),
    "identify": ("procedures.identify:command", "Excitation, recording and dynamic identification (5.1-5.5)."),
    "friction-ramp": ("procedures.friction_ramp:command", "Stick-slip force-ramp and constant-velocity friction tests of joint 3 (5.6)."),
    "cooperative": ("procedures.cooperative:command", "Cooperative manipulation with force tracking (6.3, 7.7)."),
    "discrepancy": ("procedures.discrepancy:command", "Find where model and measurement disagree, name the effect, add it."),
    "estimate-force": ("procedures.estimate_force:command", "The force at a tool tip over a recording, from the arm's joints, efforts and model (no force sensor)."),
    "validate": ("procedures.validate:command", "Predict a recording's efforts from a model file, effects included; relative error and RMS per joint."),
    "sim": ("procedures.sim:command", "Serve the simulated rig over the real device protocols (ROS 2, serial)."),
    "selftest": ("procedures.selftest:command", "Short run of the simulated rig: PID step on every arm, object tension."),
    "doctor": ("procedures.doctor:command", "Preflight of the rig in rig.toml: every device and result, one line each."),
    "loadcell-calibrate": ("procedures.loadcell_calibrate:command", "Two-point load-cell calibration with known masses, stored for later runs."),
    "runs": ("rig.runs_cli:runs_command", "List recorded runs (time, procedure, status, key result)."),
    "export": ("rig.export_cli:export_command", "Export a run's recorded streams as CSV: one file per topic (--out) or an arm's q, dq, tau (--csv, wpi-psm)."),
    "plot": ("rig.plot_cli:plot_command", "Draw a run's figures again from its recording (aborted runs too)."),
}


class LazyGroup(click.Group):
    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted(COMMANDS)

    def get_command(self, ctx: click.Context, name: str) -> click.Command | None:
        if name not in COMMANDS:
            return None
        target, _ = COMMANDS[name]
        module_name, attr = target.split(":")
        return getattr(importlib.import_module(module_name), attr)

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        rows = [(name, COMMANDS[name][1]) for name in self.list_commands(ctx)]
        with formatter.section("Commands"):
            formatter.write_dl(rows)


def _exit_codes_epilog() -> str:
    from rig.commands.exit_codes import MEANINGS

    return "\b\nExit status:\n" + "\n".join(f"  {code:>3}  {text}" for code, text in MEANINGS)


@click.group(cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"]}, epilog=_exit_codes_epilog())
@click.version_option(__version__, prog_name="rig")
@click.option("--config", "config_path", type=click.Path(dir_okay=False), default=None,
              envvar="RIG_CONFIG", help="Rig configuration (TOML). Default: ./rig.toml if present, else the built-in simulated rig.")
@click.pass_context
def main(ctx: click.Context, config_path: str | None) -> None:
    """Drive the dVRK cooperative-manipulation rig (or its simulation).

    Every procedure is recorded under logs/. With no rig.toml, every command runs on the
    built-in simulated rig (PSM1, PSM2, a spring object with a load cell, a mocap system).
    Units are SI: m, rad, N, N m, s.
    """
    ctx.obj = {"config_path": config_path}
    if config_path is not None:  # a file the user named is checked whatever the command
        from rig import config

        try:
            config.load(config_path)
        except config.ConfigError as exc:
            from rig.commands.exit_codes import InputError

            raise InputError(str(exc)) from None


def run() -> None:
    """The `rig` program: the command, then the process's end through `drivers.common.ros_exit.leave`
    (a command that used ROS 2 leaves its DDS participants to the process's end)."""
    from drivers.common import ros_exit

    ros_exit.end_with_process()
    try:
        main()
    except SystemExit as done:
        ros_exit.leave(done.code)
    ros_exit.leave(0)


if __name__ == "__main__":  # pragma: no cover
    run()
