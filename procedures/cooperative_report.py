"""The force-tracking figures and the report of a `rig cooperative` run."""

from __future__ import annotations

import numpy as np

from procedures import cooperative_figures as figures


def slave_control_text(slave_control: str, mode: str, rate: float) -> str:
    if mode == "position":
        return f"position (slaves on servo_jp at {rate:g} Hz, thesis 7.7.3)"
    if slave_control == "arm":
        return (f"arm impedance (servo_ci: the arm closes the slaves' spring and damper; this loop moved "
                f"their goals at {rate:g} Hz)")
    return f"effort (servo_jf: this loop closed the slaves' impedance at {rate:g} Hz)"


def missed_bound(result: dict, params: dict) -> str | None:
    """What the run missed of its purpose (None: met). It exists to reach the tension and
    hold it within the tolerance while the object moves."""
    tol, force = params["tolerance"], params["force"]
    moving = result.get("max_error_during_motion")
    end = params["settle"] + params["duration"] + params["hold_after"]
    if result.get("settling_time") is not None and result["settling_time"] >= 0.95 * end:
        return (f"the tension never settled within {max(0.1 * force, 0.25):.2f} N of {force:g} N "
                f"(settling time {result['settling_time']:.2f} s of {end:.2f} s)")
    if moving is not None and moving > tol:
        return f"max |F - {force:g} N| while moving {moving:.3f} N, above the tolerance {tol:g} N"
    return None


def force_error_figures(log, params, names, master, mode, kind, controller, last_live: float | None = None) -> dict:
    """Force-error figures. Errors are taken against the live set-point (--force plus the
    increments received so far); `last_live` (s since the loop started) is when the last
    live increment was applied: the hold figures (peak-to-peak, limit cycle) start `settle`
    seconds after it, so a set-point step is not mistaken for a limit cycle."""
    t, F = log["t"], log["tension"]           # F: one column per object element
    force = params["force"]
    e_all = F - (force + log["force_offset"])[:, None]
    # the element furthest from the set-point at each instant
    e = e_all[np.arange(len(t)), np.argmax(np.abs(e_all), axis=1)]
    m0 = params["settle"]
    m1 = params["settle"] + params["duration"]
    during = (t >= m0) & (t <= m1)
    startup = t < m0
    band = max(0.1 * force, 0.25)
    outside = np.nonzero(np.abs(e) > band)[0]
    settle_idx = outside[-1] + 1 if len(outside) else 0
    settling_time = float(t[min(settle_idx, len(t) - 1)]) if len(outside) else 0.0
    rms_mask = t >= max(settling_time, m0 * 0.5)
    hold = t > m1
    if last_live is not None and (hold & (t >= last_live + params["settle"])).any():
        hold = hold & (t >= last_live + params["settle"])
    tail = e[hold] if hold.any() else e[-int(0.2 * len(e)):]
    summary = {
        "max_error_during_motion": float(np.max(np.abs(e[during]))) if during.any() else None,
        "rms_error": float(np.sqrt(np.mean(e[rms_mask] ** 2))) if rms_mask.any() else None,
        "overshoot": float(max(0.0, np.max(e_all[startup]))) if startup.any() else 0.0,
        "element_rms_error": [float(np.sqrt(np.mean(c[rms_mask] ** 2))) for c in e_all.T] if rms_mask.any() else None,
        "settling_time": settling_time,
        "hold_peak_to_peak": float(np.ptp(tail)) if len(tail) else None,
        "loop_time_us": {"median": float(np.median(log["loop_us"])),
                         "p99": float(np.percentile(log["loop_us"], 99)),
                         "max": float(np.max(log["loop_us"]))},
    }
    # A limit cycle: after the motion the force loop keeps hunting, its target reversing
    # again and again (position mode steps), or the tension keeps swinging beyond the band.
    xf = log["x_f"][hold] if hold.any() else log["x_f"][-int(0.2 * len(t)):]
    reversals = 0
    for col in xf.T:
        d = np.diff(col)
        d = d[np.abs(d) > 1e-12]
        reversals = max(reversals, int(np.sum(np.diff(np.sign(d)) != 0)) if len(d) > 1 else 0)
    summary["hold_reversals"] = reversals
    if mode == "position":
        summary["limit_cycle"] = reversals >= 6
    else:
        summary["limit_cycle"] = bool(summary["hold_peak_to_peak"] is not None and summary["hold_peak_to_peak"] > 2 * band)
    return {"summary": {k: v for k, v in summary.items() if not isinstance(v, dict)}, **summary,
            "force": force, "motion_duration": params["duration"]}


def _timing_line(lt: dict | None) -> str:
    if not lt or lt.get("period_ms_median") is None:
        return ""
    return (f"  loop at {lt['rate_hz']:g} Hz: period median {lt['period_ms_median']:.3f} ms, p99 "
            f"{lt['period_ms_p99']:.3f} ms, max {lt['period_ms_max']:.1f} ms; late ticks (begun after their "
            f"deadline) {lt['overruns_per_10k']:.0f} and skipped {lt['skipped_per_10k']:.0f} per 10 000; "
            "measured_js not renewed in "
            f"{lt['repeated_measured_js_per_10k']:.0f} of 10 000 reads"
            + (f"; the arms' samples {lt['arm_sample_age_ms']['median']:.1f} ms old at the loop (median; p99 "
               f"{lt['arm_sample_age_ms']['p99']:.1f}, max {lt['arm_sample_age_ms']['max']:.1f} ms)"
               if lt.get("arm_sample_age_ms") else "")
            + (f"; the arms' clock jumped on {lt['arm_clock_jumps']} ticks, by up to {lt['arm_clock_jump_ms_max']:.0f} ms "
               "(the console, or rig sim, fell behind its own clock)" if lt.get("arm_clock_jumps") else "")
            + (f"; force loop held (tension older than {lt['force_max_age_ms']:.0f} ms) on "
               f"{lt['force_hold_per_10k']:.0f} per 10 000 ticks, the oldest {lt['force_hold_longest_ms']:.0f} ms"
               if lt.get("force_hold_per_10k") else ""))


def force_hold_figures(blind_ticks: int, n_ticks: int, longest: float, max_age: float) -> dict:
    """Ticks on which the force loop held because the newest tension was older than
    `max_age` (s), per 10 000 ticks, and the oldest tension such a tick found (ms)."""
    return {"force_hold_per_10k": blind_ticks * 1e4 / max(n_ticks, 1),
            "force_hold_longest_ms": 1e3 * longest, "force_max_age_ms": 1e3 * max_age}


def loop_timing(t: np.ndarray, rate: float, overruns: int, skipped: int, repeated_js: int, arms: int,
                step_us: np.ndarray | None = None) -> dict:
    """The control loop's timing: tick periods (ms; on the simulated rig exactly 1/rate),
    ticks that began late (overruns) or were skipped, per 10 000 ticks, and the share of
    arm reads that found no new measured_js since the tick before (per 10 000 reads)."""
    n = len(t)
    period = np.diff(t) * 1e3
    per10k = 1e4 / max(n, 1)
    return {"rate_hz": float(rate), "ticks": int(n),
            "period_ms_median": float(np.median(period)) if n > 1 else None,
            "period_ms_p99": float(np.percentile(period, 99)) if n > 1 else None,
            "period_ms_max": float(np.max(period)) if n > 1 else None,
            "overruns_per_10k": overruns * per10k, "skipped_per_10k": skipped * per10k,
            "repeated_measured_js_per_10k": repeated_js * 1e4 / max(n * arms, 1),
            # ticks whose own computation took longer than the period (the loop then runs late)
            "steps_over_period_per_10k": (float(np.sum(np.asarray(step_us) > 1e6 / rate)) * per10k
                                          if step_us is not None and len(step_us) else 0.0)}


def filter_delays(controller) -> dict:
    jf = controller.joint_filter[controller.master]
    ff = controller.force_filter
    out = {}
    for f in (2.0, 10.0):
        vq, rq = jf.delay(f, 0)
        vf, rf = ff.delay(f, 0)
        out[f"{f:g} Hz"] = {"joint_position_s": vq, "joint_velocity_s": rq, "tension_s": vf, "tension_rate_s": rf}
    return out


def _model_lines(result: dict) -> list[str]:
    """One line per arm naming the model (file) it ran on."""
    models = result.get("models")
    if not models:
        return [f"  {result.get('model')}"] if result.get("model") else []
    return [f"  model {m.get('note') or m.get('file')}" for m in models.values()]


def report(result: dict) -> str:
    if result.get("status") == "dry-run":
        return "\n".join([f"plan checked for {', '.join(result['arms'])} (master {result['master']}): inside every "
                          "limit; nothing moved"] + _model_lines(result)
                         + [f"  warning: {w}" for w in result.get("warnings") or []])
    lines = [f"cooperative ({result.get('mode')}, {result.get('object')}): {result.get('status')}",
             *_model_lines(result), f"  {result.get('registration')}"]
    if result.get("slave_control"):
        lines.append(f"  slaves: {result['slave_control']}")
    lines += [f"  warning: {w}" for w in result.get("warnings") or []]
    if result.get("max_error_during_motion") is not None:
        lines += [f"  max |F - {result['force']:.2f} N| during the motion: {result['max_error_during_motion']:.3f} N",
                  f"  RMS error after settling: {result['rms_error']:.3f} N",
                  f"  start-up overshoot: {result['overshoot']:.3f} N, settling time {result['settling_time']:.2f} s",
                  f"  limit cycle: {'yes' if result['limit_cycle'] else 'no'} "
                  f"(peak-to-peak while holding {result['hold_peak_to_peak']:.3f} N"
                  + (f", {result['hold_reversals']} reversals of the position steps)" if result.get("mode") == "position"
                     else ")"),
                  f"  controller step ({len(result.get('arms') or []) or '?'} arms): median "
                  f"{result['loop_time_us']['median']:.0f} us, p99 {result['loop_time_us']['p99']:.0f} us of "
                  f"computation, against the {1e6 / result['loop_timing']['rate_hz']:.0f} us period at "
                  f"{result['loop_timing']['rate_hz']:g} Hz; longer than the period on "
                  f"{result['loop_timing'].get('steps_over_period_per_10k', 0.0):.0f} per 10 000 ticks"
                  if result.get("loop_timing") else "",
                  _timing_line(result.get("loop_timing"))]
        lines += _estimate_lines(result.get("tension_estimate"))
        lines += figures.tracking_lines(result.get("cartesian_tracking") or {})
        lines += [f"  plot: {result.get('plot')}"]
        if result.get("tracking_plot"):
            lines.append(f"  tracking plot: {result['tracking_plot']}")
    lines = [ln for ln in lines if ln]
    live = result.get("live_commands")
    if live:
        lines.append(f"  live commands: {sum(live['received'].values())} received, "
                     f"{sum(live['applied'].values())} applied, {len(live['rejected'])} refused")
    if result.get("run_dir"):
        lines.append(f"  run folder: {result['run_dir']}")
    return "\n".join(lines)


def _estimate_lines(doc: dict | None) -> list[str]:
    """The model's tension estimate beside the load cell (issue 47)."""
    if not doc:
        return []
    head = f"  tension from the model (loop closed on the {doc['loop_closed_on']})"
    if doc.get("rms_difference") is None:
        return [head + (f": {doc['note']}" if doc.get("note") else "")]
    return [head + f": against the load cell while moving RMS {doc['rms_difference']:.3f} N, max "
            f"{doc['max_difference']:.3f} N, bias {doc['bias']:+.3f} N; ambiguous on "
            f"{100 * (doc.get('ambiguous_share') or 0.0):.0f} % of the ticks"]
