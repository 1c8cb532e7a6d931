"""The identified-model file: what `rig identify` and `rig friction-ramp` leave for later runs.

One JSON document (``model.json`` in the identify run's folder) holding:

* ``schema`` / ``schema_version``: what this is and which layout (a reader refuses a newer
  major version rather than misreading it);
* ``standard_parameters``: the 82 physically consistent standard parameters of the SDP
  (7 bodies x [m, m cx, m cy, m cz, Ixx, Ixy, Iyy, Ixz, Iyz, Izz] in kg, kg m, kg m^2, then
  3 joints x [Fc, Fv, Fo, Ia]) with their names;
* ``base_parameters``: values and their expressions in standard parameters (eq. 5.22);
* ``friction``: per joint Fc (N m or N), Fv (N m s/rad or N s/m), Fo (N m or N), Ia
  (kg m^2 or kg) and the sigmoid slope a (s/rad) of tanh(a dq / 2); optionally
  ``friction.stribeck`` {"Fst": [3], "vs": [3]}: the Stribeck excess Fst exp(-(dq/vs)^2)
  tanh(a dq / 2) identified with the model (absent in older files: no excess);
* ``stick_slip`` (after `rig friction-ramp`): breakaway forces Fs_pos, Fs_neg (N) of
  joint 3 and the viscous/Coulomb/Stribeck fits, for the compensation of thesis 7.5.1;
* ``gravity``: the gravity vector in frame 0 (m/s^2) the parameters belong to, and how it
  was obtained;
* ``validation``: the figures of the identification;
* ``provenance``: data source, run folder, UTC date, package version, git revision.

`latest_model()` finds the newest completed `identify` run's model and, when a newer
`friction-ramp` run has results it does not carry yet, merges them in (in memory: a run's
files are its record and are never rewritten by a later run).
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

SCHEMA = "dvrk-rig/identified-model"
SCHEMA_VERSION = 1
MODEL_FILENAME = "model.json"
STICK_SLIP_FILENAME = "stick_slip.json"
N_STANDARD = 82


class ModelFileError(ValueError):
    """A model file that is missing, unreadable, corrupt or of an incompatible schema."""


@dataclass
class StickSlip:
    """Stick-slip terms of one joint (thesis 5.6, 7.5.1); forces in N (joint 3) or N m.

    fs_pos / fs_neg: force above the model's gravity and offset compensation at which the
    joint broke away in the positive / negative direction (fs_neg < 0, as in the thesis'
    Fs_neg = -1). fits: {"viscous_coulomb": {...}, "stribeck": {...}} from the
    constant-velocity sweeps (None when not run). deadbands: velocity and position
    deadbands for the compensation (m/s, m).
    """

    joint: int
    fs_pos: float
    fs_neg: float
    fits: dict = field(default_factory=dict)
    deadbands: dict = field(default_factory=dict)
    provenance: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {"joint": self.joint, "Fs_pos": self.fs_pos, "Fs_neg": self.fs_neg, "fits": self.fits,
                "deadbands": self.deadbands, "provenance": self.provenance}

    @classmethod
    def from_dict(cls, d: dict, where: str = "stick_slip") -> "StickSlip":
        try:
            return cls(int(d["joint"]), float(d["Fs_pos"]), float(d["Fs_neg"]), dict(d.get("fits") or {}),
                       dict(d.get("deadbands") or {}), dict(d.get("provenance") or {}))
        except (KeyError, TypeError, ValueError) as exc:
            raise ModelFileError(f"{where}: malformed stick-slip section ({exc})") from None

    def compensation(self, dq: float, position_error: float) -> float:
        """Thesis 7.5.1 for this joint at rest: Fs_pos, Fs_neg or 0 (N) from the position error
        (m); in motion the Stribeck fit if present, else viscous+Coulomb, else 0."""
        vdb = self.deadbands.get("velocity", 0.005)
        pdb = self.deadbands.get("position", 0.0003)
        if abs(dq) < vdb:
            if position_error > pdb:
                return self.fs_pos
            if position_error < -pdb:
                return self.fs_neg
            return 0.0
        fit = self.fits.get("stribeck") or self.fits.get("viscous_coulomb")
        return float(friction_curve(fit, dq)) if fit else 0.0


def friction_curve(fit: dict, v) -> np.ndarray:
    """Friction force of a fit dict at velocity v (m/s or rad/s): Fo + Fv v + sign(v) (Fc +
    (Fs - Fc) exp(-(|v|/vs)^2)); the viscous+Coulomb fit has no Fs/vs (then Fs = Fc).
    Sign-dependent levels (Fc_pos/Fc_neg, Fs_pos/Fs_neg) are used when present."""
    v = np.asarray(v, dtype=float)
    pos = v >= 0
    fc = np.where(pos, fit.get("Fc_pos", fit.get("Fc", 0.0)), fit.get("Fc_neg", fit.get("Fc", 0.0)))
    fs = np.where(pos, fit.get("Fs_pos", fit.get("Fs", fc)), fit.get("Fs_neg", fit.get("Fs", fc)))
    vs = fit.get("vs", 1.0)
    level = fc + (fs - fc) * np.exp(-(np.abs(v) / vs) ** 2)
    return fit.get("Fo", 0.0) + fit.get("Fv", 0.0) * v + np.sign(v) * level


@dataclass
class IdentifiedModel:
    """A loaded model file (see the module docstring). ``standard`` is None for a
    friction-only file (friction-ramp run with no identified model)."""

    path: Path
    standard: np.ndarray | None
    names: list[str]
    slope: float
    gravity: np.ndarray
    document: dict
    stick_slip_terms: StickSlip | None = None

    @property
    def kind(self) -> str:
        return self.document.get("kind", "identified")

    def dynamics(self):
        """A `rig.psm_dynamics.PSMDynamics` with the identified standard parameters, gravity
        and, when the file has one, the Stribeck excess."""
        from dataclasses import replace

        from rig.psm_dynamics import PSMDynamics, PSMParameters

        if self.standard is None:
            raise ModelFileError(f"{self.path}: a friction-only model file has no dynamic parameters: "
                                 "run `rig identify` first")
        params = PSMParameters.from_standard_vector(self.standard, self.slope)
        st = self.stribeck
        if st is not None:
            params = replace(params, drive=replace(params.drive, Fst=st["Fst"], vs=st["vs"]))
        return PSMDynamics(params, gravity=self.gravity)

    @property
    def stribeck(self) -> dict | None:
        """{"Fst": (3,), "vs": (3,)} arrays of the identified Stribeck excess, or None."""
        st = self.friction.get("stribeck")
        if not st:
            return None
        try:
            Fst, vs = np.asarray(st["Fst"], float), np.asarray(st["vs"], float)
            if Fst.shape != (3,) or vs.shape != (3,) or not np.all(np.isfinite(Fst)) or np.any(~(vs > 0)):
                raise ValueError("Fst and vs must be 3 finite numbers each, vs > 0")
        except (KeyError, TypeError, ValueError) as exc:
            raise ModelFileError(f"{self.path}: malformed friction.stribeck ({exc})") from None
        return {"Fst": Fst, "vs": vs}

    def stick_slip(self) -> StickSlip | None:
        """The stick-slip compensation terms of joint 3, or None before `rig friction-ramp`."""
        return self.stick_slip_terms

    @property
    def friction(self) -> dict:
        return self.document.get("friction", {})

    @property
    def validation(self) -> dict:
        return self.document.get("validation", {})

    @property
    def provenance(self) -> dict:
        return self.document.get("provenance", {})


def _finite_list(x, what: str) -> list[float]:
    arr = np.asarray(x, dtype=float).ravel()
    if not np.all(np.isfinite(arr)):
        raise ModelFileError(f"{what}: contains a non-finite value")
    return arr.tolist()


def provenance(data_source: str, run_dir: str | Path | None, extra: dict | None = None) -> dict:
    """Where a model came from: data, run folder, UTC date, package version, git revision."""
    from rig.records import git_revision, package_version

    out = {"data_source": str(data_source), "run_dir": None if run_dir is None else str(run_dir),
           "date": datetime.now(timezone.utc).isoformat(), "package_version": package_version(),
           "git_revision": git_revision()}
    out.update(extra or {})
    return out


def save_model(path, *, standard, names, slope: float, gravity, base_values=None, base_expressions=None,
               base_independent=None, gravity_source: str = "configured", validation: dict | None = None,
               provenance_info: dict | None = None, stick_slip: StickSlip | None = None,
               checks: dict | None = None, kind: str = "identified", extra: dict | None = None,
               stribeck: dict | None = None) -> Path:
    """Write a model file atomically; returns its path. Units in the module docstring."""
    path = Path(path)
    doc: dict[str, Any] = {"schema": SCHEMA, "schema_version": SCHEMA_VERSION, "kind": kind}
    if standard is not None:
        std = _finite_list(standard, "standard parameters")
        if len(std) != N_STANDARD or len(names) != N_STANDARD:
            raise ModelFileError(f"{path}: expected {N_STANDARD} standard parameters and names, "
                                 f"got {len(std)} and {len(names)}")
        doc["standard_parameters"] = {"names": list(names), "values": std,
                                      "units": "kg, kg m, kg m^2 per body; N m|N, N m s/rad|N s/m, N m|N, "
                                               "kg m^2|kg per joint"}
        fr = np.asarray(std[70:], float).reshape(3, 4)
        doc["friction"] = {"slope": float(slope), "model": "Fc tanh(slope dq / 2) + Fv dq + Fo + Ia ddq",
                           "joints": [{"joint": j + 1, "Fc": fr[j, 0], "Fv": fr[j, 1], "Fo": fr[j, 2],
                                       "Ia": fr[j, 3]} for j in range(3)]}
        if stribeck is not None:
            Fst = _finite_list(stribeck["Fst"], "Stribeck excess")
            vs = _finite_list(stribeck["vs"], "Stribeck velocities")
            if len(Fst) != 3 or len(vs) != 3 or min(vs) <= 0:
                raise ModelFileError(f"{path}: the Stribeck term needs 3 excesses and 3 velocities > 0")
            doc["friction"]["model"] += " + Fst exp(-(dq/vs)^2) tanh(slope dq / 2)"
            doc["friction"]["stribeck"] = {"Fst": Fst, "vs": vs, "units": "N m|N; rad/s|m/s"}
    else:
        doc["friction"] = {"slope": float(slope)}
    if base_values is not None:
        doc["base_parameters"] = {"values": _finite_list(base_values, "base parameters"),
                                  "expressions": list(base_expressions or []),
                                  "independent": [int(i) for i in (base_independent if base_independent is not None else [])]}
    doc["gravity"] = {"vector": _finite_list(gravity, "gravity"), "units": "m/s^2, PSM frame 0",
                      "source": gravity_source}
    doc["stick_slip"] = stick_slip.to_dict() if stick_slip is not None else None
    doc["validation"] = validation or {}
    if checks is not None:
        doc["checks"] = checks
    doc["provenance"] = provenance_info or {}
    if extra:
        doc.update(extra)
    _write_json(path, doc)
    return path


def _write_json(path: Path, doc: dict) -> None:
    from rig.run import result_json

    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(result_json(doc) + "\n")
    os.replace(tmp, path)


def load_model(path) -> IdentifiedModel:
    """Read and check a model file; raises ModelFileError naming the file and the problem."""
    path = Path(path)
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise ModelFileError(f"{path}: no such model file: run `rig identify` (or give the path "
                             "of a model.json)") from None
    except OSError as exc:
        raise ModelFileError(f"{path}: cannot read the model file ({exc.strerror})") from None
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ModelFileError(f"{path}: corrupt model file (not JSON: {exc.msg} at line {exc.lineno}); "
                             "re-run `rig identify`") from None
    if not isinstance(doc, dict) or doc.get("schema") != SCHEMA:
        raise ModelFileError(f"{path}: not a dvrk-rig model file (schema {doc.get('schema') if isinstance(doc, dict) else None!r}, "
                             f"expected {SCHEMA!r})")
    version = doc.get("schema_version")
    if not isinstance(version, int) or version > SCHEMA_VERSION or version < 1:
        raise ModelFileError(f"{path}: model file schema version {version!r} is not supported by this "
                             f"package (reads version 1..{SCHEMA_VERSION}): upgrade dvrk-rig or re-identify")
    try:
        slope = float(doc["friction"]["slope"])
        gravity = np.asarray(doc["gravity"]["vector"], dtype=float)
        if gravity.shape != (3,) or not np.all(np.isfinite(gravity)) or not math.isfinite(slope) or slope <= 0:
            raise ValueError("gravity must be 3 finite numbers and the slope > 0")
        std_doc = doc.get("standard_parameters")
        if std_doc is None:
            if doc.get("kind") != "friction-only":
                raise ValueError("standard_parameters missing")
            standard, names = None, []
        else:
            standard = np.asarray(std_doc["values"], dtype=float)
            names = list(std_doc["names"])
            if standard.shape != (N_STANDARD,) or len(names) != N_STANDARD:
                raise ValueError(f"expected {N_STANDARD} standard parameters and names, got "
                                 f"{standard.size} and {len(names)}")
            if not np.all(np.isfinite(standard)):
                raise ValueError("a standard parameter is not finite")
    except (KeyError, TypeError, ValueError) as exc:
        raise ModelFileError(f"{path}: incompatible or corrupt model file: {exc}") from None
    ss = doc.get("stick_slip")
    stick = StickSlip.from_dict(ss, f"{path}: stick_slip") if ss else None
    return IdentifiedModel(path, standard, names, slope, gravity, doc, stick)


def update_stick_slip(path, stick: StickSlip) -> IdentifiedModel:
    """Write (or replace) the stick-slip section of an existing model file atomically."""
    model = load_model(path)
    doc = dict(model.document)
    doc["stick_slip"] = stick.to_dict()
    _write_json(Path(path), doc)
    return load_model(path)


def friction_only_model(path, stick: StickSlip, gravity, slope: float, provenance_info: dict) -> Path:
    """A model file with only the stick-slip section (friction-ramp without an identify run)."""
    return save_model(path, standard=None, names=[], slope=slope, gravity=gravity, gravity_source="configured",
                      provenance_info=provenance_info, stick_slip=stick, kind="friction-only")


def latest_model(with_friction_ramp: bool = True) -> IdentifiedModel | None:
    """The newest completed `rig identify` run's model, or None when there is none.

    When a completed `rig friction-ramp` run is newer than the stick-slip terms the model
    carries (or it carries none), its terms are merged into the returned model (not into
    the identify run's file), so the order in which the two procedures ran does not matter. With no identify run, the
    newest friction-ramp run's friction-only model is returned, if any.
    """
    from rig.paths import latest_result

    found = latest_result("identify")
    ramp = latest_result("friction-ramp") if with_friction_ramp else None
    if found is None:
        if ramp is not None and (ramp[0] / MODEL_FILENAME).exists():
            return load_model(ramp[0] / MODEL_FILENAME)
        return None
    run_dir, result = found
    path = Path(result.get("model") or run_dir / MODEL_FILENAME)
    if not path.is_absolute():
        path = run_dir / path
    model = load_model(path)
    if ramp is not None and (ramp[0] / STICK_SLIP_FILENAME).exists():
        ramp_dir = str(ramp[0])
        have = model.stick_slip_terms.provenance.get("run_dir") if model.stick_slip_terms else None
        # Run folders sort by their UTC start time: merge only a newer friction-ramp result.
        if have is None or Path(have).name < Path(ramp_dir).name:
            try:
                stick = StickSlip.from_dict(json.loads((ramp[0] / STICK_SLIP_FILENAME).read_text()),
                                            str(ramp[0] / STICK_SLIP_FILENAME))
            except json.JSONDecodeError as exc:
                raise ModelFileError(f"{ramp[0] / STICK_SLIP_FILENAME}: corrupt ({exc.msg})") from None
            doc = dict(model.document)
            doc["stick_slip"] = stick.to_dict()
            model = dataclasses.replace(model, document=doc, stick_slip_terms=stick)
    return model
