"""A command's result shown (one JSON document or a report) and the exit status it ends with."""

from __future__ import annotations

import sys
from typing import Any

import click

from rig.commands.exit_codes import EXIT_ABORTED, EXIT_BUG, EXIT_MISSED
from rig.sealed_json import result_json


def emit_result(result: dict, as_json: bool, report: str | None = None) -> None:
    """Show a run's result: with `as_json`, the result as one JSON document on stdout and
    the human report on stderr; otherwise the report on stdout.

    `report` defaults to the result's "summary" (or top-level scalars) as `key: value` lines.
    """
    text = report if report is not None else format_report(result)
    if as_json:
        if text:
            click.echo(text, err=True)
        click.echo(result_json(result, indent=None))
    elif text:
        click.echo(text)


def format_report(result: dict) -> str:
    summary = result.get("summary")
    if not isinstance(summary, dict):
        summary = {k: v for k, v in result.items()
                   if isinstance(v, (int, float, str, bool)) and k not in ("run_dir",)}
    lines = [f"{k}: {_short(v)}" for k, v in summary.items()]
    head = f"{result.get('procedure', 'run')}: {result.get('status', '')}".rstrip(": ")
    if result.get("error"):
        head += f" ({result['error']})"
    if result.get("run_dir"):
        lines.append(f"run folder: {result['run_dir']}")
    return "\n".join([head] + lines)


def _short(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.6g}"
    return str(value)


def exit_for_status(name: str, result: dict) -> None:
    """End a procedure's command after its report: a run that missed its purpose (status
    "failed") prints one last line with the reason on stderr and exits EXIT_MISSED; any
    "aborted" exits EXIT_ABORTED; any other status but "completed" and "dry-run" exits EXIT_BUG."""
    status = result.get("status")
    if status == "failed":
        where = f" (run folder {result['run_dir']})" if result.get("run_dir") else ""
        click.echo(f"rig {name}: failed: {result.get('error')}{where}", err=True)
        sys.exit(EXIT_MISSED)
    if status == "aborted":
        sys.exit(EXIT_ABORTED)
    if status not in ("completed", "dry-run"):
        sys.exit(EXIT_BUG)
