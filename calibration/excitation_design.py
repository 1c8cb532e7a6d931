"""The trajectories `rig identify` streams: optimised, kept clear of the limits by a measured margin, cached.

**Margin.** A joint under its PID does not follow its set-points exactly: it lags, and it
overshoots at a reversal. A trajectory designed right up to Table 4.2's limits therefore
takes the arm past them (over the wire, joint 3 commanded to 2.4 mm above its lower limit
reached -2.0 mm and the console faulted). The margin is measured, not guessed: the
trajectory is streamed, set-point by set-point at the rig rate with the velocity
feed-forward the procedure sends (servo_jp position and velocity), to the simulated plant
of the arm (`rig.sim.world`: the configured arm's parameters, hidden effects, PID, effort limits
and sensor noise), from rest at its start after the PID has settled there. Per joint, how
far the joint went beyond the commanded range (at least how far it was off the set-point
at the range's ends) and how far its speed went beyond the commanded peak, times SAFETY,
plus the sensors' quantum and noise, are the margins; the trajectory is then shrunk (per
joint, about its centre, which keeps it at rest at both ends) and moved until it lies
within the limits less the margins, and measured again, until the margins it was fitted
to cover what is measured on it. (The lag mid-motion, far from any limit, is reported
but is not a margin.)

**Where a run stops.** A procedure aborts (and holds the arm) when a measured joint comes
within ABORT_FRACTION of its margin of a limit, or moves faster than its velocity limit
less that fraction of the velocity margin: a run that tracks as measured never gets
there (it stays a margin / SAFETY inside), and one that does is stopped before the arm's
own limit, not by the console's fault.

**Cache.** The design (the optimisation takes a minute of CPU) is kept in the user's cache
folder, $RIG_CACHE, else $XDG_CACHE_HOME/dvrk-rig, else ~/.cache/dvrk-rig, one JSON file per
set of inputs (the optimiser's settings, the limits, gravity, the plant and the rig
rate), so every later run with the same inputs finds it whatever its logs folder.

Units: SI (rad, m, rad/s, m/s, s, Hz).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from calibration.blas_threads import blas_threads
from calibration.excitation import ExcitationDesigner, FourierTrajectory, rest_basis

#: The margin is this multiple of the largest tracking error measured on the simulated
#: plant: the plant is the model of the arm, and over the wire set-points arrive with the
#: jitter of a busy machine; the bench (bench/bench_identify_wire.py) reports the errors
#: runs actually met against the margin.
SAFETY = 2.0
#: A run aborts when a measured joint enters the last ABORT_FRACTION of its margin.
ABORT_FRACTION = 0.25
#: The stall test: the plant gets no command for STALL s once every STALL_EVERY s of the
#: trajectory (at phases spread over it). A stall longer than the time the set-point takes
#: to lead by the lag bound (under 0.04 s at the trajectories' speeds) makes the trajectory
#: wait; what follows is then bounded by the lag whatever the stall's length (over the wire
#: on a busy 2-core machine commands stopped for 20-500 ms).
STALL = 0.1
STALL_EVERY = 1.0
#: s at the start's set-point before streaming: the PID's integrator settles on the load.
SETTLE = 1.0
#: The margin a trajectory is fitted to is this much above what was measured, so that the
#: fitted trajectory's own measurement (a little different) is covered at the next round.
HEADROOM = 1.05
#: Rounds of measure-and-fit before giving up (each shrinks the motion; two suffice in practice).
MAX_ROUNDS = 6
#: Bump when the design or its margin changes meaning, so old cache entries are not reused.
DESIGN_VERSION = 3


class DesignError(ValueError):
    """The excitation cannot be kept within the limits with the measured margin."""


def cache_dir() -> Path:
    """The excitation design cache: $RIG_CACHE, else $XDG_CACHE_HOME/dvrk-rig, else ~/.cache/dvrk-rig."""
    env = os.environ.get("RIG_CACHE")
    if env:
        return Path(env).expanduser()
    xdg = os.environ.get("XDG_CACHE_HOME")
    return (Path(xdg).expanduser() if xdg else Path.home() / ".cache") / "dvrk-rig"


def _plain(x):
    """A JSON-able, deterministic form of a spec (dataclasses, arrays, dicts)."""
    if dataclasses.is_dataclass(x) and not isinstance(x, type):
        return {f.name: _plain(getattr(x, f.name)) for f in dataclasses.fields(x)}
    if isinstance(x, dict):
        return {str(k): _plain(v) for k, v in sorted(x.items())}
    if isinstance(x, (list, tuple)):
        return [_plain(v) for v in x]
    if isinstance(x, np.ndarray):
        return _plain(x.tolist())
    if isinstance(x, (float, np.floating)):
        return float(f"{float(x):.12g}") if np.isfinite(x) else str(float(x))
    if isinstance(x, (np.integer,)):
        return int(x)
    return x


@dataclass
class Plant:
    """The simulated plant a trajectory is measured on: one arm of `rig.sim.world` at the rig rate.

    spec: a `rig.sim.world.ArmSpec` (parameters, hidden effects, PID, effort limit, noise, base);
    rate: the rig rate, Hz (one set-point per period, as the procedure streams them);
    gravity: world gravity, m/s^2; seed: the world's noise seed.
    """

    spec: object
    rate: float
    gravity: np.ndarray
    seed: int = 0

    def fingerprint(self) -> dict:
        d = _plain(self.spec)
        d.pop("name", None)
        d.pop("q0", None)  # the trajectory starts where it starts
        return {"spec": d, "rate": float(self.rate), "gravity": _plain(np.asarray(self.gravity, float)),
                "seed": int(self.seed)}

    def world(self):
        from rig.sim.world import SimWorld

        spec = dataclasses.replace(self.spec, name="arm")
        return SimWorld([spec], None, seed=self.seed, dt=1.0 / self.rate, gravity=np.asarray(self.gravity, float),
                        pace=False)


def lagging(q_meas, q_set, dq_set, lag) -> bool:
    """True when a set-point leads the measured joint, in its direction of motion, by more
    than `lag` on any joint: the trajectory's time then waits (see `tracking_error`)."""
    ahead = (np.asarray(q_set) - np.asarray(q_meas)) * np.sign(dq_set)
    return bool(np.any(ahead > lag))


def tracking_error(traj: FourierTrajectory, plant: Plant, lag=None, stall: float = 0.0,
                   stall_every: float = 1.0) -> dict:
    """Stream `traj` to the plant (servo_jp position and velocity at the rig rate, from rest
    at its start, the PID settled there for SETTLE s) and measure what the arm does.

    With `lag` (per joint, rad, rad, m) the trajectory's time waits while its set-point
    leads the measured joint by more than `lag` (`lagging`), as the procedure streams it;
    with `stall` (s) the plant receives no command for `stall` s once every `stall_every`
    s (at phases spread over the trajectory), as when the arm's process is held off the
    CPU, keeping the last set-point and its velocity.

    Returns per joint (3,), on the encoder side of the joint (what the console's limit
    check and measured_js see):
    ``position``: how far the arm went beyond the commanded range [min q_cmd, max q_cmd],
    and at least how far it was from the set-point when the set-point was at either end of
    that range (a lag that never reaches the end still says how the joint tracks there);
    ``velocity``: how far max |dq| went beyond max |dq_cmd|, and at least |dq - dq_cmd| at
    the sample of max |dq_cmd|;
    ``tracking`` / ``tracking_velocity``: max |q - q_cmd| and |dq - dq_cmd| anywhere (the
    lag mid-motion, far from the limits: reported, not part of the margin);
    ``sensor`` / ``sensor_velocity``: what measured_js adds on top, half the encoder quantum
    and 4 standard deviations of the velocity noise of the plant's sensors; ``waited``:
    periods the trajectory's time waited.
    """
    w = plant.world()
    n = int(round(traj.duration * plant.rate)) + 1
    Q, DQ, _ = traj.sample(np.arange(n) / plant.rate)
    w.set_state("arm", Q[0])
    w.servo_jp("arm", Q[0])
    w.advance(SETTLE)
    sl = w.arms["arm"].sl
    every = max(1, int(round(stall_every * plant.rate)))
    length = int(round(stall * plant.rate))
    rows, k, tick, waited = [], 0, 0, 0
    while k < n:
        # stalls start at a phase that moves by 37 % of a period each time: spread over the motion
        held = length > 0 and (tick - int(0.37 * every * (tick // every)) % every) % every < length
        if not held:
            w.servo_jp("arm", Q[k], DQ[k])
        w.step()
        q = w.qm[sl].copy()
        rows.append((k, q, w.dqm[sl].copy(), not held))
        tick += 1
        if lag is not None and lagging(q, Q[k], DQ[k], lag):
            waited += 1
        else:
            k += 1
        if tick > 20 * n:
            raise DesignError("the plant does not follow the trajectory (it waited 20 times its length)")
    ks = np.array([r[0] for r in rows])
    got = np.array([r[3] for r in rows])
    qm, dqm = np.array([r[1] for r in rows]), np.array([r[2] for r in rows])
    Qk, DQk = Q[ks], DQ[ks]
    j = np.arange(3)
    lo, hi, fast = Qk.argmin(axis=0), Qk.argmax(axis=0), np.abs(DQk).argmax(axis=0)
    beyond = np.maximum(Qk[lo, j] - qm.min(axis=0), qm.max(axis=0) - Qk[hi, j])
    excess = np.abs(dqm).max(axis=0) - np.abs(DQk[fast, j])
    # the floors where the plant had the set-point (not during a stall)
    Qd, DQd, qd, dqd = Qk[got], DQk[got], qm[got], dqm[got]
    lo, hi, fast = Qd.argmin(axis=0), Qd.argmax(axis=0), np.abs(DQd).argmax(axis=0)
    at_ends = np.maximum(np.abs(qd[lo, j] - Qd[lo, j]), np.abs(qd[hi, j] - Qd[hi, j]))
    at_peak = np.abs(dqd[fast, j] - DQd[fast, j])
    noise = plant.spec.noise
    return {"position": np.maximum(beyond, at_ends), "velocity": np.maximum(excess, at_peak),
            "tracking": np.abs(qm - Qk).max(axis=0), "tracking_velocity": np.abs(dqm - DQk).max(axis=0),
            "sensor": 0.5 * np.asarray(noise.position_quantum, float),
            "sensor_velocity": 4.0 * np.asarray(noise.velocity_noise, float), "waited": waited}


@dataclass
class Margin:
    """Per joint: position (rad, rad, m) and velocity (rad/s, rad/s, m/s) margins kept from
    Table 4.2's limits, the lag (rad, rad, m) by which a set-point may lead the measured
    joint before the trajectory's time waits, and what they were measured from on the
    plant (`measure`): tracking_position, how far the joint went beyond the commanded range
    (or was off the set-point at its ends), tracking_velocity, how far its speed went
    beyond the commanded peak, each the larger of SAFETY x the ordinary streaming and
    once the stall test."""

    position: np.ndarray
    velocity: np.ndarray
    tracking_position: np.ndarray
    tracking_velocity: np.ndarray
    rate: float
    lag: np.ndarray = None
    safety: float = SAFETY
    stall: float = STALL

    def covers(self, other: "Margin") -> bool:
        return bool(np.all(self.position >= other.position - 1e-12) and np.all(self.velocity >= other.velocity - 1e-12))

    def abort_limits(self, q_min, q_max, dq_max) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(low, high, speed): where a run aborts, ABORT_FRACTION of the margin inside the limits."""
        g, v = ABORT_FRACTION * self.position, ABORT_FRACTION * self.velocity
        return np.asarray(q_min, float) + g, np.asarray(q_max, float) - g, np.asarray(dq_max, float) - v

    def to_dict(self) -> dict:
        return {"position": self.position.tolist(), "velocity": self.velocity.tolist(), "lag": self.lag.tolist(),
                "tracking_position": self.tracking_position.tolist(),
                "tracking_velocity": self.tracking_velocity.tolist(), "rate": self.rate, "safety": self.safety,
                "stall": self.stall, "abort_fraction": ABORT_FRACTION}

    @classmethod
    def from_dict(cls, d: dict) -> "Margin":
        return cls(*(np.asarray(d[k], float) for k in ("position", "velocity", "tracking_position",
                                                          "tracking_velocity")), float(d["rate"]),
                   np.asarray(d["lag"], float), float(d.get("safety", SAFETY)), float(d.get("stall", STALL)))


def measure(traj: FourierTrajectory, plant: Plant) -> tuple[Margin, dict]:
    """The margin `traj` needs on `plant`: streamed as usual, SAFETY x what the joint does
    (the plant is a model of the arm); streamed with the stall test (`tracking_error`'s
    stall: STALL s without commands once every STALL_EVERY s, the trajectory waiting while
    its set-point leads by more than the lag), what the joint does once (the test is the
    worst case itself); plus the sensors. The lag is SAFETY x the ordinary mid-motion
    tracking error, plus the sensors."""
    plain = tracking_error(traj, plant)
    lag = SAFETY * plain["tracking"] + plain["sensor"]
    stalled = tracking_error(traj, plant, lag=lag, stall=STALL, stall_every=STALL_EVERY)
    e_q = np.maximum(SAFETY * plain["position"], stalled["position"])
    e_dq = np.maximum(SAFETY * plain["velocity"], stalled["velocity"])
    m = Margin(e_q + plain["sensor"], e_dq + plain["sensor_velocity"], e_q, e_dq, float(plant.rate), lag)
    report = {"plain_position": plain["position"].tolist(), "plain_velocity": plain["velocity"].tolist(),
              "plain_tracking": plain["tracking"].tolist(), "stall_position": stalled["position"].tolist(),
              "stall_velocity": stalled["velocity"].tolist(), "stall_waited_periods": int(stalled["waited"])}
    return m, report


def fit_inside(traj: FourierTrajectory, q_low, q_high, dq_high, rate: float) -> tuple[FourierTrajectory, np.ndarray]:
    """Per joint, shrink the motion about the centre of its range (if it is wider than the
    window or faster than dq_high) and move it into [q_low, q_high]; the rest conditions
    hold (a shrink scales the Fourier coefficients). Returns the trajectory and the scales."""
    q_low, q_high, dq_high = (np.asarray(x, float) for x in (q_low, q_high, dq_high))
    if np.any(q_high <= q_low) or np.any(dq_high <= 0):
        bad = int(np.argmax((q_high <= q_low) | (dq_high <= 0)))
        raise DesignError(f"joint {bad + 1}: the margin leaves no room within its limits "
                          f"(window [{q_low[bad]:.4g}, {q_high[bad]:.4g}], speed {dq_high[bad]:.4g})")
    Q, DQ, _ = traj.sample(traj.times(rate))
    lo, hi = Q.min(axis=0), Q.max(axis=0)
    half, mid = 0.5 * (hi - lo), 0.5 * (hi + lo)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.minimum.reduce([np.ones(3), np.where(half > 0, 0.5 * (q_high - q_low) / half, 1.0),
                               dq_high / np.maximum(np.abs(DQ).max(axis=0), 1e-300)])
    s = np.where(s < 1.0, s * (1.0 - 1e-9), 1.0)
    new_mid = np.clip(mid, q_low + s * half, q_high - s * half)
    q0 = new_mid + s * (traj.q0 - mid)
    return FourierTrajectory(traj.frequency_hz, traj.a * s[:, None], traj.b * s[:, None], q0, traj.duration), s


def keep_clear(traj: FourierTrajectory, plant: Plant, q_min, q_max, dq_max,
               measure: Callable = measure) -> tuple[FourierTrajectory, Margin, dict]:
    """`traj` fitted within the limits less a margin that covers what is measured (`measure`)
    on the fitted trajectory itself. Returns (trajectory, margin, report)."""
    q_min, q_max, dq_max = (np.asarray(x, float) for x in (q_min, q_max, dq_max))
    scales = np.ones(3)
    rounds = []
    margin = None
    for _ in range(MAX_ROUNDS):
        measured, report = measure(traj, plant)
        rounds.append(report)
        if margin is not None and margin.covers(measured):
            margin = Margin(margin.position, margin.velocity, margin.tracking_position, margin.tracking_velocity,
                            margin.rate, np.maximum(margin.lag, measured.lag))
            break  # fitted within a margin that covers what it meets
        # fit to the larger of this and the previous measurement, with HEADROOM, so that the
        # fitted trajectory's own (slightly different) measurement is covered
        prev = measured if margin is None else margin
        margin = Margin(np.maximum(prev.position, measured.position * HEADROOM),
                        np.maximum(prev.velocity, measured.velocity * HEADROOM),
                        np.maximum(prev.tracking_position, measured.tracking_position),
                        np.maximum(prev.tracking_velocity, measured.tracking_velocity), plant.rate,
                        np.maximum(prev.lag, measured.lag))
        traj, s = fit_inside(traj, q_min + margin.position, q_max - margin.position, dq_max - margin.velocity,
                             plant.rate)
        scales *= s
    else:
        raise DesignError(f"the trajectory's tracking error did not settle in {MAX_ROUNDS} rounds of "
                          f"measuring and shrinking ({rounds[-1]})")
    return traj, margin, {"rounds": len(rounds), "scale": scales.tolist(), "measured": rounds}


def check(traj: FourierTrajectory, margin: Margin, q_min, q_max, dq_max, rate: float, what: str) -> str | None:
    """None when every sample of `traj` keeps the margin from the limits at the rig `rate`
    the margin was measured at, else one line naming the joint and what to do."""
    if abs(margin.rate - rate) > 1e-6 * rate:
        return (f"the {what} trajectory's margin was measured at {margin.rate:g} Hz but the rig runs at {rate:g} Hz: "
                "run again to design it for this rate")
    Q, DQ, _ = traj.sample(traj.times(rate))
    low, high = np.asarray(q_min, float) + margin.position, np.asarray(q_max, float) - margin.position
    speed = np.asarray(dq_max, float) - margin.velocity
    for j in range(3):
        u, vu = ("m", "m/s") if j == 2 else ("rad", "rad/s")
        if Q[:, j].min() < low[j] - 1e-9 or Q[:, j].max() > high[j] + 1e-9:
            return (f"the {what} trajectory takes joint {j + 1} to [{Q[:, j].min():.4f}, {Q[:, j].max():.4f}] {u}, "
                    f"within {margin.position[j]:.4g} {u} (its margin) of its limits [{q_min[j]:g}, {q_max[j]:g}]: "
                    "delete the cached design and run again")
        if np.abs(DQ[:, j]).max() > speed[j] + 1e-9:
            return (f"the {what} trajectory moves joint {j + 1} at {np.abs(DQ[:, j]).max():.3f} {vu}, within "
                    f"{margin.velocity[j]:.3g} {vu} (its margin) of its limit {dq_max[j]:g}: delete the cached "
                    "design and run again")
    return None


def validation_trajectory(frequency_hz: float, duration: float, harmonics: int, seed: int, fill: float,
                          q_min, q_max, dq_max) -> FourierTrajectory:
    """A random rest-to-rest Fourier trajectory (not optimised) using ``fill`` of the limits.

    Different frequency and random coefficients from the excitation, so validating on it
    tests the model on motion it was not fitted to (thesis Figure 5.3).
    """
    q_min, q_max, dq_max = (np.asarray(x, float) for x in (q_min, q_max, dq_max))
    rng = np.random.default_rng(10_000 + seed)
    Z = rest_basis(frequency_hz, duration, harmonics)
    c = rng.normal(size=(3, Z.shape[1])) @ Z.T
    raw = FourierTrajectory(frequency_hz, c[:, :harmonics], c[:, harmonics:], np.zeros(3), duration)
    q, dq, _ = raw.sample(raw.times(200.0))
    half, mid = 0.5 * (q_max - q_min), 0.5 * (q_max + q_min)
    dev = np.abs(q - q.mean(axis=0)).max(axis=0)
    s = np.minimum(fill * half / dev, fill * dq_max / np.abs(dq).max(axis=0))
    return FourierTrajectory(frequency_hz, raw.a * s[:, None], raw.b * s[:, None], mid - s * q.mean(axis=0), duration)


#: designers built in this process (a worker builds one per set of inputs, then reuses it)
_DESIGNERS: dict = {}


def _designer(args: tuple) -> ExcitationDesigner:
    """The optimiser of `design` for (gravity_base, q_min, q_max, dq_max, dq_opt, f, L, T), as tuples."""
    if args not in _DESIGNERS:
        from calibration.base_params import base_parameters_of
        from calibration.identification import make_model

        gravity_base, q_min, q_max, dq_max, dq_opt, f, L, T = args
        model = make_model(np.array(gravity_base), 400.0)
        base = base_parameters_of(model.regressor_batch, model, np.array(q_min), np.array(q_max), np.array(dq_max))
        _DESIGNERS[args] = ExcitationDesigner(model.regressor_batch, base.independent, np.array(q_min),
                                              np.array(q_max), np.array(dq_opt), frequency_hz=f, harmonics=L,
                                              duration=T, rate=200.0)
    return _DESIGNERS[args]


def _start_worker(args: tuple, x0: np.ndarray, maxiter: int) -> dict:
    with blas_threads(1):
        return _designer(args).run_start(x0, maxiter)


def _keep_clear_worker(traj: dict, plant: Plant, q_min, q_max, dq_max) -> tuple[dict, dict, dict]:
    with blas_threads(1):
        t, m, r = keep_clear(FourierTrajectory.from_dict(traj), plant, q_min, q_max, dq_max)
    return t.to_dict(), m.to_dict(), r


def workers() -> int:
    """Processes the design runs in: the machine's cores, at most 4 (the starts are 4 by default)."""
    return max(1, min(4, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1))


def design_key(settings: dict, gravity_base, plant: Plant, q_min, q_max, dq_max) -> tuple[dict, str]:
    """(inputs, key): everything a design depends on, and the cache file's key (its hash)."""
    inputs = {"version": DESIGN_VERSION, "settings": _plain(settings), "design_rate": 200.0,
              "q_min": _plain(np.asarray(q_min, float)), "q_max": _plain(np.asarray(q_max, float)),
              "dq_max": _plain(np.asarray(dq_max, float)),
              "gravity": _plain(np.round(np.asarray(gravity_base, float), 9)), "model": "PSMDynamics nominal, slope 400",
              "plant": plant.fingerprint(), "safety": SAFETY, "headroom": HEADROOM, "stall": [STALL, STALL_EVERY], "abort_fraction": ABORT_FRACTION, "settle": SETTLE}
    return inputs, hashlib.sha256(json.dumps(inputs, sort_keys=True).encode()).hexdigest()[:16]


def design(settings: dict, gravity_base, plant: Plant, q_min, q_max, dq_max, progress: Callable | None = None,
           processes: int | None = None) -> dict:
    """See _design; with one BLAS thread (calibration.blas_threads: many small SVDs)."""
    with blas_threads(1):
        return _design(settings, gravity_base, plant, q_min, q_max, dq_max, progress, processes)


def _design(settings: dict, gravity_base, plant: Plant, q_min, q_max, dq_max, progress: Callable | None = None,
            processes: int | None = None) -> dict:
    """The excitation and validation trajectories for these settings, each kept clear of
    the limits by its measured margin; from the cache when designed before.

    settings: frequency_hz, harmonics, duration, starts, iterations, seed, velocity_fraction
    (of dq_max the optimiser may use), validation_frequency_hz, fill. gravity_base: gravity in
    the arm's frame 0 (m/s^2), for the regressor. ``progress(k, n, cond)`` after each start.
    The optimiser's starts and the validation trajectory's margin run in `processes`
    worker processes (default `workers()`; 1: all in this one); the result is the same.

    Returns {"excitation", "validation": FourierTrajectory, "margin", "validation_margin":
    Margin, "figures": {...}, "cached": bool, "path": str, "key": str, "lookup_seconds": s}.
    """
    t0 = time.perf_counter()
    q_min, q_max, dq_max = (np.asarray(x, float) for x in (q_min, q_max, dq_max))
    inputs, key = design_key(settings, gravity_base, plant, q_min, q_max, dq_max)
    path = cache_dir() / f"excitation-{key}.json"
    found = _load(path, inputs)
    if found is not None:
        found.update(cached=True, key=key, path=str(path), lookup_seconds=time.perf_counter() - t0)
        return found
    args = (tuple(np.round(np.asarray(gravity_base, float), 9).tolist()), tuple(q_min.tolist()),
            tuple(q_max.tolist()), tuple(dq_max.tolist()), tuple((settings["velocity_fraction"] * dq_max).tolist()),
            float(settings["frequency_hz"]), int(settings["harmonics"]), float(settings["duration"]))
    designer = _designer(args)
    vraw = validation_trajectory(settings["validation_frequency_hz"], settings["duration"], settings["harmonics"],
                                 settings["seed"], settings["fill"], q_min, q_max, dq_max)
    n = processes or workers()
    if n > 1:
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor, as_completed

        # spawn, not fork: the caller may hold threads (a recorder, a ROS executor)
        with ProcessPoolExecutor(max_workers=n, mp_context=multiprocessing.get_context("spawn")) as pool:
            vfut = pool.submit(_keep_clear_worker, vraw.to_dict(), plant, q_min, q_max, dq_max)

            def run_starts(points, maxiter):
                futs = {pool.submit(_start_worker, args, x0, maxiter): k for k, x0 in enumerate(points)}
                for f in as_completed(futs):
                    yield futs[f], f.result()

            res = designer.optimise(n_starts=settings["starts"], seed=settings["seed"],
                                    maxiter=settings["iterations"], progress=progress, run_starts=run_starts)
            t1 = time.perf_counter()
            traj, margin, report = keep_clear(res.trajectory, plant, q_min, q_max, dq_max)
            vt, vm, vreport = vfut.result()
        vtraj, vmargin = FourierTrajectory.from_dict(vt), Margin.from_dict(vm)
    else:
        res = designer.optimise(n_starts=settings["starts"], seed=settings["seed"], maxiter=settings["iterations"],
                                time_budget=float("inf"), progress=progress)
        t1 = time.perf_counter()
        traj, margin, report = keep_clear(res.trajectory, plant, q_min, q_max, dq_max)
        vtraj, vmargin, vreport = keep_clear(vraw, plant, q_min, q_max, dq_max)
    figures = {"condition_objective": designer.condition(traj, designer.t_obj),
               "condition_full": designer.condition(traj, designer.t_full),
               "condition_objective_before_margin": res.condition_objective,
               "limit_use": designer.limit_use(traj), "scale_applied": res.scale_applied, "starts": res.starts,
               "optimisation_seconds": res.seconds, "margin_seconds_after_optimisation": time.perf_counter() - t1,
               "design_seconds": time.perf_counter() - t0, "processes": n, "margin_fit": report,
               "validation_margin_fit": vreport}
    doc = {"inputs": inputs, "trajectory": traj.to_dict(), "validation_trajectory": vtraj.to_dict(),
           "margin": margin.to_dict(), "validation_margin": vmargin.to_dict(), "figures": figures}
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f"{path.name}.{os.getpid()}.tmp")
    tmp.write_text(json.dumps(doc))
    tmp.replace(path)  # atomic: a concurrent run reads the old file or the new one, never half of one
    return {"excitation": traj, "validation": vtraj, "margin": margin, "validation_margin": vmargin,
            "figures": figures, "cached": False, "key": key, "path": str(path),
            "lookup_seconds": time.perf_counter() - t0}


def _load(path: Path, inputs: dict) -> dict | None:
    """The cached design for exactly these inputs, or None (missing, damaged or another's)."""
    try:
        doc = json.loads(path.read_text())
        if doc.get("inputs") != inputs:
            return None
        return {"excitation": FourierTrajectory.from_dict(doc["trajectory"]),
                "validation": FourierTrajectory.from_dict(doc["validation_trajectory"]),
                "margin": Margin.from_dict(doc["margin"]), "validation_margin": Margin.from_dict(doc["validation_margin"]),
                "figures": doc["figures"]}
    except (OSError, json.JSONDecodeError, KeyError, TypeError, ValueError):
        return None  # designed again and overwritten
