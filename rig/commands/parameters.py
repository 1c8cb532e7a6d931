"""Procedure parameters, declared once.

One `Parameter` declaration gives a procedure its click option (help with units and
default, range and choice checks with a clear message), its defaults when it is called
from Python, and the description stored in the run's start metadata:

    FORCE = Parameter("force", 5.0, "N", "Tension to hold between the tool tips",
                      minimum=0.0, maximum=12.0)

    @click.command()
    @with_parameters([FORCE, DURATION])
    def command(parameters, ...):      # parameters == {"force": 5.0, "duration": 30.0}
        with Run("cooperative", parameters=parameters) as run: ...

`parameters` is a `ParameterSet` (a dict of name -> value) whose `describe()` adds units,
defaults and help for the start record.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Iterable, Sequence

import click


@dataclass(frozen=True)
class Parameter:
    """One procedure parameter.

    Args:
        name: Python identifier; the option is `--name` with `_` spelled `-`.
        default: value when not given (None means required).
        units: SI units shown in help and stored with the value ("" when dimensionless).
        help: one line saying what it sets.
        minimum, maximum: inclusive bounds, in `units`.
        choices: allowed values (then `type` is the type of each choice).
        type: float, int, str or bool (bool gives a `--name/--no-name` flag).
    """

    name: str
    default: Any
    units: str
    help: str
    minimum: float | None = None
    maximum: float | None = None
    choices: Sequence[Any] | None = None
    type: type = float

    def __post_init__(self) -> None:
        if not self.name.isidentifier():
            raise ValueError(f"parameter name must be a Python identifier: {self.name!r}")
        if self.type not in (float, int, str, bool):
            raise ValueError(f"parameter {self.name}: type must be float, int, str or bool")
        if self.minimum is not None and self.maximum is not None and self.minimum > self.maximum:
            raise ValueError(f"parameter {self.name}: minimum {self.minimum} > maximum {self.maximum}")
        if self.default is not None:
            self.check(self.default)  # a declaration whose default is out of range is a bug

    @property
    def option(self) -> str:
        return "--" + self.name.replace("_", "-")

    def _units(self) -> str:
        return f" {self.units}" if self.units else ""

    def convert(self, value: Any) -> Any:
        """The value as `type`, range and choice checked; raises ValueError saying why."""
        if value is None:
            raise ValueError(f"{self.option} is required")
        if self.type is bool:
            if isinstance(value, str):
                lowered = value.strip().lower()
                if lowered not in ("true", "false", "1", "0", "yes", "no"):
                    raise ValueError(f"{self.option}: {value!r} is not true or false")
                return lowered in ("true", "1", "yes")
            return bool(value)
        try:
            if self.type is int and isinstance(value, float) and not value.is_integer():
                raise ValueError
            converted = self.type(value)
        except (TypeError, ValueError):
            raise ValueError(f"{self.option}: {value!r} is not a valid {self.type.__name__}") from None
        return self.check(converted)

    def check(self, value: Any) -> Any:
        if self.type is float and not math.isfinite(value):
            raise ValueError(f"{self.option}: {value} is not a finite number")
        if self.choices is not None and value not in self.choices:
            allowed = ", ".join(str(c) for c in self.choices)
            raise ValueError(f"{self.option}: {value!r} is not one of {allowed}")
        if self.minimum is not None and value < self.minimum:
            raise ValueError(f"{self.option}: {value}{self._units()} is below the minimum "
                             f"{self.minimum}{self._units()}")
        if self.maximum is not None and value > self.maximum:
            raise ValueError(f"{self.option}: {value}{self._units()} is above the maximum "
                             f"{self.maximum}{self._units()}")
        return value

    def help_text(self) -> str:
        bits = []
        if self.units:
            bits.append(self.units)
        if self.minimum is not None and self.minimum == self.maximum:
            # one legal value: say it plainly (the option exists for the CSV format's sake)
            bits.append(f"only {self.minimum} is supported")
            return f"{self.help} [{'; '.join(bits)}]"
        if self.minimum is not None or self.maximum is not None:
            lo = "" if self.minimum is None else f"{self.minimum} <= "
            hi = "" if self.maximum is None else f" <= {self.maximum}"
            bits.append(f"{lo}x{hi}")
        if self.default is None:
            bits.append("required")
        elif self.default != "":  # an empty text default means "not given": nothing to show
            bits.append(f"default: {self.default}")
        return f"{self.help} [{'; '.join(bits)}]" if bits else self.help

    def describe(self, value: Any) -> dict:
        """The start-metadata entry: value, units, default, help."""
        return {"value": value, "units": self.units, "default": self.default, "help": self.help}


class _Checked(click.ParamType):
    """A click type that converts with the Parameter, so CLI and Python share one check."""

    def __init__(self, parameter: Parameter):
        self.parameter = parameter
        self.name = parameter.type.__name__

    def convert(self, value, param, ctx):
        try:
            return self.parameter.convert(value)
        except ValueError as exc:
            self.fail(str(exc).split(": ", 1)[-1], param, ctx)


class ParameterSet(dict):
    """name -> value, plus the declarations they came from."""

    def __init__(self, declarations: Iterable[Parameter], values: dict):
        super().__init__(values)
        self.declarations = {p.name: p for p in declarations}

    def describe(self) -> dict:
        """name -> {value, units, default, help}, for the run_start record."""
        return {name: (self.declarations[name].describe(value) if name in self.declarations
                       else {"value": value})
                for name, value in self.items()}


def _check_unique(declarations: Sequence[Parameter]) -> None:
    seen = set()
    for p in declarations:
        if p.name in seen:
            raise ValueError(f"parameter {p.name} is declared twice")
        seen.add(p.name)


def resolve(declarations: Sequence[Parameter], values: dict | None = None) -> ParameterSet:
    """Defaults overridden by `values`, every value checked; for calling from Python.

    Raises ValueError naming the parameter for an unknown name, a missing required value
    or a value out of range.
    """
    _check_unique(declarations)
    values = dict(values or {})
    known = {p.name for p in declarations}
    unknown = sorted(set(values) - known)
    if unknown:
        raise ValueError(f"unknown parameter(s) {', '.join(unknown)}; known: {', '.join(sorted(known))}")
    out = {p.name: p.convert(values.get(p.name, p.default)) for p in declarations}
    return ParameterSet(declarations, out)


def with_parameters(declarations: Sequence[Parameter], dest: str = "parameters") -> Callable:
    """Decorator for a click command: one option per Parameter, passed as one dict.

    The command receives `dest` (default `parameters`), a ParameterSet, instead of one
    keyword per option.
    """
    declarations = list(declarations)
    _check_unique(declarations)

    def decorate(fn: Callable) -> Callable:
        import functools

        @functools.wraps(fn)
        def wrapper(*args, **kwargs):
            values = {p.name: kwargs.pop(p.name) for p in declarations}
            kwargs[dest] = ParameterSet(declarations, values)
            return fn(*args, **kwargs)

        # click applies decorators bottom-up and lists options in reverse, so add them
        # reversed to keep the declaration order in --help.
        for p in reversed(declarations):
            if p.type is bool:
                option = click.option(f"{p.option}/--no-{p.option[2:]}", p.name,
                                      default=bool(p.default), help=p.help_text())
            else:
                # Click (8.3+) treats an explicit default=None as a value that satisfies
                # required=True, so a required option gets no default at all.
                extra = {"required": True} if p.default is None else {"default": p.default}
                if p.choices is not None:
                    option = click.option(p.option, p.name, type=click.Choice([str(c) for c in p.choices]),
                                          callback=lambda ctx, param, v, p=p: None if v is None else p.convert(v),
                                          help=p.help_text(), **extra)
                else:
                    option = click.option(p.option, p.name, type=_Checked(p), help=p.help_text(), **extra)
            wrapper = option(wrapper)
        return wrapper

    return decorate
