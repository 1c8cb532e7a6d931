"""A model file's efforts on a recording, effects included, and the figures that compare models (issue 26).

The figures: relative error and RMS per joint.

The prediction is the one `rig discrepancy` makes of a given model's baseline (the same
steps on the same samples, `calibration.discrepancy`), with what the workflow leaves out of
that baseline added, so that the whole model file is judged:

1. **Prepare** (`calibration.discrepancy.preparation.prepare`): zero-phase Butterworth (order 4, 10 Hz
   by default) on q and dq, ddq by central differences of the filtered dq; the model's
   friction and effects are built on the measured state ``effort_lag`` (1 ms) before each
   sample, as the dVRK's 1 kHz PID reports the effort it computed a servo cycle earlier. A
   joint is stuck on a sample where its measured or filtered velocity is inside its
   deadband (0.01 rad/s, 0.01 rad/s, 0.002 m/s): its effort there is whatever the
   controller left inside the static friction band. The measured effort and the
   prediction are both zeroed on the joint's stuck samples and then low-passed with the
   same filter (masked parallel filtering); the ends are trimmed by the filter's settling
   length.
2. **Rigid body and friction**: the 82 standard parameters times the regressor on the
   filtered state; the Coulomb sign tanh(a dq / 2) and the model file's Stribeck excess
   Fst exp(-(dq/vs)^2) tanh(a dq / 2) on the measured velocity (`rig discrepancy`'s
   baseline leaves the Stribeck excess out). The inertial term of each joint from the
   filtered acceleration or from fourth-order differences of the measured velocity,
   whichever leaves the smaller residual on the training block (the first part of the
   recording, before the held-out block), as the workflow chooses it.
3. **Effects** (the model file's ``effects`` list, in its order): each entry's catalogue
   torque (`calibration.effects`) on the measured state. Stateful ones run through the
   recording in time order: a hysteresis entry's Dahl state starts at rest (z = 0) on the
   first sample and is advanced by each sample's position change, exactly as
   `EffectCompensation` advances it step by step in the controller's feedforward. An
   effort delay and a backlash, which a controller does not feed forward (they describe
   the effort reading and the crossing of the play, not a load to push against), are part
   of the predicted effort, built on the model's effort up to that entry. A payload is in
   the standard parameters (folded in when its entry says it is not).
4. **Figures** per joint on the moving samples of a block: relative error
   ||tau - pred|| / ||tau|| (dimensionless) and the RMS of tau - pred (N m, N m, N), for
   the whole recording (ends trimmed) and for the held-out block at its end (the last
   ``heldout`` fraction, the block `rig discrepancy` reports its baseline on).

Units: SI (rad, m, rad/s, m/s, N m, N, s, Hz).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from calibration.discrepancy.preparation import DEADBAND, Prepared, prepare
from calibration.discrepancy.settings import Settings
from calibration.effects import CATALOGUE, NOT_COMPENSATED, payload_standard_delta
from calibration.signals import differentiate, settling_samples

#: Sources of the inertial term (see the module docstring, step 2).
INERTIA_SOURCES = ("filtered", "measured")
#: Moving samples a joint needs in the training and in the held-out block.
MIN_MOVING = 50


class PredictionError(ValueError):
    """Data the prediction cannot use (too short, not moving, not finite); one line."""


def minimum_samples(rate: float, settings: Settings) -> int:
    """Samples a recording needs: the filter's settling at both ends, a training and a
    held-out block (as `rig discrepancy` needs)."""
    return 8 * settling_samples(rate, settings.cutoff, settings.order) + 200


@dataclass
class Prediction:
    """A model's efforts on a recording and the measured ones, as compared.

    ``measured``, ``predicted`` (m, 3): masked and low-passed efforts on the kept samples
    (N m, N m, N), ``t`` (m,) their times (s from the first sample); ``moving`` (m, 3) where
    each joint moves; ``raw`` (n, 3) the model's effort on every raw sample, not filtered,
    and ``effects_raw`` (n, 3) the effects' share of it;
    ``blocks`` the kept-sample slices of "all", "heldout" and "train";
    ``inertia_source`` per joint; ``effects`` what was done with each effect entry;
    ``seconds`` the time the prediction took."""

    rate: float
    t: np.ndarray
    measured: np.ndarray
    predicted: np.ndarray
    moving: np.ndarray
    raw: np.ndarray
    effects_raw: np.ndarray
    blocks: dict
    inertia_source: list
    effects: list
    stribeck: bool
    seconds: float = 0.0
    notes: list = field(default_factory=list)

    def figures(self, block: str) -> dict:
        """Relative error and RMS per joint on the moving samples of ``block``, the number
        of those samples and the block's first and last raw sample (0-based)."""
        sl = self.blocks[block]
        r = (self.measured - self.predicted)[sl]
        tau = self.measured[sl]
        mov = self.moving[sl]
        rel, rms, count = [], [], []
        for j in range(3):
            rj, tj = r[mov[:, j], j], tau[mov[:, j], j]
            count.append(int(rj.size))
            rel.append(float(np.linalg.norm(rj) / np.linalg.norm(tj)) if rj.size and np.any(tj) else float("nan"))
            rms.append(float(np.sqrt(np.mean(rj ** 2))) if rj.size else float("nan"))
        return {"relative_error": rel, "rms": rms, "moving_samples": count,
                "samples": [self._raw_index(sl.start), self._raw_index(sl.stop - 1)],
                "t": [float(self.t[sl.start]), float(self.t[sl.stop - 1])]}

    def _raw_index(self, k: int) -> int:
        return int(round(self.t[k] * self.rate))


def _checked(q, dq, tau, source: str):
    q, dq, tau = (np.asarray(x, float) for x in (q, dq, tau))
    if q.ndim != 2 or q.shape[1] < 3 or not (q.shape == dq.shape == tau.shape):
        raise PredictionError(f"{source}: expected q, dq, tau of (samples, 3 joints), got shapes "
                              f"{q.shape}, {dq.shape}, {tau.shape}")
    q, dq, tau = q[:, :3], dq[:, :3], tau[:, :3]
    for name, x in (("q", q), ("dq", dq), ("tau", tau)):
        bad = ~np.isfinite(x)
        if bad.any():
            k, j = np.argwhere(bad)[0]
            raise PredictionError(f"{source}: {name}{j + 1} at sample {k} is {x[k, j]} "
                                  f"({int(bad.sum())} non-finite value(s)): drop or repair them")
    return q, dq, tau


def _standard(model) -> tuple[np.ndarray, list[str]]:
    """The model's standard parameters with any payload entry not yet in them folded in."""
    pi = np.asarray(model.standard, float).copy()
    notes = []
    for i, e in enumerate(model.effects):
        if e["name"] == "payload" and e.get("applied_to") != "standard_parameters":
            from rig.model.model_file import ModelFileError
            from rig.model.psm_dynamics import BODY_NAMES

            try:
                pi = pi + payload_standard_delta(e["params"], BODY_NAMES)
            except (KeyError, TypeError, ValueError) as exc:
                raise ModelFileError(f"{model.path}: effects[{i}] (payload@{e['joint']}): cannot be evaluated "
                                     f"({type(exc).__name__}: {exc})") from None
            notes.append(f"effects[{i}] payload@{e['joint']} folded into the standard parameters")
    return pi, notes


def _rigid_body(dyn, pi: np.ndarray, q: np.ndarray, dq: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The rigid-body part of the standard-parameter model at states (q, dq) (n, 3): its
    effort at zero acceleration (gravity, Coriolis and centrifugal: N m, N m, N) and its
    mass matrix (n, 3, 3) without the rotor inertias, both as the regressor times the
    parameters (Y(q, dq, 0) pi and the change of Y(q, 0, e_k) pi for a unit acceleration
    of joint k), so that they hold for any parameter vector, consistent or not. The tree's
    regressor is taken from Pinocchio per sample and multiplied at once: the 82-column
    `PSMDynamics.regressor_batch` builds its drive columns in Python and took 0.1 s per
    pass over 6000 samples, of which five are needed here."""
    import pinocchio as pin

    G, GT, pin_model, data = dyn.G, dyn.GT, dyn.model, dyn.data
    inertial = np.ascontiguousarray(pi[:10 * G.shape[0]])
    units = [np.ascontiguousarray(G[:, k]) for k in range(3)]
    zero = np.zeros(G.shape[0])
    n = q.shape[0]
    static = np.empty((n, 3))
    mass = np.empty((n, 3, 3))
    regressor = pin.computeJointTorqueRegressor
    for i in range(n):
        qt = G @ q[i]
        # The regressor is returned by reference into `data`: each product is taken at once.
        rest = regressor(pin_model, data, qt, zero, zero) @ inertial
        static[i] = GT @ (regressor(pin_model, data, qt, G @ dq[i], zero) @ inertial)
        for k in range(3):
            mass[i, :, k] = GT @ (regressor(pin_model, data, qt, zero, units[k]) @ inertial - rest)
    return static, mass


def _rigid_and_friction(dyn, pi: np.ndarray, p: Prepared) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Per inertia source, the model's (n, 3) effort without effects on the raw samples:
    rigid body on the filtered state, viscous term on the filtered velocity, the Coulomb
    sign and the Stribeck excess on the measured (lagged) velocity, the inertial term on
    the source's acceleration (the discrepancy workflow's regressor, `Discrepancy._chains`
    with `_set_slope`). Also the model's mass-matrix diagonal on the samples (n, 3), rotor
    inertia included (for a backlash's crossing)."""
    static, mass = _rigid_body(dyn, pi, p.qf_all, p.dqf_all)
    drive = np.asarray(pi[-12:], float).reshape(3, 4)
    fc, fv, fo, ia = drive.T
    sign = np.tanh(0.5 * dyn.slope * p.dq)
    base = static + fc * sign + fv * p.dqf_all + fo + dyn.Fst * np.exp(-(p.dq / dyn.vs) ** 2) * sign
    accelerations = {"filtered": p.ddqf_all, "measured": differentiate(p.dq, p.rate, "central4")}
    efforts = {src: base + np.einsum("nij,nj->ni", mass, a) + ia * a for src, a in accelerations.items()}
    return efforts, np.diagonal(mass, axis1=1, axis2=2) + ia


def _effects(model, entries: list[dict], p: Prepared, base: np.ndarray, slope: float, mass_diag: np.ndarray,
             cache: dict) -> np.ndarray:
    """(n, 3) model effort with the effects added in the file's order on ``base``; entries
    that do not use the model's effort are computed once (``cache``)."""
    from rig.model.model_file import ModelFileError

    total = base.copy()
    for i, e in enumerate(entries):
        name, joint = e["name"], int(e["joint"])
        if name == "payload":
            continue
        eff = CATALOGUE[name]
        try:
            if eff.uses_model or i not in cache:
                torque = eff.torque(e["params"], joint, p.q, p.dq, total, p.rate, slope, ddq=p.ddqf_all,
                                    mass_diag=mass_diag if eff.needs_dynamics else None)
                if not np.all(np.isfinite(torque)):
                    raise ValueError("its torque is not finite")
                if not eff.uses_model:
                    cache[i] = torque
            else:
                torque = cache[i]
        except (KeyError, TypeError, ValueError, ZeroDivisionError) as exc:
            what = f"parameter {exc} missing" if isinstance(exc, KeyError) else f"{type(exc).__name__}: {exc}"
            raise ModelFileError(f"{model.path}: effects[{i}] ({name}@{joint}): cannot be evaluated ({what})") from None
        total = total + torque
    return total


def _effect_docs(entries: list[dict]) -> list[dict]:
    out = []
    for e in entries:
        name = e["name"]
        if name == "payload":
            how = ("in the standard parameters" if e.get("applied_to") == "standard_parameters"
                   else "folded into the standard parameters")
        elif name in NOT_COMPENSATED:
            why = NOT_COMPENSATED[name].split(":")[0]
            how = f"in the predicted effort ({why}; a controller does not feed it forward)"
        elif name == "hysteresis":
            how = "fed forward: Dahl state run through the recording in time order from rest"
        else:
            how = "fed forward"
        out.append({"name": name, "joint": int(e["joint"]), "use": how})
    return out


def predict(model, q, dq, tau, rate: float, settings: Settings | None = None, source: str = "the data",
            inertia: str = "auto") -> Prediction:
    """The efforts a model file (`rig.model.model_file.IdentifiedModel`) predicts for a recording
    (q, dq, tau (n, 3) at ``rate`` Hz, SI) and the measured ones, as compared (see the
    module docstring). ``inertia``: "auto" (the workflow's choice per joint) or one of
    INERTIA_SOURCES for every joint. Raises PredictionError for data it cannot use and
    `rig.model.model_file.ModelFileError` for a model it cannot evaluate, each naming them."""
    if inertia != "auto" and inertia not in INERTIA_SOURCES:
        raise ValueError(f"inertia must be 'auto' or one of {INERTIA_SOURCES}, got {inertia!r}")
    t0 = time.perf_counter()
    settings = settings or Settings()
    q, dq, tau = _checked(q, dq, tau, source)
    n, need = q.shape[0], minimum_samples(rate, settings)
    if n < need:
        raise PredictionError(f"{source}: {n} samples ({n / rate:.1f} s at {rate:g} Hz) are too few: a prediction "
                              f"needs at least {need} ({need / rate:.1f} s) for the {settings.cutoff:g} Hz filter's "
                              f"settling at both ends, a training and a held-out block")
    if not 0.0 <= settings.effort_lag < 1.0 / rate:
        raise PredictionError(f"effort lag {settings.effort_lag * 1e3:g} ms: it must be >= 0 and under one sample "
                              f"({1e3 / rate:g} ms at {rate:g} Hz)")
    dyn = model.dynamics()          # ModelFileError for a friction-only file
    entries = model.effects         # checked entries (ModelFileError otherwise)
    pi, notes = _standard(model)
    p = prepare(q, dq, tau, rate, settings)
    moving = p.moving_raw[p.kept] > 0
    m = moving.shape[0]
    blocks = {"all": slice(0, m), "heldout": p.heldout, "train": p.train}
    for name in ("train", "heldout"):
        counts = moving[blocks[name]].sum(0)
        for j in np.flatnonzero(counts < MIN_MOVING):
            unit = "m/s" if j == 2 else "rad/s"
            block = "training block" if name == "train" else "held-out block"
            raise PredictionError(f"{source}: joint {j + 1} moves faster than its deadband ({DEADBAND[j]:g} {unit}) "
                                  f"in only {int(counts[j])} samples of the {block} (needs {MIN_MOVING}): the "
                                  "recording does not move it enough to compare efforts")
    plain, mass_diag = _rigid_and_friction(dyn, pi, p)
    cache: dict = {}
    raw = {src: _effects(model, entries, p, plain[src], dyn.slope, mass_diag, cache) for src in INERTIA_SOURCES}
    filtered = {src: p.filt_rows(raw[src]) for src in INERTIA_SOURCES}
    # The inertial term's source per joint: the smaller training residual (the workflow's rule).
    tr = blocks["train"]
    choice = []
    for j in range(3):
        mov = moving[tr, j]
        score = {src: np.sqrt(np.mean((p.tauf[tr][mov, j] - filtered[src][tr][mov, j]) ** 2))
                 for src in INERTIA_SOURCES}
        choice.append(min(INERTIA_SOURCES, key=lambda s: score[s]) if inertia == "auto" else inertia)
    predicted = np.column_stack([filtered[choice[j]][:, j] for j in range(3)])
    raw_chosen = np.column_stack([raw[choice[j]][:, j] for j in range(3)])
    effects_raw = raw_chosen - np.column_stack([plain[choice[j]][:, j] for j in range(3)])
    t = np.arange(n)[p.kept] / rate
    return Prediction(rate, t, p.tauf.copy(), predicted, moving, raw_chosen, effects_raw, blocks, choice,
                      _effect_docs(entries),
                      stribeck=bool(np.any(dyn.Fst != 0)), seconds=time.perf_counter() - t0, notes=notes)


def extra_effort(model, p: Prepared) -> np.ndarray:
    """(n, 3) the part of a model file's effort on the raw samples of ``p`` that its 82
    standard parameters' regressor does not give: the Stribeck excess and the effects (in the
    file's order, stateful ones run through the samples in time order; a payload is in the
    standard parameters, see `standard_parameters`). With it, `calibration.discrepancy`
    takes a given model whole (`Discrepancy(..., given_extra=...)`)."""
    dyn = model.dynamics()
    pi, _ = _standard(model)
    efforts, mass_diag = _rigid_and_friction(dyn, pi, p)
    base = efforts["filtered"]
    total = _effects(model, model.effects, p, base, dyn.slope, mass_diag, {})
    extra = total - base
    if np.any(dyn.Fst != 0):
        extra = extra + dyn.Fst * np.exp(-(p.dq / dyn.vs) ** 2) * np.tanh(0.5 * dyn.slope * p.dq)
    return extra


def standard_parameters(model) -> np.ndarray:
    """The model file's 82 standard parameters with a payload entry not yet in them folded in."""
    return _standard(model)[0]
