"""Each arm's own identified model for a run that drives several arms (`rig cooperative`).

Two PSMs differ (counterweights, cables, tools): the feedforward of one is not the
other's. So every arm of a run gets the newest completed `rig identify` model *of that
arm* on this rig (rig.runs.provenance: same identity and mounting), with the newest
`rig friction-ramp` terms *of that arm* merged in (rig.runs.model_results.latest_model),
and never another arm's. A model file given by hand (`--model FILE` or `--model
ARM=FILE`) is checked the same way: a file goes to the arm its provenance names, and one
that names another arm or rig is refused unless forced.

An arm with no model of its own is refused on a real rig in one line naming the command
that makes one (`rig identify --arm PSM1`); the simulated rig runs it on the nominal model
and says so.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from rig.commands.exit_codes import InputError
from rig.runs import provenance


@dataclass
class ArmModel:
    """The model one arm runs on: its dynamics, joint 3's stick-slip terms (None when no
    friction ramp gave any), the effects a `rig discrepancy` model adds, and the files."""

    arm: str
    dynamics: object                      # rig.model.psm_dynamics.PSMDynamics
    stick: object | None = None           # rig.model.model_file.StickSlip
    effects: list = field(default_factory=list)
    file: str | None = None               # the model file, None for the nominal model
    stick_file: str | None = None         # where the stick-slip terms come from
    note: str = ""

    def summary(self) -> dict:
        """What a result records of this arm's model."""
        return {"file": self.file, "stick_slip_file": self.stick_file, "note": self.note,
                "effects": [f"{e['name']}@{e['joint']}" for e in self.effects]}


def parse_model_options(values, names) -> tuple[list[tuple[str | None, str]], str | None]:
    """`--model` values, each ``FILE`` or ``ARM=FILE``, as (arm or None, file) pairs; the
    second item is a usage error in words, or None."""
    out = []
    for v in values or ():
        v = str(v)
        arm, sep, path = v.partition("=")
        if sep and arm in names:
            out.append((arm, path))
        elif sep and arm and "/" not in arm and not Path(v).exists():
            return [], f"{v!r}: {arm!r} is not one of the run's arms ({', '.join(names)}); give ARM=FILE or FILE"
        else:
            out.append((None, v))
    given = [a for a, _ in out if a is not None]
    if len(given) != len(set(given)):
        return [], "one --model per arm"
    return out, None


def _describe(arm: str, m) -> ArmModel:
    """An ArmModel from a loaded model file."""
    from rig.model import model_file

    note = f"{arm}: identified model {m.path}"
    effects = m.effects
    if effects:
        note += " with its effects " + ", ".join(f"{e['name']}@{e['joint']}" for e in effects)
    stick = m.stick_slip()
    stick_file = None
    if stick is not None:
        ramp = (stick.provenance or {}).get("run_dir")
        stick_file = str(Path(ramp) / model_file.STICK_SLIP_FILENAME) if ramp else str(m.path)
        note += f"; joint 3 stick-slip and friction terms from {stick_file}"
    return ArmModel(arm, m.dynamics(), stick, list(effects), str(m.path), stick_file, note)


def _arm_of_file(path: str, doc: dict, cfg, names) -> tuple[list[str], str | None]:
    """The run's arms a model file belongs to (its provenance), and why not when none."""
    fits = [n for n in names if provenance.mismatch(doc, cfg, arm=n) is None]
    return fits, (None if fits else provenance.mismatch(doc, cfg))


def models_for(cfg, names, model_paths=(), simulated: bool = True, force_model: bool = False,
               warnings: list | None = None) -> dict[str, ArmModel]:
    """Each of `names`' model (see the module docstring). `model_paths`: (arm or None, file)
    pairs from `parse_model_options`; newer results passed over go to `warnings`."""
    from rig.model import model_file
    from rig.model.psm_dynamics import PSMDynamics
    from rig.runs import model_results

    warnings = warnings if warnings is not None else []
    chosen: dict[str, ArmModel] = {}
    unassigned_forced = []
    for arm, path in model_paths:
        m = model_file.load_model(path)
        if arm is not None:
            why = provenance.mismatch(m.document, cfg, arm=arm)
            if why is not None:
                if not force_model:
                    raise InputError(f"{path}: not a model of {arm} on this rig: {why}; run `rig identify --arm {arm}`"
                                     f", or add --force-model to use it anyway")
                warnings.append(f"--force-model: {path} used for {arm} although {why}")
            chosen[arm] = _describe(arm, m)
            continue
        fits, why = _arm_of_file(path, m.document, cfg, names)
        if fits:
            for n in fits:
                if n in chosen:
                    raise InputError(f"{path}: a second model for {n}: give one --model per arm")
                chosen[n] = _describe(n, m)
        elif not force_model:
            raise InputError(f"{path}: not a model of any of {', '.join(names)} on this rig: {why}; run "
                             "`rig identify --arm ARM` on this rig, give it as --model ARM=FILE, or add "
                             "--force-model to use it anyway")
        else:
            unassigned_forced.append((path, m, why))
    for path, m, why in unassigned_forced:
        # forced and fitting no arm: every arm not given a file of its own
        rest = [n for n in names if n not in chosen]
        if rest:
            warnings.append(f"--force-model: {path} used although {why}")
        for n in rest:
            chosen[n] = _describe(n, m)
    for n in names:
        if n in chosen:
            continue
        skipped: list[str] = []
        m = model_results.latest_model(cfg=cfg, arm=n, skipped=skipped)
        if skipped:  # one line per arm, not one per run set aside
            warnings.append(f"{n}: " + provenance.set_aside_line(skipped))
        if m is not None and m.standard is not None:
            chosen[n] = _describe(n, m)
            continue
        if not simulated:
            raise InputError(f"no identified model of {n} on this rig: run `rig identify --arm {n}` (then "
                             f"`rig friction-ramp --arm {n}`), or pass --model {n}=FILE"
                             + (f" ({provenance.set_aside_line(skipped)})" if skipped else ""))
        chosen[n] = ArmModel(n, PSMDynamics(), None, [], None, None,
                             f"{n}: nominal model (no identified model of {n} on this rig yet)")
    return {n: chosen[n] for n in names}
