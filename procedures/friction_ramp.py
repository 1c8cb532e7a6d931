"""`rig friction-ramp`: stick-slip and friction-velocity tests of the insertion joint (thesis 5.6, 5.6.1).

At q1 = q2 = 0 (the tool vertical, as the thesis):

1. **Force ramps** (Figure 5.6). The arm is put in effort mode (servo_jf). Joints 1-2 are
   held by a joint PD on top of the model's gravity compensation; joint 3 gets the model's
   gravity and offset compensation g3(q) + Fo3 plus a ramp 0 -> ``max_force`` (N), first
   positive, then negative. The joint has broken away when its measured velocity stays above
   ``threshold`` for a few samples; the ramp value there is Fs+ (resp. Fs-, negative).
   So Fs+/Fs- are the forces *beyond the model's compensation* at which the joint starts
   moving, which is what the compensation of 7.5.1 adds when the joint must start. If the
   model's compensation is off by e, Fs+ = Fs + e and Fs- = -Fs + e: their half-difference
   (Fs+ - Fs-)/2 is the breakaway level Fs itself and their mean is e (both reported).
2. **Constant-velocity sweeps** (Figures 5.4/5.5): joint 3 is moved by servo_jp at several
   speeds in both directions; friction = measured effort - model rigid-body effort
   (eq. 5.49), averaged over the constant-velocity part of each pass.
3. **Fits**: viscous + Coulomb (linear LS) and Stribeck (bounded non-linear LS).
4. The results go into the model file: the latest `rig identify` model (section
   ``stick_slip``), or, without one, a friction-only model in this run's folder.

The compensation model is the latest identified model if there is one, else the nominal
PSM model with the configured gravity; the result says which. Units: N, m, m/s, s.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import click
import numpy as np

from rig.commands.exit_codes import InputError
from rig.commands.options import config_from_context
from rig.commands.parameters import Parameter
from rig.commands.procedure import procedure_command
from rig.commands.report import emit_result, exit_for_status
from rig.control.arm_command import ArmCommand, CommandKind
from rig.runs import provenance
from rig.runs.control_loop import ControlLoop
from rig.runs.run import AbortRun, Run

PROCEDURE = "friction-ramp"
JOINT = 2  # joint 3, 0-based

STEPS = ("move to q1 = q2 = 0", "force ramp, positive direction", "force ramp, negative direction",
         "constant-velocity sweeps", "fit viscous, Coulomb and Stribeck friction", "plot and write the model file")

PARAMETERS = [
    Parameter("arm", "PSM1", "", "Arm to test", type=str),
    Parameter("q3", 0.12, "m", "Insertion where the ramps start (q1 = q2 = 0)", minimum=0.03, maximum=0.21),
    Parameter("max_force", 2.0, "N", "End of each force ramp, beyond the model's compensation", minimum=0.1,
              maximum=8.0),
    Parameter("ramp_time", 4.0, "s", "Duration of a ramp from 0 to --max-force", minimum=0.5, maximum=60.0),
    Parameter("threshold", 0.005, "m/s", "Breakaway: joint-3 speed above this (the 7.5.1 deadband)",
              minimum=0.0005, maximum=0.05),
    Parameter("speeds", "0.0025,0.005,0.01,0.02,0.04,0.08", "m/s", "Constant-velocity sweep speeds", type=str),
    Parameter("stroke", 0.08, "m", "Longest constant-velocity stroke (shorter for slow speeds)", minimum=0.01,
              maximum=0.15),
    Parameter("seed", -1, "", "Seed of the simulated rig (-1: the configuration's)", type=int),
    Parameter("plots", True, "", "Write the Figure 5.5/5.6-style PNGs", type=bool),
]

#: PD holding joints 1-2 while the arm is in effort mode (N m/rad, N m s/rad): the dVRK's
#: position gains, so the hold is as stiff as the position controller's.
HOLD_KP = np.array([200.0, 200.0])
HOLD_KD = np.array([8.0, 8.0])
SETTLE = 0.3  # s at zero ramp before each ramp (lets the effort-mode switch settle)
SUSTAIN = 3   # samples above the threshold that make a breakaway


def parse_speeds(text: str) -> np.ndarray:
    try:
        v = np.array([float(x) for x in text.split(",") if x.strip()])
    except ValueError:
        v = np.zeros(0)
    if v.size < 3 or np.any(~np.isfinite(v)) or np.any(v <= 0) or np.any(v > 0.4):
        raise click.BadParameter(f"{text!r}: give at least 3 comma-separated speeds in (0, 0.4] m/s",
                                 param_hint="--speeds")
    return np.sort(v)


def compensation_model(cfg, arm: str, say=None):
    """(PSMDynamics, description, model or None): the newest identified model of this arm
    on this rig, else nominal with the configuration's gravity. Newer models that belong to
    another arm or rig are named through `say` and passed over."""
    from rig.runs import model_results
    from rig.model.psm_dynamics import PSMDynamics

    skipped: list[str] = []
    found = model_results.latest_model(with_friction_ramp=False, cfg=cfg, arm=arm, skipped=skipped)
    for line in skipped:
        (say or (lambda m: click.echo(m, err=True)))(f"rig {PROCEDURE}: {line}")
    info = {"skipped": skipped} if skipped else {}
    if found is not None and found.standard is not None:
        return found.dynamics(), {"model": str(found.path), "kind": "identified", **info}, found
    return (PSMDynamics(gravity=cfg.gravity_in_base(arm)),
            {"model": "nominal PSM parameters", "kind": "nominal", **info}, None)


def move_to(arm, q, what: str, timeout: float = 10.0) -> None:
    """move_jp and wait; not there within `timeout` s (joint 3 within 5 mm) aborts the run."""
    if arm.move_jp(q, wait=True, timeout=timeout):
        return
    now = np.asarray(arm.measured_js().position[:3], float)
    if np.any(np.abs(now - q) > np.array([0.02, 0.02, 0.005])):
        raise AbortRun(f"{arm.name} did not reach {what} {np.round(q, 4).tolist()} (rad, rad, m) within "
                       f"{timeout:g} s; it is at {np.round(now, 4).tolist()}")


def force_ramp(run, arm, clock, dyn, q_ref, direction: int, p: dict, step) -> dict:
    """One ramp (module docstring, 1). Returns the samples and the breakaway (or None).

    The run engine's control loop reads the arm, this step computes the effort (the
    compensation, the PD holding joints 1-2 and the ramp on joint 3) and the loop sends it;
    the clock ticks at the end of each period."""
    rate = clock.rate
    n_settle = int(round(SETTLE * rate))
    n_ramp = int(round(p["ramp_time"] * rate))
    slope = p["max_force"] / p["ramp_time"]
    rows = []

    def ramp_step(tick) -> dict:
        js = tick.js[arm.name]
        q, dq = np.asarray(js.position[:3], float), np.asarray(js.velocity[:3], float)
        ramp = direction * slope * max(tick.k - n_settle, 0) / rate
        comp = dyn.gravity_torque(q) + dyn.Fo
        tau = comp.copy()
        tau[:2] += HOLD_KP * (q_ref[:2] - q[:2]) - HOLD_KD * dq[:2]
        tau[JOINT] += ramp
        tick.command_t = js.t
        rows.append((js.t, ramp, comp[JOINT], q[JOINT], dq[JOINT], js.effort[JOINT]))
        k_b = _detect(np.array(rows), p["threshold"], direction)
        # far enough: the breakaway is long past (and the stroke is finite); or 40 ms of
        # motion after the breakaway, which shows it in the plot
        tick.last = abs(q[JOINT] - q_ref[JOINT]) > 0.03 or (k_b is not None and len(rows) - k_b > 40)
        return {arm.name: ArmCommand(CommandKind.EFFORT, effort=tau)}

    ControlLoop(run, clock, {arm.name: arm}).run(ramp_step, n_settle + n_ramp, progress=step, every=50,
                                                 tick_last=True)
    arm.hold()
    arr = np.array(rows)
    k_b = _detect(arr, p["threshold"], direction)
    return {"t": arr[:, 0], "ramp": arr[:, 1], "compensation": arr[:, 2], "q": arr[:, 3], "dq": arr[:, 4],
            "effort": arr[:, 5], "index": k_b, "force": None if k_b is None else float(arr[k_b, 1]),
            "settle_samples": n_settle}


def _detect(arr, threshold, direction):
    from calibration.friction_fit import breakaway

    return breakaway(arr[:, 1], arr[:, 4], threshold, SUSTAIN, direction)


def sweep_profile(q_start: float, distance: float, speed: float, rate: float, accel: float = 0.5):
    """Positions of a trapezoidal out-and-back stroke (m) at ``rate`` Hz and the mask of its
    constant-velocity samples (+1 out, -1 back, 0 otherwise)."""
    t_acc = speed / accel
    d_acc = 0.5 * accel * t_acc ** 2
    if 2 * d_acc > distance:  # a stroke too short to reach the speed: accelerate harder
        accel = speed ** 2 / (0.5 * distance)
        t_acc = speed / accel
        d_acc = 0.5 * accel * t_acc ** 2
    t_const = (distance - 2 * d_acc) / speed
    T = 2 * t_acc + t_const
    t = np.arange(int(np.ceil(T * rate)) + 1) / rate
    s = np.where(t < t_acc, 0.5 * accel * t ** 2,
                 np.where(t < t_acc + t_const, d_acc + speed * (t - t_acc),
                          distance - 0.5 * accel * np.clip(T - t, 0, None) ** 2))
    s = np.minimum(s, distance)
    # constant-velocity part, without its first and last 15 % (tracking transients)
    lo, hi = t_acc + 0.15 * t_const, t_acc + 0.85 * t_const
    const = (t >= lo) & (t <= hi)
    q = np.concatenate([q_start + s, q_start + distance - s])
    sign = np.concatenate([np.where(const, 1, 0), np.where(const, -1, 0)])
    return q, sign


def constant_velocity_sweeps(run, arm, clock, dyn, q_ref, speeds, p: dict, step) -> dict:
    """Module docstring, 2. Returns per-pass means and every constant-velocity sample."""
    name = arm.name
    rate = clock.rate
    passes, samples = [], []
    for i, v in enumerate(speeds):
        # A stroke of at least 2.5 s of constant velocity (or the longest allowed).
        distance = float(np.clip(v * 2.5 + v * v / 0.5, 0.01, p["stroke"]))
        q_start = q_ref[JOINT] - 0.5 * distance
        if not arm.move_jp(np.array([q_ref[0], q_ref[1], q_start]), wait=True, timeout=10.0):
            q = np.asarray(arm.measured_js().position[:3], float)
            if abs(q[JOINT] - q_start) > 0.005:
                raise AbortRun(f"{name} did not reach the start of the {v} m/s stroke")
        qs, sign = sweep_profile(q_start, distance, v, rate)
        vals = []

        def command(k: int) -> dict:
            return {name: ArmCommand(CommandKind.POSITION, q=np.array([q_ref[0], q_ref[1], qs[k]]))}

        def sweep_step(tick) -> dict | None:
            # the set-point of period k was sent at its start: the arm's answer to it
            k, js = tick.k, tick.js[name]
            if sign[k] != 0:
                q, dq = np.asarray(js.position[:3], float), np.asarray(js.velocity[:3], float)
                # eq. 5.49: the measured effort minus the model's rigid-body effort
                rigid = dyn.inverse_dynamics(q, dq, np.zeros(3), friction=False)[JOINT]
                f = float(js.effort[JOINT] - rigid)
                vals.append((sign[k], dq[JOINT], f))
                samples.append((sign[k] * v, dq[JOINT], f))
            return command(k + 1) if k + 1 < len(qs) else None

        loop = ControlLoop(run, clock, {name: arm})
        loop.send(command(0), clock.now())
        loop.run(sweep_step, len(qs))
        vals = np.array(vals)
        for s in (1, -1):
            sel = vals[vals[:, 0] == s]
            passes.append({"speed": float(s * v), "velocity_mean": float(sel[:, 1].mean()),
                           "friction_mean": float(sel[:, 2].mean()), "friction_std": float(sel[:, 2].std()),
                           "n": int(len(sel))})
        step.update(i + 1)
    move_to(arm, q_ref, "the ramps' start")
    return {"passes": passes, "samples": np.array(samples)}


def figures(ramps: dict, sweeps: dict, fits: dict, run_dir) -> dict:
    """Figures 5.6 (the force ramps) and 5.5 (friction against velocity) as PNGs in
    `run_dir`; their paths by figure."""
    paths = {"figure_5_6": str(Path(run_dir) / "figure_5_6_force_ramp.png"),
             "figure_5_5": str(Path(run_dir) / "figure_5_5_friction_velocity.png")}
    _ramps_figure(ramps, paths["figure_5_6"])
    _friction_figure(sweeps, fits, paths["figure_5_5"])
    return paths


def _ramps_figure(ramps: dict, path) -> None:
    """Figure 5.6 style: applied force beyond compensation vs velocity (and vs time)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 2, figsize=(12, 4.5))
    for label, r, c in (("positive ramp", ramps["pos"], "tab:blue"), ("negative ramp", ramps["neg"], "tab:red")):
        ax[0].plot(r["dq"], r["ramp"], color=c, lw=0.8, label=label)
        ax[1].plot(r["t"] - r["t"][0], r["ramp"], color=c, lw=0.8, label=f"{label}: force")
        ax[1].plot(r["t"] - r["t"][0], r["dq"] * 100, color=c, lw=0.6, ls=":", label=f"{label}: velocity x100")
        if r["index"] is not None:
            ax[0].plot(r["dq"][r["index"]], r["ramp"][r["index"]], "ko")
            ax[1].axvline(r["t"][r["index"]] - r["t"][0], color=c, lw=0.6, ls="--")
    ax[0].set_xlabel("joint 3 velocity [m/s]")
    ax[0].set_ylabel("applied force beyond compensation [N]")
    ax[0].set_title("Force ramp (Figure 5.6 style); dots: breakaway")
    ax[1].set_xlabel("time from ramp start [s]")
    ax[1].set_ylabel("N ; m/s x 100")
    for a in ax:
        a.legend(fontsize=7)
        a.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _friction_figure(sweeps: dict, fits: dict, path) -> None:
    """Figure 5.5 style: friction force vs velocity, pass means and the fits."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from calibration.friction_fit import stribeck_curve

    fig, ax = plt.subplots(figsize=(8, 5))
    s = sweeps["samples"]
    ax.plot(s[:, 1], s[:, 2], ".", ms=1, color="0.7", label="samples (constant-velocity parts)")
    pv = np.array([p["velocity_mean"] for p in sweeps["passes"]])
    pf = np.array([p["friction_mean"] for p in sweeps["passes"]])
    ax.plot(pv, pf, "ko", label="pass means")
    v = np.linspace(min(pv.min(), -1e-3), max(pv.max(), 1e-3), 600)
    vc = fits["viscous_coulomb"]
    ax.plot(v, vc["Fo"] + vc["Fv"] * v + vc["Fc"] * np.sign(v), "b--", label="viscous + Coulomb")
    st = fits.get("stribeck")
    if st:
        ax.plot(v, stribeck_curve([st["Fo"], st["Fv"], st["Fc"], st["Fs"], st["vs"]], v), "r-",
                label="Stribeck" + ("" if st["success"] else " (not resolved)"))
    ax.set_xlabel("joint 3 velocity [m/s]")
    ax.set_ylabel("friction force (eq. 5.49) [N]")
    ax.set_title("Constant-velocity test of joint 3 (Figure 5.5 style)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def run(cfg, parameters: dict, run_root=None, progress: bool = True) -> dict:
    """The procedure as a function (CLI, tests and bench). Returns the result."""
    from rig.devices.factory import open_rig

    arm_name = parameters["arm"]
    if arm_name not in cfg.arms:
        raise InputError(f"no arm {arm_name!r} in {cfg.source}; arms: {', '.join(cfg.arms)}")
    speeds = parse_speeds(parameters["speeds"])
    seed = None if parameters["seed"] < 0 else parameters["seed"]
    dyn, comp_info, prior = compensation_model(cfg, arm_name)
    # the force is applied and read through the arm's own effort: no load cell, no mocap
    dev = open_rig(cfg, [arm_name], seed=seed, uses=())
    try:
        with Run(PROCEDURE, parameters=parameters, config=cfg.snapshot(), seed=seed, steps=list(STEPS),
                 root=run_root, progress=progress) as run:
            clock = dev.clock
            dev.operator.detach_object()  # joint 3 alone: nothing may pull on the tool
            arm = run.claim(dev.arms[arm_name])
            q_ref = np.array([0.0, 0.0, parameters["q3"]])
            with run.step(STEPS[0]):
                arm.power_on()
                move_to(arm, q_ref, "the ramps' start", timeout=15.0)
                q_ref = np.array([0.0, 0.0, float(arm.measured_js().position[JOINT])])
            ramps = {}
            n_total = int(round((SETTLE + parameters["ramp_time"]) * clock.rate))
            for key, direction, step_name in (("pos", 1, STEPS[1]), ("neg", -1, STEPS[2])):
                with run.step(step_name, total=n_total) as st:
                    move_to(arm, q_ref, "the ramps' start")
                    ramps[key] = force_ramp(run, arm, clock, dyn, q_ref, direction, parameters, st)
                    move_to(arm, q_ref, "the ramps' start")
            with run.step(STEPS[3], total=len(speeds)) as st:
                sweeps = constant_velocity_sweeps(run, arm, clock, dyn, q_ref, speeds, parameters, st)
            with run.step(STEPS[4]):
                fits = _fits(sweeps, ramps)
                fs_pos, fs_neg = ramps["pos"]["force"], ramps["neg"]["force"]
            with run.step(STEPS[5]):
                plots = figures(ramps, sweeps, fits, run.dir) if parameters["plots"] else {}
                if fs_pos is None or fs_neg is None:
                    missing = "positive" if fs_pos is None else "negative"
                    raise AbortRun(f"joint 3 did not break away in the {missing} direction up to "
                                   f"{parameters['max_force']} N beyond the compensation: raise --max-force")
                result = _result(run, cfg, arm_name, q_ref, ramps, sweeps, fits, plots, parameters, dyn, comp_info,
                                 prior)
                if dev.world is not None:
                    result["truth"] = simulated_truth(dev.world, arm_name, dyn, ramps)
                # a breakaway is a force against the motion: up for the positive ramp, down
                # for the negative; anything else is a measurement that went wrong
                missed = None if fs_pos > 0 > fs_neg else (
                    f"breakaway forces Fs+ {fs_pos:.3f} N, Fs- {fs_neg:.3f} N do not oppose their ramps "
                    "(expected Fs+ > 0 > Fs-)")
                run.finish(result, "failed" if missed else "completed", missed)
    finally:
        dev.close()
    return run.result


def _fits(sweeps: dict, ramps: dict) -> dict:
    """Viscous + Coulomb and Stribeck fits of the sweeps' friction (a Stribeck fit that
    fails is said, under "stribeck_error")."""
    from calibration.friction_fit import FrictionFitError, fit_stribeck, fit_viscous_coulomb

    pv = np.array([p["velocity_mean"] for p in sweeps["passes"]])
    pf = np.array([p["friction_mean"] for p in sweeps["passes"]])
    fits = {"viscous_coulomb": fit_viscous_coulomb(pv, pf)}
    fs_pos, fs_neg = ramps["pos"]["force"], ramps["neg"]["force"]
    guess = None if fs_pos is None or fs_neg is None else 0.5 * (fs_pos - fs_neg)
    try:
        fits["stribeck"] = fit_stribeck(pv, pf, guess)
    except FrictionFitError as exc:
        fits["stribeck"] = None
        fits["stribeck_error"] = str(exc)
    return fits


def _result(run, cfg, arm_name: str, q_ref, ramps: dict, sweeps: dict, fits: dict, plots: dict, parameters: dict,
            dyn, comp_info: dict, prior) -> dict:
    """The stick-slip terms and the model file they go into (written to the run folder),
    and the result document."""
    from rig.model import model_file
    from rig.runs import model_results

    fs_pos, fs_neg = ramps["pos"]["force"], ramps["neg"]["force"]
    comp0 = float(ramps["pos"]["compensation"][0])
    stick = model_file.StickSlip(
        joint=3, fs_pos=fs_pos, fs_neg=fs_neg,
        # a Stribeck fit that did not converge is reported, never compensated with
        # (StickSlip takes the Stribeck curve over the viscous + Coulomb one)
        fits={k: v for k, v in fits.items()
              if k in ("viscous_coulomb", "stribeck") and v and (k != "stribeck" or v.get("success"))},
        deadbands={"velocity": parameters["threshold"], "position": 0.0003},
        provenance=model_results.provenance(f"{run.dir / 'run.mcap'} ({arm_name})", run.dir,
                                         {"procedure": PROCEDURE, "compensation": comp_info}))
    (run.dir / model_file.STICK_SLIP_FILENAME).write_text(json.dumps(stick.to_dict(), indent=2) + "\n")
    origin = provenance.live(cfg, [arm_name], run.dir)
    own = run.dir / model_file.MODEL_FILENAME
    if prior is not None:
        written = model_file.with_stick_slip(own, prior, stick, {**stick.provenance, **origin}).path
        where = f"the identified model {prior.path} plus this run's stick-slip terms"
    else:
        written = model_file.friction_only_model(own, stick, dyn.gravity, dyn.slope,
                                                 {**stick.provenance, **origin})
        where = ("friction terms only: no identified model of this arm yet; a later `rig identify` "
                 "takes these terms")
    result = {
        "arm": arm_name, "joint": 3, "q_ref": q_ref.tolist(),
        "Fs_pos": fs_pos, "Fs_neg": fs_neg,
        "Fs_symmetric": 0.5 * (fs_pos - fs_neg), "compensation_bias": 0.5 * (fs_pos + fs_neg),
        "compensation": {**comp_info, "joint3_at_start": comp0,
                         "note": "ramps are applied on top of g3(q) + Fo3 of this model"},
        "breakaway_position": {k: float(r["q"][r["index"]]) for k, r in ramps.items()},
        "fits": fits, "passes": sweeps["passes"], "plots": plots,
        "model": str(written), "model_kind": where, "stick_slip": stick.to_dict(),
        "provenance": origin,
        "summary": {"Fs_pos": fs_pos, "Fs_neg": fs_neg, "Fs_symmetric": 0.5 * (fs_pos - fs_neg),
                    "model": str(written)},
    }
    return result


def simulated_truth(world, arm_name: str, dyn, ramps: dict) -> dict:
    """What the simulated joint 3 should give: with true load L (gravity + offset + hidden
    constant load) and compensation C, it breaks away at ramp = +Fs + (L - C) and -Fs + (L - C)."""
    from rig.model.psm_dynamics import PSMDynamics

    a = world.arms[arm_name]
    i = a.index * 3 + JOINT
    fs = float(world.Fs[i])
    asym = float(world.asym[i])
    true = PSMDynamics(a.params, gravity=dyn.gravity)
    out = {"Fs": fs}
    for key, sgn in (("pos", 1), ("neg", -1)):
        r = ramps[key]
        k = r["index"] if r["index"] is not None else 0
        q = np.array([0.0, 0.0, r["q"][k]])
        load = float(true.gravity_torque(q)[JOINT] + world.Fo[i] + world.offset[i])
        comp = float(dyn.gravity_torque(q)[JOINT] + dyn.Fo[JOINT])
        level = fs + (0.5 * asym if sgn > 0 else -0.5 * asym)
        out[f"expected_Fs_{key}"] = sgn * level + (load - comp)
        out[f"load_minus_compensation_{key}"] = load - comp
    return out


def report(r: dict) -> str:
    lines = [f"friction-ramp: {r.get('status', '')}",
             f"joint 3 breakaway beyond the compensation ({r['compensation']['model']}): "
             f"Fs+ = {r['Fs_pos']:+.3f} N, Fs- = {r['Fs_neg']:+.3f} N",
             f"  breakaway level (Fs+ - Fs-)/2 = {r['Fs_symmetric']:.3f} N, compensation bias (Fs+ + Fs-)/2 = "
             f"{r['compensation_bias']:+.3f} N"]
    vc = r["fits"]["viscous_coulomb"]
    lines.append(f"viscous + Coulomb: Fo {vc['Fo']:+.3f} N, Fv {vc['Fv']:.3f} N s/m, Fc {vc['Fc']:.3f} N "
                 f"(rms {vc['rms']:.3f} N)")
    st = r["fits"].get("stribeck")
    if st and st["success"]:
        vs = ("vs not determined by the swept speeds" if (st.get("std") or {}).get("vs", 0.0) is None
              else f"vs {st['vs'] * 1e3:.2f} mm/s")
        lines.append(f"Stribeck: Fo {st['Fo']:+.3f} N, Fv {st['Fv']:.3f} N s/m, Fc {st['Fc']:.3f} N, Fs {st['Fs']:.3f} N, "
                     f"{vs} (rms {st['rms']:.3f} N)")
    elif st:
        # the run did its job (the breakaway forces and the viscous + Coulomb fit); the
        # swept speeds only did not pin the Stribeck curve down
        lines.append(f"Stribeck curve: not determined by the swept speeds (its fit did not converge; rms "
                     f"{st['rms']:.3f} N): the viscous + Coulomb fit above is the one the model uses; sweep "
                     "slower speeds (--speeds) to resolve it")
    if r.get("truth"):
        t = r["truth"]
        lines.append(f"simulated rig truth: Fs = {t['Fs']:.3f} N; expected Fs+ {t['expected_Fs_pos']:+.3f} N, "
                     f"Fs- {t['expected_Fs_neg']:+.3f} N")
    lines.append(f"model file written: {r['model']} ({r['model_kind']})")
    lines.append(f"run folder: {r.get('run_dir')}")
    return "\n".join(lines)


@procedure_command(PROCEDURE, STEPS, PARAMETERS)
def command(ctx, parameters, as_json: bool) -> None:
    """Stick-slip force ramps and constant-velocity friction sweeps of joint 3 (thesis 5.6).

    Finds the breakaway forces Fs+ and Fs- (N, beyond the model's gravity and offset
    compensation), fits viscous, Coulomb and Stribeck friction, and writes them into the
    latest identified model file for the compensation of 7.5.1. SI units.
    """
    from calibration.friction_fit import FrictionFitError
    from rig.model.model_file import ModelFileError

    try:
        result = run(config_from_context(ctx), parameters)
    except (FrictionFitError, ModelFileError) as exc:
        where = f" (run folder {exc.run_dir})" if getattr(exc, "run_dir", None) else ""
        click.echo(f"rig {PROCEDURE}: {exc}{where}", err=True)
        sys.exit(1)
    emit_result(result, as_json, report(result))
    exit_for_status(PROCEDURE, result)
