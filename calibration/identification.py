"""Dynamic identification of PSM joints 1-3 on processed recordings (thesis 5.1-5.5).

The model, the equation rows (parallel filtering), the gravity and friction-slope selection,
OLS, WLS and the physically consistent SDP, joint 3's optional Stribeck excess and
position-dependent friction profile, and the validation figures.

`rig identify` runs it on its recordings and on CSV files; `rig discrepancy` identifies its
plain model with it, so the mathematics lives here rather than in either procedure.

Units: SI (rad, m, rad/s, m/s, N m, N, s, Hz).
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field

import numpy as np

#: The zero-phase Butterworth of the identification (thesis 5.3): cut-off (Hz) and order.
CUTOFF_HZ = 3.5
FILTER_ORDER = 8

def make_model(gravity, slope: float):
    """PSMDynamics with the nominal parameters, this gravity (frame 0, m/s^2) and slope (s/rad)."""
    from rig.model.psm_dynamics import DriveParameters, PSMDynamics, PSMParameters

    return PSMDynamics(PSMParameters(drive=DriveParameters(slope=float(slope))), gravity=np.asarray(gravity, float))


@dataclass
class FitOutcome:
    """Everything the fit produced (also used by the bench)."""

    model: object
    base: object
    ident: object
    fits: dict
    gravity: np.ndarray
    gravity_source: str
    slope: float
    selection: dict = field(default_factory=dict)
    seconds: dict = field(default_factory=dict)
    parallel: bool = True
    stribeck_vs: float | None = None  # m/s; None: no Stribeck term identified
    position_friction: tuple | None = None  # (period m, harmonics) of joint 3's profile; None: none
    effects: tuple = ()  # EffectTerm: catalogue effects identified with the rigid body

    def extra_rows(self, data, parallel: bool | None = None) -> np.ndarray | None:
        """The extra columns of processed ``data`` (the Stribeck column, the position
        friction profile's, then the effects'), or None without any."""
        par = self.parallel if parallel is None else parallel
        cols = []
        if self.stribeck_vs is not None:
            cols.append(stribeck_rows(self.model, data, self.stribeck_vs, par))
        if self.position_friction is not None:
            cols.append(position_friction_rows(self.model, data, self.position_friction, par))
        cols += [e.rows(self.model.slope, data, par) for e in self.effects]
        return np.hstack(cols) if cols else None

    def effect_entries(self, source: str) -> list[dict]:
        """The effects identified with the rigid body (``effects``) as model file ``effects``
        entries (their SDP amplitudes), each with ``source``."""
        from calibration.effects import CATALOGUE

        if not self.effects:
            return []
        sdp = self.fits["sdp"]
        names = list(self.model.param_names())
        start = sdp.extra.size - sum(e.n_columns for e in self.effects)
        out = []
        for e in self.effects:
            eff = CATALOGUE[e.effect]
            theta = np.zeros(len(e.free))
            theta[np.asarray(e.free, bool)] = sdp.extra[start:start + e.n_columns]
            start += e.n_columns
            fc = float(sdp.pi[names.index(f"joint{e.joint}.Fc")]) if sdp.pi is not None else 0.0
            out.append({"name": e.effect, "joint": e.joint, "params": eff.params(theta, e.grid, e.joint, {"Fc": fc}),
                        "units": eff.units(e.joint), "source": source})
        return out

    def position_friction_effect(self) -> dict | None:
        """Joint 3's identified friction profile as a model file ``effects`` entry
        (calibration.effects position_friction), or None."""
        if self.position_friction is None:
            return None
        from calibration.effects import CATALOGUE

        eff = CATALOGUE[POSITION_FRICTION]
        sdp = self.fits["sdp"]
        theta = sdp.extra[0 if self.stribeck_vs is None else 1:]
        fc3 = float(sdp.pi[self.model.param_names().index("joint3.Fc")]) if sdp.pi is not None else 0.0
        params = eff.params(theta, self.position_friction, 3, {"Fc": fc3})
        return {"name": POSITION_FRICTION, "joint": 3, "params": params, "units": eff.units(3),
                "source": "identified with the rigid body (rig identify --position-friction)"}

    def stribeck(self) -> dict | None:
        """{"Fst": (3,), "vs": (3,)} of the SDP fit (zero on the joints without the term)."""
        if self.stribeck_vs is None:
            return None
        Fst = np.zeros(3)
        Fst[STRIBECK_JOINT] = float(self.fits["sdp"].extra[0])
        vs = np.full(3, self.stribeck_vs)
        return {"Fst": Fst, "vs": vs}


#: Velocity deadband of thesis 7.5.1 (rad/s, rad/s, m/s): slower than this a joint may be
#: stuck, and its effort is then whatever the controller left within the static friction
#: band, which no rigid-body and friction model predicts.
DEADBAND = np.array([0.01, 0.01, 0.005])


@dataclass(frozen=True)
class EffectTerm:
    """A catalogue effect (`calibration.effects`) identified with the rigid body: its columns
    at a fixed non-linear parameter ``grid`` (a period, a travel, a Stribeck velocity, a
    delay) join the regressor, its linear amplitudes are fitted with the base parameters
    (signed in the SDP; the catalogue's sanity check judges them after). ``free`` marks the
    columns fitted (the others, e.g. a spring's constant beside the offset Fo, left out).
    An effect built from the model's torque (a delay) takes it from ``torque(q, dq, ddq) ->
    (n, 3)``, a model fixed beforehand (the columns are then linear in the amplitude only:
    the torque of a model fitted without the effect stands in for the refitted one's). See
    `identifiable`."""

    effect: str
    joint: int          # 1-3
    grid: object
    free: tuple
    torque: object = field(default=None, compare=False)

    @property
    def n_columns(self) -> int:
        return int(np.sum(self.free))

    @staticmethod
    def identifiable(effect: str, with_model_torque: bool = False) -> bool:
        """Whether ``effect``'s columns depend on the motion alone (or, ``with_model_torque``,
        on the motion and a fixed model's torque, not its mass matrix) and are not terms of
        the rigid-body and friction model already (a payload is an inertia, an offset is Fo)."""
        from calibration.effects import CATALOGUE

        e = CATALOGUE[effect]
        if e.in_rigid_body_model or e.point_mass or e.needs_dynamics:
            return False
        return with_model_torque or not e.uses_model

    def names(self) -> list[str]:
        from calibration.effects import CATALOGUE

        return [f"joint{self.joint}.{self.effect}.{n}" for n, f in
                zip(CATALOGUE[self.effect].linear_names_at(self.grid), self.free) if f]

    def columns(self, q, dq, ddq, rate: float, slope: float) -> np.ndarray:
        """(n*3, k) stacked sample-major columns on the motion (q, dq, ddq) (n, 3), in time order."""
        from calibration.effects import CATALOGUE, EffectContext

        eff = CATALOGUE[self.effect]
        if eff.uses_model and self.torque is None:
            raise ValueError(f"{self.effect}@{self.joint}: its columns need a model's torque (EffectTerm.torque)")
        tau_model = self.torque(q, dq, ddq) if eff.uses_model else None
        cols = eff.columns(EffectContext(q=q, dq=dq, rate=rate, slope=slope, tau_model=tau_model), self.joint,
                           self.grid)
        return cols[:, :, np.asarray(self.free, bool)].reshape(-1, self.n_columns)

    def rows(self, slope: float, data, parallel: bool) -> np.ndarray:
        """The columns as equation rows of processed ``data``: with ``parallel``, computed on
        the measured q and dq, as a prediction and the controller's feedforward compute the
        effect (a hysteresis state runs on the raw samples there), and low-passed like the
        torques; otherwise of the filtered motion (see :func:`equation_rows`)."""
        fn = lambda q, dq, ddq: self.columns(q, dq, ddq, data.rate, slope)   # noqa: E731
        if parallel and data.context is not None:
            return data.context.rows_raw(fn, data.n_samples)
        return equation_rows(data, parallel)(fn)


#: An effect's column that the joint's own friction columns (Fc, Fv, Fo, Ia and joint 3's
#: Stribeck column) reproduce to this R^2 on the training rows cannot be told from them in
#: the identification's band: fitted together the split is arbitrary. On the real PSM a
#: joint-3 Dahl hysteresis of 0.5 mm travel reached 0.980 in the 3.5 Hz band and, fitted
#: with the rigid body, predicted the held-out quarter's joint 3 at 0.158 in `rig validate`
#: (0.100 without it; the plain model 0.123); joint 1's (R^2 0.945) and joint 2's (0.833) helped.
#: The line is close: the simulated rig's joint-3 Dahl cases (0.45-0.55 mm travel) give
#: 0.95-0.97 on its trajectories, and fitted with the rigid body there they predicted another
#: motion better than fitted on top of the plain model.
SEPARABLE_R2 = 0.97


def inseparable_effects(train, terms, parallel: bool = True, deadband=DEADBAND) -> list[tuple]:
    """The effects of ``terms`` (EffectTerm) whose columns the friction columns of their joint
    reproduce to SEPARABLE_R2 or more on the moving training rows of processed ``train``:
    [(term, R^2)]."""
    if not terms:
        return []
    model = make_model(np.array([0.0, 0.0, -9.81]), 400.0)
    W = equation_rows(train, parallel)(model.regressor_batch)
    stribeck = stribeck_rows(model, train, STRIBECK_VELOCITIES[len(STRIBECK_VELOCITIES) // 2], parallel)
    moving = moving_mask(train.dq, deadband).reshape(-1)
    out = []
    for t in terms:
        j = t.joint - 1
        rows = (np.arange(W.shape[0]) % 3 == j) & moving
        F = W[rows][:, 70 + 4 * j:74 + 4 * j]
        if j == STRIBECK_JOINT:
            F = np.hstack([F, stribeck[rows]])
        X = t.rows(model.slope, train, parallel)[rows]
        worst = 0.0
        for x in X.T:
            r = x - F @ np.linalg.lstsq(F, x, rcond=None)[0]
            ss = float(np.sum((x - x.mean()) ** 2))
            worst = max(worst, 1.0 - float(r @ r) / ss if ss > 0 else 1.0)
        if worst >= SEPARABLE_R2:
            out.append((t, worst))
    return out


def fit_plausible_effects(fit, terms) -> tuple[FitOutcome, list[str]]:
    """``fit(terms) -> FitOutcome`` (fit_identification with those effects), the effects whose
    amplitudes leave the catalogue's plausible range (`calibration.effects` sanity checks: a
    friction profile dipping below the Coulomb level, a non-positive Dahl level, ...) left
    out and the rest fitted again, until all pass. Returns the outcome and a line per effect
    left out."""
    from calibration.effects import CATALOGUE

    left = []
    while True:
        outcome = fit(terms)
        bad = [(t, why) for t, e in zip(terms, outcome.effect_entries(""))
               if (why := CATALOGUE[t.effect].sanity(e["params"], t.joint)) is not None]
        if not bad:
            return outcome, left
        left += [f"{t.effect}@{t.joint}: implausible beside the rigid body ({why})" for t, why in bad]
        terms = [t for t in terms if all(t is not b for b, _ in bad)]


def fit_with_effects(train, terms, fit, parallel: bool = True) -> tuple[FitOutcome, list[str]]:
    """``fit(terms) -> FitOutcome`` (fit_identification with those effects) on processed
    ``train``, with the effects the joint's own friction reproduces left out beforehand
    (`inseparable_effects`) and those the fit leaves implausible after (`fit_plausible_effects`):
    the outcome and a line per effect left out."""
    bad = inseparable_effects(train, terms, parallel)
    left = [f"{t.effect}@{t.joint}: not separable from joint {t.joint}'s friction in the identification's band "
            f"(its column is R^2 {r2:.3f} >= {SEPARABLE_R2} of Fc, Fv, Fo, Ia" + (", Stribeck" if t.joint == 3 else "")
            + ")" for t, r2 in bad]
    outcome, implausible = fit_plausible_effects(fit, [t for t in terms if all(t is not b for b, _ in bad)])
    return outcome, left + implausible


def effect_terms(entries, source: str) -> tuple[list[EffectTerm], list[str]]:
    """Model-file ``effects`` entries (e.g. `rig discrepancy`'s model.json) as EffectTerms at
    their non-linear parameters (``params[grid_name]``, with the option a pair), every column
    free but those constant on the joint (the joint's offset Fo is in the model); and one line
    per entry left out (built from a model's torque, or a term of the rigid body itself).
    ``source`` names the file in errors (ValueError)."""
    from calibration.effects import CATALOGUE

    terms, left = [], []
    rng = np.random.default_rng(0)
    q = rng.uniform(-0.5, 0.5, (64, 3)) + np.array([0.0, 0.0, 0.6])
    dq = rng.normal(0.0, 0.2, (64, 3))
    for i, e in enumerate(entries):
        eff, j, p = CATALOGUE[e["name"]], int(e["joint"]), e["params"]
        label = f"{e['name']}@{j}"
        if not EffectTerm.identifiable(eff.id):
            left.append(f"{label}: " + ("a term of the rigid-body and friction model itself" if eff.in_rigid_body_model
                                        or eff.point_mass else "built from the model's torque"))
            continue
        try:
            g = None if eff.grid_name is None else float(p[eff.grid_name])
            if eff.option_name is not None:
                g = (g, int(p[eff.option_name]))
        except (KeyError, TypeError, ValueError):
            raise ValueError(f"{source}: effects[{i}] ({label}) has no usable {eff.grid_name!r}"
                             + (f" and {eff.option_name!r}" if eff.option_name else "")) from None
        probe = EffectTerm(eff.id, j, g, (True,) * len(eff.linear_names_at(g)))
        cols = probe.columns(q, dq, np.zeros_like(q), 200.0, 400.0).reshape(64, 3, -1)[:, j - 1, :]
        free = tuple(bool(np.ptp(c) > 0) for c in cols.T)
        if not any(free):
            left.append(f"{label}: its columns are constant (the joint's offset Fo)")
            continue
        terms.append(EffectTerm(eff.id, j, g, free))
    return terms, left


def moving_mask(dq: np.ndarray, deadband=DEADBAND) -> np.ndarray:
    """(n, 3) True where the joint moves faster than its deadband."""
    return np.abs(np.asarray(dq, float)) >= np.asarray(deadband, float)


def slow_joints(dq: np.ndarray, deadband=DEADBAND, least: float = 0.1) -> list[tuple[int, float]]:
    """(joint index, share of moving samples) of each joint that moves faster than its
    ``deadband`` in less than ``least`` of the samples: too little motion to fit it."""
    moving = moving_mask(dq, deadband).mean(axis=0)
    return [(int(j), float(moving[j])) for j in np.flatnonzero(moving < least)]


def equation_rows(data, parallel: bool):
    """``rows(fn)``: a function of the motion ``fn(q, dq, ddq) -> (n*3, p)`` (a regressor)
    as the equation rows of processed ``data``.

    With ``parallel`` the rows are low-passed like the torques were (parallel filtering,
    calibration.signals.lowpass_stacked), over the untrimmed motion the data were cut from;
    otherwise ``fn`` of the filtered motion itself.
    """
    if not parallel:
        return lambda fn: fn(data.q, data.dq, data.ddq)
    if data.context is None:
        raise ValueError(f"{data.source}: parallel filtering needs data processed by "
                         "calibration.datasets.processed (the untrimmed filtered motion is missing)")
    return lambda fn: data.context.rows(fn, data.n_samples)


#: The joint with the Stribeck term (the insertion joint, thesis 5.6) and the grid of
#: Stribeck velocities (m/s) the training fit chooses from.
STRIBECK_JOINT = 2
STRIBECK_VELOCITIES = (0.0025, 0.005, 0.01, 0.02, 0.04)


def stribeck_rows(model, data, vs: float, parallel: bool) -> np.ndarray:
    """(n*3, 1) stacked Stribeck column of joint 3 for ``data`` (see PSMDynamics.stribeck_columns)."""
    return equation_rows(data, parallel)(lambda q, dq, ddq: model.stribeck_columns(dq, vs)[:, [STRIBECK_JOINT]])


#: The catalogue effect of joint 3's position-dependent Coulomb level, and the blocks in
#: time of the cross-validation that decides whether (and with which period and harmonics)
#: the training data support it.
POSITION_FRICTION = "position_friction"
CV_BLOCKS = 5
#: A profile is kept only when it lowers joint 3's cross-validated relative residual by at
#: least this share of it (a smaller gain is within what the choice among 36 candidates
#: finds in noise) and by at least CV_MIN_EXPLAINED of joint 3's effort: a profile that
#: explains less is immaterial to a controller (25 mN of a 5 N effort) and, on a well-fitted
#: record, is the filter's end effects being fitted rather than friction.
CV_MIN_GAIN = 0.02
CV_MIN_EXPLAINED = 0.005


def position_friction_rows(model, data, g: tuple, parallel: bool) -> np.ndarray:
    """(n*3, 2K) stacked columns of joint 3's friction profile at (period, K) for processed
    ``data``: sigma(dq3) sin(2 pi k q3 / P), sigma(dq3) cos(...) on joint 3's rows."""
    from calibration.effects import CATALOGUE, EffectContext

    eff = CATALOGUE[POSITION_FRICTION]
    k = len(eff.linear_names_at(g))
    return equation_rows(data, parallel)(
        lambda q, dq, ddq: eff.columns(EffectContext(q=q, dq=dq, rate=data.rate, slope=model.slope), 3, g
                                       ).reshape(-1, k))


def _cv_joint3(A: np.ndarray, y: np.ndarray, block: np.ndarray) -> float:
    """Joint 3's relative residual of least squares over ``CV_BLOCKS`` blocks in time, each
    predicted from a fit on the others (A, y: equation rows; block: each row's block)."""
    j3 = np.arange(A.shape[0]) % 3 == 2
    err = 0.0
    for b in range(CV_BLOCKS):
        test = block == b
        x, *_ = np.linalg.lstsq(A[~test], y[~test], rcond=None)
        r = (y - A @ x)[test & j3]
        err += float(r @ r)
    return float(np.sqrt(err / max(float(y[j3] @ y[j3]), 1e-300)))


def choose_position_friction(model, data, Wb, extra, mask, parallel: bool) -> tuple[tuple | None, dict]:
    """The (period, harmonics) of joint 3's friction profile that predicts held-out blocks
    in time of the training data best, or None when no candidate beats the model without
    it by CV_MIN_GAIN and CV_MIN_EXPLAINED; and every candidate's cross-validated joint-3
    residual."""
    from calibration.effects import CATALOGUE, FRICTION_HARMONICS

    rows = np.ones(Wb.shape[0], bool) if mask is None else mask.reshape(-1)
    block = np.minimum((np.arange(Wb.shape[0]) // 3) * CV_BLOCKS // max(data.n_samples, 1), CV_BLOCKS - 1)
    base = Wb if extra is None else np.hstack([Wb, extra])
    n = np.linalg.norm(base, axis=0)
    base = base / np.where(n > 0, n, 1.0)
    y = np.asarray(data.tau, float).reshape(-1)
    score0 = _cv_joint3(base[rows], y[rows], block[rows])
    scores = {"none": score0}
    best = (min(score0 * (1.0 - CV_MIN_GAIN), score0 - CV_MIN_EXPLAINED), None)
    for period in CATALOGUE[POSITION_FRICTION].grid(3):
        X = position_friction_rows(model, data, (period, max(FRICTION_HARMONICS)), parallel)
        for k in FRICTION_HARMONICS:
            A = np.hstack([base, X[:, :2 * k]])
            sc = _cv_joint3(A[rows], y[rows], block[rows])
            scores[f"{period:.4g} m x{k}"] = sc
            if sc < best[0]:
                best = (sc, (float(period), int(k)))
    return best[1], scores


def _choose_stribeck_velocity(Wb, tau, X_of, mask) -> tuple[float, dict]:
    """The Stribeck velocity of STRIBECK_VELOCITIES whose column ``X_of(vs)`` (n*3, 1), added
    to the base regressor ``Wb``, leaves the smallest joint-3 least-squares residual on the
    (masked) training rows; returns it and every velocity's relative residual."""
    rows = np.ones(Wb.shape[0], bool) if mask is None else mask.reshape(-1)
    y = np.asarray(tau, float).reshape(-1)[rows]
    j3 = (np.arange(Wb.shape[0]) % 3 == STRIBECK_JOINT)[rows]
    A = Wb[rows]
    n = np.linalg.norm(A, axis=0)
    # One QR of the base regressor; each candidate column then only adds one direction.
    Q, _ = np.linalg.qr(A / np.where(n > 0, n, 1.0))
    y_r = y - Q @ (Q.T @ y)
    scores = {}
    for vs in STRIBECK_VELOCITIES:
        x = X_of(vs)[rows, 0]
        x_r = x - Q @ (Q.T @ x)
        xx = float(x_r @ x_r)
        r = y_r - x_r * (float(x_r @ y_r) / xx) if xx > 0 else y_r
        scores[vs] = float(np.linalg.norm(r[j3]) / np.linalg.norm(y[j3]))
    return min(scores, key=scores.get), scores


def _masked_identification(model, data, base, mask, parallel: bool, stribeck: bool = False,
                           position_friction=None, effects=()):
    """Identification with the joint samples outside ``mask`` turned into 0 = 0 equations.

    With ``stribeck`` joint 3's Stribeck column is added, its velocity chosen by
    :func:`_choose_stribeck_velocity`; with ``position_friction`` ('auto' or (period, K))
    joint 3's friction profile columns (signed), 'auto' chosen by
    :func:`choose_position_friction`; then the columns of ``effects`` (EffectTerm, signed),
    which are in the regressor the Stribeck velocity is chosen with too. Returns
    (Identification, vs or None, scores, profile (period, K) or None, its scores)."""
    from calibration.estimators import Identification, model_nominal
    from calibration.layout import ParamLayout

    Wb = base.regressor(equation_rows(data, parallel)(model.regressor_batch))
    vs, scores, extra = None, {}, None
    names, signed = [], []
    effect_rows = [e.rows(model.slope, data, parallel) for e in effects]
    if stribeck:
        vs, scores = _choose_stribeck_velocity(np.hstack([Wb] + effect_rows), data.tau,
                                               lambda v: stribeck_rows(model, data, v, parallel), mask)
        extra = stribeck_rows(model, data, vs, parallel)
        names, signed = [f"joint{STRIBECK_JOINT + 1}.Fst"], [False]
    profile, pf_scores = position_friction, {}
    if position_friction == "auto":
        profile, pf_scores = choose_position_friction(model, data, Wb, extra, mask, parallel)
    if profile is not None:
        X = position_friction_rows(model, data, profile, parallel)
        extra = X if extra is None else np.hstack([extra, X])
        from calibration.effects import CATALOGUE

        names += [f"joint3.{n}" for n in CATALOGUE[POSITION_FRICTION].linear_names_at(profile)]
        signed += [True] * X.shape[1]
    for e, X in zip(effects, effect_rows):
        extra = X if extra is None else np.hstack([extra, X])
        names += e.names()
        signed += [True] * X.shape[1]
    tau = data.tau
    if mask is not None:
        rows = mask.reshape(-1)[:, None]
        Wb = Wb * rows
        tau = tau * mask
        extra = None if extra is None else extra * rows
    idx = np.linspace(0, data.n_samples - 1, min(50, data.n_samples)).astype(int)
    ident = Identification(Wb, tau, base, ParamLayout.of(model), nominal=model_nominal(model),
                           regressor=model.regressor, q_check=data.q[idx], extra=extra,
                           extra_names=None if extra is None else names, extra_signed=None if extra is None else signed)
    return ident, vs, scores, profile, pf_scores


def fit_identification(train, gravity_mode, slope_mode, configured_gravity=None, progress=None,
                       deadband=None, parallel: bool = True, stribeck: bool = True,
                       position_friction=None, effects=()) -> FitOutcome:
    """Base parameters, OLS, WLS and SDP on processed ``train`` data (JointData with ddq).

    ``gravity_mode``: 'auto', or a gravity vector (m/s^2, frame 0); ``configured_gravity``
    is the reference direction for the reported tilt. ``slope_mode``: 'auto' or a slope.
    With 'auto' gravity the two hemispheres' best directions are both fitted by the SDP and
    the better physically consistent fit decides the sign. ``deadband`` (3,): joint samples
    slower than it are left out of the fit (see DEADBAND); None uses every sample.
    ``parallel``: filter the regressor like the torques (see :func:`equation_rows`).
    ``stribeck``: add joint 3's Stribeck excess as a column (amplitude >= 0 in the SDP) with
    the Stribeck velocity of STRIBECK_VELOCITIES that fits the training data best (OLS).
    ``position_friction``: None, 'auto' or (period m, harmonics): joint 3's friction profile
    (see :func:`choose_position_friction`).
    ``effects``: EffectTerm, catalogue effects fitted with the rigid body; their columns are in
    the gravity and slope search too (as gravity-free columns) (an unmodelled spring on the insertion joint tilted the
    chosen gravity by 26 degrees on the simulated rig).
    """
    from calibration.base_params import RankDeficientError, base_parameters_of
    from calibration.model_selection import DEFAULT_SLOPES, STANDARD_GRAVITY, GravitySlopeSearch
    from rig.model.psm_kinematics import DQ_MAX, Q_MAX, Q_MIN

    say = progress or (lambda s: None)
    t0 = time.perf_counter()
    ref = np.array([0.0, 0.0, -1.0]) if configured_gravity is None else np.asarray(configured_gravity, float)
    selection: dict = {"deadband": None if deadband is None else np.asarray(deadband, float).tolist(),
                       "parallel_filter": bool(parallel)}
    slopes = DEFAULT_SLOPES if slope_mode == "auto" else (float(slope_mode),)
    if deadband is not None:
        for j, share in slow_joints(train.dq, deadband):
            raise RankDeficientError(
                f"{train.source}: joint {j + 1} moves faster than its deadband ({deadband[j]:g} "
                f"{'m/s' if j == 2 else 'rad/s'}) in only {share * 100:.1f} % of the samples: the trajectory "
                "does not excite it (or use --no-fit-deadband)")
    need_search = isinstance(gravity_mode, str) or slope_mode == "auto"
    candidates = []
    if need_search:
        mask = None if deadband is None else moving_mask(train.dq, deadband)
        effects = tuple(effects)
        # the effects' columns (at the search's reference slope) beside the gravity-free ones
        extra = np.hstack([e.rows(400.0, train, parallel) for e in effects]) if effects else None
        search = GravitySlopeSearch(make_model, train.q, train.dq, train.ddq, train.tau, n_inertial=70, mask=mask,
                                    rows=equation_rows(train, parallel), extra=extra)
        if isinstance(gravity_mode, str):
            res = search.search(slopes, magnitude=float(np.linalg.norm(ref)) if configured_gravity is not None
                                else STANDARD_GRAVITY, nominal_direction=ref)
            candidates = [res.gravity(k) for k in range(len(res.candidates))]
            selection["gravity_candidates"] = [c.to_dict() for c in res.candidates]
            selection["gravity_reference"] = {"vector": ref.tolist(), **res.nominal.to_dict()}
        else:
            res = search.search(slopes, fixed_gravity=gravity_mode)
            candidates = [np.asarray(gravity_mode, float)]
        slope = res.slope
        selection["slope_scores"] = {f"{k:g}": v for k, v in res.slope_scores.items()}
        selection["search_seconds"] = res.seconds
        say(f"friction slope {slope:g} s/rad (scores {', '.join(f'{k:g}: {v:.4g}' for k, v in res.slope_scores.items())})")
    else:
        slope = float(slope_mode)
        candidates = [np.asarray(gravity_mode, float)]
    t1 = time.perf_counter()
    best = None
    for k, g in enumerate(candidates):
        model = make_model(g, slope)
        base = base_parameters_of(model.regressor_batch, model, Q_MIN, Q_MAX, DQ_MAX)
        mask = None if deadband is None else moving_mask(train.dq, deadband)
        try:
            ident, vs, vs_scores, profile, pf_scores = _masked_identification(model, train, base, mask, parallel,
                                                                              stribeck, position_friction, effects)
            if position_friction is not None:
                selection.setdefault("position_friction", []).append(
                    {"joint": 3, "chosen": None if profile is None else {"period": profile[0], "harmonics": profile[1]},
                     "gravity_candidate": k + 1, "cv_blocks": CV_BLOCKS, "cv_min_gain": CV_MIN_GAIN,
                     "cv_min_explained": CV_MIN_EXPLAINED,
                     "cv_relative_residual_joint3": pf_scores})
                if position_friction == "auto":
                    say("joint 3 position friction: " + ("none beats the model without it in cross-validation"
                                                        if profile is None else
                                                        f"period {profile[0]:.4g} m, {profile[1]} harmonic(s)")
                        + f" (CV joint 3 residual without {pf_scores['none']:.4g}, best "
                        f"{min(pf_scores.values()):.4g})")
            if stribeck:
                selection.setdefault("stribeck", []).append(
                    {"joint": STRIBECK_JOINT + 1, "vs": vs, "gravity_candidate": k + 1,
                     "ls_relative_residual_joint3": {f"{v:g}": sc for v, sc in vs_scores.items()}})
                say(f"Stribeck velocity {vs:g} m/s (joint 3 LS residual "
                    + ", ".join(f"{v:g}: {sc:.4g}" for v, sc in vs_scores.items()) + ")")
        except RankDeficientError as exc:
            raise RankDeficientError(f"{train.source}: {exc}") from None
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # "inaccurate" is in the fit's info and checks
            sdp = ident.sdp()
        score = float(np.sum(sdp.relative_error ** 2))
        if len(candidates) > 1:
            selection["gravity_candidates"][k]["sdp_training_relative_error"] = sdp.relative_error.tolist()
            selection["gravity_candidates"][k]["sdp_score"] = score
            say(f"gravity candidate {k + 1}: {np.round(g, 3).tolist()} m/s^2, SDP training relative error "
                f"{np.round(sdp.relative_error, 4).tolist()}")
        if best is None or score < best[0]:
            best = (score, g, model, base, ident, sdp, vs, profile)
    _, g, model, base, ident, sdp, vs, profile = best
    fits = {"ols": ident.ols(), "wls": ident.wls(), "sdp": sdp}
    fits["wls_tau_max"] = ident.wls("tau_max")
    t2 = time.perf_counter()
    source = "estimated" if isinstance(gravity_mode, str) else "given"
    if isinstance(gravity_mode, str):
        tilt = float(np.degrees(np.arccos(np.clip(g @ ref / (np.linalg.norm(g) * np.linalg.norm(ref)), -1, 1))))
        selection["gravity_tilt_deg"] = tilt
    return FitOutcome(model, base, ident, fits, np.asarray(g, float), source, float(slope), selection,
                      {"selection": t1 - t0, "fit": t2 - t1}, bool(parallel), vs, profile, tuple(effects))
