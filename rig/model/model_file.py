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
* ``provenance``: data source, run folder, UTC date, package version, git revision;
* ``effects`` (after `rig discrepancy`): the catalogue effects added to the model, each
  {"name", "joint" 1-3, "params", "units"} (``calibration.effects``, catalogue version in
  ``effects_catalogue``). `IdentifiedModel.plant` turns the file into a simulated arm's plant
  with those effects; `calibration.effects.EffectCompensation` gives a controller their
  torques step by step.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

SCHEMA = "dvrk-rig/identified-model"
SCHEMA_VERSION = 1
MODEL_FILENAME = "model.json"
STICK_SLIP_FILENAME = "stick_slip.json"
N_STANDARD = 82
#: Effect ids a model file's ``effects`` section may carry (calibration.effects.IDS).
EFFECT_IDS = ("stiction", "coulomb_asymmetry", "position_friction", "spring", "payload", "backlash",
              "hysteresis", "time_delay", "torque_offset", "viscous_nonlinear")


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
        """A `rig.model.psm_dynamics.PSMDynamics` with the identified standard parameters, gravity
        and, when the file has one, the Stribeck excess."""
        from dataclasses import replace

        from rig.model.psm_dynamics import PSMDynamics, PSMParameters

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
    def effects(self) -> list[dict]:
        """The ``effects`` entries (empty when the file has none), checked: a known id, a
        joint 1-3 and a params object; raises ModelFileError naming the entry otherwise."""
        entries = self.document.get("effects") or []
        if not isinstance(entries, list):
            raise ModelFileError(f"{self.path}: effects: expected a list of effect entries")
        for i, e in enumerate(entries):
            where = f"{self.path}: effects[{i}]"
            if not isinstance(e, dict) or e.get("name") not in EFFECT_IDS:
                raise ModelFileError(f"{where}: not a catalogue effect (name {e.get('name') if isinstance(e, dict) else e!r}; "
                                     f"known: {', '.join(EFFECT_IDS)})")
            if e.get("joint") not in (1, 2, 3) or not isinstance(e.get("params"), dict):
                raise ModelFileError(f"{where} ({e['name']}): needs a joint 1-3 and a params object")
        return entries

    def plant(self):
        """The simulated plant this model describes: (`rig.model.psm_dynamics.PSMParameters`,
        `rig.model.plant_effects.HiddenEffects`), for `rig.sim.world.ArmSpec(params=..., effects=...)`.

        The rigid body and Coulomb/viscous/offset/rotor terms are the standard parameters;
        an identified Stribeck excess and the ``effects`` entries become the sim's physical
        effects: stiction as the breakaway level Fc + excess at the Stribeck velocity,
        a direction-dependent level as its mean rise on the Coulomb level plus half its
        difference as a constant load, position-dependent friction as the absolute Coulomb
        profile, spring, Dahl hysteresis, backlash (play and motor-side inertia), per-joint
        effort delay, constant load and non-linear damping as themselves. A payload entry is
        already in the standard parameters. The simulated friction is dry (exact stick) where
        the model's is the smooth sign tanh(a dq / 2); the plant's gravity is the simulated
        world's, not the file's vector. Raises ModelFileError for a file without dynamic
        parameters or effects the plant cannot hold (two friction profiles of different
        periods on a joint, say).
        """
        from dataclasses import replace

        from rig.model.plant_effects import HiddenEffects
        from rig.model.psm_dynamics import PSMParameters

        if self.standard is None:
            raise ModelFileError(f"{self.path}: a friction-only model file has no dynamic parameters: "
                                 "run `rig identify` first")
        params = PSMParameters.from_standard_vector(self.standard, self.slope)
        drive = params.drive
        Fc, Ia = drive.Fc.copy(), drive.Ia.copy()
        eff = HiddenEffects()
        excess, vs = np.zeros(3), eff.stribeck_velocity.copy()
        st = self.stribeck
        if st is not None:
            excess += st["Fst"]
            vs = st["vs"].copy()
        periods: dict[int, float] = {}
        for i, e in enumerate(self.effects):
            j, p, name = int(e["joint"]) - 1, e["params"], e["name"]
            where = f"{self.path}: effects[{i}] ({name}@{j + 1})"
            try:
                if name == "stiction":
                    excess[j] += float(p["dFs"])
                    vs[j] = float(p["vs"])
                elif name == "coulomb_asymmetry":
                    # dFc (1 + sigma(dq)) / 2: the level rises by dFc/2 both ways, plus dFc/2.
                    Fc[j] += 0.5 * float(p["dFc"])
                    eff.torque_offset[j] += 0.5 * float(p["dFc"])
                elif name == "position_friction":
                    a_sin, a_cos = _profile_coefficients(p)
                    period = float(p["period"])
                    if j in periods and not math.isclose(periods[j], period, rel_tol=1e-9):
                        raise ValueError(f"a second friction profile of period {period:g} (the first: "
                                         f"{periods[j]:g}); the simulated plant holds one per joint")
                    if len(a_sin) > eff.friction_profile_sin.shape[1]:
                        raise ValueError(f"{len(a_sin)} harmonics; the simulated plant holds "
                                         f"{eff.friction_profile_sin.shape[1]}")
                    periods[j] = period
                    eff.friction_profile_period[j] = period
                    eff.friction_profile_sin[j, :len(a_sin)] += a_sin
                    eff.friction_profile_cos[j, :len(a_cos)] += a_cos
                elif name == "spring":
                    k, q0 = float(p["k"]), float(p.get("q0") or 0.0)
                    total = eff.spring[j] + k
                    eff.spring_rest[j] = (eff.spring[j] * eff.spring_rest[j] + k * q0) / total if total else 0.0
                    eff.spring[j] = total
                elif name == "payload":
                    if e.get("applied_to") != "standard_parameters":
                        raise ValueError("a payload not folded into the standard parameters")
                elif name == "backlash":
                    if eff.backlash[j] > 0:
                        raise ValueError("a second play on the joint")
                    if not Ia[j] > 0:
                        raise ValueError(f"a play needs a rotor inertia > 0 on the motor side (Ia {Ia[j]:.4g})")
                    if not float(p["width"]) > 0:
                        raise ValueError("needs a play width > 0")
                    eff.backlash[j] = float(p["width"])
                    if "motor_inertia" in p:
                        eff.backlash_motor_inertia[j] = min(float(p["motor_inertia"]), Ia[j])
                elif name == "hysteresis":
                    if eff.hysteresis[j] > 0:
                        raise ValueError("a second Dahl friction on the joint")
                    if not (float(p["Fd"]) > 0 and float(p["travel"]) > 0):
                        raise ValueError("needs a Dahl level Fd > 0 and a travel > 0")
                    eff.hysteresis[j] = float(p["Fd"])
                    eff.hysteresis_stiffness[j] = float(p["Fd"]) / float(p["travel"])
                elif name == "time_delay":
                    delay = np.broadcast_to(np.asarray(eff.time_delay, float), (3,)).copy()
                    delay[j] += float(p["delay"])
                    eff.time_delay = delay
                elif name == "torque_offset":
                    eff.torque_offset[j] += float(p["offset"])
                elif name == "viscous_nonlinear":
                    if eff.viscous_nonlinear[j] != 0:
                        raise ValueError("a second non-linear damping law on the joint")
                    eff.viscous_nonlinear[j] = float(p["c"])
                    eff.viscous_exponent[j] = float(p["exponent"])
            except KeyError as exc:
                raise ModelFileError(f"{where}: cannot be simulated: parameter {exc} missing") from None
            except (TypeError, ValueError, ZeroDivisionError) as exc:
                raise ModelFileError(f"{where}: cannot be simulated: {exc}") from None
        eff.stiction = np.where(excess > 0, Fc + excess, 0.0)
        eff.stribeck_velocity = vs
        values = [eff.spring, eff.spring_rest, eff.torque_offset, eff.viscous_nonlinear, eff.hysteresis,
                  eff.friction_profile_sin, eff.friction_profile_cos, eff.backlash, eff.stiction, Fc]
        if not all(np.all(np.isfinite(v)) for v in values) or np.any(eff.stribeck_velocity <= 0) \
                or np.any(eff.backlash < 0) or np.any(np.asarray(eff.time_delay) < 0):
            raise ModelFileError(f"{self.path}: effects: a parameter is not finite or out of its range")
        return replace(params, drive=replace(drive, Fc=Fc)), eff

    @property
    def validation(self) -> dict:
        return self.document.get("validation", {})

    @property
    def provenance(self) -> dict:
        return self.document.get("provenance", {})


def _profile_coefficients(p: dict) -> tuple[np.ndarray, np.ndarray]:
    """(a_sin, a_cos) of a position_friction entry; an entry of catalogue 1.1 (one ripple
    A sin(2 pi q / P + phi)) has a_sin = A cos(phi), a_cos = A sin(phi)."""
    if "a_sin" in p:
        a_sin, a_cos = np.asarray(p["a_sin"], float), np.asarray(p["a_cos"], float)
        if a_sin.shape != a_cos.shape or a_sin.ndim != 1:
            raise ValueError("a_sin and a_cos must be lists of the same length")
        return a_sin, a_cos
    A, phi = float(p["amplitude"]), float(p["phase"])
    return np.array([A * math.cos(phi)]), np.array([A * math.sin(phi)])


def _finite_list(x, what: str) -> list[float]:
    arr = np.asarray(x, dtype=float).ravel()
    if not np.all(np.isfinite(arr)):
        raise ModelFileError(f"{what}: contains a non-finite value")
    return arr.tolist()


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
    """Write atomically; a document with a rig provenance (rig.runs.provenance) is sealed with
    its digest, so a later hand edit is seen."""
    from rig import sealed_json as P
    from rig.sealed_json import result_json

    doc = json.loads(result_json(doc))
    if isinstance(doc.get(P.KEY), dict) and doc[P.KEY].get("arms"):
        P.seal(doc)
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
    except UnicodeDecodeError:
        raise ModelFileError(f"{path}: not a model file (binary content, not JSON); give the model.json "
                             "of a `rig identify` or `rig discrepancy` run") from None
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


def with_stick_slip(path, model: IdentifiedModel, stick: StickSlip, provenance_info: dict) -> IdentifiedModel:
    """Write to `path` a new model file: `model`'s document with `stick` as its stick-slip
    section and `provenance_info` (the rigid body's file is named in it); the earlier file
    is left as it was (a run's files are its record)."""
    doc = dict(model.document)
    doc["stick_slip"] = stick.to_dict()
    doc["provenance"] = {**provenance_info, "rigid_body_from": str(model.path)}
    _write_json(Path(path), doc)
    return load_model(path)


def friction_only_model(path, stick: StickSlip, gravity, slope: float, provenance_info: dict) -> Path:
    """A model file with only the stick-slip section (friction-ramp without an identify run)."""
    return save_model(path, standard=None, names=[], slope=slope, gravity=gravity, gravity_source="configured",
                      provenance_info=provenance_info, stick_slip=stick, kind="friction-only")
