"""A procedure's command ended by one line and an exit status: aborts, device faults, Ctrl-C, bad input, bugs."""

from __future__ import annotations

import functools
import json
import os
import sys
from pathlib import Path
from typing import Callable

import click

from rig.commands.exit_codes import EXIT_ABORTED, EXIT_BUG, EXIT_INTERRUPTED, InputError
from rig.config import ConfigError
from rig.faults import DeviceFault
from rig.model.model_file import ModelFileError
from rig.runs.run import AbortRun


def exit_on_abort(fn: Callable) -> Callable:
    """Decorator for a procedure's click command: an AbortRun, a device fault
    (rig.faults.DeviceFault) or Ctrl-C becomes one line on stderr and a non-zero exit (3
    aborted, 130 interrupted); click's own errors pass; anything else is one line naming
    it as a bug, exit 1 (RIG_DEBUG=1 re-raises it for the traceback)."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        ctx = click.get_current_context(silent=True)
        # under `rig`, the name it was invoked by; run on its own, the command's name
        if ctx is None:
            name = fn.__name__
        else:
            name = ctx.info_name if ctx.parent is not None else (ctx.command.name or ctx.info_name)

        def end(exc: BaseException, line: str, code: int) -> None:
            """The one line (naming the run folder, if any) and the exit; with --json the
            result document goes to stdout first, whatever the ending."""
            run_dir = getattr(exc, "run_dir", None)
            if kwargs.get("as_json") and run_dir is not None:
                try:
                    click.echo(json.dumps(json.loads((Path(run_dir) / "result.json").read_text())))
                except (OSError, ValueError):
                    pass
            where = f" (run folder {run_dir})" if run_dir else ""
            click.echo(f"rig {name}: {line}{where}", err=True)
            sys.exit(code)

        try:
            return fn(*args, **kwargs)
        except AbortRun as exc:
            end(exc, f"aborted: {exc.reason}", EXIT_ABORTED)
        except KeyboardInterrupt as exc:
            end(exc, "aborted: interrupted (Ctrl-C)", EXIT_INTERRUPTED)
        except DeviceFault as exc:
            end(exc, f"aborted: {exc}", EXIT_ABORTED)
        except (click.ClickException, click.exceptions.Exit, click.exceptions.Abort):
            raise
        except ConfigError as exc:
            raise InputError(str(exc)) from None
        except ModelFileError as exc:  # a file the user named: theirs to fix, not a bug
            raise InputError(str(exc)) from None
        except Exception as exc:  # noqa: BLE001 - a traceback is for developers (RIG_DEBUG=1)
            if os.environ.get("RIG_DEBUG"):
                raise
            text = str(exc).splitlines()[0] if str(exc) else ""
            end(exc, f"failed: {type(exc).__name__}: {text}; a bug of rig: please report it "
                     "(RIG_DEBUG=1 shows where)", EXIT_BUG)

    return wrapper
