"""`rig selftest`: a short run of the simulated rig that shows the kernel works.

The arms first hang for PRE_LIFT seconds under the joint PIDs holding q0; then every
simulated arm lifts its tool tip by 10 mm (a step of the joint PID to the inverse
kinematics target of the tip where it hangs, plus LIFT). Every tip moves by the same
world vector, so the object between the tips keeps its length. Checks, each with its bound:

* per arm, settled: every joint error within TOLERANCE at the end, and inside it for at
  least one period of the slowest joint loop before the end;
* per object element, the tension change the lift caused: no more than the stiffness times
  the tip motion along the element that the joint tolerances allow;
* the simulated rig runs at least as fast as real time.

A check that fails makes the status "failed" and the exit code EXIT_MISSED (4).
"""

from __future__ import annotations

import sys
import time

import click
import numpy as np

from rig.commands.abort import exit_on_abort
from rig.commands.exit_codes import EXIT_MISSED, InputError
from rig.commands.options import json_option
from rig.sealed_json import result_json

LIFT = np.array([0.0, 0.0, 0.010])          # world-frame tip step, m
# Settled: every joint within this of its target (rad, rad, m). 0.5 mm on the insertion is
# 5 % of the lift; 1 mrad of yaw or pitch moves the tip ~0.1 mm at the insertion depths of q0.
TOLERANCE = np.array([1e-3, 1e-3, 5e-4])
PRE_LIFT = 0.5                              # s the arms hang under their PIDs before the step
JOINT_UNITS = (("mrad", 1e3), ("mrad", 1e3), ("mm", 1e3))


def _check(name: str, passed: bool, shown: str, bound_text: str, detail: str, missed: str,
           **figures) -> dict:
    """One check: `shown` is the measured figure with units, `bound_text` the bound with
    where it comes from, `missed` what the error line says if it fails; `figures` (value,
    bound, units, ...) go to the JSON as numbers."""
    out = {"name": name, "passed": bool(passed), **figures, "shown": shown, "bound_text": bound_text,
           "detail": detail}
    if not passed:
        out["missed"] = missed
    return out


def tip_at(world, name: str, q: np.ndarray) -> np.ndarray:
    """World position (m) of an arm's tool tip at joints q."""
    from rig.model import psm_kinematics as K

    rcm = world.arms[name].rcm_world
    return rcm[:3, :3] @ K.tip_in_rcm(q) + rcm[:3, 3]


def _joints(v, signed: bool = True) -> str:
    fmt = "{:+.3g}" if signed else "{:.3g}"
    return ", ".join(f"q{j + 1} {fmt.format(x * scale)} {unit}"
                     for j, (x, (unit, scale)) in enumerate(zip(v, JOINT_UNITS)))


def loop_period(world, name: str, q: np.ndarray) -> float:
    """Period (s) of the slowest joint loop of an arm at q: 2 pi sqrt(M_jj / kp_j).

    The PID's proportional gain against the joint's inertia (mass-matrix diagonal, rotor
    inertia included) sets how fast an error swings through the tolerance band; an arm that
    stayed in the band this long is settled, not passing through it."""
    from rig.model.psm_dynamics import PSMDynamics

    arm = world.arms[name]
    inertia = np.diag(PSMDynamics(arm.params).mass_matrix(q))
    return float(np.max(2 * np.pi * np.sqrt(inertia / arm.spec.pid.kp)))


def steady_load(world, name: str, q: np.ndarray) -> np.ndarray:
    """Joint loads (N m, N m, N) an arm's PID must hold at rest at q, as the simulated plant
    applies them: gravity (the world's, in the arm's frame 0), the drives' constant friction
    offset Fo (thesis eq. 4.16) and any configured torque offset or joint spring. Coulomb
    friction can hold up to Fc of it either way, so this is the centre of a band."""
    from rig.model.psm_dynamics import PSMDynamics

    arm = world.arms[name]
    gravity = np.asarray(arm.spec.base, float)[:3, :3].T @ np.asarray(world.model.gravity.linear, float)
    e = arm.spec.effects
    return (PSMDynamics(arm.params, gravity=gravity).gravity_torque(q) + arm.params.drive.Fo
            + np.asarray(e.torque_offset, float) + np.asarray(e.spring, float) * (q - np.asarray(e.spring_rest, float)))


def tip_jacobian_world(world, name: str, q: np.ndarray) -> np.ndarray:
    from rig.model import psm_kinematics as K

    return world.arms[name].rcm_world[:3, :3] @ K.tip_jacobian_rcm(q)


def run(cfg, duration: float, seed: int | None = None) -> dict:
    """Run the self-test on the simulated arms of `cfg`; the result with its checks."""
    from rig.model import psm_kinematics as K
    from rig.sim.world import world_from_config

    if not any(a["driver"] == "sim" for a in cfg.arms.values()):
        raise InputError(f"{cfg.source}: no simulated arm to test (no arm has driver 'sim'); "
                                   f"the self-test runs the simulated rig only")
    world = world_from_config(cfg, seed=seed)
    n_steps = int(round(duration / world.dt))
    if n_steps < 1:
        raise InputError(f"--duration {duration:g} s is less than one step of the rig "
                                   f"({world.dt:g} s at rig.rate {1 / world.dt:g} Hz)")
    # The rate check measures the headroom over real time: pacing to the wall clock (a
    # `rig sim` setting) would hide it.
    world.pace = False
    elements = world.object_elements
    obj = world.object
    q0 = {n: world.true_state(n)[0] for n in world.names}
    distance = {e: lambda a=e[0], b=e[1]: float(np.linalg.norm(world.tip_world(b) - world.tip_world(a)))
                for e in elements}
    d_q0 = {e: distance[e]() for e in elements}

    world.advance(PRE_LIFT)
    q_lift = {n: world.true_state(n)[0] for n in world.names}
    d_lift = {e: distance[e]() for e in elements}
    t_lift = {e: world.tension(i) for i, e in enumerate(elements)}
    targets = {}
    for n in world.names:
        tip = world.tip_world(n) + LIFT
        try:
            targets[n] = K.ik_rcm((np.linalg.inv(world.arms[n].rcm_world) @ np.append(tip, 1.0))[:3])
        except K.IKError as exc:
            raise InputError(f"{cfg.source}: {n} cannot lift its tip {LIFT[2] * 1000:.0f} mm "
                                       f"from where it hangs ({_joints(q_lift[n])}): {exc}") from None
        world.servo_jp(n, targets[n])

    errors = {n: np.empty((n_steps, 3)) for n in world.names}
    tension = np.empty((n_steps, len(elements)))
    wall = time.perf_counter()
    for k in range(n_steps):
        world.step()
        for n in world.names:
            errors[n][k] = world.true_state(n)[0] - targets[n]
        for i in range(len(elements)):
            tension[k, i] = world.tension(i)
    wall = time.perf_counter() - wall

    checks, arms = _arm_checks(world, errors, targets, duration, q0, q_lift)
    tension_checks, tensions = _tension_checks(world, tension, targets, t_lift, d_q0, d_lift, distance)
    checks += tension_checks

    factor = n_steps * world.dt / wall
    # Slower than real time the simulated rig cannot serve its devices at the rig rate.
    checks.append(_check("rate", factor >= 1.0, f"{factor:.0f}x real time", ">= 1x (slower, `rig sim` "
                         "could not keep its streams at the rig rate)",
                         f"{n_steps} steps at {1 / world.dt:g} Hz in {wall:.3f} s of wall time",
                         f"{factor:.2f}x real time, below 1x",
                         value=factor, bound=1.0, units="x real time"))

    failed = [c for c in checks if not c["passed"]]
    result = {
        "status": "failed" if failed else "completed",
        "checks": checks,
        "arms": arms,
        "tension": tensions,
        "lift": LIFT.tolist(),
        "pre_lift": PRE_LIFT,
        "tolerance": TOLERANCE.tolist(),
        "simulated_time": duration,
        "real_time_factor": factor,
        "config": cfg.source,
    }
    if failed:
        result["error"] = "; ".join(f"{c['name']}: {c['missed']}" for c in failed)
    return result


def _arm_checks(world, errors: dict, targets: dict, duration: float, q0: dict, q_lift: dict):
    """Each arm settled at its lift target within TOLERANCE: (checks, per-arm figures)."""
    checks, arms = [], {}
    for n, e in errors.items():
        outside = np.nonzero((np.abs(e) > TOLERANCE).any(axis=1))[0]
        settle = float((outside[-1] + 1) * world.dt) if len(outside) else 0.0
        hold = loop_period(world, n, targets[n])
        # settled by `duration - hold` at the latest: in the band for one loop period at the end
        bound = duration - hold
        final = e[-1]
        within = bool(np.all(np.abs(final) <= TOLERANCE))
        passed = within and settle <= bound
        pid = world.arms[n].spec.pid
        integral = world.integral[world.arms[n].sl]
        arms[n] = {"settling_time": settle, "final_error": final.tolist(), "loop_period": hold,
                   "load_at_q0": steady_load(world, n, q0[n]).tolist(),
                   "sag_before_lift": (q_lift[n] - q0[n]).tolist(),
                   # the slow mode of a PID taking a steady load: error ~ exp(-t ki / kp)
                   "integral_time": float(np.max(pid.kp / pid.ki)),
                   "integral_final": integral.tolist(), "integral_limit": pid.integral_limit.tolist(),
                   # joints (1-3) whose integral term is clamped: the P term holds the rest
                   # of the load with a steady error (load - limit) / kp
                   "integral_at_limit": [j + 1 for j in range(3)
                                         if abs(integral[j]) >= pid.integral_limit[j] * (1 - 1e-9)]}
        tol = _joints(TOLERANCE, signed=False)
        checks.append(_check(
            f"{n} settled", passed, f"{settle:.3f} s" if within else "not settled",
            f"<= {bound:.3f} s ({duration:g} s less one joint-loop period, {hold:.3f} s)",
            f"final error {_joints(final)}: {'within' if within else 'OUTSIDE'} ±({tol})"
            + ("; --duration is shorter than the loop period" if bound <= 0 else ""),
            f"final error outside ±({tol})" if not within
            else f"in the band only from {settle:.3f} s, after {bound:.3f} s",
            value=settle if within else None, bound=bound, units="s", final_error=final.tolist(),
            tolerance=TOLERANCE.tolist()))
    return checks, arms


def _tension_checks(world, tension, targets: dict, t_lift: dict, d_q0: dict, d_lift: dict, distance: dict):
    """Each element's tension changed by the lift no more than the joint tolerances allow:
    (checks, per-element figures)."""
    elements, obj = world.object_elements, world.object
    checks = []
    tensions = {}
    for i, (a, b) in enumerate(elements):
        name = f"{a}-{b}"
        t_end = float(tension[-1, i])
        change = t_end - t_lift[(a, b)]
        # Tip motion along the element that joint errors within TOLERANCE allow, at the
        # targets: sum over both arms and joints of |u . dtip/dq_j| * tolerance_j. The lift
        # itself moves both tips by LIFT and leaves the length alone, so a settled rig changes
        # the tension by at most stiffness times this (a string's slack only lowers it). The
        # damper's share (damping x relative tip speed) is left out: it vanishes at rest.
        along = tip_at(world, b, targets[b]) - tip_at(world, a, targets[a])
        u = along / np.linalg.norm(along)
        allowed = sum(float(np.abs(u @ tip_jacobian_world(world, arm, targets[arm])) @ TOLERANCE) for arm in (a, b))
        bound = obj.stiffness * allowed
        rest = obj.rest_length if obj.rest_length is not None else d_q0[(a, b)]
        tensions[name] = {
            "before_lift": t_lift[(a, b)], "final": t_end, "change": change, "bound": bound,
            "min": float(tension[:, i].min()), "max": float(tension[:, i].max()),
            "rest_length": rest, "distance_at_q0": d_q0[(a, b)], "distance_before_lift": d_lift[(a, b)],
            "distance_final": distance[(a, b)](), "stiffness": obj.stiffness, "kind": obj.kind,
        }
        checks.append(_check(
            f"{name} tension change", abs(change) <= bound, f"{change:+.3f} N",
            f"within ±{bound:.3f} N ({obj.stiffness:g} N/m x {allowed * 1000:.3f} mm of tip motion "
            f"the joint tolerances allow)",
            f"{t_lift[(a, b)]:+.3f} N before the lift, {t_end:+.3f} N after; "
            f"{tension[:, i].min():+.3f} to {tension[:, i].max():+.3f} N while moving",
            f"the lift changed it by {change:+.3f} N, beyond ±{bound:.3f} N",
            value=change, bound=bound, units="N"))
    return checks, tensions


def _efforts(v) -> str:
    return ", ".join(f"q{j + 1} {x:+.3g} {'N' if j == 2 else 'N m'}" for j, x in enumerate(v))


def explain_tension(result: dict) -> list[str]:
    """Why the object reads what it reads (report lines): it is compressed or stretched
    before the lift already, and the lift's targets start from there.

    Tension = stiffness x (tip distance - rest length) + damping x its rate. Each joint
    carries a steady load (steady_load) that its PID's P term answers with a deflection of
    load / kp until the integral term takes it over, with the time constant kp / ki; the
    arms sag in the PRE_LIFT s before the lift, and an integral term clamped at its limit
    leaves the rest of the deflection for good."""
    tensions, arms = result["tension"], result["arms"]
    if not tensions:
        return []
    holding = sorted({n for name in tensions for n in name.split("-")}, key=list(arms).index)
    integral = max(arms[n]["integral_time"] for n in holding)
    lines = ["  why the object reads what it reads:",
             "    at q0 every joint carries a steady load its PID must hold (gravity, the drives' constant "
             "friction offset Fo, any configured torque offset):"]
    lines += [f"      {n} {_efforts(arms[n]['load_at_q0'])}" for n in holding]
    lines += [f"    the integral terms take it over with a time constant kp/ki = {integral:.3g} s, so in the "
              f"{PRE_LIFT:g} s before the lift the arms sag:"]
    lines += [f"      {n} moved {_joints(arms[n]['sag_before_lift'])}" for n in holding]
    for name, t in tensions.items():
        k = t["stiffness"]
        preload = k * (t["distance_at_q0"] - t["rest_length"])
        sag = k * (t["distance_before_lift"] - t["distance_at_q0"])
        damper = t["before_lift"] - k * (t["distance_before_lift"] - t["rest_length"])
        state = ("compressed: it pushes the tips apart" if t["before_lift"] < 0 else
                 "stretched: it pulls the tips together" if t["before_lift"] > 0 else "slack")
        moved = t["distance_before_lift"] - t["distance_at_q0"]
        lines += [f"    {name} reads {t['before_lift']:+.3f} N at the lift ({state}) = {k:g} N/m x "
                  f"({t['distance_before_lift'] * 1000:.3f} mm between the tips - {t['rest_length'] * 1000:.3f} mm "
                  f"rest length) {damper:+.3f} N from the damper:",
                  f"      at q0 the tips were {t['distance_at_q0'] * 1000:.3f} mm apart ({preload:+.3f} N); "
                  f"the sag moved them {abs(moved) * 1000:.3f} mm {'closer' if moved < 0 else 'apart'} ({sag:+.3f} N)"]
        if t["kind"] == "string":
            lines.append("      (a string reads 0 N, slack, when shorter than its rest length)")
    lines.append("    The lift starts from the sagged pose and moves every tip alike, so that load stays; "
                 "the check is on the change the lift causes.")
    clamped = [(n, j) for n in holding for j in arms[n]["integral_at_limit"]]
    if clamped:
        lines.append("    At the end these integral terms sit at their limit, so the P term holds the rest of the "
                     "load with a steady error (load - limit) / kp:")
        lines += [f"      {n} q{j}: limit {arms[n]['integral_limit'][j - 1]:g} {'N' if j == 3 else 'N m'}, "
                  f"error {_joints(arms[n]['final_error']).split(', ')[j - 1].split(' ', 1)[1]}"
                  for n, j in clamped]
    for name, t in tensions.items():
        end = t["distance_final"] - t["distance_before_lift"]
        lines.append(f"    {name}: the joint errors left at the end (final error above) put the tips "
                     f"{abs(end) * 1000:.3g} mm {'closer' if end < 0 else 'further apart'} than at the lift: "
                     f"{t['change']:+.3f} N.")
    return lines


def report(result: dict) -> str:
    lines = [f"simulated rig ({result['config']}): each tool tip hangs {PRE_LIFT:g} s, then lifts "
             f"{LIFT[2] * 1000:g} mm; {result['simulated_time']:g} s simulated after the lift"]
    rows = [("check", "result", "measured", "bound")]
    rows += [(c["name"], "pass" if c["passed"] else "FAIL", c["shown"], c["bound_text"]) for c in result["checks"]]
    widths = [max(len(r[i]) for r in rows) for i in range(3)]
    for r, c in zip(rows, [None] + result["checks"]):
        lines.append("  " + "  ".join(r[i].ljust(widths[i]) for i in range(3)) + "  " + r[3])
        if c is not None:
            lines.append(f"  {'':{widths[0]}}  {c['detail']}")
    if not result["tension"]:
        lines.append("  no object between simulated arms: no tension check")
    lines += explain_tension(result)
    n = len(result["checks"])
    failed = [c["name"] for c in result["checks"] if not c["passed"]]
    if failed:
        lines.append(f"selftest: FAILED {len(failed)} of {n} checks: {', '.join(failed)}")
    else:
        lines.append(f"selftest: passed all {n} checks")
    return "\n".join(lines)


HELP = f"""Short run of the simulated rig with a pass/fail verdict (SI units).

Every simulated arm hangs {PRE_LIFT:g} s under its joint PID, then lifts its tool tip
{LIFT[2] * 1000:g} mm. Checks: each arm settles (every joint within {_joints(TOLERANCE, signed=False)}
of its target at the end, and inside that band for at least one period of its slowest
joint loop); the lift changes the object tension by no more than the stiffness times the
tip motion those tolerances allow; the rig runs at least as fast as real time. The report
also says why the object is already compressed or stretched when the lift starts.
Nothing is recorded under logs/.

Exit code 0 when every check passes, 4 when one fails (the report names it). With --json,
stdout carries the checks and "status" ("completed" or "failed"), the report goes to stderr.
"""


@click.command(name="selftest", help=HELP)
@click.option("--duration", type=click.FloatRange(min=0.0, min_open=True), default=2.0, show_default=True,
              help="Simulated time after the lift, s.")
@click.option("--seed", type=int, default=None, help="Seed of the simulated rig (default: from the configuration).")
@json_option
@click.pass_context
@exit_on_abort
def command(ctx: click.Context, duration: float, seed: int | None, as_json: bool) -> None:
    from rig.commands.options import config_from_context

    cfg = config_from_context(ctx)
    result = run(cfg, duration, seed)
    click.echo(report(result), err=as_json)
    if as_json:
        click.echo(result_json(result, indent=None))
    if result["status"] == "failed":
        click.echo(f"rig selftest: failed: {result['error']}", err=True)
        sys.exit(EXIT_MISSED)
