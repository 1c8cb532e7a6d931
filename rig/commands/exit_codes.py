"""What `rig`'s exit status means: one code per kind of ending, and the error of a user's input.

| code | meaning |
|------|---------|
| 0    | completed (or a dry run, or a listing) |
| 1    | a bug of rig: an error it did not expect (the line says so; RIG_DEBUG=1 shows where) |
| 2    | usage: an unknown option, a value out of its range (click's own) |
| 3    | aborted: a safety limit, a device fault (a stale stream, an arm in FAULT, a cable), SIGTERM |
| 4    | failed: the run ended but missed what it exists for (a tolerance, a check) |
| 5    | configuration or input: rig.toml, a file or run named, an arm the configuration has not |
| 130  | interrupted by Ctrl-C (the shell's 128 + SIGINT) |
"""

from __future__ import annotations

import click

EXIT_COMPLETED = 0
EXIT_BUG = 1
EXIT_USAGE = 2
EXIT_ABORTED = 3
EXIT_MISSED = 4
EXIT_INPUT = 5
EXIT_INTERRUPTED = 130

#: the table of `rig --help` and the README (code, meaning)
MEANINGS: tuple[tuple[int, str], ...] = (
    (EXIT_COMPLETED, "completed"),
    (EXIT_BUG, "a bug of rig (an error it did not expect; RIG_DEBUG=1 shows where)"),
    (EXIT_USAGE, "usage: an unknown option or a value out of its range"),
    (EXIT_ABORTED, "aborted: a safety limit, a device fault or SIGTERM; the arms held, the recording closed"),
    (EXIT_MISSED, "failed: the run ended without meeting its target (a tolerance, a check)"),
    (EXIT_INPUT, "configuration or input: rig.toml, a file, run or arm named that is not usable"),
    (EXIT_INTERRUPTED, "interrupted by Ctrl-C"),
)


class InputError(click.ClickException):
    """A user's configuration or input that cannot be used (exit EXIT_INPUT): one line
    naming the file, key or value and what to do."""

    exit_code = EXIT_INPUT
