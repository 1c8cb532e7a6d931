"""The newest identified model of a rig's arm, with a newer friction-ramp run's terms merged in.

`latest_model()` finds the newest completed `identify` run's model and, when a newer
`friction-ramp` run has results it does not carry yet, merges them in (in memory: a run's
files are its record and are never rewritten by a later run).
"""

from __future__ import annotations

import dataclasses
import json
from datetime import datetime, timezone
from pathlib import Path

from rig.model.model_file import (MODEL_FILENAME, STICK_SLIP_FILENAME, IdentifiedModel, ModelFileError, StickSlip,
                                  load_model)


def provenance(data_source: str, run_dir: str | Path | None, extra: dict | None = None) -> dict:
    """Where a model came from: data, run folder, UTC date, package version, git revision."""
    from rig.runs.recording import git_revision, package_version

    out = {"data_source": str(data_source), "run_dir": None if run_dir is None else str(run_dir),
           "date": datetime.now(timezone.utc).isoformat(), "package_version": package_version(),
           "git_revision": git_revision()}
    out.update(extra or {})
    return out


def _model_document(run_dir: Path, result: dict) -> dict | None:
    """The model file a completed identify run's result names, as JSON (None if unreadable)."""
    path = Path(result.get("model") or run_dir / MODEL_FILENAME)
    if not path.is_absolute():
        path = run_dir / path
    try:
        doc = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return doc if isinstance(doc, dict) else None


def ramp_stick_slip(run_dir: Path, result: dict) -> StickSlip | None:
    """A friction-ramp run's stick-slip terms: from its (sealed) result, else its file."""
    if isinstance(result.get("stick_slip"), dict):
        return StickSlip.from_dict(result["stick_slip"], str(run_dir / "result.json"))
    f = run_dir / STICK_SLIP_FILENAME
    if not f.exists():
        return None
    try:
        return StickSlip.from_dict(json.loads(f.read_text()), str(f))
    except json.JSONDecodeError as exc:
        raise ModelFileError(f"{f}: corrupt ({exc.msg})") from None


def latest_model(with_friction_ramp: bool = True, cfg=None, arm: str | None = None,
                 skipped: list | None = None) -> IdentifiedModel | None:
    """The newest completed `rig identify` run's model, or None when there is none.

    With `cfg` (the rig a procedure runs on) only results that belong to it are taken
    (rig.runs.provenance: same rig configuration, same arm identity, file not edited; with `arm`,
    a result of that arm): a newer result that does not is passed over and named in
    `skipped`. Without `cfg` the newest result is taken unchecked (tools and tests).

    When a completed `rig friction-ramp` run is newer than the stick-slip terms the model
    carries (or it carries none), its terms are merged into the returned model (in memory:
    no run's file is rewritten), so the order in which the two procedures ran does not
    matter. With no identify run, the newest friction-ramp run's friction-only model is
    returned, if any.
    """
    from rig.runs import provenance as P
    from rig.runs.paths import latest_result

    notes: list[str] = skipped if skipped is not None else []

    def has_model(run: Path, result: dict) -> bool:
        return (run / MODEL_FILENAME).exists() or bool(result.get("model"))

    if cfg is None:
        found = latest_result("identify")
        ramp = latest_result("friction-ramp") if with_friction_ramp else None
    else:
        f = P.find("identify", cfg, arm=arm, document=_model_document, usable=has_model)
        notes.extend(f.skipped)
        found = (f.run_dir, f.data) if f.run_dir is not None else None
        ramp = None
        if with_friction_ramp:
            r = P.find("friction-ramp", cfg, arm=arm,
                       usable=lambda run, res: "stick_slip" in res or (run / STICK_SLIP_FILENAME).exists())
            notes.extend(r.skipped)
            ramp = (r.run_dir, r.data) if r.run_dir is not None else None
    if found is None:
        if ramp is not None and (ramp[0] / MODEL_FILENAME).exists():
            return load_model(ramp[0] / MODEL_FILENAME)
        return None
    run_dir, result = found
    path = Path(result.get("model") or run_dir / MODEL_FILENAME)
    if not path.is_absolute():
        path = run_dir / path
    model = load_model(path)
    if ramp is not None:
        stick = ramp_stick_slip(*ramp)
        have = model.stick_slip_terms.provenance.get("run_dir") if model.stick_slip_terms else None
        # Run folders sort by their UTC start time: merge only a newer friction-ramp result.
        if stick is not None and (have is None or Path(have).name < ramp[0].name):
            doc = dict(model.document)
            doc["stick_slip"] = stick.to_dict()
            model = dataclasses.replace(model, document=doc, stick_slip_terms=stick)
    return model
