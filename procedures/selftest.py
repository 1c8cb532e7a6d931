"""`rig selftest`: a short run of the simulated rig that shows the kernel works.

Every simulated arm lifts its tool tip by 10 mm (a step of the joint PID to the inverse
kinematics target) so that the object between the tips moves without being stretched;
the report gives each arm's settling time and final joint error, the object tension and
how much faster than real time the rig ran.
"""

from __future__ import annotations

import json
import sys
import time

import click
import numpy as np

LIFT = np.array([0.0, 0.0, 0.010])          # world-frame tip step, m
TOLERANCE = np.array([1e-3, 1e-3, 5e-4])    # settled: every joint within this (rad, rad, m)


@click.command(name="selftest")
@click.option("--duration", type=float, default=2.0, show_default=True, help="Simulated time after the step, s.")
@click.option("--seed", type=int, default=None, help="Seed of the simulated rig (default: from the configuration).")
@click.option("--json", "as_json", is_flag=True, help="Print the result as one JSON document on stdout.")
@click.pass_context
def command(ctx: click.Context, duration: float, seed: int | None, as_json: bool) -> None:
    """Short run of the simulated rig: PID step on every arm, object tension (SI units)."""
    from rig.run import config_from_context
    from rig import psm_kinematics as K
    from rig.sim import world_from_config

    cfg = config_from_context(ctx)
    if duration <= 0:
        raise click.BadParameter("must be > 0 s", param_hint="--duration")
    world = world_from_config(cfg, seed=seed)
    if not world.names:
        raise click.ClickException(f"{cfg.source}: no simulated arm to test (every arm has driver 'ros')")
    world.advance(0.5)  # settle under gravity
    targets = {}
    for n in world.names:
        rcm = world.arms[n].rcm_world
        tip = world.tip_world(n) + LIFT
        targets[n] = K.ik_rcm((np.linalg.inv(rcm) @ np.append(tip, 1.0))[:3])
        world.servo_jp(n, targets[n])
    n_steps = int(round(duration / world.dt))
    errors = {n: np.empty((n_steps, 3)) for n in world.names}
    tension = np.empty(n_steps)
    wall = time.perf_counter()
    for k in range(n_steps):
        world.step()
        for n in world.names:
            errors[n][k] = world.true_state(n)[0] - targets[n]
        tension[k] = world.tension()
    wall = time.perf_counter() - wall
    arms = {}
    ok = True
    for n, e in errors.items():
        band = np.abs(e) > TOLERANCE
        outside = np.nonzero(band.any(axis=1))[0]
        settle = float((outside[-1] + 1) * world.dt) if len(outside) else 0.0
        final = e[-1]
        arms[n] = {"settling_time": settle, "final_error": final.tolist()}
        ok &= bool(len(outside) == 0 or outside[-1] < n_steps - 1)
    result = {
        "status": "completed" if ok else "failed",
        "arms": arms,
        "tension": {"final": float(tension[-1]), "max": float(tension.max()), "min": float(tension.min())},
        "simulated_time": duration,
        "real_time_factor": duration / wall,
        "config": cfg.source,
    }
    lines = [f"simulated rig ({cfg.source}): every tool tip lifted {LIFT[2] * 1000:.0f} mm, "
             f"{duration:.1f} s simulated"]
    for n, a in arms.items():
        fe = a["final_error"]
        lines.append(f"  {n}: settled in {a['settling_time']:.3f} s, final error "
                     f"{fe[0]:+.2e} rad {fe[1]:+.2e} rad {fe[2] * 1000:+.3f} mm")
    lines.append(f"  object tension: {tension[-1]:.2f} N (range {tension.min():.2f} to {tension.max():.2f} N)")
    lines.append(f"  real-time factor: {result['real_time_factor']:.0f}")
    click.echo("\n".join(lines), err=as_json)
    if as_json:
        click.echo(json.dumps(result))
    if not ok:
        sys.exit(1)
