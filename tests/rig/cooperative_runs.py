"""Short in-process `rig cooperative` runs for the export and plot tests (a few s each)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from click.testing import CliRunner

from rig.cli import main

#: a gentle 1 cm move: 1 s to settle, 1 s of motion, 0.3 s after (2300 ticks at 1 kHz)
SHORT = ("--force", "3", "--settle", "1", "--duration", "1", "--hold-after", "0.3", "--move", "0.01,0,0")
#: the tension ceiling just above the set-point: aborts about 0.6 s into the hold
ABORTING = ("--force", "3", "--tension-ceiling", "3.02", "--settle", "1", "--duration", "1",
            "--hold-after", "0.3")


def cooperative_run(folder: Path, args: tuple[str, ...]) -> tuple[Path, dict, str]:
    """Run `rig cooperative ARGS --json` with its logs under `folder`; returns (its run folder,
    its result.json, its stderr)."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("RIG_LOGS", str(folder / "logs"))
        mp.delenv("RIG_CONFIG", raising=False)
        mp.chdir(folder)
        res = CliRunner().invoke(main, ["cooperative", *args, "--json"])
    assert "Traceback" not in res.output, res.output
    run_dir = sorted((folder / "logs").iterdir())[-1]
    return run_dir, json.loads((run_dir / "result.json").read_text()), res.stderr
