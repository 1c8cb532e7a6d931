"""One decorator for a procedure's command: `@procedure_command(name, STEPS, PARAMETERS)`.

    @procedure_command("friction-ramp", STEPS, PARAMETERS)
    @click.option(...)                      # the command's own options, if any
    def command(ctx, parameters, ..., as_json): ...

It gives every procedure the same command line: the declared parameters' options first
(rig.commands.parameters, units and bounds in --help), then the command's own, then
`--steps` (the steps listed, nothing run), `--yes` and `--json`; the click context; the
one-line exit on an abort, a fault or bad input (rig.commands.abort). `--steps` is handled
here: the function runs only when the steps are not asked for.
"""

from __future__ import annotations

import functools
from typing import Callable, Sequence

import click

from rig.commands.abort import exit_on_abort
from rig.commands.options import json_option, yes_option
from rig.commands.parameters import Parameter, with_parameters

STEPS_HELP = "List the steps and exit without moving anything."


def _params_of(*decorators) -> list:
    """The click parameters these option decorators make, innermost first (click's order)."""
    def holder():
        pass
    for d in reversed(decorators):
        holder = d(holder)
    return list(holder.__click_params__)


def procedure_command(name: str, steps: Sequence[str] | Callable[[dict], Sequence[str]],
                      parameters: Sequence[Parameter] | None = None, *, steps_help: str = STEPS_HELP,
                      yes: bool = True, json_help: str | None = None, json: bool = True,
                      context: bool = True, abort: bool = True, echo: Callable[[str], None] = click.echo,
                      order: Sequence[str] = ("steps", "yes", "json")) -> Callable:
    """The click command of a procedure (see the module docstring). `steps`: its step names,
    or a function of the command's keyword arguments giving them (a procedure whose steps
    depend on an option); `echo`: how the steps are printed; `order`: of --steps, --yes
    and --json in --help; `abort`: the one-line exit (rig sim, which records no run,
    has its own)."""

    def decorate(fn: Callable) -> Callable:
        own = list(getattr(fn, "__click_params__", []))

        @functools.wraps(fn)
        def run(*args, **kwargs):
            if kwargs.pop("list_steps"):
                names = steps(kwargs) if callable(steps) else steps
                for i, s in enumerate(names, 1):
                    echo(f"{i}. {s}")
                return None
            return fn(*args, **kwargs)

        f = exit_on_abort(run) if abort else run
        if context:
            f = click.pass_context(f)
        made = {"steps": click.option("--steps", "list_steps", is_flag=True, help=steps_help),
                "yes": yes_option if yes else None,
                "json": (json_option if json_help is None else click.option("--json", "as_json", is_flag=True,
                                                                            help=json_help)) if json else None}
        tail = [made[k] for k in order if made[k] is not None]
        # --steps, --yes and --json after the command's own options in --help
        f.__click_params__ = _params_of(*tail) + own
        if parameters is not None:
            f = with_parameters(parameters)(f)
        return click.command(name=name)(f)

    return decorate
