"""The floors of docs/floors.md, read from every module's imports: no import points up a floor."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("rig", "drivers", "procedures", "calibration")

#: module prefix -> floor (the longest prefix wins); docs/floors.md draws the same table
FLOORS = {
    "rig.cli": 4, "rig.runs_cli": 4, "rig.runs_setup": 4, "rig.export_cli": 4, "rig.plot_cli": 4,
    "procedures": 3,
    "rig.config": 2, "rig.devices": 2, "rig.runs": 2, "rig.commands": 2, "rig.sim_server": 2,
    "drivers": 1, "calibration": 1, "rig.sim": 1, "rig.control": 1,
    "rig.model": 0, "rig.faults": 0, "rig.sealed_json": 0, "rig": 0,
}


def floor_of(module: str) -> int:
    best = max((p for p in FLOORS if module == p or module.startswith(p + ".")), key=len)
    return FLOORS[best]


def module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imports_of(path: Path) -> set[str]:
    """Every package module `path` imports, at any depth of its code (a function's late import too)."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out.add(node.module)
            out.update(f"{node.module}.{a.name}" for a in node.names)
    return {m for m in out if m.split(".")[0] in PACKAGES}


def modules() -> list[Path]:
    return sorted(p for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py"))


def test_the_floor_table_knows_every_module():
    assert len(modules()) > 100
    for p in modules():
        floor_of(module_name(p))


@pytest.mark.parametrize("path", modules(), ids=lambda p: str(p.relative_to(ROOT)))
def test_no_import_points_up_a_floor(path):
    me = module_name(path)
    mine = floor_of(me)
    up = sorted(m for m in imports_of(path) if floor_of(m) > mine)
    assert not up, f"{me} (floor {mine}) imports from above: {up}"


#: modules of procedures/ that are a procedure (a `rig` command); the others are a procedure's
#: report, figures or helpers, imported by their own procedure
def _procedure_modules() -> set[str]:
    return {module_name(p) for p in (ROOT / "procedures").glob("*.py")
            if "@click.command" in p.read_text() or "procedure_command(" in p.read_text()}


def test_a_procedure_never_imports_another_procedure():
    procedures = _procedure_modules()
    assert {"procedures.cooperative", "procedures.identify"} <= procedures
    for name in sorted(procedures):
        path = ROOT / (name.replace(".", "/") + ".py")
        others = {m for m in imports_of(path) if any(m == p or m.startswith(p + ".") for p in procedures - {name})}
        assert not others, f"{name} imports the procedure(s) {sorted(others)}"
