"""Run `rig <command> ... --json` in-process and split its JSON (stdout) from its report."""

from __future__ import annotations

import json

from click.testing import CliRunner

from rig.cli import main


def run_cli(*args: str):
    """(exit code, parsed stdout JSON or None, stderr text)."""
    res = CliRunner().invoke(main, list(args), catch_exceptions=False)
    out = res.stdout.strip()
    try:
        doc = json.loads(out) if out else None
    except json.JSONDecodeError:
        doc = None
    return res.exit_code, doc, res.stderr
