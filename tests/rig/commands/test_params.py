"""Parameters declared once: click options, checks, defaults, start metadata."""

import re

import click
import pytest
from click.testing import CliRunner

from rig.commands.parameters import Parameter, ParameterSet, resolve, with_parameters

FORCE = Parameter("force", 5.0, "N", "Tension to hold between the tool tips", minimum=0.0, maximum=12.0)
CYCLES = Parameter("cycles", 3, "", "Number of excitation periods", minimum=1, type=int)
JOINT = Parameter("joint", 3, "", "Joint to ramp", choices=(1, 2, 3), type=int)
MODE = Parameter("mode", "ramp", "", "Test kind", choices=("ramp", "constant"), type=str)
DRY = Parameter("dry_run", False, "", "Check limits without moving", type=bool)
ALL = [FORCE, CYCLES, JOINT, MODE, DRY]


@click.command()
@with_parameters(ALL)
def command(parameters):
    click.echo(repr(sorted(parameters.items())))
    click.echo(repr(parameters.describe()["force"]))


def run(*args):
    return CliRunner().invoke(command, list(args))


def test_defaults_reach_the_command_as_one_dict():
    result = run()
    assert result.exit_code == 0, result.output
    assert "[('cycles', 3), ('dry_run', False), ('force', 5.0), ('joint', 3), ('mode', 'ramp')]" in result.output
    assert "{'value': 5.0, 'units': 'N', 'default': 5.0, 'help': 'Tension to hold between the tool tips'}" in result.output


def test_options_convert_and_check():
    result = run("--force", "7.5", "--cycles", "4", "--joint", "2", "--mode", "constant", "--dry-run")
    assert result.exit_code == 0, result.output
    assert "('force', 7.5)" in result.output and "('cycles', 4)" in result.output
    assert "('joint', 2)" in result.output and "('dry_run', True)" in result.output
    assert "('mode', 'constant')" in result.output


def test_help_shows_units_range_and_default():
    text = " ".join(run("--help").output.split())
    assert "--force FLOAT Tension to hold between the tool tips [N; 0.0 <= x <= 12.0; default: 5.0]" in text
    assert "--cycles INT Number of excitation periods [1 <= x; default: 3]" in text
    assert "--dry-run / --no-dry-run" in text
    # declaration order is kept
    assert text.index("--force") < text.index("--cycles") < text.index("--joint") < text.index("--mode")


def test_help_of_every_command_says_one_legal_value_plainly_and_shows_no_empty_default():
    """`--joints [3 <= x <= 3]` and `[default: ]` in a command's help are noise: an option
    with one legal value says so, an empty text default is not shown."""
    from rig.cli import COMMANDS, main

    for name in COMMANDS:
        text = " ".join(CliRunner().invoke(main, [name, "--help"]).output.split())
        assert "[default: ]" not in text and "default: ;" not in text, name
        for lo, hi in re.findall(r"\[(?:[^\]]*; )?([-0-9.e]+) <= x <= ([-0-9.e]+)", text):
            assert lo != hi, f"{name}: {lo} <= x <= {hi}"
        assert "issue " not in text.lower(), f"{name} --help names an issue"
    text = " ".join(CliRunner().invoke(main, ["identify", "--help"]).output.split())
    assert "(the model has joints 1-3) [only 3 is supported]" in text


@pytest.mark.parametrize("args, message", [
    (["--force", "15"], "15.0 N is above the maximum 12.0 N"),
    (["--force", "-1"], "-1.0 N is below the minimum 0.0 N"),
    (["--force", "nan"], "nan is not a finite number"),
    (["--force", "abc"], "'abc' is not a valid float"),
    (["--cycles", "2.5"], "'2.5' is not a valid int"),
    (["--joint", "4"], "'4' is not one of"),
])
def test_bad_values_get_a_clear_error(args, message):
    result = run(*args)
    assert result.exit_code == 2
    assert message in result.output
    assert "Invalid value for '" + args[0] in result.output


def test_resolve_for_calling_from_python():
    values = resolve(ALL, {"force": 2})
    assert isinstance(values, ParameterSet)
    assert values["force"] == 2.0 and isinstance(values["force"], float)
    assert values["cycles"] == 3
    with pytest.raises(ValueError, match="--force: 20.0 N is above the maximum 12.0 N"):
        resolve(ALL, {"force": 20})
    with pytest.raises(ValueError, match="unknown parameter\\(s\\) forse"):
        resolve(ALL, {"forse": 2})
    with pytest.raises(ValueError, match="--mode: 'sweep' is not one of ramp, constant"):
        resolve(ALL, {"mode": "sweep"})


def test_required_parameter():
    needed = Parameter("body", None, "", "Mocap rigid body name", type=str)
    with pytest.raises(ValueError, match="--body is required"):
        resolve([needed], {})

    @click.command()
    @with_parameters([needed])
    def cmd(parameters):
        click.echo(parameters["body"])

    assert CliRunner().invoke(cmd, []).exit_code == 2
    assert CliRunner().invoke(cmd, ["--body", "tool"]).output == "tool\n"


def test_bad_declarations_are_refused():
    with pytest.raises(ValueError, match="above the maximum"):
        Parameter("force", 20.0, "N", "x", maximum=12.0)
    with pytest.raises(ValueError, match="identifier"):
        Parameter("max-force", 1.0, "N", "x")
    with pytest.raises(ValueError, match="declared twice"):
        with_parameters([FORCE, FORCE])
    with pytest.raises(ValueError, match="minimum 2 > maximum 1"):
        Parameter("k", 1.5, "", "x", minimum=2, maximum=1)
