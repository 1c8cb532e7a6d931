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
import time
from contextlib import contextmanager
from pathlib import Path

import click
import numpy as np

from procedures import cooperative_figures as figures
from procedures.cooperative_estimate import estimate_figures as _estimate_figures
from procedures.cooperative_estimate import stamps as _stamps
from procedures.cooperative_estimate import tension_source_for
from procedures.cooperative_live import KEY_STEP_M, KEY_STEP_N, KEY_STEP_RAD, SLEW_M, SLEW_N, SLEW_RAD, _LiveCommands
from procedures.cooperative_report import (_figures, _filter_delays, _force_hold_figures, _loop_timing, _missed,
                                           _slave_control_text, format_report)
from rig.commands.abort import exit_on_abort
from rig.control.arm_loop_rates import ARM_LOOP_MIN_RATE, arm_loop_min_rate  # noqa: F401
from rig.commands.exit_codes import InputError
from rig.commands.options import config_from_context, json_option, yes_option
from rig.commands.parameters import Parameter, with_parameters
from rig.commands.report import emit_result, exit_for_status
from rig.runs import provenance
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


@click.command(name="cooperative")
@with_parameters(PARAMETERS)
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
@click.option("--steps", "list_steps", is_flag=True, help="List the steps and exit without moving anything.")
@yes_option
@json_option
@click.pass_context
@exit_on_abort
def command(ctx, parameters, move, rotate, arms, master, object_kind, mode, model_path, force_model, slave_control,
            tension_source, seed, dry_run, ros_commands, interactive, list_steps, as_json):
    """Cooperative manipulation with force tracking (thesis 6.3, 7.7).

    Holds FORCE newtons of tension on the object between the tool tips while the master
    moves it by --move over --duration seconds. Figures: max |F - force| during the
    motion, RMS error after settling, start-up overshoot, settling time (N, s), and
    each tool tip's Cartesian tracking of its plan (mm). `rig plot RUN` draws the
    figures again from the recording, an aborted run's too.
    """
    if list_steps:
        click.echo("\n".join(f"{i + 1}. {name}" for i, name in enumerate(STEPS)))
        return
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
    result = run_cooperative(cfg, names, master, dict(parameters), translation, rotation, mode,
                             model_path=model_path, seed=seed, dry_run=dry_run, ros_commands=ros_commands,
                             interactive=interactive, parameter_set=parameters, force_model=force_model,
                             slave_control=slave_control, tension_source=tension_source)
    emit_result(result, as_json, report=format_report(result))
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
    from rig.control.cooperative_controller import (CooperativeController, ForceLoop, Motion, PositionForceLoop,
                                                    arm_preset, preset)

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


#: Hz: the arm-impedance loop runs at the rate the arms publish, up to this. It moves set-
#: points; a tick with one slave costs 3-5 ms of Python (controller 1.5-2 ms, the servo_ci
#: goal and message 0.4 ms, publishing and recording the rest). Against rig sim on this
#: 2-core machine (both processes at 80-90 % of a core) 200 Hz starved the loop (periods
#: to 30-70 ms at p99/max, the tension older than 10 ms on 8-18 % of ticks): 0.34-2.2 N
#: while moving and aborts; 100 Hz: 0.25-0.68 N, no aborts in those runs.
ARM_LOOP_MAX_RATE = 100.0


def _pace_at_published_rate(rig, names, master) -> None:
    """The arm-impedance path's loop runs at the rate the arms publish, at most
    ARM_LOOP_MAX_RATE and [rig] rate: every tick has a fresh state of every arm
    (rig.devices.clock.StreamClock); refuses, in one line, a slave whose arm cannot run servo_ci."""
    for n in names:
        # the console's subscription, not only the type here: servo_ci sent into the void
        # would leave the slave in whatever mode it was
        problem = rig.arms[n].servo_ci_problem() if hasattr(rig.arms[n], "servo_ci_problem") else "no servo_ci"
        if n != master and problem is not None:
            raise AbortRun(f"{n} cannot run its impedance in the arm: {problem}; use --slave-control effort "
                           "(this loop closes it over servo_jf at [rig] rate)")
    rates = [rig.arms[n].published_rate() for n in names if hasattr(rig.arms[n], "published_rate")]
    heard = min(r for r in rates if r > 0) if any(r > 0 for r in rates) else rig.clock.rate
    if hasattr(rig.clock, "set_rate"):
        rig.clock.set_rate(min(rig.clock.rate, ARM_LOOP_MAX_RATE, float(round(heard))), min_fraction=0.9)


def run_cooperative(cfg, names, master, params, translation, rotation, mode, *, model_path=None, seed=None,
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
    ros = all(cfg.arms[n]["driver"] == "ros" for n in names)
    if slave_control == "auto":
        slave_control = "arm" if ros and mode == "impedance" else "effort"
    elif slave_control == "arm" and not ros:
        raise click.BadParameter("'arm' needs ROS arms (the dVRK runs servo_ci); the in-process simulated arms "
                                 "take efforts: use 'effort' or 'auto'", param_hint="--slave-control")
    elif slave_control == "arm" and mode != "impedance":
        raise click.BadParameter("'arm' is the impedance mode's; --mode position keeps the slaves on servo_jp",
                                 param_hint="--slave-control")
    rig = open_rig(cfg, names, seed=seed, uses=("loadcell",),
                   loop_rate=arm_loop_min_rate(cfg.object["kind"], len(names)) if slave_control == "arm" else None)
    try:
        return _run(rig, cfg, names, master, params, translation, rotation, mode, dyn, stick, rcm_frames,
                    model_note, registration_note, limits, dry_run, ros_commands, interactive,
                    parameter_set, seed, progress, effects, warnings, slave_control, tension_source, models=models)
    finally:
        rig.close()


def _run(rig, cfg, names, master, params, translation, rotation, mode, dyn, stick, rcm_frames, model_note,
         registration_note, limits, dry_run, ros_commands, interactive, parameter_set, seed, progress,
         effects=(), warnings=(), slave_control="effort", tension_source="cell", models=None):
    clock = rig.clock
    if slave_control == "arm":
        _pace_at_published_rate(rig, names, master)
    elements = [(a, b) for i, a in enumerate(names) for b in names[i + 1:]]
    kind = cfg.object["kind"]
    stiffness = cfg.object["stiffness"]
    with Run("cooperative", parameters=parameter_set if parameter_set is not None else params,
             config=cfg.snapshot(), seed=seed if seed is not None else cfg.rig["seed"], steps=STEPS,
             progress=progress) as run:
        rec = run.recorder
        notes = [f"model: {model_note}", f"registration: {registration_note}"] + [
            f"warning: {w}" for w in warnings]
        for line in notes:
            run._write(line + "\n")
        def new_controller():
            return build_controller(cfg, names, master, params, translation, rotation, mode, dyn, stick,
                                    rcm_frames, kind, stiffness, elements, 1.0 / clock.rate, effects,
                                    slave_control)

        if dry_run:
            # plan only: nothing is powered, moved or attached; the plan starts where a
            # real run would (the simulated rig's start, or each arm's configured q0)
            q0 = {n: (rig.arms[n].measured_js().position[:3] if rig.world is not None
                      else np.array(cfg.arms[n]["q0"], float)) for n in names}
            controller = new_controller()
            controller.start(clock.now(), q0, {n: np.zeros(3) for n in names},
                             np.full(len(elements), float(params["force"])))
            total = params["settle"] + params["duration"] + params["hold_after"]
            with run.step(STEPS[2]):
                plan = _check_plan(controller, names, q0, total, limits)
            result = {"plan": plan, "model": model_note, "models": models, "registration": registration_note,
                      "arms": names, "master": master, "mode": mode, "object": kind, "warnings": list(warnings)}
            run.finish(result, status="dry-run")
            return run.result
        with run.step(STEPS[0]):
            for n in names:
                arm = rig.arms[n]
                if hasattr(arm, "power_on"):
                    arm.power_on()
            if rig.world is None:
                # a real (or served) rig is wherever the last procedure left it: with the
                # object off, bring every arm to its configured start q0, where the object
                # fits between the tips (the simulated rig starts there, object attached)
                rig.operator.detach_object()
                for n in names:
                    run.claim(rig.arms[n])
                    if not rig.arms[n].move_jp(np.array(cfg.arms[n]["q0"]), wait=True, timeout=15.0):
                        raise AbortRun(f"{n} did not reach its start q0 = {cfg.arms[n]['q0']} (rad, rad, m) in 15 s")
        with run.step(STEPS[1]):
            rig.operator.attach_object(kind)
            # the simulated object is attached at construction; let it settle under the PIDs
            # the model's tension estimate (issue 47) runs through the settling: its observers
            # start at rest and have taken up the object's pull when the loop starts
            estimate = tension_source_for(dyn, effects, stick, rcm_frames, names, elements)
            for _ in range(int(0.5 * clock.rate)):
                clock.tick()
                estimate.update({n: rig.arms[n].measured_js() for n in names}, 1.0 / clock.rate)
            if rig.force is None and tension_source == "cell":
                raise AbortRun("no load cell: the tension cannot be tracked (or close the loop on the model's "
                               "estimate: --tension-source model)")
            sensed = sorted(rig.forces or {})
            if sensed and len(sensed) != len(elements):
                held = [elements[k] for k in sensed]
                raise AbortRun(f"the object has {len(elements)} elements but load cells on only {held}: "
                               "a triangle of three arms needs a load cell on every element")
        controller = new_controller()
        if tension_source == "model":
            # closed on the estimate, which lags by the observer's filter: no proportional
            # feedback of it (a stiff string's k_fp rang up to the ceiling at 7-8 Hz), and
            # the slaves keep their own inertia, whose impedance needs no force fed back
            # (rig.control.controllers.Impedance; with the spring's 1 kg the loop rang)
            controller.k_fp = 0.0
            for imp in controller.impedance.values():
                imp.Md = None
        comp = next(iter(controller.impedance.values())).model.effects if controller.impedance else None
        model_effects = {"fed_forward": [], "not_fed_forward": []}
        if comp is not None:
            model_effects = {"fed_forward": [f"{e['name']}@{e['joint']}" for e in comp.entries],
                             "not_fed_forward": comp.skipped}
            for sk in comp.skipped:
                run._write(f"model effect {sk['name']}@{sk['joint']} not fed forward: {sk['reason']}\n")
        js = {n: rig.arms[n].measured_js() for n in names}
        q0 = {n: js[n].position[:3] for n in names}
        sensors = [rig.forces[k] for k in sorted(rig.forces or {})]
        first = [s.read() for s in sensors]
        tension = np.array([s.force for s in first]) if sensors else estimate.update(js, 1.0 / clock.rate)
        on_model = tension_source == "model"
        controller.start(clock.now(), q0, {n: js[n].velocity[:3] for n in names},
                         estimate.update(js, 1.0 / clock.rate) if on_model else tension, stamps={n: js[n].t for n in names},
                         tension_t=_stamps(js, len(elements)) if on_model else np.array([s.t for s in first]))
        total = params["settle"] + params["duration"] + params["hold_after"]
        with run.step(STEPS[2]):
            plan = _check_plan(controller, names, q0, total, limits)
        for n in names:
            run.claim(rig.arms[n])
        live = _LiveCommands(controller, ros_commands, interactive, rec, names, limits,
                             maximum_force=_parameter("force").maximum, say=run._write)
        n_ticks = int(round(total * clock.rate))
        log = {"t": np.empty(n_ticks), "tension": np.empty((n_ticks, len(elements))), "setpoint": np.empty(n_ticks),
               "loop_us": np.empty(n_ticks), "x_f": np.empty((n_ticks, len(controller.slaves))),
               "force_offset": np.empty(n_ticks), "tension_estimate": np.empty((n_ticks, len(elements))),
               "estimate_ambiguous": np.zeros(n_ticks, bool)}
        for n in names:
            log[f"{n}.x"] = np.empty((n_ticks, 3))
            log[f"{n}.xd"] = np.empty((n_ticks, 3))
        servo_ci = None
        if slave_control == "arm":
            servo_ci = _ServoCI(rig, controller.slaves)
            # the set-point ramp starts with the loop (checking the plan took a while; in
            # the effort path the slack take-up starts it)
            js = {n: rig.arms[n].measured_js() for n in names}
            newest = [s.read() for s in sensors]
            controller.start(clock.now(), {n: js[n].position[:3] for n in names},
                             {n: js[n].velocity[:3] for n in names},
                             estimate.update(js, 1.0 / clock.rate) if on_model else np.array([s.force for s in newest]),
                             stamps={n: js[n].t for n in names},
                             tension_t=_stamps(js, len(elements)) if on_model else np.array([s.t for s in newest]))
        t_start = clock.now()
        # where the loop and the motion begin on the run clock: `rig plot` draws the figures
        # from the recording on this time base (procedures/cooperative_figures.py)
        motion = (controller.t0 + controller.motion.start - t_start,
                  controller.t0 + controller.motion.start + controller.motion.duration - t_start)
        rec.metadata(figures.LOOP_METADATA, figures.loop_metadata(t_start, names, master, t_start + motion[0],
                                                                  t_start + motion[1], elements))
        overruns0, skipped0 = getattr(clock, "overruns", 0), getattr(clock, "skipped", 0)
        last_js_t = {n: None for n in names}
        repeated_js = 0  # ticks that found an arm's measured_js not renewed since the last one
        # The arms' clock against the loop's: a sample stamped further on from the last one
        # than the loop's own time moved is a jump of the console's clock (its servo loop
        # fell behind and caught up, or rig sim re-anchored its time on a starved machine):
        # the arm moved less than the stamps say. Their largest (ms) and count (> 20 ms).
        stamp_jumps, stamp_jump_max, t_prev_tick = 0, 0.0, None
        # and how old the arms' samples were when the loop acted on them (ms, the oldest arm's)
        sample_age_ms = np.zeros(n_ticks)
        # The force loop acts only on a tension at most two of the cell's frame periods old
        # (at a tick the newest sample is up to one period old, plus its way to the loop);
        # older, the controller holds its force loop (CooperativeController.step, blind).
        # Samples can stop reaching the loop while the port still has them: the driver's
        # reader thread held up on a loaded machine (100-475 ms seen over the wire with
        # one CPU burner) delivers them in a burst later, and its stream age does not
        # count that as silence. A tension no newer than the stale timeout ends the run.
        max_force_age = max(2.0 / cfg.loadcell["rate"], 2.0 / clock.rate)
        stale_timeout = cfg.loadcell["stale_timeout"]
        # With the impedance in the arm a late tension only holds the set-point where it
        # is (the arm keeps the slaves in place): samples that reach the loop late, the
        # cell still streaming, are then waited for as long as the arms' own streams are
        loop_stale = (max(stale_timeout, *(cfg.arms[n]["watchdog"] for n in names)) if slave_control == "arm"
                      else stale_timeout)
        last_force_t = [s.t for s in first]
        # The cells have streamed since they were opened: record what they hold now, so
        # the first tick of the hold does not (three cells held ~3900 samples each after
        # connecting; recording them took that tick 60 ms, just as the slaves went over to
        # effort control).
        for k_el, sensor in enumerate(sensors):
            topic = "/loadcell/force" if k_el == 0 else f"/loadcell{k_el}/force"
            for s in sensor.samples():
                rec.tension(topic, s.t, s.force)
                last_force_t[k_el] = max(last_force_t[k_el], s.t)
        blind_ticks, blind_longest = 0, 0.0
        t_last_tick = None
        # the ROS 2 context and the keyboard are released however the loop ends
        done = 0  # ticks completed

        def timing_so_far() -> dict:
            """The loop's timing over the ticks it completed (an aborted run's result has it)."""
            lt = _loop_timing(log["t"][:done], clock.rate, getattr(clock, "overruns", 0) - overruns0,
                              getattr(clock, "skipped", 0) - skipped0, repeated_js, len(names), log["loop_us"][:done])
            lt["arm_clock_jumps"] = int(stamp_jumps)
            lt["arm_clock_jump_ms_max"] = 1e3 * stamp_jump_max
            ages = sample_age_ms[:done]
            lt["arm_sample_age_ms"] = ({"median": float(np.median(ages)), "p99": float(np.percentile(ages, 99)),
                                        "max": float(np.max(ages))} if len(ages) else None)
            return lt

        with live, _plot_hint(run, timing_so_far), run.step(STEPS[3], total=n_ticks) as step:
            for k in range(n_ticks):
                clock.tick()
                t = clock.now()
                js = {n: rig.arms[n].measured_js() for n in names}
                for n in names:
                    repeated_js += js[n].t == last_js_t[n]
                    if last_js_t[n] is not None and t_prev_tick is not None:
                        jump = (js[n].t - last_js_t[n]) - (t - t_prev_tick)
                        stamp_jump_max = max(stamp_jump_max, jump)
                        stamp_jumps += jump > 0.02
                    last_js_t[n] = js[n].t
                t_prev_tick = t
                sample_age_ms[k] = 1e3 * max(t - js[n].t for n in names)
                fresh = None
                newest = []
                for k_el, sensor in enumerate(sensors):
                    new = sensor.samples()
                    topic = "/loadcell/force" if k_el == 0 else f"/loadcell{k_el}/force"
                    for s in new:
                        rec.tension(topic, s.t, s.force)
                    newest.append(new[-1] if new else None)
                    if new:
                        last_force_t[k_el] = max(last_force_t[k_el], new[-1].t)
                fresh_t = None
                if sensors and all(s is not None for s in newest):
                    tension = np.array([s.force for s in newest])
                    fresh, fresh_t = tension, np.array([s.t for s in newest])
                force_age = t - min(last_force_t) if sensors else 0.0
                # a tick late itself (this process held) finds samples as old as the gap:
                # they are the newest there are, not a stalled cell
                gap = t - t_last_tick if t_last_tick is not None else 0.0
                t_last_tick = t
                blind = force_age > max(max_force_age, gap + 1.0 / cfg.loadcell["rate"])
                if blind:
                    blind_ticks += 1
                    blind_longest = max(blind_longest, force_age)
                    if force_age > stale_timeout:
                        _check_stale_tension(sensors, force_age, stale_timeout, loop_stale, cfg.loadcell["rate"],
                                             "[loadcell] stale_timeout")
                est = estimate.update(js, 1.0 / clock.rate)
                for k_el, value in enumerate(est):
                    rec.scalar(figures.TENSION_ESTIMATE_TOPIC + (str(k_el) if k_el else ""), t, float(value))
                log["tension_estimate"][k] = est
                log["estimate_ambiguous"][k] = estimate.ambiguous
                if on_model:
                    # the loop closes on the estimate: as fresh as the joint states it came from
                    fresh, fresh_t, blind = est, _stamps(js, len(est)), False
                    if not sensors:
                        tension = est
                live.poll(t)
                c0 = time.perf_counter()
                q = {n: js[n].position[:3] for n in names}
                dq = {n: js[n].velocity[:3] for n in names}
                # the samples' own times: the loop's ticks are not `dt` apart over the wire
                commands = controller.step(t, q, dq, fresh, blind=blind, stamps={n: js[n].t for n in names},
                                           tension_t=fresh_t)
                loop_us = (time.perf_counter() - c0) * 1e6
                xd, _, _ = controller.desired(t)
                # recorded before the checks: an aborted run's recording holds the tick that
                # broke a limit
                rec.scalar(figures.SETPOINT_TOPIC, t, controller.force_setpoint)
                x = {}
                for n in names:
                    x[n] = controller.tip_world(n, q[n])
                    rec.joint_state(f"/{n}/measured_js", js[n].t, js[n].position, js[n].velocity, js[n].effort)
                    rec.point(figures.measured_cp_topic(n), js[n].t, x[n], "world")
                    rec.point(figures.setpoint_cp_topic(n), t, xd[n], "world")
                limits.check_tension(float(tension.max()))
                for n in names:
                    limits.check_arm(n, q[n], dq[n], js[n].effort[:3], x[n])
                    cmd = commands[n]
                    if cmd.kind == "position":
                        rig.arms[n].servo_jp(cmd.q, cmd.dq)
                        rec.joint_state(f"/{n}/servo_jp", t, cmd.q, cmd.dq, ())
                    elif cmd.kind == "impedance":
                        limits.check_effort(n, cmd.feedforward)
                        servo_ci.send(n, cmd, t, rec)
                    else:
                        limits.check_effort(n, cmd.effort)
                        rig.arms[n].servo_jf(cmd.effort)
                        rec.joint_state(f"/{n}/servo_jf", t, (), (), cmd.effort)
                    log[f"{n}.x"][k] = x[n]
                    log[f"{n}.xd"][k] = xd[n]
                rec.scalar("/cooperative/loop_time_us", t, loop_us)
                log["t"][k] = t - t_start
                log["tension"][k] = tension
                log["setpoint"][k] = controller.force_setpoint
                log["force_offset"][k] = controller.applied_force_offset
                log["loop_us"][k] = loop_us
                log["x_f"][k] = [controller.x_f[s] for s in controller.slaves]
                rec.scalar("/cooperative/x_f", t, float(log["x_f"][k][0]))
                done = k + 1
                if k % 100 == 0:
                    step.update(k)
                    live.show(t - t_start, float(tension.mean()), {n: log[f"{n}.x"][k] for n in names})
            step.update(n_ticks)
        with run.step(STEPS[4]):
            result = _figures(log, params, names, master, mode, kind, controller,
                              last_live=None if live.last_applied is None else live.last_applied - t_start)
            result["loop_timing"] = timing_so_far()
            result["loop_timing"].update(_force_hold_figures(blind_ticks, n_ticks, blind_longest, max_force_age))
            if ros_commands or interactive:
                result["live_commands"] = live.summary(t_start)
            result["slave_control"] = _slave_control_text(slave_control, mode, clock.rate)
            result["tension_estimate"] = _estimate_figures(log, params, tension_source, bool(sensors), estimate)
            result.update({"model": model_note, "models": models, "model_effects": model_effects,
                           "registration": registration_note, "arms": names,
                           "master": master, "mode": mode, "object": kind,
                           "filter_delay": _filter_delays(controller), "warnings": list(warnings)})
            missed = _missed(result, params)
            trace = figures.trace_from_log(log, names, master, motion,
                                           f"{run.dir.name} ({'failed: ' + missed if missed else 'completed'})",
                                           tolerance=params.get("tolerance"), ceiling=params.get("tension_ceiling"),
                                           elements=elements)
            result["cartesian_tracking"] = figures.cartesian_tracking(trace)
            result["plot"] = str(figures.draw_force_figure(trace, Path(run.dir) / "cooperative.png"))
            result["tracking_plot"] = str(figures.draw_tracking_figure(trace, Path(run.dir) / "cooperative-tracking.png"))
            run.finish(result, status="failed" if missed else "completed", reason=missed)
        return run.result


@contextmanager
def _plot_hint(run, timing=None):
    """A loop cut short (an abort, Ctrl-C, a fault) draws no figure: say how to see it, and
    leave the loop's timing so far (`timing()`) in the run's result (result.json of an
    aborted run then says whether the machine kept time)."""
    try:
        yield
    except BaseException:
        run._write(f"the figures of this run up to where it stopped: rig plot {run.dir}\n")
        if timing is not None and run.result is None:
            try:
                run.result = {"loop_timing": timing()}
            except Exception:  # noqa: BLE001 - the abort's own reason is the one to report
                pass
        raise


class _ServoCI:
    """Sends the slaves' arm-impedance commands as the dVRK's servo_ci (rig.control.arm_impedance),
    with the tool-tip orientation held where it was when the loop started."""

    def __init__(self, rig, slaves):
        from rig.model.psm_arm_kinematics import PSMKinematics

        self.arms = {n: rig.arms[n] for n in slaves}
        self.kinematics = PSMKinematics()
        self.hold = {n: self.kinematics.forward(self.arms[n].measured_arm()[0][:6])[:3, :3] for n in slaves}

    def send(self, n: str, cmd, t: float, rec) -> None:
        from rig.control.arm_impedance import servo_ci_goal

        arm = self.arms[n]
        q = arm.measured_arm()[0][:6]
        g = servo_ci_goal(self.kinematics, q, cmd.target, cmd.velocity, cmd.u, cmd.stiffness, cmd.damping,
                          cmd.feedforward, orientation=self.hold[n])
        arm.servo_ci(g.position, g.orientation, g.stiffness, g.damping, g.bias,
                     torque_stiffness=g.torque_stiffness, torque_damping=g.torque_damping, torque_bias=g.torque_bias,
                     force_orientation=g.force_orientation)
        rec.pose(f"/{n}/servo_ci/goal", t, g.position, (0.0, 0.0, 0.0, 1.0))
        rec.wrench(f"/{n}/servo_ci/bias", t, g.force_orientation @ g.bias)


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


def _check_stale_tension(sensors, age: float, timeout: float, loop_limit: float, rate: float, setting: str) -> None:
    """The newest tension at the loop is `age` s old, beyond the stale `timeout`: end the
    run if the cell fell silent (its driver saw no sample for longer than `timeout`), or
    if samples have not reached the loop for longer than `loop_limit` while the cell
    still streamed (this process held off the CPU); else keep holding."""
    from rig.faults import silence_text, starved_text

    silent = max(s.stream_age() for s in sensors)
    if silent <= timeout and age <= loop_limit:
        return
    cells = ", ".join(str(getattr(s, "name", None) or f"element {k}") for k, s in enumerate(sensors))
    if silent > timeout:
        raise AbortRun(f"load cell stale: {silence_text(silent, rate, 'sample')}, beyond the stale timeout "
                       f"{1000 * timeout:.0f} ms ({setting}). " + starved_text(
                           setting, f"the cell{'s' if len(sensors) > 1 else ''} ({cells}) are plugged in and powered "
                           "(or `rig sim` runs)", "check the cable and power"))
    raise AbortRun(f"load cell stale: no sample reached the control loop for {1000 * age:.0f} ms "
                   f"(limit {1000 * loop_limit:.0f} ms) while the cell{'s' if len(sensors) > 1 else ''} "
                   f"({cells}) still streamed at {rate:g} Hz: this process was held off the CPU, the machine is too "
                   f"busy for the loop (free a CPU or raise {setting}; the force loop held meanwhile)")

