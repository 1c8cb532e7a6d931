"""What `rig identify` reports: Table 5.1, whether the run met its purpose, the report text."""

from __future__ import annotations

import math

import numpy as np

from calibration.identification import FitOutcome

#: The published figure of the WPI package (7-DOF model, SDP, unseen test trajectory).
PUBLISHED_7DOF = (0.093, 0.178, 0.191)

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


def fmt3(v, digits=4) -> str:
    return " / ".join(f"{x:.{digits}f}" for x in v)


def report(result: dict) -> str:
    lines = [f"identify: {result.get('status', '')}"]
    v = result.get("validation", {})
    rms = result.get("validation_rms", {})
    if v:
        lines.append(f"validation on {result.get('validation_source', '?')} (a trajectory of this run left out "
                     "of the fit; for a motion the model never saw, `rig validate` another recording)")
        lines.append("  method  rel. error j1 / j2 / j3        RMS j1 [N m] / j2 [N m] / j3 [N]")
        for m in ("ols", "wls", "sdp"):
            lines.append(f"  {m.upper():6s}  {fmt3(v[m]):28s}  {fmt3(rms.get(m, [np.nan] * 3))}")
        mv = result.get("validation_moving", {}).get("sdp")
        if mv:
            lines.append(f"  SDP on moving samples only (|dq| above the 7.5.1 deadband): {fmt3(mv)}")
        mu = result.get("validation_moving_unfiltered", {}).get("sdp")
        if mu and result.get("parallel_filter"):
            lines.append(f"  the same with the model's efforts not low-passed like the torques: {fmt3(mu)}")
        if result.get("source") == "csv":
            lines.append(f"  published 7-DOF (SDP, unseen trajectory): {fmt3(PUBLISHED_7DOF, 3)} "
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
                     f"rel. error {fmt3(tr['sdp_vs_true_relative_error'])}")
    if result.get("model"):
        lines.append(f"model file: {result['model']}")
    if result.get("run_dir"):
        lines.append(f"run folder: {result['run_dir']}")
    return "\n".join(lines)
