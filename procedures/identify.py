"""`rig identify`: excitation, recording and dynamic identification of PSM joints 1-3 (thesis 5.1-5.5).

Live (on the rig or its simulation):

1. design the excitation: a 5-harmonic Fourier trajectory (eq. 5.28, 0.13 Hz, 30 s) that
   minimises the condition number of the base regressor within Table 4.2's limits, and a
   validation trajectory; each is then kept clear of every position and velocity limit by
   a margin measured on the arm's simulated plant at the rig rate (twice how far its PID
   lets each joint pass the commanded range and peak speed, or what a 0.1 s stall of its
   commands does, the larger, plus the sensors' noise; see calibration.excitation_design),
   and checked before anything moves. The design is done
   before the devices are opened and cached by its inputs in the user's cache folder
   ($RIG_CACHE, else ~/.cache/dvrk-rig), so every later run reuses it;
2. move to its start (move_jp), stream it with servo_jp (position and velocity
   feed-forward) at the rig rate, recording q, dq, tau of measured_js to the run's MCAP;
   its time waits while the set-point leads the arm by more than the margin's lag (an arm
   whose commands stalled meets no jump when they resume); a measured joint that comes
   within a quarter of its margin of a limit aborts the run (the arm held) before the
   console would fault;
3. the same with a validation trajectory (another frequency and seed, not optimised);
4. process (block mean to the identification rate, zero-phase Butterworth, differentiation,
   trimming), base parameters, OLS, WLS, SDP (physically consistent, checked);
5. the validation table (per joint relative error and RMS, OLS/WLS/SDP side by side),
   plots in the style of Figures 5.2/5.3, Table 5.1's figures, and the model file.

Offline: ``rig identify --csv FILE [--rate 200] [--joints 3] [--validate-csv FILE2]`` on
data in the WPI format (shared/data/wpi-psm); validation on FILE2, else on a held-out
contiguous last block of FILE.

Gravity. On the simulated rig and a configured real rig the gravity vector in frame 0 is
the world gravity rotated into the arm's base (``--gravity config``). For recorded data the
arm's tilt on its set-up joints is unknown: ``--gravity auto`` (the default with --csv)
estimates the direction (calibration.model_selection: least-squares scan of the sphere,
then the sign from the physically consistent SDP fit) and stores it in the model file.

Parallel filtering (default; ``--no-parallel-filter`` to turn it off). The measured torques
are low-passed (3.5 Hz), so the friction step at a velocity reversal, which the Coulomb term
makes in a few milliseconds, shows as a ramp over a few hundred. The regressor columns get
the same zero-phase filter (over the same untrimmed samples), in the fit and in the
validation: tau = W pi holds for the filtered pair, not for the filtered torque against
the model of the filtered motion. The model file's parameters are the same kind as
without it (efforts for a motion); only the comparison is like for like.

Validation figures (per joint, norm(tau_meas - tau_pred) / norm(tau_meas) on the validation
data): ``validation`` on all samples; ``validation_moving`` on the samples where the joint
moves faster than the 7.5.1 deadband -- the figure held against the issue's 5 % target,
since a stuck joint's effort is anywhere within its static friction band and no model of
the motion predicts it; ``validation_moving_unfiltered`` the same with the model's efforts
not low-passed (the definition before parallel filtering); on the simulated rig
``truth.sdp_vs_true_relative_error``, the SDP model's efforts against the true parameters'.

Stribeck term (default; ``--no-stribeck`` to leave it out). Joint 3's friction near zero
velocity exceeds the Coulomb level (thesis 5.6; stiction in the simulator): the fit adds
Fst exp(-(dq3/vs)^2) tanh(a dq3/2) as a column outside the standard parameters, Fst >= 0
in the SDP, vs the value of STRIBECK_VELOCITIES with the smallest joint-3 least-squares
residual on the training data. The model file carries it (``friction.stribeck``).
Fst is the excess of this model's law, in which the Coulomb level and the excess both
carry the smooth sign: where tanh(a dq3/2) is still short of 1 at the Stribeck speeds
(the thesis' a = 400 at a few mm/s) Fst also takes up that shortfall, and on the
simulated rig it then reads above the plant's excess; with a nearly exact sign
(--friction-slope 3000) it reads below. It is the excess of this smooth law, not the
breakaway excess Fs - Fc of dry friction, which `rig friction-ramp` measures.

Friction slope. ``--friction-slope auto`` (default) chooses the slope a of the smooth
Coulomb sign tanh(a dq / 2) on a grid by the training fit; a number fixes it (400 s/rad
is the thesis' controller value).

Units: SI (rad, m, rad/s, m/s, N m, N, s, Hz).
"""

from __future__ import annotations

import bisect
import math
import sys
from pathlib import Path

import click
import numpy as np

from calibration.datasets import load_timed_csv
from calibration.identification import (CUTOFF_HZ, DEADBAND, FILTER_ORDER, FitOutcome, fit_identification,
                                        fit_with_effects, predict,
                                        validation_table)
from rig.commands.abort import exit_on_abort
from rig.commands.exit_codes import InputError
from rig.commands.options import config_from_context, json_option, yes_option
from rig.commands.parameters import Parameter, with_parameters
from rig.commands.report import emit_result, exit_for_status
from rig.runs import provenance
from rig.runs.run import AbortRun, Run

PROCEDURE = "identify"

STEPS_LIVE = ("design the excitation trajectory", "move to the start", "run the excitation trajectory",
              "run the validation trajectory", "process the recordings", "fit OLS, WLS and SDP",
              "validate, plot and save the model")
STEPS_CSV = ("load the CSV data", "process the recordings", "fit OLS, WLS and SDP",
             "validate, plot and save the model")

#: The published figure of the WPI package (7-DOF model, SDP, unseen test trajectory).
PUBLISHED_7DOF = (0.093, 0.178, 0.191)

PARAMETERS = [
    Parameter("arm", "PSM1", "", "Arm to identify (live)", type=str),
    Parameter("csv", "", "", "Identify offline from this WPI-format CSV (q1..qn, dq1..dqn, tau1..taun) instead "
              "of moving the arm", type=str),
    Parameter("validate_csv", "", "", "Offline: validate on this second CSV (default: a held-out block of --csv)",
              type=str),
    Parameter("rate", 200.0, "Hz", "Offline: sampling rate of the CSV rows", minimum=1.0, maximum=20000.0),
    Parameter("joints", 3, "", "Offline: joints used from the CSV (the model has joints 1-3)", minimum=3,
              maximum=3, type=int),
    Parameter("time_column", False, "", "Offline: the CSV's first column is the sample time (s), followed by the "
              "3n WPI columns; the rows are resampled to --rate", type=bool),
    Parameter("heldout", 0.25, "", "Offline without --validate-csv: fraction of FILE held out at its end",
              minimum=0.05, maximum=0.5),
    Parameter("gravity", "", "m/s^2", "Gravity in frame 0: 'auto' (estimate the direction), 'config' (world "
              "gravity rotated into the arm base) or 'gx,gy,gz'; default auto with --csv, config live", type=str),
    Parameter("friction_slope", "auto", "s/rad", "Slope a of the Coulomb sigmoid tanh(a dq/2): 'auto' (chosen by "
              "the training fit) or a number", type=str),
    Parameter("frequency", 0.13, "Hz", "Fundamental frequency of the excitation (eq. 5.28)", minimum=0.02,
              maximum=1.0),
    Parameter("harmonics", 5, "", "Harmonics of the excitation", minimum=2, maximum=10, type=int),
    Parameter("duration", 30.0, "s", "Duration of the excitation and of the validation trajectory", minimum=4.0,
              maximum=300.0),
    Parameter("validation_frequency", 0.16, "Hz", "Fundamental frequency of the validation trajectory",
              minimum=0.02, maximum=1.0),
    Parameter("fill", 0.7, "", "Validation trajectory: fraction of the position and velocity limits used (then "
              "kept a measured margin from every limit)", minimum=0.1, maximum=0.95),
    Parameter("velocity_fraction", 0.6, "", "Fraction of Table 4.2's velocity limits (2, 2 rad/s, 0.4 m/s) the "
              "excitation's optimiser may use; the trajectory is then kept a margin from every position and "
              "velocity limit measured on the arm's simulated plant (2 x its tracking error, or the 0.1 s "
              "stall test)", minimum=0.2,
              maximum=1.0),
    Parameter("starts", 4, "", "Seeded starts of the excitation optimisation", minimum=1, maximum=20, type=int),
    Parameter("iterations", 60, "", "SLSQP iterations per start of the excitation optimisation", minimum=1,
              maximum=500, type=int),
    Parameter("design_seed", 0, "", "Seed of the excitation optimisation (and of the validation trajectory)",
              type=int),
    Parameter("sample_rate", 200.0, "Hz", "Identification rate: recordings are block-averaged to it",
              minimum=20.0, maximum=2000.0),
    Parameter("cutoff", CUTOFF_HZ, "Hz", "Butterworth cut-off of the zero-phase filter", minimum=0.2, maximum=50.0),
    Parameter("filter_order", FILTER_ORDER, "", "Butterworth order", minimum=1, maximum=12, type=int),
    Parameter("parallel_filter", True, "", "Filter the regressor columns with the torques' Butterworth before "
              "fitting and predicting (parallel filtering): the filtered torque's friction step at a velocity "
              "reversal is smeared, and so must be the model's", type=bool),
    Parameter("stribeck", True, "", "Identify a Stribeck excess on joint 3 (thesis 5.6): Fst exp(-(dq3/vs)^2) "
              "tanh(a dq3/2) with Fst >= 0 and vs chosen on a grid by the training fit", type=bool),
    Parameter("position_friction", "off", "", "Joint 3 Coulomb level varying with the insertion, sigma(dq3) f(q3), "
              "f a Fourier series (the effect `rig discrepancy` names on the real arm): 'off'; 'auto' (period and "
              "harmonics chosen by cross-validation over blocks in time of the training data, kept only where they "
              "predict held-out blocks better); or 'P' / 'P,K' (period in m, K harmonics 1-4)", type=str),
    Parameter("effects_from", "", "", "A model file whose effects are identified with the rigid body (e.g. the "
              "model.json of `rig discrepancy`: the effects it confirmed on other motion): their columns, at the file's "
              "non-linear parameters (a period, a travel, a Stribeck velocity, an exponent), join the regressor and "
              "the gravity and slope search, and their amplitudes are fitted with the base parameters. Effects built "
              "from a model's torque (a delay, a play), terms of the rigid body (an offset, a payload), effects whose "
              "column the joint's own friction columns reproduce (R^2 >= 0.97 in the 3.5 Hz band) and effects the fit "
              "leaves implausible are left out and named; '' (default): none", type=str),
    Parameter("fit_deadband", True, "", "Leave joint samples slower than the 7.5.1 velocity deadband (0.01 rad/s, "
              "0.01 rad/s, 0.005 m/s) out of the fit: a stuck joint's effort is not a function of the motion",
              type=bool),
    Parameter("seed", -1, "", "Seed of the simulated rig (-1: the configuration's)", type=int),
    Parameter("plots", True, "", "Write the Figure 5.2/5.3-style PNGs", type=bool),
]


# ----------------------------------------------------------------------------- model helpers
def parse_gravity(text: str) -> str | np.ndarray:
    """'auto', 'config' or three numbers 'gx,gy,gz' (m/s^2)."""
    t = text.strip().lower()
    if t in ("auto", "config"):
        return t
    try:
        g = np.array([float(x) for x in t.replace(" ", "").split(",")])
    except ValueError:
        g = np.zeros(0)
    if g.shape != (3,) or not np.all(np.isfinite(g)) or np.linalg.norm(g) == 0:
        raise click.BadParameter(f"{text!r}: use 'auto', 'config' or three numbers 'gx,gy,gz' in m/s^2",
                                 param_hint="--gravity")
    return g


def parse_slope(text: str) -> str | float:
    t = text.strip().lower()
    if t == "auto":
        return t
    try:
        a = float(t)
    except ValueError:
        a = float("nan")
    if not (math.isfinite(a) and a > 0):
        raise click.BadParameter(f"{text!r}: use 'auto' or a slope > 0 s/rad", param_hint="--friction-slope")
    return a


# ----------------------------------------------------------------------------- option parsing
def effects_from(parameters: dict) -> tuple[list, list[str]]:
    """The EffectTerms of --effects-from (none without it) and the lines of the effects left out."""
    path = str(parameters.get("effects_from") or "").strip()
    if not path:
        return [], []
    from calibration.identification import effect_terms
    from rig.model.model_file import ModelFileError, load_model

    try:
        entries = load_model(path).effects
    except ModelFileError as exc:
        raise click.BadParameter(str(exc), param_hint="--effects-from") from None
    if not entries:
        raise click.BadParameter(f"{path}: the model file has no effects to identify", param_hint="--effects-from")
    try:
        terms, left = effect_terms(entries, path)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="--effects-from") from None
    if parse_position_friction(parameters["position_friction"]) is not None and \
            any(t.effect == "position_friction" and t.joint == 3 for t in terms):
        raise click.BadParameter(f"{path} has a joint-3 position friction and --position-friction is "
                                 f"{parameters['position_friction']!r}: use one of them", param_hint="--effects-from")
    return terms, left


def _fit(train, gmode, smode, configured_gravity, parameters: dict, terms, say):
    """The identification at the command's options, with --effects-from's effects (those the
    fit can take): the FitOutcome and a line per effect left out."""
    return fit_with_effects(train, terms, lambda ts: fit_identification(
        train, gmode, smode, configured_gravity=configured_gravity, progress=say,
        deadband=DEADBAND if parameters["fit_deadband"] else None, parallel=parameters["parallel_filter"],
        stribeck=parameters["stribeck"], position_friction=parse_position_friction(parameters["position_friction"]),
        effects=ts), parameters["parallel_filter"])


def parse_position_friction(text: str):
    """'off' -> None, 'auto' -> 'auto', 'P' or 'P,K' -> (P m, K)."""
    t = str(text).strip().lower()
    if t in ("off", "", "none"):
        return None
    if t == "auto":
        return "auto"
    from calibration.effects import FRICTION_HARMONICS

    try:
        parts = [float(x) for x in t.split(",")]
    except ValueError:
        parts = []
    if len(parts) not in (1, 2) or not parts[0] > 0 or (len(parts) == 2 and parts[1] not in FRICTION_HARMONICS):
        raise click.BadParameter(f"{text!r}: give off, auto, a period in m (e.g. 0.05) or period,harmonics "
                                 f"(harmonics {FRICTION_HARMONICS[0]}-{FRICTION_HARMONICS[-1]})",
                                 param_hint="--position-friction")
    return (parts[0], int(parts[1]) if len(parts) == 2 else 1)


#: The identified model's relative validation error above which a run has not produced a
#: usable model: at 0.5 the model leaves a quarter of the effort's energy unexplained (the
#: thesis's own models reach 0.05-0.2 on the real arm, the simulated rig well under 0.1).
VALIDATION_SANITY = 0.5


def missed_purpose(result: dict) -> tuple[str, str | None]:
    """("completed", None), or ("failed", why) when the identified (SDP) model failed its
    physical checks or its validation error is not finite or above VALIDATION_SANITY."""
    problems = []
    if not result.get("checks", {}).get("sdp"):
        failed = [k for k, v in result.get("checks", {}).get("sdp_detail", {}).items()
                  if isinstance(v, dict) and v.get("pass") is False]
        problems.append("the SDP model fails its physical checks" + (f" ({', '.join(failed)})" if failed else ""))
    errors = result.get("validation", {}).get("sdp") or []
    bad = [f"j{j + 1} {e}" for j, e in enumerate(errors) if e is None or not math.isfinite(e)]
    high = [f"j{j + 1} {e:.3f}" for j, e in enumerate(errors) if e is not None and math.isfinite(e)
            and e > VALIDATION_SANITY]
    if not errors:
        problems.append("no validation error was computed")
    if bad:
        problems.append(f"validation error not finite ({', '.join(bad)})")
    if high:
        problems.append(f"validation relative error {', '.join(high)} above the sanity bound {VALIDATION_SANITY}")
    return ("failed", "; ".join(problems)) if problems else ("completed", None)


def table_5_1(outcome: FitOutcome, excitation: dict | None) -> dict:
    f = outcome.fits
    return {"optimisation_condition": None if excitation is None else excitation.get("condition_objective"),
            "optimisation_condition_full": None if excitation is None else excitation.get("condition_full"),
            "ls_condition": f["ols"].condition, "wls_condition": f["wls"].condition,
            "wls_condition_tau_max": f["wls_tau_max"].condition,
            "ls_residual": f["ols"].residual_norm, "wls_residual": f["wls"].residual_norm,
            "sdp_residual": f["sdp"].residual_norm,
            "note": "residuals are ||tau - W_b beta|| over all samples and joints (mixed N m and N), as Table 5.1"}


# ----------------------------------------------------------------------------- plots
def plot_torques(t, tau, preds: dict, path: Path, title: str) -> None:
    """Figure 5.2/5.3 style: (a) measured vs predicted torque per joint, (b) absolute errors."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(3, 2, figsize=(12, 8), sharex=True)
    units = ("N m", "N m", "N")
    styles = {"ols": ("tab:orange", "--"), "wls": ("tab:green", ":"), "sdp": ("tab:red", "-")}
    for j in range(3):
        ax, ae = axes[j, 0], axes[j, 1]
        ax.plot(t, tau[:, j], color="k", lw=1.2, label="measured")
        for m, p in preds.items():
            c, ls = styles[m]
            ax.plot(t, p[:, j], color=c, ls=ls, lw=1.0, label=m.upper())
            ae.plot(t, np.abs(tau[:, j] - p[:, j]), color=c, ls=ls, lw=0.8, label=m.upper())
        ax.set_ylabel(f"joint {j + 1} [{units[j]}]")
        ae.set_ylabel(f"|error| [{units[j]}]")
    axes[0, 0].legend(loc="upper right", fontsize=8)
    axes[0, 1].legend(loc="upper right", fontsize=8)
    axes[0, 0].set_title("(a) measured vs predicted")
    axes[0, 1].set_title("(b) absolute error")
    for ax in axes[2]:
        ax.set_xlabel("time [s]")
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_trajectory(t, q, dq, path: Path, title: str) -> None:
    """Figure 5.1 style: position and velocity of the three joints."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 1, figsize=(10, 6), sharex=True)
    for j, lab in enumerate(("q1 [rad]", "q2 [rad]", "q3 [m]")):
        axes[0].plot(t, q[:, j], label=lab)
        axes[1].plot(t, dq[:, j], label="d" + lab.replace("]", "/s]"))
    axes[0].legend(fontsize=8)
    axes[1].legend(fontsize=8)
    axes[1].set_xlabel("time [s]")
    axes[0].set_title(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


# ----------------------------------------------------------------------------- excitation
def design_settings(parameters: dict) -> dict:
    """The options the trajectories depend on (calibration.excitation_design.design's settings)."""
    return {"frequency_hz": parameters["frequency"], "harmonics": parameters["harmonics"],
            "duration": parameters["duration"], "starts": parameters["starts"], "iterations": parameters["iterations"],
            "seed": parameters["design_seed"], "velocity_fraction": parameters["velocity_fraction"],
            "validation_frequency_hz": parameters["validation_frequency"], "fill": parameters["fill"]}


def plant_of(cfg, arm_name: str):
    """The simulated twin of `arm_name` at the rig rate (what the margins are measured on):
    the configured parameters, effects, PID, effort limit and sensors, whatever its driver."""
    from calibration.excitation_design import Plant
    from rig.sim.world import world_from_config

    world = world_from_config(cfg, [arm_name], with_object=False, seed=0)
    return Plant(world.arms[arm_name].spec, float(cfg.rig["rate"]), np.asarray(cfg.rig["gravity"], float), 0)


def design_excitation(parameters: dict, gravity: np.ndarray, plant, progress=None, processes: int | None = None) -> dict:
    """The optimised excitation and the validation trajectory for these settings, each kept
    clear of Table 4.2's limits by the margin measured on `plant` (calibration.
    excitation_design), from the user's cache when designed before (see its docstring)."""
    from calibration.excitation_design import design
    from rig.model.psm_kinematics import DQ_MAX, Q_MAX, Q_MIN

    return design(design_settings(parameters), gravity, plant, Q_MIN, Q_MAX, DQ_MAX, progress=progress,
                  processes=processes)


def validation_trajectory(frequency_hz: float, duration: float, harmonics: int, seed: int, fill: float):
    """The validation trajectory before its margin (calibration.excitation_design.validation_trajectory
    at Table 4.2's limits)."""
    from calibration.excitation_design import validation_trajectory as raw
    from rig.model.psm_kinematics import DQ_MAX, Q_MAX, Q_MIN

    return raw(frequency_hz, duration, harmonics, seed, fill, Q_MIN, Q_MAX, DQ_MAX)


#: Close enough to a trajectory's start to begin streaming (rad, rad, m): the first
#: servo_jp set-points then differ from the measured joints by less than the PID's
#: usual tracking error (a loaded joint can rest a few mrad short under the dVRK PID).
START_TOLERANCE = np.array([0.02, 0.02, 0.005])


def reach_start(arm, goal, what: str, say) -> None:
    """move_jp to ``goal``; accept arrival within START_TOLERANCE, else abort the run."""
    if arm.move_jp(goal, wait=True, timeout=20.0):
        return
    q = np.asarray(arm.measured_js().position[:3], float)
    off = np.abs(q - goal)
    if np.all(off <= START_TOLERANCE):
        say(f"start of the {what} trajectory reached within {np.round(off, 4).tolist()} (rad, rad, m)")
        return
    raise AbortRun(f"{arm.name} did not reach the start of the {what} trajectory within 20 s "
                   f"(off by {np.round(off, 4).tolist()} rad, rad, m)")


def stream_trajectory(run, arm, clock, traj, topic_prefix: str, step, limits, margin) -> dict:
    """servo_jp the trajectory (position and velocity feed-forward) at the clock rate,
    recording measured_js; returns arrays and what the arm met.

    Aborts the run (the engine holds the arm) as soon as a measured joint comes within
    ABORT_FRACTION of its margin of a position limit, or faster than its velocity limit
    less that fraction of its velocity margin (calibration.excitation_design): before the
    limit, where the console would fault. The trajectory's time waits while its set-point
    leads the arm by more than the margin's lag (calibration.excitation_design.lagging).
    """
    from calibration.excitation_design import lagging

    rate = clock.rate
    n = int(round(traj.duration * rate)) + 1
    q_cmd, dq_cmd, _ = traj.sample(np.arange(n) / rate)
    low, high, speed = margin.abort_limits(limits.q_min, limits.q_max, limits.dq_max)
    samples = []
    sent, sent_t = [], []
    rec = run.recorder
    every = max(1, n // 100)
    arm.drain_js()  # what arrived before the trajectory starts is not part of it
    ticks_without = waited = 0
    q_last = t_last = None
    silent_after = SILENT * max(1.0 / rate, _stream_period(arm))
    delay = np.inf  # the least (now - stamp) seen: transport plus any offset of the two clocks
    k = 0
    while k < n:
        arm.servo_jp(q_cmd[k], dq_cmd[k])
        sent.append((clock.now(), k))
        sent_t.append(sent[-1][0])
        rec.joint_state(f"/{arm.name}/servo_jp", sent[-1][0], q_cmd[k], dq_cmd[k])
        clock.tick()
        # every sample the arm sent since the last tick: a tick held up by the machine
        # finds several, and the fit still gets the stream whole
        new = arm.drain_js()
        ticks_without += not new
        for js in new:
            samples.append((js.t, js.position[:3], js.velocity[:3], js.effort[:3]))
            rec.joint_state(f"/{arm.name}/measured_js", js.t, js.position, js.velocity, js.effort)
        if new:
            t_last = new[-1].t
            delay = min(delay, clock.now() - t_last)
            q_last, dq = np.asarray(new[-1].position[:3]), np.asarray(new[-1].velocity[:3])
            if np.any(q_last < low) or np.any(q_last > high) or np.any(np.abs(dq) > speed):
                raise AbortRun(f"{arm.name} during the {topic_prefix} trajectory at t = {k / rate:.2f} s: "
                               f"{_abort_reason(q_last, dq, low, high, speed, limits, margin)}; the arm is held")
        # The trajectory's time waits while the arm's newest sample is older than usual (it
        # is silent, or its process fell behind and catches up: over the wire a served arm
        # held off the CPU for 0.5 s applied the commands queued meanwhile at once), or
        # while the set-point in force at that sample's stamp leads it by more than the
        # margin's lag: an arm whose commands stopped arriving then meets, when they
        # resume, a set-point a lag ahead, not one that ran on by the stall times the speed
        # (calibration.excitation_design). The set-point of the sample's own time leaves
        # the transport delay out of the lag.
        then = sent[max(0, bisect.bisect_right(sent_t, t_last) - 1)][1] if t_last is not None else k
        if (t_last is not None and clock.now() - t_last - delay > silent_after) or (
                q_last is not None and lagging(q_last, q_cmd[then], dq_cmd[then], margin.lag)):
            waited += 1
        else:
            k += 1
            if k % every == 0:
                step.update(k)
    step.update(n)
    if not samples:
        raise AbortRun(f"{arm.name}: no measured_js during the {topic_prefix} trajectory")
    T = np.array([s[0] for s in samples])
    Q, DQ, TAU = (np.array([s[i] for s in samples], float) for i in (1, 2, 3))
    sent_k = np.array([x[1] for x in sent])
    met = tracking_met(T, Q, DQ, np.array(sent_t), q_cmd[sent_k], dq_cmd[sent_k], limits)
    met["periods_waited_for_the_arm"] = waited
    # Keep each sample once (time must increase), and put them on a uniform grid of their
    # own stamps (the arm's sample times), which the filtering and the decimation assume:
    # over the wire the samples jitter, and a gap (a publisher held up) is interpolated.
    keep = np.concatenate([[True], np.diff(T) > 0])
    t, q, dq, tau = T[keep], Q[keep], DQ[keep], TAU[keep]
    if len(t) > 1 and not np.allclose(np.diff(t), 1.0 / rate, rtol=1e-3, atol=1e-6):
        grid = t[0] + np.arange(int(np.floor((t[-1] - t[0]) * rate)) + 1) / rate

        def on_grid(x):
            return np.column_stack([np.interp(grid, t, x[:, j]) for j in range(x.shape[1])])

        t, q, dq, tau = grid, on_grid(q), on_grid(dq), on_grid(tau)
    return {"t": t, "q": q, "dq": dq, "tau": tau, "rate": rate, "ticks_without_sample": ticks_without, "met": met}


#: Loop or arm periods (the longer) by which the arm's newest sample may be older than the
#: least delay seen before the trajectory's time waits for the arm (stream_trajectory).
SILENT = 5.0


def _stream_period(arm) -> float:
    """s between the arm's measured_js messages as it publishes them (0 when it does not say)."""
    rate = getattr(arm, "published_rate", None)
    r = rate() if callable(rate) else 0.0
    return 1.0 / r if r > 0 else 0.0


def _abort_reason(q, dq, low, high, speed, limits, margin) -> str:
    for j in range(3):
        u = "m" if j == 2 else "rad"
        if q[j] < low[j] or q[j] > high[j]:
            edge = limits.q_min[j] if q[j] < low[j] else limits.q_max[j]
            return (f"joint {j + 1} at {q[j]:.4f} {u}, {abs(q[j] - edge) * (1e3 if j == 2 else 1):.4g} "
                    f"{'mm' if j == 2 else u} from its limit {edge:g} {u} (the excitation keeps "
                    f"{margin.position[j] * (1e3 if j == 2 else 1):.4g} {'mm' if j == 2 else u}: the arm tracks worse "
                    f"than the {margin.tracking_position[j] * (1e3 if j == 2 else 1):.3g} measured on its simulated plant; "
                    "check its PID gains and load, or lower --velocity-fraction)")
    for j in range(3):
        if abs(dq[j]) > speed[j]:
            u = "m/s" if j == 2 else "rad/s"
            where = ("above" if abs(dq[j]) > limits.dq_max[j] else
                     f"within {limits.dq_max[j] - abs(dq[j]):.3g} {u} of")
            return (f"joint {j + 1} velocity {dq[j]:.3f} {u}, {where} its limit {limits.dq_max[j]:g} {u} "
                    f"(the excitation keeps {margin.velocity[j]:.3g} {u}: the arm tracks "
                    f"worse than measured on its simulated plant; lower --velocity-fraction)")
    return "limit"


def tracking_met(T, Q, DQ, sent, q_cmd, dq_cmd, limits) -> dict:
    """What the arm met during a streamed trajectory, per joint: ``position_tracking`` and
    ``velocity_tracking``, max |q - q_cmd| and |dq - dq_cmd| against the newest set-point
    sent before each sample's stamp (over the wire the two clocks are the same machine's
    or NTP's: a few ms of offset read as dq x offset); ``overshoot`` how far q went beyond
    the commanded range and ``velocity_excess`` max |dq| - max |dq_cmd| (neither depends on
    timing); ``closest_to_position_limit`` (rad, rad, m) and ``peak_velocity_fraction`` of
    Table 4.2's limit."""
    k = np.clip(np.searchsorted(sent, T, side="right") - 1, 0, len(sent) - 1)
    over = np.maximum(q_cmd.min(axis=0) - Q.min(axis=0), Q.max(axis=0) - q_cmd.max(axis=0))
    return {"position_tracking": np.abs(Q - q_cmd[k]).max(axis=0).tolist(),
            "velocity_tracking": np.abs(DQ - dq_cmd[k]).max(axis=0).tolist(),
            "overshoot": over.tolist(),
            "velocity_excess": (np.abs(DQ).max(axis=0) - np.abs(dq_cmd).max(axis=0)).tolist(),
            "closest_to_position_limit": np.minimum(Q.min(axis=0) - limits.q_min, limits.q_max - Q.max(axis=0)).tolist(),
            "peak_velocity_fraction": (np.abs(DQ).max(axis=0) / limits.dq_max).tolist()}


def block_mean(rec: dict, target_rate: float, source: str):
    """JointData at ~``target_rate`` Hz by averaging blocks of samples (an anti-alias filter
    for the decimation that keeps the thesis' 200 Hz identification rate)."""
    from calibration.datasets import JointData

    factor = max(1, int(round(rec["rate"] / target_rate)))
    n = (len(rec["t"]) // factor) * factor

    def avg(x):
        return x[:n].reshape(-1, factor, *x.shape[1:]).mean(axis=1)

    return JointData.from_arrays(avg(rec["q"]), avg(rec["dq"]), avg(rec["tau"]), rate=rec["rate"] / factor,
                                 t=avg(rec["t"]), source=source)


# ----------------------------------------------------------------------------- procedure
def _sayer(progress: bool):
    """A progress-detail printer (stderr, indented under the step lines)."""
    return (lambda text: click.echo(f"    {text}", err=True)) if progress else (lambda text: None)


def _fmt3(v, digits=4) -> str:
    return " / ".join(f"{x:.{digits}f}" for x in v)


def report_text(result: dict) -> str:
    lines = [f"identify: {result.get('status', '')}"]
    v = result.get("validation", {})
    rms = result.get("validation_rms", {})
    if v:
        lines.append(f"validation on {result.get('validation_source', '?')} (a trajectory of this run left out "
                     "of the fit; for a motion the model never saw, `rig validate` another recording)")
        lines.append("  method  rel. error j1 / j2 / j3        RMS j1 [N m] / j2 [N m] / j3 [N]")
        for m in ("ols", "wls", "sdp"):
            lines.append(f"  {m.upper():6s}  {_fmt3(v[m]):28s}  {_fmt3(rms.get(m, [np.nan] * 3))}")
        mv = result.get("validation_moving", {}).get("sdp")
        if mv:
            lines.append(f"  SDP on moving samples only (|dq| above the 7.5.1 deadband): {_fmt3(mv)}")
        mu = result.get("validation_moving_unfiltered", {}).get("sdp")
        if mu and result.get("parallel_filter"):
            lines.append(f"  the same with the model's efforts not low-passed like the torques: {_fmt3(mu)}")
        if result.get("source") == "csv":
            lines.append(f"  published 7-DOF (SDP, unseen trajectory): {_fmt3(PUBLISHED_7DOF, 3)} "
                         "(not like for like: other trajectory, other model)")
    g = result.get("gravity")
    if g:
        lines.append(f"gravity in frame 0: {np.round(g['vector'], 3).tolist()} m/s^2 ({g['source']}"
                     + (f", {g['tilt_deg']:.1f} deg from {np.round(g['reference'], 3).tolist()}" if 'tilt_deg' in g else "")
                     + ")")
    if "friction_slope" in result:
        lines.append(f"Coulomb sigmoid slope: {result['friction_slope']:g} s/rad")
    st = result.get("stribeck")
    if st:
        lines.append(f"joint 3 Stribeck excess of the smooth-sign law: Fst {st['Fst'][2]:.3f} N, vs "
                     f"{st['vs'][2] * 1e3:g} mm/s (it includes the sigmoid's shortfall below 1 at low speed; the "
                     "dry-friction breakaway level is what rig friction-ramp measures)")
    for e in result.get("effects_identified") or []:
        lines.append(f"effect {e['name']}@{e['joint']} identified with the rigid body: "
                     + ", ".join(f"{k} {v:.4g}" for k, v in e["params"].items() if isinstance(v, (int, float))))
    for line in result.get("effects_left_out") or []:
        lines.append(f"--effects-from: {line}: left out")
    t = result.get("table_5_1")
    if t:
        oc = t.get("optimisation_condition")
        lines.append("Table 5.1: " + (f"optimisation cond {oc:.1f}, " if oc else "")
                     + f"LS cond {t['ls_condition']:.1f}, WLS cond {t['wls_condition']:.1f} "
                     f"(1/tau_max: {t['wls_condition_tau_max']:.1f}), residuals LS {t['ls_residual']:.2f} / "
                     f"WLS {t['wls_residual']:.2f} / SDP {t['sdp_residual']:.2f}")
    c = result.get("checks", {}).get("sdp")
    if c is not None:
        lines.append(f"SDP physical checks: {'all pass' if c else 'FAILED'}")
    if result.get("truth"):
        tr = result["truth"]
        lines.append(f"simulated rig truth: SDP model vs true-parameter torques on the validation data, "
                     f"rel. error {_fmt3(tr['sdp_vs_true_relative_error'])}")
    if result.get("model"):
        lines.append(f"model file: {result['model']}")
    if result.get("run_dir"):
        lines.append(f"run folder: {result['run_dir']}")
    return "\n".join(lines)


def _finish_fit(run, outcome: FitOutcome, train, val, val_source: str, source: str, data_source: str,
                parameters: dict, excitation: dict | None, reference_gravity, origin: dict,
                extra: dict | None = None, stick_slip=None) -> dict:
    """Validation, plots, model file and the result document (common to both paths);
    `origin`: the model's provenance (rig.runs.provenance.live or .recording); `stick_slip`: an
    earlier friction-ramp run's terms of the same arm, carried into the model file."""
    from rig.model import model_file
    from rig.runs import model_results

    table = validation_table(outcome, val)
    train_table = validation_table(outcome, train)
    sdp = outcome.fits["sdp"]
    plots = {}
    if parameters["plots"]:
        for name, data, title in (("figure_5_2_training.png", train, "Training trajectory (Figure 5.2 style)"),
                                  ("figure_5_3_validation.png", val, f"Validation: {val_source} (Figure 5.3 style)")):
            preds = {m: predict(outcome, data, m) for m in ("ols", "wls", "sdp")}
            plot_torques(data.t - data.t[0], data.tau, preds, run.dir / name, title)
            plots[name] = str(run.dir / name)
    gravity = {"vector": outcome.gravity.tolist(), "source": outcome.gravity_source}
    if "gravity_tilt_deg" in outcome.selection:
        gravity.update(tilt_deg=outcome.selection["gravity_tilt_deg"],
                       reference=np.asarray(reference_gravity, float).tolist())
    validation_doc = {"source": val_source, "relative_error": {m: table[m]["relative_error"] for m in table},
                      "moving_relative_error": {m: table[m]["moving_relative_error"] for m in table},
                      "moving_relative_error_unfiltered": {m: table[m]["moving_relative_error_unfiltered"]
                                                           for m in table},
                      "parallel_filter": outcome.parallel,
                      "rms": {m: table[m]["rms"] for m in table},
                      "training_relative_error": {m: train_table[m]["relative_error"] for m in train_table}}
    checks = {m: f.checks for m, f in outcome.fits.items() if m in ("ols", "wls", "sdp")}
    profile = outcome.position_friction_effect()
    identified = outcome.effect_entries(f"identified with the rigid body (rig identify --effects-from "
                                        f"{parameters.get('effects_from')})")
    effects_doc = None
    if profile is not None or identified:
        from calibration.effects import describe

        effects_doc = {"effects": ([profile] if profile is not None else []) + identified,
                       "effects_catalogue": describe()["version"]}
    path = model_file.save_model(
        run.dir / model_file.MODEL_FILENAME, standard=sdp.pi, names=list(outcome.model.param_names()),
        slope=outcome.slope, gravity=outcome.gravity, base_values=sdp.beta, stribeck=outcome.stribeck(),
        base_expressions=outcome.base.expressions(), base_independent=outcome.base.independent,
        gravity_source=outcome.gravity_source, validation=validation_doc, checks=checks["sdp"], stick_slip=stick_slip,
        provenance_info={**model_results.provenance(data_source, run.dir, {"procedure": PROCEDURE,
                                                                         "training_samples": int(train.n_samples),
                                                                         "validation_samples": int(val.n_samples)}),
                         **origin},
        extra=effects_doc)
    result = {
        "source": source,
        "model": str(path),
        "validation": {m: table[m]["relative_error"] for m in table},
        "validation_rms": {m: table[m]["rms"] for m in table},
        "validation_moving": {m: table[m]["moving_relative_error"] for m in table},
        "validation_moving_unfiltered": {m: table[m]["moving_relative_error_unfiltered"] for m in table},
        "parallel_filter": outcome.parallel,
        "stribeck": None if outcome.stribeck() is None else {k: v.tolist() for k, v in outcome.stribeck().items()},
        "validation_source": val_source,
        "fit_deadband": outcome.selection.get("deadband"),
        "training": {m: train_table[m]["relative_error"] for m in train_table},
        "gravity": gravity,
        "friction_slope": outcome.slope,
        "selection": outcome.selection,
        "table_5_1": table_5_1(outcome, excitation),
        "checks": {"sdp": bool(sdp.checks.get("all_pass")), "ols_realizable": bool(outcome.fits["ols"].checks["all_pass"]),
                   "wls_realizable": bool(outcome.fits["wls"].checks["all_pass"]), "sdp_detail": sdp.checks},
        "sdp_solver": {k: v for k, v in sdp.info.items() if isinstance(v, (int, float, str))},
        "base_parameters": {"count": outcome.base.n_base, "expressions": outcome.base.expressions(digits=4),
                            "values": sdp.beta.tolist()},
        "plots": plots,
        "fit_seconds": outcome.seconds,
        "samples": {"training": int(train.n_samples), "validation": int(val.n_samples)},
        "summary": {"validation_sdp": table["sdp"]["relative_error"], "validation_ols": table["ols"]["relative_error"],
                    "model": str(path)},
        "provenance": origin,
    }
    if profile is not None:
        result["position_friction"] = profile
    if identified:
        result["effects_identified"] = identified
    if source == "csv":
        result["published_7dof"] = {"sdp": list(PUBLISHED_7DOF),
                                    "note": "WPI package, 7-DOF model, a different unseen test trajectory of the "
                                            "same robot: not like for like with a held-out block of one file"}
    if extra:
        result.update(extra)
    return result


#: s: the shortest training or validation block accepted. A few periods of the excitation's
#: fundamental (0.1-0.5 Hz on the dVRK) are what a good fit wants; this is the floor under
#: which there is no fit at all: at 200 Hz 100 rows, 300 equations for some 40 base
#: parameters, and the 3.5 Hz filter's output is still correlated over tens of rows.
MIN_BLOCK_SECONDS = 0.5


def _enough_rows(data, parameters: dict, held_out: bool) -> None:
    """Raise a DataError saying how many rows are needed when `data` is too short to
    filter (its ends are trimmed) and split into training and held-out blocks."""
    from calibration.datasets import DataError
    from calibration.signals import settling_samples

    rate = parameters["rate"]
    trim = settling_samples(rate, parameters["cutoff"], parameters["filter_order"])
    block = int(math.ceil(MIN_BLOCK_SECONDS * rate))
    if held_out:
        h = parameters["heldout"]
        need = 2 * trim + int(math.ceil(max(block / h, (block + trim) / (1.0 - h))))
        why = (f"{trim} at each end for the {parameters['cutoff']:g} Hz filter to settle, a {trim}-row guard, and "
               f"{block} rows ({MIN_BLOCK_SECONDS:g} s) in each of the training and held-out "
               f"({h * 100:.0f} %) blocks")
    else:
        need = 2 * trim + block
        why = (f"{trim} at each end for the {parameters['cutoff']:g} Hz filter to settle and {block} rows "
               f"({MIN_BLOCK_SECONDS:g} s) to use")
    n = data.n_samples
    if n < need:
        raise DataError(f"{data.source}: {n} rows ({n / rate:.1f} s at {rate:g} Hz) are too few: identification "
                        f"needs at least {need} ({need / rate:.1f} s): {why}")


def run_offline(parameters: dict, run_root=None, progress: bool = True) -> dict:
    """`rig identify --csv`: identification of recorded data. Returns the result."""
    from calibration.blas_threads import blas_threads
    from calibration.datasets import load_csv, processed, split_blocks
    from calibration.signals import settling_samples

    gmode = parse_gravity(parameters["gravity"] or "auto")
    terms, left_out = effects_from(parameters)
    if isinstance(gmode, str) and gmode == "config":
        # Recorded data belong to no configured arm: 'config' means the model's own frame-0
        # gravity (z0 up), as for an untilted PSM.
        gmode = np.array([0.0, 0.0, -9.81])
    smode = parse_slope(parameters["friction_slope"])
    with Run(PROCEDURE, parameters=parameters, config=None, steps=list(STEPS_CSV), root=run_root,
             progress=progress) as run:
        say = _sayer(progress)
        with run.step(STEPS_CSV[0]):
            loader = load_timed_csv if parameters["time_column"] else load_csv
            raw = loader(parameters["csv"], parameters["rate"], parameters["joints"])
            raw_val = (loader(parameters["validate_csv"], parameters["rate"], parameters["joints"])
                       if parameters["validate_csv"] else None)
            _enough_rows(raw, parameters, held_out=raw_val is None)
            if raw_val is not None:
                _enough_rows(raw_val, parameters, held_out=False)
        with run.step(STEPS_CSV[1]):
            proc = processed(raw, parameters["cutoff"], parameters["filter_order"])
            if raw_val is not None:
                train = proc
                val = processed(raw_val, parameters["cutoff"], parameters["filter_order"])
                val_source = f"{parameters['validate_csv']} (second file)"
            else:
                # The filter is run over the whole file, then a guard of one filter settling
                # length is dropped between the blocks, so no filtered training sample is
                # built from held-out measurements or the reverse (beyond the filter's tail).
                train_all, val = split_blocks(proc, parameters["heldout"])
                guard = min(settling_samples(parameters["rate"], parameters["cutoff"], parameters["filter_order"]),
                            train_all.n_samples // 4)
                train = train_all.rows(slice(0, train_all.n_samples - guard), f"minus a {guard}-sample guard")
                val_source = (f"held-out last {parameters['heldout'] * 100:.0f} % of {parameters['csv']} "
                              f"({val.n_samples} samples, guard {guard})")
        with run.step(STEPS_CSV[2]), blas_threads(1):  # small matrices: one BLAS thread
            outcome, more = _fit(train, gmode, smode, None, parameters, terms, say)
            left_out = left_out + more
        with run.step(STEPS_CSV[3]):
            result = _finish_fit(run, outcome, train, val, val_source, "csv", str(parameters["csv"]), parameters,
                                 None, np.array([0.0, 0.0, -9.81]), provenance.recording(parameters["csv"]),
                                 extra={"effects_left_out": left_out} if left_out else None)
            run.finish(result, *missed_purpose(result))
    return run.result


def run_live(cfg, parameters: dict, run_root=None, progress: bool = True) -> dict:
    """`rig identify` on the rig (or the simulated rig). Returns the result."""
    from calibration.datasets import processed
    from calibration.blas_threads import blas_threads
    from calibration.excitation_design import check
    from rig.devices.factory import open_rig
    from rig.model.psm_kinematics import JointLimits

    arm_name = parameters["arm"]
    if arm_name not in cfg.arms:
        raise InputError(f"no arm {arm_name!r} in {cfg.source}; arms: {', '.join(cfg.arms)}")
    g_config = cfg.gravity_in_base(arm_name)
    gmode = parse_gravity(parameters["gravity"] or "config")
    terms, left_out = effects_from(parameters)
    if isinstance(gmode, str) and gmode == "config":
        gmode = g_config
    smode = parse_slope(parameters["friction_slope"])
    seed = None if parameters["seed"] < 0 else parameters["seed"]
    limits = JointLimits()
    dev = None
    try:
        with Run(PROCEDURE, parameters=parameters, config=cfg.snapshot(), seed=seed, steps=list(STEPS_LIVE),
                 root=run_root, progress=progress) as run:
            say = _sayer(progress)
            # The design is computed before the devices are opened: it takes seconds of CPU
            # that a connected driver would otherwise have to share.
            with run.step(STEPS_LIVE[0], total=parameters["starts"]) as st:
                design = design_excitation(parameters, g_config, plant_of(cfg, arm_name),
                                           progress=lambda k, n, c: (st.update(k), say(f"start {k}/{n}: cond {c:.1f}")))
                say((f"found the design in the cache ({design['lookup_seconds']:.3f} s): " if design["cached"] else
                     f"designed in {design['figures']['design_seconds']:.1f} s and cached: ") + design["path"])
                traj, vtraj = design["excitation"], design["validation"]
                margin, vmargin = design["margin"], design["validation_margin"]
                say("margins kept from the limits, measured on the arm's simulated plant at "
                    f"{margin.rate:g} Hz ({margin.safety:g} x its tracking, the {margin.stall:g} s stall test, the "
                    f"sensors): position {_fmt3(margin.position)} rad, rad, m; velocity {_fmt3(margin.velocity)} "
                    "rad/s, rad/s, m/s")
                st.update(parameters["starts"])
                for tr, m, what in ((traj, margin, "excitation"), (vtraj, vmargin, "validation")):
                    problem = check(tr, m, limits.q_min, limits.q_max, limits.dq_max, cfg.rig["rate"], what)
                    if problem:
                        raise AbortRun(problem)
            dev = open_rig(cfg, [arm_name], seed=seed, uses=())
            clock = dev.clock
            # one arm moves alone: nothing may tie it to another (the object is taken off)
            dev.operator.detach_object()
            if abs(clock.rate - cfg.rig["rate"]) > 1e-6 * clock.rate:
                raise AbortRun(f"the rig runs at {clock.rate:g} Hz, the margins were measured at {cfg.rig['rate']:g} Hz")
            arm = run.claim(dev.arms[arm_name])
            with run.step(STEPS_LIVE[1]):
                power = getattr(arm, "power_on", None)
                if power is not None:
                    power()
                reach_start(arm, traj.sample([0.0])[0][0], "excitation", say)
            n = int(round(parameters["duration"] * clock.rate)) + 1
            with run.step(STEPS_LIVE[2], total=n) as st:
                rec_x = stream_trajectory(run, arm, clock, traj, "excitation", st, limits, margin)
            with run.step(STEPS_LIVE[3], total=n) as st:
                reach_start(arm, vtraj.sample([0.0])[0][0], "validation", say)
                rec_v = stream_trajectory(run, arm, clock, vtraj, "validation", st, limits, vmargin)
            arm.hold()
            with run.step(STEPS_LIVE[4]):
                train = processed(block_mean(rec_x, parameters["sample_rate"], f"{run.dir / 'run.mcap'} excitation"),
                                  parameters["cutoff"], parameters["filter_order"])
                val = processed(block_mean(rec_v, parameters["sample_rate"], f"{run.dir / 'run.mcap'} validation"),
                                parameters["cutoff"], parameters["filter_order"])
            with run.step(STEPS_LIVE[5]), blas_threads(1):  # small matrices: one BLAS thread
                outcome, more = _fit(train, gmode, smode, g_config, parameters, terms, say)
                left_out = left_out + more
            with run.step(STEPS_LIVE[6]):
                figures = {k: v for k, v in design["figures"].items() if k != "starts"}
                extra = {**({"effects_left_out": left_out} if left_out else {}), "arm": arm_name,
                         "excitation": {"cached": design["cached"], "cache_file": design["path"],
                                        "lookup_seconds": design["lookup_seconds"], "trajectory": traj.to_dict(),
                                        "margin": margin.to_dict(), "met": rec_x["met"], **figures},
                         "validation_trajectory": vtraj.to_dict(), "validation_margin": vmargin.to_dict(),
                         "validation_met": rec_v["met"], "rig_rate": clock.rate,
                         "ticks_without_sample": {"excitation": rec_x["ticks_without_sample"],
                                                  "validation": rec_v["ticks_without_sample"]}}
                if parameters["plots"]:
                    plot_trajectory(rec_x["t"] - rec_x["t"][0], rec_x["q"], rec_x["dq"], run.dir / "figure_5_1_excitation.png",
                                    f"Excitation trajectory as measured ({parameters['frequency']} Hz, "
                                    f"{parameters['harmonics']} harmonics)")
                stick, ramp_note = earlier_stick_slip(cfg, arm_name)
                if ramp_note:
                    say(ramp_note)
                    extra["stick_slip_from"] = ramp_note
                result = _finish_fit(run, outcome, train, val, "validation trajectory "
                                     f"({parameters['validation_frequency']} Hz, not optimised)", "live",
                                     f"{run.dir / 'run.mcap'} ({arm_name})", parameters, design["figures"], g_config,
                                     provenance.live(cfg, [arm_name], run.dir), extra, stick_slip=stick)
                if parameters["plots"]:
                    result["plots"]["figure_5_1_excitation.png"] = str(run.dir / "figure_5_1_excitation.png")
                world = getattr(dev, "world", None)
                if world is not None:
                    result["truth"] = simulated_truth(world, arm_name, outcome, val)
                run.finish(result, *missed_purpose(result))
    finally:
        if dev is not None:  # after the run's exit has held the arm
            dev.close()
    return run.result


def earlier_stick_slip(cfg, arm_name: str):
    """(StickSlip or None, note): the newest completed `rig friction-ramp` result of this
    arm on this rig, so that the model file holds it whichever of the two ran first."""
    from rig.model import model_file
    from rig.runs import model_results

    found = provenance.find("friction-ramp", cfg, arm=arm_name,
                            usable=lambda run, res: "stick_slip" in res
                            or (run / model_file.STICK_SLIP_FILENAME).exists())
    notes = list(found.skipped)
    if found.run_dir is None:
        return None, "; ".join(notes)
    stick = model_results.ramp_stick_slip(found.run_dir, found.data)
    notes.append(f"stick-slip terms of joint 3 taken from friction-ramp run {found.run_dir.name}")
    return stick, "; ".join(notes)


def simulated_truth(world, arm_name: str, outcome: FitOutcome, val) -> dict:
    """On the simulated rig: the SDP model's efforts against the true parameters' for the
    same (filtered) validation motion, neither low-passed again.

    The truth is the rigid body with the simulator's sliding friction: eq. 4.16 plus the
    Stribeck excess (stiction - Fc) exp(-(dq/vs)^2) of the configured stiction, with the
    sigmoid of the nominal slope in place of the simulator's exact sign
    (``sdp_vs_true_relative_error``); ``sdp_vs_nominal_law_relative_error`` leaves the
    excess out (the reference before the Stribeck term was identified). The other hidden
    effects are not in either.
    """
    from dataclasses import replace

    from calibration.estimators import validation_errors
    from rig.model.psm_dynamics import PSMDynamics

    a = world.arms[arm_name]
    eff = a.spec.effects
    excess = np.maximum(np.asarray(eff.stiction, float) - a.params.drive.Fc, 0.0)
    sliding = replace(a.params, drive=replace(a.params.drive, Fst=excess,
                                              vs=np.asarray(eff.stribeck_velocity, float)))
    pred = predict(outcome, val, "sdp", parallel=False)
    out = {}
    for key, params in (("sdp_vs_true", sliding), ("sdp_vs_nominal_law", a.params)):
        true = PSMDynamics(params, gravity=outcome.gravity)
        tau_true = np.array([true.inverse_dynamics(q, dq, ddq) for q, dq, ddq in zip(val.q, val.dq, val.ddq)])
        e = validation_errors(tau_true, pred)
        out[f"{key}_relative_error"] = e["relative_error"].tolist()
        out[f"{key}_rms"] = e["rms"].tolist()
    out["hidden_effects"] = {"stiction": np.asarray(eff.stiction).tolist(),
                             "stribeck_velocity": np.asarray(eff.stribeck_velocity).tolist()}
    st = outcome.stribeck()
    if st is not None:
        out["stribeck"] = {"identified_Fst": st["Fst"].tolist(), "identified_vs": st["vs"].tolist(),
                           "true_Fst": excess.tolist()}
    return out


def _data_errors():
    from calibration.base_params import RankDeficientError
    from calibration.datasets import DataError
    from calibration.signals import SignalError

    return (DataError, SignalError, RankDeficientError)


@click.command(name=PROCEDURE)
@with_parameters(PARAMETERS)
@click.option("--steps", "list_steps", is_flag=True, help="List the steps and exit without moving anything.")
@yes_option
@json_option
@click.pass_context
@exit_on_abort
def command(ctx, parameters, list_steps: bool, as_json: bool) -> None:
    """Dynamic identification of PSM joints 1-3 (thesis 5.1-5.5), live or from a CSV.

    Live: designs (or reuses, from ~/.cache/dvrk-rig or $RIG_CACHE) the optimal
    excitation, kept a measured margin from every joint limit, streams it and a
    validation trajectory with servo_jp, and fits OLS, WLS and a physically consistent SDP.
    Offline: --csv FILE in the WPI format. Writes model.json (found by later runs),
    result.json and Figure 5.2/5.3-style PNGs to the run folder. SI units.
    """
    offline = bool(parameters["csv"])
    if list_steps:
        for i, s in enumerate(STEPS_CSV if offline else STEPS_LIVE, 1):
            click.echo(f"{i}. {s}")
        return
    if parameters["validate_csv"] and not offline:
        raise click.UsageError("--validate-csv needs --csv")
    errors = _data_errors()
    try:
        if offline:
            result = run_offline(parameters, progress=True)
        else:
            result = run_live(config_from_context(ctx), parameters)
    except errors as exc:
        where = f" (run folder {exc.run_dir})" if getattr(exc, "run_dir", None) else ""
        click.echo(f"rig {PROCEDURE}: {exc}{where}", err=True)
        sys.exit(1)
    emit_result(result, as_json, report_text(result))
    exit_for_status(PROCEDURE, result)
