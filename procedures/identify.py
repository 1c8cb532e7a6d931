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

import math
import sys

import click
import numpy as np

from calibration.datasets import load_timed_csv
from calibration.identification import (CUTOFF_HZ, DEADBAND, FILTER_ORDER, FitOutcome, fit_identification,
                                        fit_with_effects)
from calibration.identification_validation import predict, validation_table
from procedures.identify_options import effects_from, parse_gravity, parse_position_friction, parse_slope
from procedures.identify_figures import torques_figure, trajectory_figure
from procedures.identify_report import PUBLISHED_7DOF, fmt3, missed_purpose, report, table_5_1
from procedures.identify_trajectories import design_excitation, plant_of, reach_start, stream_trajectory
from rig.commands.exit_codes import InputError
from rig.commands.options import config_from_context
from rig.commands.parameters import Parameter
from rig.commands.procedure import procedure_command
from rig.commands.report import emit_result, exit_for_status
from rig.runs import provenance
from rig.runs.run import AbortRun, Run

PROCEDURE = "identify"

STEPS_LIVE = ("design the excitation trajectory", "move to the start", "run the excitation trajectory",
              "run the validation trajectory", "process the recordings", "fit OLS, WLS and SDP",
              "validate, plot and save the model")
STEPS_CSV = ("load the CSV data", "process the recordings", "fit OLS, WLS and SDP",
             "validate, plot and save the model")


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


def _fit(train, gmode, smode, configured_gravity, parameters: dict, terms, say):
    """The identification at the command's options, with --effects-from's effects (those the
    fit can take): the FitOutcome and a line per effect left out."""
    return fit_with_effects(train, terms, lambda ts: fit_identification(
        train, gmode, smode, configured_gravity=configured_gravity, progress=say,
        deadband=DEADBAND if parameters["fit_deadband"] else None, parallel=parameters["parallel_filter"],
        stribeck=parameters["stribeck"], position_friction=parse_position_friction(parameters["position_friction"]),
        effects=ts), parameters["parallel_filter"])


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
    plots = _torque_plots(run, outcome, train, val, val_source) if parameters["plots"] else {}
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
    return _with_notes(result, source, extra)


def _torque_plots(run, outcome, train, val, val_source: str) -> dict:
    """Figures 5.2 and 5.3: measured and predicted torques on training and validation."""
    plots = {}
    for name, data, title in (("figure_5_2_training.png", train, "Training trajectory (Figure 5.2 style)"),
                              ("figure_5_3_validation.png", val, f"Validation: {val_source} (Figure 5.3 style)")):
        preds = {m: predict(outcome, data, m) for m in ("ols", "wls", "sdp")}
        torques_figure(data.t - data.t[0], data.tau, preds, run.dir / name, title)
        plots[name] = str(run.dir / name)
    return plots


def _with_notes(result: dict, source: str, extra: dict | None) -> dict:
    """The published figures a CSV fit is compared with, and what the caller adds."""
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


def run(cfg, parameters: dict, run_root=None, progress: bool = True) -> dict:
    """`rig identify` on the rig (or the simulated rig). Returns the result."""
    from calibration.datasets import processed
    from calibration.blas_threads import blas_threads
    from rig.devices.factory import check_crtk_messages, open_rig
    from rig.model.psm_kinematics import JointLimits

    arm_name = parameters["arm"]
    if arm_name not in cfg.arms:
        raise InputError(f"no arm {arm_name!r} in {cfg.source}; arms: {', '.join(cfg.arms)}")
    check_crtk_messages(cfg, [arm_name])  # before minutes of design, not after
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
                design = _design(cfg, arm_name, parameters, g_config, limits, st, say)
                traj, vtraj = design["excitation"], design["validation"]
                margin, vmargin = design["margin"], design["validation_margin"]
            dev = open_rig(cfg, [arm_name], seed=seed, uses=())
            clock = dev.clock
            # one arm moves alone: nothing may tie it to another (the object is taken off)
            dev.operator.detach_object()
            if abs(clock.rate - cfg.rig["rate"]) > 1e-6 * clock.rate:
                raise AbortRun(f"the rig runs at {clock.rate:g} Hz, the margins were measured at {cfg.rig['rate']:g} Hz")
            arm = run.claim(dev.arms[arm_name])
            with run.step(STEPS_LIVE[1]):
                arm.power_on()
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
                extra = _live_extra(design, rec_x, rec_v, left_out, arm_name, clock.rate)
                if parameters["plots"]:
                    trajectory_figure(rec_x["t"] - rec_x["t"][0], rec_x["q"], rec_x["dq"], run.dir / "figure_5_1_excitation.png",
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
                if dev.world is not None:
                    result["truth"] = simulated_truth(dev.world, arm_name, outcome, val)
                run.finish(result, *missed_purpose(result))
    finally:
        if dev is not None:  # after the run's exit has held the arm
            dev.close()
    return run.result


def _design(cfg, arm_name: str, parameters: dict, g_config, limits, st, say) -> dict:
    """The excitation and validation trajectories with their margins, designed (or found in
    the cache) and checked against every limit. The design is computed before the devices
    are opened: it takes seconds of CPU that a connected driver would otherwise have to share."""
    from calibration.excitation_design import check

    design = design_excitation(parameters, g_config, plant_of(cfg, arm_name),
                               progress=lambda k, n, c: (st.update(k), say(f"start {k}/{n}: cond {c:.1f}")))
    say((f"found the design in the cache ({design['lookup_seconds']:.3f} s): " if design["cached"] else
         f"designed in {design['figures']['design_seconds']:.1f} s and cached: ") + design["path"])
    traj, vtraj = design["excitation"], design["validation"]
    margin, vmargin = design["margin"], design["validation_margin"]
    say("margins kept from the limits, measured on the arm's simulated plant at "
        f"{margin.rate:g} Hz ({margin.safety:g} x its tracking, the {margin.stall:g} s stall test, the "
        f"sensors): position {fmt3(margin.position)} rad, rad, m; velocity {fmt3(margin.velocity)} "
        "rad/s, rad/s, m/s")
    st.update(parameters["starts"])
    for tr, m, what in ((traj, margin, "excitation"), (vtraj, vmargin, "validation")):
        problem = check(tr, m, limits.q_min, limits.q_max, limits.dq_max, cfg.rig["rate"], what)
        if problem:
            raise AbortRun(problem)
    return design


def _live_extra(design: dict, rec_x: dict, rec_v: dict, left_out: list, arm_name: str, rate: float) -> dict:
    """What a live identification adds to its result: the trajectories, their margins and
    what the arm met."""
    traj, vtraj = design["excitation"], design["validation"]
    margin, vmargin = design["margin"], design["validation_margin"]
    figures = {k: v for k, v in design["figures"].items() if k != "starts"}
    extra = {**({"effects_left_out": left_out} if left_out else {}), "arm": arm_name,
             "excitation": {"cached": design["cached"], "cache_file": design["path"],
                            "lookup_seconds": design["lookup_seconds"], "trajectory": traj.to_dict(),
                            "margin": margin.to_dict(), "met": rec_x["met"], **figures},
             "validation_trajectory": vtraj.to_dict(), "validation_margin": vmargin.to_dict(),
             "validation_met": rec_v["met"], "rig_rate": rate,
             "ticks_without_sample": {"excitation": rec_x["ticks_without_sample"],
                                      "validation": rec_v["ticks_without_sample"]}}
    return extra


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


@procedure_command(PROCEDURE, lambda kwargs: STEPS_CSV if kwargs["parameters"]["csv"] else STEPS_LIVE, PARAMETERS)
def command(ctx, parameters, as_json: bool) -> None:
    """Dynamic identification of PSM joints 1-3 (thesis 5.1-5.5), live or from a CSV.

    Live: designs (or reuses, from ~/.cache/dvrk-rig or $RIG_CACHE) the optimal
    excitation, kept a measured margin from every joint limit, streams it and a
    validation trajectory with servo_jp, and fits OLS, WLS and a physically consistent SDP.
    Offline: --csv FILE in the WPI format. Writes model.json (found by later runs),
    result.json and Figure 5.2/5.3-style PNGs to the run folder. SI units.
    """
    offline = bool(parameters["csv"])
    if parameters["validate_csv"] and not offline:
        raise click.UsageError("--validate-csv needs --csv")
    errors = _data_errors()
    try:
        if offline:
            result = run_offline(parameters, progress=True)
        else:
            result = run(config_from_context(ctx), parameters)
    except errors as exc:
        where = f" (run folder {exc.run_dir})" if getattr(exc, "run_dir", None) else ""
        click.echo(f"rig {PROCEDURE}: {exc}{where}", err=True)
        sys.exit(1)
    emit_result(result, as_json, report(result))
    exit_for_status(PROCEDURE, result)
