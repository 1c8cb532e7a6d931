"""`rig cooperative`: hold a tension on an object between two or three PSMs while it moves.

Steps (thesis 6.3, 7.7): power and home the arms; attach the object (a person on the real
rig; the simulation on the simulated one); check the plan against every limit; hold the
tension while the master moves (and rotates) the object; report.

The master PSM follows its Cartesian trajectory under the dVRK's position control
(servo_jp); each slave holds the object with the impedance of `rig.control.cooperative_controller`, and its
target moves to track the tension. Where the arms run a Cartesian impedance themselves
(the dVRK's servo_ci, over ROS) the arm closes the spring and damper in its servo loop and
this loop only moves the goal and its feedforward, at the rate the arms publish;
elsewhere (the in-process simulated rig, `--slave-control effort`) this loop closes the
impedance and commands efforts (servo_jf) at the rig rate. Every stream is recorded. Safety limits (tension ceiling,
joint, velocity and effort limits, workspace box, stale streams) abort the run, which
holds every arm it moved.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import click
import numpy as np

from procedures import cooperative_figures as figures
from procedures.cooperative_estimate import estimate_figures as _estimate_figures
from procedures.cooperative_estimate import stamps as _stamps
from procedures.cooperative_estimate import tension_source_for
from procedures.cooperative_live import KEY_STEP_M, KEY_STEP_N, KEY_STEP_RAD, SLEW_M, SLEW_N, SLEW_RAD, LiveCommands
from procedures.cooperative_loop import ServoCI, TensionHold, plot_hint
from procedures.cooperative_report import (filter_delays, force_error_figures, force_hold_figures, loop_timing,
                                           missed_bound, report, slave_control_text)
from rig.commands.exit_codes import InputError
from rig.commands.options import config_from_context
from rig.commands.parameters import Parameter
from rig.commands.procedure import procedure_command
from rig.commands.report import emit_result, exit_for_status
from rig.control.arm_loop_rates import arm_loop_min_rate
from rig.runs import provenance
from rig.runs.control_loop import ControlLoop
from rig.runs.run import AbortRun, Run

STEPS = ["power and home the arms", "attach the object", "check the plan",
         "hold the tension while moving", "report"]

PARAMETERS = [
    Parameter("force", 5.0, "N", "Tension to hold on the object", minimum=0.0, maximum=12.0),
    Parameter("duration", 5.0, "s", "Duration of the master's motion", minimum=0.1, maximum=120.0),
    Parameter("settle", 2.0, "s", "Time to reach the tension before the motion starts", minimum=0.5, maximum=30.0),
    Parameter("hold_after", 2.0, "s", "Time to keep holding after the motion", minimum=0.0, maximum=60.0),
    Parameter("deadband", 0.4, "N", "Force deadband of the position-based mode (7.7.3)", minimum=0.0, maximum=5.0),
    Parameter("tension_ceiling", 15.0, "N", "Abort above this tension", minimum=0.5, maximum=15.0),
    Parameter("tolerance", 0.5, "N", "Success: the tension settles and stays within this of the set-point while "
              "moving (the thesis' bound); else the run ends 'failed'", minimum=0.01, maximum=5.0),
]


def _parameter(name: str) -> Parameter:
    return next(p for p in PARAMETERS if p.name == name)


def _vector(text: str | None, what: str) -> np.ndarray:
    if text is None or text == "":
        return np.zeros(3)
    try:
        v = np.array([float(x) for x in text.split(",")])
    except ValueError:
        raise click.BadParameter(f"expected three numbers separated by commas, got {text!r}", param_hint=what) from None
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise click.BadParameter(f"expected three finite numbers, got {text!r}", param_hint=what)
    return v


@procedure_command("cooperative", STEPS, PARAMETERS)
@click.option("--move", default="0.05,0,0", show_default=True, metavar="DX,DY,DZ",
              help="Master motion in the world frame, m (the slaves follow, eq. 6.2).")
@click.option("--rotate", default="0,0,0", show_default=True, metavar="RX,RY,RZ",
              help="Object reorientation about its centroid, x-y-z Euler angles in rad (eq. 6.3).")
@click.option("--arms", default=None, metavar="PSM1,PSM2[,PSM3]",
              help="Arms holding the object (default: the configuration's object arms).")
@click.option("--master", default=None, help="The master arm (default: the last of --arms, as in the thesis).")
@click.option("--object", "object_kind", type=click.Choice(["spring", "string"]), default=None,
              help="Simulated object: spring (2450 N/m) or string (20000 N/m). Default: the configuration's.")
@click.option("--mode", type=click.Choice(["impedance", "position"]), default="impedance", show_default=True,
              help="Slave control: impedance with tension tracking, or the position-based tracking of 7.7.3.")
@click.option("--model", "model_path", multiple=True, metavar="[ARM=]FILE",
              help="Identified model file for the arm its provenance names, or ARM=FILE for that arm; repeat it for "
                   "each arm (default: each arm's own newest `rig identify` result with its newest `rig "
                   "friction-ramp` terms; nominal on the simulated rig; never another arm's). Effects a `rig "
                   "discrepancy` model adds are fed forward with the rigid body where they are loads (backlash and "
                   "an effort delay are named, not fed forward). A file measured on another arm or rig, or edited "
                   "by hand, is refused unless --force-model is given.")
@click.option("--force-model", is_flag=True,
              help="Use a --model file even though its provenance says it belongs to another arm or rig (or it "
                   "was edited): the run's report and result carry a warning. A forced FILE that names none of "
                   "the run's arms is used for every arm given no file of its own.")
@click.option("--slave-control", type=click.Choice(["auto", "arm", "effort"]), default="auto", show_default=True,
              help="Who closes the slaves' impedance: 'arm' = the arm, in its servo loop (dVRK servo_ci over ROS; "
                   "this loop moves its goal at the rate the arms publish, 100 Hz and up); 'effort' = this loop, "
                   "commanding efforts (servo_jf) at [rig] rate; 'auto' = arm on ROS arms, effort in-process.")
@click.option("--tension-source", type=click.Choice(["cell", "model"]), default="cell", show_default=True,
              help="What the tension loop closes on: the load cell, or the tension the arms' identified model "
                   "estimates from their joints and efforts (N; calibration.tension_estimate). A load cell, if "
                   "there, is then only recorded, and max_error_during_motion stays its figure.")
@click.option("--seed", type=int, default=None, help="Seed of the simulated rig.")
@click.option("--dry-run", is_flag=True, help="Check the plan against every limit, print it, move nothing.")
@click.option("--ros-commands", is_flag=True,
              help="Also take live increments over ROS 2 while holding: /psm/cmd_vel geometry_msgs/Twist, "
                   "linear = Cartesian increment of the object in m (world frame), angular = object Euler-angle "
                   "(x-y-z) increment in rad; /psm/cmd_force std_msgs/Float64 = tension increment in N. One message "
                   f"is one increment (not a velocity), ramped in at {1000 * SLEW_M:g} mm/s, {SLEW_RAD:g} rad/s and "
                   f"{SLEW_N:g} N/s. A message with a NaN, or one that would take a target out "
                   f"of the limits or the tension set-point out of 0-{_parameter('force').maximum:g} N or to the "
                   "ceiling, is refused and reported.")
@click.option("--interactive", is_flag=True, help=f"Steer from the keyboard (a small terminal UI): wasdrf move {1000 * KEY_STEP_M:g} mm, ijkluo "
                   f"rotate {KEY_STEP_RAD:g} rad, +/- change the tension by {KEY_STEP_N:g} N (ramped in like "
                   "--ros-commands).")
def command(ctx, parameters, move, rotate, arms, master, object_kind, mode, model_path, force_model, slave_control,
            tension_source, seed, dry_run, ros_commands, interactive, as_json):
    """Cooperative manipulation with force tracking (thesis 6.3, 7.7).

    Holds FORCE newtons of tension on the object between the tool tips while the master
    moves it by --move over --duration seconds. Figures: max |F - force| during the
    motion, RMS error after settling, start-up overshoot, settling time (N, s), and
    each tool tip's Cartesian tracking of its plan (mm). `rig plot RUN` draws the
    figures again from the recording, an aborted run's too.
    """
    if force_model and not model_path:
        raise click.UsageError("--force-model applies to a --model FILE: give the file")
    if interactive and not sys.stdin.isatty():  # before anything is powered or moved
        raise click.UsageError("--interactive needs a terminal on stdin; from a script steer with --ros-commands")
    cfg = config_from_context(ctx)
    names = [a.strip() for a in arms.split(",")] if arms else list(cfg.object["arms"] or list(cfg.arms)[:2])
    if not 2 <= len(names) <= 3 or len(set(names)) != len(names):
        raise click.BadParameter(f"name two or three different arms, got {names}", param_hint="--arms")
    for n in names:
        if n not in cfg.arms:
            raise click.BadParameter(f"{n!r} is not an arm of {cfg.source} ({', '.join(cfg.arms)})", param_hint="--arms")
    master = master or names[-1]
    if master not in names:
        raise click.BadParameter(f"{master!r} is not one of {names}", param_hint="--master")
    translation, rotation = _vector(move, "--move"), _vector(rotate, "--rotate")
    if object_kind is not None:
        # on the real rig the operator is asked to attach this object (the gains follow it)
        cfg.object["kind"] = object_kind
        cfg.object["stiffness"] = 2450.0 if object_kind == "spring" else 20000.0
    cfg.object["arms"] = names
    result = run(cfg, names, master, dict(parameters), translation, rotation, mode,
                 model_path=model_path, seed=seed, dry_run=dry_run, ros_commands=ros_commands,
                 interactive=interactive, parameter_set=parameters, force_model=force_model,
                 slave_control=slave_control, tension_source=tension_source)
    emit_result(result, as_json, report=report(result))
    exit_for_status("cooperative", result)


# ----------------------------------------------------------------------------- set-up
def _model_for(cfg, names, model_path, simulated: bool, force_model: bool = False, warnings: list | None = None):
    """Each arm's own model (rig.runs.arm_models.models_for): {arm: ArmModel}; `model_path`
    a --model value or values (``FILE`` or ``ARM=FILE``)."""
    from rig.runs import arm_models

    values = (model_path,) if isinstance(model_path, (str, Path)) else tuple(model_path or ())
    pairs, problem = arm_models.parse_model_options(values, names)
    if problem:
        raise click.BadParameter(problem, param_hint="--model")
    return arm_models.models_for(cfg, names, pairs, simulated, force_model, warnings)


def _registration_for(cfg, names, simulated: bool, warnings: list | None = None):
    """Each arm's RCM frame in the world, and where it came from: the newest registration
    of these arms on this rig (rig.runs.provenance; newer ones passed over go to `warnings`)."""
    from rig.model import psm_kinematics as K

    def frames_of(data: dict) -> dict:
        transforms = data.get("rcm_frames") or {}
        return {n: np.asarray(transforms[n], float) for n in names if n in transforms}

    found = provenance.find("register", cfg, arms=names, usable=lambda run, data: len(frames_of(data)) == len(names))
    if warnings is not None:
        warnings.extend(found.skipped)
    if found.run_dir is not None:
        return frames_of(found.data), f"registration {found.run_dir}"
    if not simulated:
        raise InputError("no registration of these arms on this rig: run `rig register` first"
                                   + (f" ({found.skipped[-1]})" if found.skipped else ""))
    return {n: cfg.base_matrix(n) @ K.RCM_FRAME for n in names}, "the configuration's arm bases (simulated rig)"


def build_controller(cfg, names, master, params, translation, rotation, mode, dyn, stick, rcm_frames,
                     object_kind, object_stiffness, elements, dt, effects=None, slave_control="effort"):
    """The cooperative controller. ``dyn``, ``stick`` and ``effects`` are each arm's own
    (dicts by arm; a single value is every arm's): its rigid-body model, joint 3's
    stick-slip terms and a model file's effects, fed forward with the rigid body
    (`calibration.effects.EffectCompensation`)."""
    from calibration.effects import EffectCompensation
    from rig.control.controllers import FeedforwardModel, StickSlipCompensation
    from rig.control.cooperative_controller import CooperativeController
    from rig.control.cooperative_gains import ForceLoop, PositionForceLoop, arm_preset, preset
    from rig.control.cooperative_plan import Motion

    def per_arm(x):
        return dict(x) if isinstance(x, dict) else {n: x for n in names}

    dyn, stick, effects = per_arm(dyn), per_arm(stick), per_arm(effects)
    friction, feedforward = {}, {}
    for n in names:
        d = dyn[n].params.drive
        comp = StickSlipCompensation(d.Fc.copy(), d.Fv.copy(), d.Fo.copy(), d.slope)
        if stick[n] is not None:
            comp.Fs_pos, comp.Fs_neg = stick[n].fs_pos, stick[n].fs_neg
        friction[n] = comp
        feedforward[n] = FeedforwardModel(dyn[n], EffectCompensation(effects[n], d.slope) if effects[n] else None)
    gains, follow = preset(object_kind)
    return CooperativeController(
        names, master, rcm_frames,
        feedforward, friction, elements,
        params["force"], dt=dt, motion=Motion(translation, rotation, params["duration"], params["settle"]),
        loop=ForceLoop(), gains=gains, object_stiffness=object_stiffness, follow_measured_master=follow,
        mode=mode, position_loop=PositionForceLoop(deadband=params["deadband"]),
        slew_translation=SLEW_M, slew_rotation=SLEW_RAD, slew_force=SLEW_N,
        slave_control=slave_control, arm_gains=arm_preset(object_kind))


# ----------------------------------------------------------------------------- the run
# the lowest rates of the arms' streams per object: rig.control.arm_loop_rates (rig doctor checks them too)


#: Hz: the arm-impedance loop runs at the rate the arms publish, up to this: a tick costs
#: milliseconds of Python, and a faster loop starved itself over the wire
#: (bench/bench_cooperative_wire.py keeps the figures).
ARM_LOOP_MAX_RATE = 100.0


def _pace_at_published_rate(rig, names, master) -> None:
    """The arm-impedance path's loop runs at the rate the arms publish, at most
    ARM_LOOP_MAX_RATE and [rig] rate: every tick has a fresh state of every arm
    (rig.devices.clock.StreamClock or SimTimeClock: ROS arms); refuses, in one line, a slave whose
    arm cannot run servo_ci."""
    for n in names:
        # the console's subscription, not only the type here: servo_ci sent into the void
        # would leave the slave in whatever mode it was
        problem = rig.arms[n].servo_ci_problem() if n != master else None
        if problem is not None:
            raise AbortRun(f"{n} cannot run its impedance in the arm: {problem}; use --slave-control effort "
                           "(this loop closes it over servo_jf at [rig] rate)")
    rates = [rig.arms[n].published_rate() for n in names]
    heard = min(r for r in rates if r > 0) if any(r > 0 for r in rates) else rig.clock.rate
    rig.clock.set_rate(min(rig.clock.rate, ARM_LOOP_MAX_RATE, float(round(heard))), min_fraction=0.9)


@dataclass
class Setup:
    """What a cooperative run is given: the arms, the plan, the model, the registration."""

    cfg: Any
    names: list[str]
    master: str
    params: dict
    translation: np.ndarray
    rotation: np.ndarray
    mode: str
    dyn: Any
    stick: Any
    rcm_frames: dict
    model_note: str
    registration_note: str
    limits: Any
    slave_control: str = "effort"
    #: each arm's model-file effects (dyn and stick are each arm's too): dicts by arm, or one value for all
    effects: Any = field(default_factory=list)
    warnings: list = field(default_factory=list)
    dry_run: bool = False
    ros_commands: bool = False
    interactive: bool = False
    parameter_set: Any = None
    seed: int | None = None
    #: each arm's model file, as the result names it ({arm: summary})
    models: dict | None = None
    #: what the tension loop closes on: "cell" (the load cell) or "model" (the model's estimate)
    tension_source: str = "cell"

    @property
    def elements(self) -> list[tuple[str, str]]:
        return [(a, b) for i, a in enumerate(self.names) for b in self.names[i + 1:]]

    @property
    def total(self) -> float:
        """s: the loop's length (settle, move, hold after)."""
        return self.params["settle"] + self.params["duration"] + self.params["hold_after"]

    def controller(self, dt: float):
        return build_controller(self.cfg, self.names, self.master, self.params, self.translation, self.rotation,
                                self.mode, self.dyn, self.stick, self.rcm_frames, self.cfg.object["kind"],
                                self.cfg.object["stiffness"], self.elements, dt, self.effects,
                                self.slave_control)


def run(cfg, names, master, params, translation, rotation, mode, *, model_path=None, seed=None,
        dry_run=False, ros_commands=False, interactive=False, parameter_set=None, model=None,
        progress=True, force_model=False, slave_control="auto", tension_source="cell"):
    """The procedure; returns the result document. `model` overrides the model file (tests, bench).

    slave_control: "arm" (the slaves' impedance in the arm: servo_ci), "effort" (closed
    here: servo_jf) or "auto" (arm on ROS arms in impedance mode, else effort)."""
    from rig.devices.factory import open_rig
    from rig.runs.safety import SafetyLimits

    simulated = cfg.simulated
    warnings: list[str] = []
    if model is not None:
        dyn, stick, model_note, effects = model, None, "model given by the caller", []
        models = {n: {"file": None, "note": f"{n}: model given by the caller"} for n in names}
    else:
        # each arm its own model and friction terms, never another arm's
        per_arm = _model_for(cfg, names, model_path, simulated, force_model, warnings)
        dyn, stick = {n: m.dynamics for n, m in per_arm.items()}, {n: m.stick for n, m in per_arm.items()}
        effects = {n: m.effects for n, m in per_arm.items()}
        model_note = "; ".join(m.note for m in per_arm.values())
        models = {n: m.summary() for n, m in per_arm.items()}
    rcm_frames, registration_note = _registration_for(cfg, names, simulated, warnings)
    limits = SafetyLimits(tension_ceiling=params["tension_ceiling"])
    if params["force"] >= limits.tension_ceiling:
        raise click.BadParameter(f"{params['force']} N is not below the tension ceiling "
                                 f"{limits.tension_ceiling} N", param_hint="--force")
    slave_control = _slave_control(cfg, names, mode, slave_control)
    setup = Setup(cfg, names, master, params, translation, rotation, mode, dyn, stick, rcm_frames, model_note,
                  registration_note, limits, slave_control, effects, warnings, dry_run, ros_commands,
                  interactive, parameter_set, seed, models, tension_source)
    rig = open_rig(cfg, names, seed=seed, uses=("loadcell",),
                   loop_rate=arm_loop_min_rate(cfg.object["kind"], len(names)) if slave_control == "arm" else None)
    try:
        return _run(rig, setup, progress)
    finally:
        rig.close()


def _slave_control(cfg, names, mode, slave_control: str) -> str:
    """--slave-control resolved: "auto" is the arm on ROS arms in impedance mode, else effort."""
    ros = all(cfg.arms[n]["driver"] == "ros" for n in names)
    if slave_control == "auto":
        return "arm" if ros and mode == "impedance" else "effort"
    if slave_control == "arm" and not ros:
        raise click.BadParameter("'arm' needs ROS arms (the dVRK runs servo_ci); the in-process simulated arms "
                                 "take efforts: use 'effort' or 'auto'", param_hint="--slave-control")
    if slave_control == "arm" and mode != "impedance":
        raise click.BadParameter("'arm' is the impedance mode's; --mode position keeps the slaves on servo_jp",
                                 param_hint="--slave-control")
    return slave_control


def _run(rig, setup: Setup, progress: bool) -> dict:
    """The steps of the run (STEPS), each a call; the hold is the run engine's control loop
    with `TensionHold.step`."""
    if setup.slave_control == "arm":
        _pace_at_published_rate(rig, setup.names, setup.master)
    with Run("cooperative", parameters=setup.parameter_set if setup.parameter_set is not None else setup.params,
             config=setup.cfg.snapshot(), seed=setup.seed if setup.seed is not None else setup.cfg.rig["seed"],
             steps=STEPS, progress=progress) as run:
        for line in [f"model: {setup.model_note}", f"registration: {setup.registration_note}"] + [
                f"warning: {w}" for w in setup.warnings]:
            run.say(line)
        if setup.dry_run:
            return _dry_run(run, rig, setup)
        with run.step(STEPS[0]):
            _power_and_home(run, rig, setup)
        with run.step(STEPS[1]):
            estimate = _attach(rig, setup)
        controller = setup.controller(1.0 / rig.clock.rate)
        model_effects = _model_effects(controller, run)
        sensors = [rig.forces[k] for k in sorted(rig.forces or {})]
        started = _start(controller, rig, setup, sensors, estimate)
        with run.step(STEPS[2]):
            plan = _check_plan(controller, setup.names, started.q0, setup.total, setup.limits)
        for n in setup.names:
            run.claim(rig.arms[n])
        return _hold(run, rig, setup, controller, sensors, started, estimate, model_effects, plan)


def _hold(run, rig, setup: Setup, controller, sensors, started, estimate, model_effects, plan) -> dict:
    """Steps 4 and 5: hold the tension while the master moves, then the figures and the report.
    `estimate`: the model's tension estimate (issue 47), updated every tick; `sensors` may
    be none when the loop closes on it."""
    clock, names = rig.clock, setup.names
    live = LiveCommands(controller, setup.ros_commands, setup.interactive, run.recorder, names, setup.limits,
                        maximum_force=_parameter("force").maximum, say=run.say)
    n_ticks = int(round(setup.total * clock.rate))
    servo_ci = None
    if setup.slave_control == "arm":
        servo_ci = ServoCI(rig, controller.slaves)
        # the set-point ramp starts with the loop (checking the plan took a while; in the
        # effort path the slack take-up starts it)
        _start(controller, rig, setup, sensors, estimate)
    t_start = clock.now()
    # where the loop and the motion begin on the run clock: `rig plot` draws the figures
    # from the recording on this time base (procedures/cooperative_figures.py)
    motion = (controller.t0 + controller.motion.start - t_start,
              controller.t0 + controller.motion.start + controller.motion.duration - t_start)
    run.recorder.metadata(figures.LOOP_METADATA, figures.loop_metadata(
        t_start, names, setup.master, t_start + motion[0], t_start + motion[1], setup.elements))
    loop = ControlLoop(run, clock, {n: rig.arms[n] for n in names}, limits=setup.limits, sensors=sensors,
                       impedance=servo_ci, loop_time_topic="/cooperative/loop_time_us", read="drain")
    loop.newest_force_t = [s.t for s in started.samples]
    loop.prime()
    hold = TensionHold(controller, loop, live, setup.cfg, n_ticks, t_start, started.tension, estimate,
                       on_model=setup.tension_source == "model")

    def timing_so_far() -> dict:
        """The loop's timing over the ticks it completed (an aborted run's result has it)."""
        return _timing(loop, hold, clock.rate, len(names))

    # the ROS 2 context and the keyboard are released however the loop ends
    with live, plot_hint(run, timing_so_far), run.step(STEPS[3], total=n_ticks) as step:
        loop.run(hold.step, n_ticks, progress=step, on_progress=hold.show)
    with run.step(STEPS[4]):
        return _report(run, setup, controller, hold, live, timing_so_far(), model_effects, motion, t_start)


def _timing(loop, hold, rate: float, arms: int) -> dict:
    lt_raw = loop.timing()
    done = len(lt_raw["t"])
    lt = loop_timing(hold.log["t"][:done], rate, lt_raw["overruns"], lt_raw["skipped"], lt_raw["repeated_js"],
                     arms, hold.log["loop_us"][:done])
    lt["arm_clock_jumps"] = int(lt_raw["arm_clock_jumps"])
    lt["arm_clock_jump_ms_max"] = 1e3 * lt_raw["arm_clock_jump_max"]
    ages = lt_raw["sample_age_ms"]
    lt["arm_sample_age_ms"] = ({"median": float(np.median(ages)), "p99": float(np.percentile(ages, 99)),
                                "max": float(np.max(ages))} if len(ages) else None)
    return lt


def _report(run, setup: Setup, controller, hold, live, timing: dict, model_effects, motion, t_start) -> dict:
    params, names, master, kind = setup.params, setup.names, setup.master, setup.cfg.object["kind"]
    n_ticks = len(hold.log["t"])
    result = force_error_figures(hold.log, params, names, master, setup.mode, kind, controller,
                                 last_live=None if live.last_applied is None else live.last_applied - t_start)
    result["loop_timing"] = timing
    result["loop_timing"].update(force_hold_figures(hold.blind_ticks, n_ticks, hold.blind_longest,
                                                    hold.max_force_age))
    if setup.ros_commands or setup.interactive:
        result["live_commands"] = live.summary(t_start)
    result["slave_control"] = slave_control_text(setup.slave_control, setup.mode, hold.loop.clock.rate)
    result["tension_estimate"] = _estimate_figures(hold.log, params, setup.tension_source, bool(hold.loop.sensors),
                                                   hold.estimate)
    result.update({"model": setup.model_note, "models": setup.models, "model_effects": model_effects,
                   "registration": setup.registration_note, "arms": names, "master": master, "mode": setup.mode,
                   "object": kind, "filter_delay": filter_delays(controller), "warnings": list(setup.warnings)})
    missed = missed_bound(result, params)
    trace = figures.trace_from_log(hold.log, names, master, motion,
                                   f"{run.dir.name} ({'failed: ' + missed if missed else 'completed'})",
                                   tolerance=params.get("tolerance"), ceiling=params.get("tension_ceiling"),
                                   elements=setup.elements)
    result["cartesian_tracking"] = figures.cartesian_tracking(trace)
    result["plot"] = str(figures.draw_force_figure(trace, Path(run.dir) / "cooperative.png"))
    result["tracking_plot"] = str(figures.draw_tracking_figure(trace, Path(run.dir) / "cooperative-tracking.png"))
    run.finish(result, status="failed" if missed else "completed", reason=missed)
    return run.result


def _dry_run(run, rig, setup: Setup) -> dict:
    """Plan only: nothing is powered, moved or attached; the plan starts where a real run
    would (the simulated rig's start, or each arm's configured q0)."""
    names = setup.names
    q0 = {n: (rig.arms[n].measured_js().position[:3] if rig.world is not None
              else np.array(setup.cfg.arms[n]["q0"], float)) for n in names}
    controller = setup.controller(1.0 / rig.clock.rate)
    controller.start(rig.clock.now(), q0, {n: np.zeros(3) for n in names},
                     np.full(len(setup.elements), float(setup.params["force"])))
    with run.step(STEPS[2]):
        plan = _check_plan(controller, names, q0, setup.total, setup.limits)
    result = {"plan": plan, "model": setup.model_note, "models": setup.models, "registration": setup.registration_note,
              "arms": names, "master": setup.master, "mode": setup.mode, "object": setup.cfg.object["kind"],
              "warnings": list(setup.warnings)}
    run.finish(result, status="dry-run")
    return run.result


def _power_and_home(run, rig, setup: Setup) -> None:
    for n in setup.names:
        rig.arms[n].power_on()
    if rig.world is None:
        # a real (or served) rig is wherever the last procedure left it: with the object
        # off, bring every arm to its configured start q0, where the object fits between
        # the tips (the simulated rig starts there, object attached)
        rig.operator.detach_object()
        for n in setup.names:
            run.claim(rig.arms[n])
            q0 = setup.cfg.arms[n]["q0"]
            if not rig.arms[n].move_jp(np.array(q0), wait=True, timeout=15.0):
                raise AbortRun(f"{n} did not reach its start q0 = {q0} (rad, rad, m) in 15 s")


def _attach(rig, setup: Setup):
    """Attach the object and let it settle; returns the model's tension estimate (issue 47),
    which runs through the settling: its observers start at rest and have taken up the
    object's pull when the loop starts."""
    rig.operator.attach_object(setup.cfg.object["kind"])
    elements = setup.elements
    estimate = tension_source_for(setup.dyn, setup.effects, setup.stick, setup.rcm_frames, setup.names, elements,
                                  setup.params.get("tolerance", _parameter("tolerance").default), setup.cfg.object)
    dt = 1.0 / rig.clock.rate
    # the simulated object is attached at construction; let it settle under the PIDs
    for _ in range(int(0.5 * rig.clock.rate)):
        rig.clock.tick()
        estimate.update({n: rig.arms[n].drain_js() or rig.arms[n].measured_js() for n in setup.names}, dt)
    if rig.force is None and setup.tension_source == "cell":
        raise AbortRun("no load cell: the tension cannot be tracked (or close the loop on the model's "
                       "estimate: --tension-source model)")
    sensed = sorted(rig.forces or {})
    if sensed and len(sensed) != len(elements):
        held = [elements[k] for k in sensed]
        raise AbortRun(f"the object has {len(elements)} elements but load cells on only {held}: "
                       "a triangle of three arms needs a load cell on every element")
    return estimate


def _model_effects(controller, run) -> dict:
    """The model file's effects the controllers feed forward and those they cannot (said)."""
    comp = next(iter(controller.impedance.values())).model.effects if controller.impedance else None
    if comp is None:
        return {"fed_forward": [], "not_fed_forward": []}
    for sk in comp.skipped:
        run.say(f"model effect {sk['name']}@{sk['joint']} not fed forward: {sk['reason']}")
    return {"fed_forward": [f"{e['name']}@{e['joint']}" for e in comp.entries], "not_fed_forward": comp.skipped}


@dataclass
class Started:
    """Where the controller started: the cells' samples, the arms' joints (rad, rad, m) and
    the tension the loop begins with (N per element: the cells', else the estimate's)."""

    samples: list
    q0: dict
    tension: np.ndarray


def _start(controller, rig, setup: Setup, sensors, estimate) -> Started:
    """Start the controller from the arms' and the cells' newest samples, or on the model's
    estimate (`--tension-source model`, as fresh as the joint states it came from)."""
    names, dt = setup.names, 1.0 / rig.clock.rate
    js = {n: rig.arms[n].measured_js() for n in names}
    first = [s.read() for s in sensors]
    tension = np.array([s.force for s in first]) if sensors else estimate.update(js, dt)
    if setup.tension_source == "model":
        start_tension, tension_t = estimate.update(js, dt), _stamps(js, len(setup.elements))
    else:
        start_tension, tension_t = tension, np.array([s.t for s in first])
    controller.start(rig.clock.now(), {n: js[n].position[:3] for n in names}, {n: js[n].velocity[:3] for n in names},
                     start_tension, stamps={n: js[n].t for n in names}, tension_t=tension_t)
    return Started(first, {n: js[n].position[:3] for n in names}, tension)


def _check_plan(controller, names, q0, total, limits) -> dict:
    """Sample the planned desired tips, check limits with the IK, return a summary."""
    from rig.model import psm_kinematics as K

    worst = {}
    for t in np.linspace(0.0, total, 200):
        xd, vd, _ = controller.desired(controller.t0 + t)
        for n in names:
            x_rcm = controller.to_rcm(n, xd[n])
            try:
                q = K.ik_rcm(x_rcm)
            except K.IKError as exc:
                raise AbortRun(f"plan: {n} cannot reach its target at t = {t:.2f} s: {exc}") from None
            dq = np.linalg.solve(K.tip_jacobian_rcm(q), controller.R[n].T @ vd[n])
            problem = limits.plan_violation(n, q[None], dq[None], xd[n][None])
            if problem:
                raise AbortRun(f"plan: {problem} at t = {t:.2f} s")
            worst[n] = max(worst.get(n, 0.0), float(np.max(np.abs(dq) / K.DQ_MAX)))
    return {"duration": total, "max_velocity_fraction": worst}


