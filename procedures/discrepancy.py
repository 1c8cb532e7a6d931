"""`rig discrepancy`: where model and measurement disagree, and which catalogue effect explains it.

The model with that effect added, and the held-out gap before and after.

    rig discrepancy (RUN_DIR | --csv FILE [--rate 200]) [--validate-csv FILE2] [--model MODEL.json] [--json]

Input: a recorded run (its /<arm>/measured_js, resampled to --rate) or a CSV in the WPI
format. Only the measured arrays reach the workflow (`calibration.discrepancy`): a run's
configuration snapshot and any simulated effects are never read. A run that recorded
several motions with pauses in its stream between them (`rig identify`: the excitation, an
unrecorded move_jp, the validation trajectory) is taken as that many continuous pieces: each
is resampled on its own, and the workflow filters and differentiates each on its own, never
across a pause (interpolated across, a pause became seconds of an arm moving with the
velocity and effort of neither end).

The model file written (issue 26) is not the workflow's own fit: it is the plain model
(`rig identify --csv`'s fit of the training block at its defaults, written beside it as
plain_model.json; or the --model file) with only the effects that predict motion the fit
has not seen better (`calibration.generalisation`): refit on top of the plain model (with
their joint's friction), checked against the catalogue's plausible ranges, and kept by
backward elimination on another motion -- --validate-csv, or the last continuous piece of a
run recorded as several (`rig identify`'s validation trajectory: the plain model and the
written parameters are fitted without it, while the workflow names effects on the whole
run, the record its thresholds were set for) -- or, with one motion only, on a
cross-validation over blocks in time. The workflow's own model (its rigid body refitted with
the effects) is written instead only when it never saw the other motion (--validate-csv)
and predicts it better on every joint. The
others are reported "seen in training, not confirmed on new motion". On the other motion
the written model predicts no joint worse than the plain model.

Baseline of the workflow: with --model, that model whole (its Stribeck excess and effects
too); without, the thesis model
(rigid body + Fc tanh(a dq/2) + Fv dq + Fo + Ia ddq) identified on the training block, the
gravity direction in frame 0 estimated from the data as `rig identify --csv` does (moving
samples; the physically consistent fit decides the hemisphere), since the arm's tilt is
unknown. Train and held-out are contiguous blocks (held-out at the
end). Writes result.json, model.json (the model with an "effects" section: each effect's
name, joint, parameters with units; a payload is also folded into the standard
parameters) and PNGs of the held-out residual against the variable that explains it,
before and after.

Units: SI (rad, m, rad/s, m/s, N m, N, s, Hz).
"""

from __future__ import annotations

import sys
from pathlib import Path

import click
import numpy as np

from rig.commands.exit_codes import EXIT_INPUT
from rig.commands.parameters import Parameter
from rig.commands.procedure import procedure_command
from rig.commands.report import emit_result
from rig.runs.recorded_joints import PAUSE_CUTOFF_PERIODS, load_run_pieces
from rig.runs.run import Run

PROCEDURE = "discrepancy"
STEPS = ("load the measured data", "baseline model", "detect, attribute, name and add effects",
         "write the augmented model, report and plots")

PARAMETERS = [
    Parameter("csv", "", "", "Measured data in the WPI CSV format (q1..qn, dq1..dqn, tau1..taun) instead of RUN_DIR",
              type=str),
    Parameter("validate_csv", "", "", "A second recording of the same arm (WPI CSV format) on which effects must improve "
              "prediction to be written; default: an identify run's last piece, else cross-validation over blocks in "
              "time", type=str),
    Parameter("rate", 200.0, "Hz", "Sampling rate of the CSV rows; a run's samples are resampled to it",
              minimum=20.0, maximum=5000.0),
    Parameter("model", "", "", "Model file (model.json) taken whole as the baseline and the plain model the written "
              "one adds confirmed effects to; default: `rig identify --csv`'s fit of the training block", type=str),
    Parameter("joints", 3, "", "Joints used (the model has joints 1-3)", minimum=3, maximum=3, type=int),
    Parameter("arm", "PSM1", "", "Arm whose /<arm>/measured_js a RUN_DIR provides", type=str),
    Parameter("heldout", 0.25, "", "Fraction of the data held out at its end", minimum=0.1, maximum=0.5),
    Parameter("cutoff", 10.0, "Hz", "Cut-off of the zero-phase Butterworth filter", minimum=1.0, maximum=50.0),
    Parameter("effort_lag", 1.0, "ms", "How much earlier than its sample the reported effort was computed (one servo "
              "period: 1 ms for the dVRK's 1 kHz PID and the simulated rig); under one sample", minimum=0.0,
              maximum=4.0),
    Parameter("plots", True, "", "Write the residual PNGs", type=bool),
]


def _require_motion(train, source: str, purpose: str) -> None:
    """DiscrepancyError naming the first joint of processed ``train`` that moves faster than
    identification's deadband in under a tenth of its samples: too little motion to ``purpose``."""
    from calibration.discrepancy.settings import DiscrepancyError
    from calibration.identification import DEADBAND as ID_DEADBAND
    from calibration.identification import slow_joints

    for j, share in slow_joints(train.dq, ID_DEADBAND):
        raise DiscrepancyError(
            f"{source}: joint {j + 1} moves faster than {ID_DEADBAND[j]:g} {'m/s' if j == 2 else 'rad/s'} in only "
            f"{share * 100:.1f} % of the training block: too little motion to {purpose}; give an identified model "
            "with --model (its gravity is used)")


def identify_plain(q, dq, tau, rate: float, settings, source: str = "the data", breaks=(), train=None):
    """The plain model: `rig identify --csv`'s fit at its defaults on the training block
    (`calibration.generalisation.plain_fit`), a FitOutcome. Its gravity direction: the
    sphere scanned by least squares on the moving samples
    (a stuck joint's effort is no function of the motion), and the best direction of each
    hemisphere fitted by the physically consistent SDP, the better fit deciding the sign (a
    mirrored direction fits the data almost as well by least squares alone). With ``breaks``
    (continuous pieces put end to end), each piece is filtered on its own and the training
    block is the first share of the pieces' processed samples, as of one record's. ``train``:
    that block, when the caller has it already (`calibration.generalisation.plain_training_block`)."""
    from calibration.base_params import RankDeficientError
    from calibration.discrepancy.settings import DiscrepancyError
    from calibration.plain_model import plain_fit, plain_training_block

    if train is None:
        train = plain_training_block(q, dq, tau, rate, settings.heldout, breaks,
                                     source if len(breaks) else "the training block")
    _require_motion(train, source, "identify the plain model and estimate the gravity direction")
    try:
        return plain_fit(train)
    except RankDeficientError as exc:
        raise DiscrepancyError(f"{source}: the plain model cannot be identified ({exc}); give an identified model "
                               "with --model (its gravity is used)") from None


def estimate_gravity(q, dq, tau, rate: float, settings, source: str = "the data", breaks=()) -> np.ndarray:
    """Gravity in frame 0 for the workflow's baseline, found on the workflow's own training
    block as `rig identify --csv` finds it (at the thesis' slope 400 s/rad, without the
    Stribeck column: the direction is what is wanted). With ``breaks`` each piece is filtered
    on its own and the training block is the first share of the pieces' processed samples."""
    from calibration.base_params import RankDeficientError
    from calibration.datasets import JointData, pieces_training_block, processed, split_blocks
    from calibration.discrepancy.settings import DiscrepancyError
    from calibration.identification import CUTOFF_HZ, FILTER_ORDER, fit_identification
    from calibration.identification import DEADBAND as ID_DEADBAND

    data = JointData(np.arange(len(q)) / rate, np.asarray(q, float), np.asarray(dq, float), np.asarray(tau, float),
                     rate, source if len(breaks) else "the training block")
    if len(breaks):
        train = pieces_training_block(data, breaks, CUTOFF_HZ, FILTER_ORDER, settings.heldout)
    else:
        train, _ = split_blocks(processed(data, CUTOFF_HZ, FILTER_ORDER), settings.heldout)
    _require_motion(train, source, "estimate the gravity direction from")
    try:
        outcome = fit_identification(train, "auto", 400.0, deadband=ID_DEADBAND, parallel=True, stribeck=False)
    except RankDeficientError as exc:
        raise DiscrepancyError(f"{source}: the gravity direction cannot be estimated ({exc}); give an identified model "
                               "with --model (its gravity is used)") from None
    return np.asarray(outcome.gravity, float)


def _save(fig, path_dir: Path, name: str, out: dict) -> None:
    """Write ``fig`` as ``name`` under ``path_dir``, close it and list it in ``out``."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    fig.savefig(path_dir / name, dpi=110)
    plt.close(fig)
    out[name] = str(path_dir / name)


#: Units of the workflow's explaining variables (`calibration.discrepancy.detection.detection_variable`), rotary
#: joints 1-2 and the insertion joint 3.
_VARIABLE_UNITS = {"q": ("rad", "m"), "dq": ("rad/s", "m/s"), "ddq": ("rad/s^2", "m/s^2"),
                   "u": ("N m", "N"), "travel since reversal ": ("rad", "m")}


def variable_label(name: str) -> str:
    """Axis label of an explaining variable ("q2", "u3", "travel since reversal 1") with its
    unit: "q2 [rad]", "u3 (model effort) [N]"."""
    kind, joint = name[:-1], int(name[-1])
    unit = _VARIABLE_UNITS[kind][joint == 3]
    what = " (model effort)" if kind == "u" else ""
    return f"{name}{what} [{unit}]"


def figures(pairs: list[dict], structured: list[dict], w, generalisation: dict, path_dir: Path) -> dict:
    """The residual PNGs (before and after each effect, and of what nothing explained) and
    the generalisation bar chart, in `path_dir`; their paths by name."""
    return _residuals_figures(pairs, structured, w, path_dir) | _generalisation_figure(generalisation, path_dir)


def _residuals_figures(pairs: list[dict], structured: list[dict], w, path_dir: Path) -> dict:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = {}
    for k, pr in enumerate(pairs, 1):
        unit = _VARIABLE_UNITS["u"][pr["joint"] == 3]
        prof = pr.get("profile")
        if prof is None:
            fig, ax = plt.subplots(figsize=(7, 4.2))
        else:
            fig, (ax, ax2) = plt.subplots(1, 2, figsize=(13, 4.2))
            qu = _VARIABLE_UNITS["q"][pr["joint"] == 3]
            ax2.plot(prof["q"], prof["direction"] * pr["before"], ".", ms=2, alpha=0.5, label="before (baseline)")
            ax2.plot(prof["q"], prof["direction"] * pr["after"], ".", ms=2, alpha=0.5, label="after")
            ax2.plot(prof["grid"], prof["f"], "k-", lw=1.5, label="fitted f(q) - mean")
            ax2.set_xlabel(f"q{pr['joint']} [{qu}]")
            ax2.set_ylabel(f"residual x sign(dq{pr['joint']}) [{unit}]")
            ax2.set_title("friction level against position")
            ax2.legend(markerscale=4)
            ax2.grid(alpha=0.3)
        ax.plot(pr["x"], pr["before"], ".", ms=2, alpha=0.5, label="before (baseline)")
        ax.plot(pr["x"], pr["after"], ".", ms=2, alpha=0.5, label=f"after (+ {pr['effect']})")
        ax.set_xlabel(variable_label(pr["variable"]))
        ax.set_ylabel(f"held-out residual joint {pr['joint']} [{unit}]")
        ax.set_title(f"{pr['effect']} on joint {pr['joint']}: residual against {pr['variable']}")
        ax.legend(markerscale=4)
        ax.grid(alpha=0.3)
        _save(fig, path_dir, f"residual_{k}_{pr['effect']}_joint{pr['joint']}.png", out)
    # Structured joints nothing explained: the residual against its best variable.
    for d in structured:
        j = d["joint"]
        att = w.attribute(j)
        from calibration.discrepancy.detection import detection_variable

        x = detection_variable(w, att["variable"])
        r = w.residual()[:, j - 1]
        ho = w.mov_ho[j - 1]
        fig, ax = plt.subplots(figsize=(7, 4.2))
        ax.plot(x[ho], r[ho], ".", ms=2, alpha=0.5)
        ax.set_xlabel(variable_label(att["variable"]))
        ax.set_ylabel(f"held-out residual joint {j} [{_VARIABLE_UNITS['u'][j == 3]}]")
        ax.set_title(f"joint {j}: structured residual no catalogue effect explains")
        ax.grid(alpha=0.3)
        _save(fig, path_dir, f"residual_unexplained_joint{j}.png", out)
    return out


def _fmt(v) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    if isinstance(v, (list, tuple)) and v and all(isinstance(x, float) for x in v):
        return "[" + ", ".join(f"{x:.4g}" for x in v) + "]"
    return str(v)


def _pieces_lines(pieces: dict | None) -> list[str]:
    """The report's line on a run recorded as several continuous pieces (none for one)."""
    if not pieces or (len(pieces["seconds"]) < 2 and not pieces["dropped_seconds"]):
        return []
    spans = ", ".join(f"{a:.1f}-{b:.1f} s" for a, b in pieces["seconds"])
    line = (f"data: {len(pieces['seconds'])} continuous pieces ({spans}; pauses over "
            f"{pieces['pause_longer_than_s'] * 1e3:.0f} ms end a piece), each filtered on its own")
    if pieces["dropped_seconds"]:
        line += "; too short, left out: " + ", ".join(f"{a:.2f}-{b:.2f} s" for a, b in pieces["dropped_seconds"])
    return [line]


def verdict_words(result: dict) -> str:
    """The verdict in plain words, first in the report: what the model misses, per joint,
    what adding it did to the held-out error, and what the written model keeps (the
    effects confirmed on another motion)."""
    left = result["detection"]["structured_left"]
    before, after = result["baseline"]["heldout_rms"], result["final"]["heldout_rms"]
    if result["verdict"] == "none":
        return "the model explains these measurements: no joint's residual is structured, nothing to add"
    by_joint: dict[int, list[str]] = {}
    for e in result["effects"]:
        by_joint.setdefault(int(e["joint"]), []).append(str(e["name"]).replace("_", " "))
    units = {1: "N m", 2: "N m", 3: "N"}
    parts = []
    if by_joint:
        missed = "; ".join(f"joint {j}: {' and '.join(names)}" for j, names in sorted(by_joint.items()))
        fell = ", ".join(f"joint {j} {before[j - 1]:.3g} -> {after[j - 1]:.3g} {units.get(j, 'N m')}"
                         for j in sorted(by_joint) if j - 1 < len(before))
        parts.append(f"the model missed {missed} (held-out RMS error with them: {fell})")
    if left:
        gap = (f"something on joint(s) {', '.join(str(j) for j in left)} that no effect of the catalogue explains "
               "(the closest candidates are below)")
        parts.append(f"it still misses {gap}" if parts else f"the model misses {gap}")
    g = result.get("generalisation")
    if g and by_joint:
        kept = ", ".join(k.replace("_", " ").replace("@", " on joint ") for k in g.get("kept", []))
        parts.append(f"confirmed on another motion and written: {kept}" if kept
                     else "none confirmed on another motion: the model written is the plain one")
    return "; ".join(parts)


def report(result: dict) -> str:
    b = result["baseline"]
    lines = [f"rig discrepancy: {verdict_words(result)}",
             f"data: {result['data']['source']}",
             "evidence:",
             f"baseline: {result['baseline_kind']}",
             *_pieces_lines(result["data"].get("pieces")),
             "inertial term per joint (the smaller training residual): " + ", ".join(result["inertia_source"]),
             "held-out RMS per joint (N m, N m, N):  baseline " + ", ".join(f"{v:.4g}" for v in b["heldout_rms"])
             + "  ->  final " + ", ".join(f"{v:.4g}" for v in result["final"]["heldout_rms"]),
             "held-out relative error per joint (samples of this recording left out of the fits; the "
             "figure to quote for prediction is `rig validate` on a recording the model never saw):",
             "                                        baseline " + ", ".join(f"{v:.3f}" for v in b["heldout_rel_error"])
             + "  ->  final " + ", ".join(f"{v:.3f}" for v in result["final"]["heldout_rel_error"])]
    for d in result["detection"]["initial"]:
        lines.append(f"  joint {d['joint']}: Ljung-Box {d['ljung_box']:.1f} (threshold {d['ljung_box_threshold']:.1f}), "
                     f"library R^2 {d['library_r2']:.3f} (threshold {d['library_r2_threshold']:.3f})"
                     + ("  STRUCTURED" if d["structured"] else ""))
    for e in result["effects"]:
        ev = e["evidence"]
        par = ", ".join(f"{k} {_fmt(v)}" for k, v in e["params"].items())
        lines.append(f"effect {e['name']} on joint {e['joint']}: {par}")
        lines.append(f"    dBIC {ev['delta_bic']:.1f}, held-out variance removed {ev['heldout_variance_removed']:.2f} "
                     f"(needed {ev['heldout_gain_needed']:.2f}); explains: {ev['attribution']['variable']}"
                     + (f"; equivalent: {', '.join(ev['equivalent_explanations'])}" if ev["equivalent_explanations"] else ""))
        lines.append("    held-out RMS " + ", ".join(f"{v:.4g}" for v in e["heldout_rms_before"]) + " -> "
                     + ", ".join(f"{v:.4g}" for v in e["heldout_rms_after"]))
    if result["detection"]["structured_left"]:
        lines.append(f"structured residual left on joint(s) {result['detection']['structured_left']}: "
                     "no catalogue effect explains it")
        for item in result.get("closest_rejected", []):
            c = item["candidate"]
            if c is None:
                continue
            why = []
            if c["delta_bic"] <= c["delta_bic_needed"]:
                why.append(f"dBIC {c['delta_bic']:.1f}, needs > {c['delta_bic_needed']:.1f}")
            if c["heldout_variance_removed"] < c["heldout_gain_needed"]:
                why.append(f"removes {c['heldout_variance_removed']:.2f} of the held-out residual variance, needs "
                           f"{c['heldout_gain_needed']:.2f} (the generic library explains {c['library_r2']:.2f})")
            lines.append(f"    joint {item['joint']}: closest catalogue effect {c['effect']}, not added: " + "; ".join(why))
    if result.get("generalisation"):
        lines += _generalisation_lines(result["generalisation"])
    lines.append(f"model: {result['model']}")
    lines.append(f"time: {result['seconds']:.1f} s")
    return "\n".join(lines)


def _generalisation_lines(g: dict) -> list[str]:
    """The written model and how its effects were judged on the other motion."""
    from calibration.generalisation import IDENTIFIED_CHOICE

    lines = []
    identified = g.get("choice") == IDENTIFIED_CHOICE
    lines.append(f"written model: the plain model {'identified again with' if identified else '+'} "
                 f"{', '.join(g['kept']) or 'no effect'}; effects judged on "
                 f"{g['method']}" + (f" ({g['note']})" if g.get("note") else ""))
    lines.append("    relative error per joint, plain -> written: "
                 + ", ".join(f"{a:.3f} -> {b:.3f}" for a, b in zip(g["relative_error"]["plain"],
                                                                   g["relative_error"]["written"])))
    if identified:
        iw = g["identified_with_effects"]
        lines.append("    written: identified again with the effects' columns in the regressor: gravity "
                     + ", ".join(f"{v:.3f}" for v in iw["gravity"]) + f" m/s^2, friction slope {iw['slope']:g}; "
                     "it predicts the other motion better than the plain model on every joint and than the "
                     "plain model with the effects fitted on top")
    if g.get("choice", "").startswith("the workflow"):
        lines.append(f"    written: {g['choice']}: it predicts the other motion better than the plain model on "
                     "every joint and than the plain model with the confirmed effects")
    hb = g.get("heldout_block")
    if hb and hb.get("rel_written"):
        lines.append("    on the held-out block, plain -> written: "
                     + ", ".join(f"{a:.3f} -> {b:.3f}" for a, b in zip(hb["rel_plain"], hb["rel_written"])))
    if g.get("friction_refitted_alone_on_joints"):
        lines.append(f"    friction of joint(s) {g['friction_refitted_alone_on_joints']} refitted on the training block "
                     "(Fc, Fv, Fo, Ia; Stribeck excess on joint 3): confirmed on the other motion without an effect")
    for f in g.get("folded_into_friction") or []:
        lines.append(f"    {f['effect']}@{f['joint']}: written as joint {f['joint']}'s friction refitted alone: "
                     f"Fo moved by {f['written']:+.4g} (the effect named {f['named']:+.4g}"
                     + (f", {f['from']}" if f.get("from") else "") + "); confirmed on the other motion as that term")
    for d in g["not_confirmed"]:
        gain = d.get("gain_on_new_motion")
        lines.append(f"    {d['effect']}@{d['joint']}: {d['why']}"
                     + (f" (it lowers joint {d['joint']}'s error there by {gain * 100:.1f} %, needs "
                        f"{g['confirm_gain'] * 100:g} % and {g.get('confirm_absolute', 0):g} of its effort)"
                        if gain is not None else ""))
    for d in g["implausible"]:
        lines.append(f"    {d['effect']}@{d['joint']}: left out, implausible beside the plain model: {d['why']}")
    lines.append("    guards: " + "; ".join(g["guards"]))
    return lines


def _other_motion(parameters: dict, settings, q, dq, tau, breaks, pieces):
    """The motion the effects are confirmed on (`calibration.generalisation`): the
    --validate-csv recording, or the last continuous piece of a run recorded as several
    (`rig identify`'s validation trajectory) when it is long enough to predict; the training
    arrays without that piece. Returns (motions, q, dq, tau, breaks, note)."""
    from calibration.datasets import load_csv
    from calibration.generalisation import Motion
    from calibration.prediction import minimum_samples

    rate = parameters["rate"]
    if parameters["validate_csv"]:
        v = load_csv(parameters["validate_csv"], rate, parameters["joints"])
        need = minimum_samples(rate, settings)
        if len(v.q) < need:
            from calibration.prediction import PredictionError

            raise PredictionError(f"{parameters['validate_csv']}: {len(v.q)} rows ({len(v.q) / rate:.1f} s at {rate:g} Hz) "
                                  f"are too few for the other motion: it needs at least {need} "
                                  f"({need / rate:.1f} s) for the {settings.cutoff:g} Hz filter's settling and two blocks")
        return [Motion(v.q, v.dq, v.tau, rate, f"{parameters['validate_csv']} (second recording)")], q, dq, tau, \
            breaks, None
    if len(breaks) and len(q) - breaks[-1] >= minimum_samples(rate, settings) \
            and breaks[-1] >= minimum_samples(rate, settings):
        k = breaks[-1]
        a, b = pieces["seconds"][-1]
        motion = Motion(q[k:], dq[k:], tau[k:], rate, f"the run's last continuous piece ({a:.1f}-{b:.1f} s)")
        return [motion], q[:k], dq[:k], tau[:k], breaks[:-1], \
            (f"the run's last piece ({a:.1f}-{b:.1f} s) is the other motion: the plain model and the written "
             "parameters are fitted without it; the workflow names effects on the whole run")
    return [], q, dq, tau, breaks, None


def run(parameters: dict, run_dir: str | None = None, run_root=None, progress: bool = True) -> dict:
    from calibration.base_params import base_parameters_of
    from calibration.discrepancy.settings import Settings
    from calibration.discrepancy.workflow import run_workflow
    from calibration.generalisation import EffectGate
    from calibration.plain_model import plain_training_block, workflow_model
    from calibration.prediction import extra_effort, standard_parameters
    from rig.model.model_file import load_model, save_model
    from rig.runs.model_results import provenance
    from rig.model.psm_dynamics import DriveParameters, PSMDynamics, PSMParameters
    from rig.model.psm_kinematics import DQ_MAX, Q_MAX, Q_MIN

    settings = Settings(cutoff=parameters["cutoff"], heldout=parameters["heldout"],
                        effort_lag=parameters["effort_lag"] * 1e-3)
    rate = parameters["rate"]
    with Run(PROCEDURE, parameters=parameters, config=None, steps=list(STEPS), root=run_root,
             progress=progress) as rn:
        with rn.step(STEPS[0]):
            q, dq, tau, source, breaks, pieces = _load(parameters, run_dir, rate, settings)
            # The workflow names effects on the whole record; the plain model and the written
            # model's parameters are fitted without the other motion (`_other_motion`).
            all_q, all_dq, all_tau, all_breaks = q, dq, tau, breaks
            motions, q, dq, tau, breaks, split_note = _other_motion(parameters, settings, q, dq, tau, breaks, pieces)
            workflow_sees_other = split_note is not None
        with rn.step(STEPS[1]):
            given, given_extra, training = None, None, None
            if parameters["model"]:
                plain = load_model(parameters["model"])
                model = plain.dynamics()
                given = standard_parameters(plain)
                given_extra = lambda p: extra_effort(plain, p)   # noqa: E731  the model whole
                kind = f"given model {plain.path} (whole: Stribeck excess and effects included)"
            else:
                # the block the plain model is fitted on: the gate may identify it again with the effects
                training = plain_training_block(q, dq, tau, rate, settings.heldout, breaks,
                                                source if len(breaks) else "the training block")
                outcome = identify_plain(q, dq, tau, rate, settings, source, breaks, training)
                sdp = outcome.fits["sdp"]
                plain_path = save_model(
                    rn.dir / "plain_model.json", standard=sdp.pi, names=list(outcome.model.param_names()),
                    slope=outcome.slope, gravity=outcome.gravity, stribeck=outcome.stribeck(),
                    gravity_source=outcome.gravity_source, checks=sdp.checks,
                    provenance_info=provenance(source, rn.dir, {"procedure": PROCEDURE, "model": "plain"}),
                    extra={"note": "the model `rig identify --csv` fits at its defaults on this training block"})
                plain = load_model(plain_path)
                g = estimate_gravity(all_q, all_dq, all_tau, rate, settings, source, all_breaks)
                model = PSMDynamics(PSMParameters(drive=DriveParameters()), gravity=g)
                kind = ("thesis model identified on the training block (gravity estimated: "
                        + ", ".join(f"{v:.3f}" for v in g) + " m/s^2)")
            base = base_parameters_of(model.regressor_batch, model, Q_MIN, Q_MAX, DQ_MAX)
        with rn.step(STEPS[2]):
            result, w = run_workflow(model, base, all_q, all_dq, all_tau, rate, given, settings, all_breaks, given_extra)
        with rn.step(STEPS[3]):
            # the workflow's own model is judged on the other motion only if it never saw it
            whole = workflow_model(plain, w, result) if motions and w.added and not workflow_sees_other else None
            effect_gate = EffectGate(plain, w.added, q, dq, tau, rate, settings, breaks, motions, whole, training)
            gate = effect_gate.run()
            written = effect_gate.written_model(gate)
            if split_note:
                gate.doc["note"] = split_note
            heldout = _heldout_figures(effect_gate, gate, result)
            gate.doc["heldout_block"] = heldout
            model_path = _save_written(rn, written, plain, gate, heldout, given is not None, source)
            pairs = w.residual_pairs(result) if parameters["plots"] else []
            result.pop("_reid")
            kept = gate.doc["kept"]
            result.update({"model": str(model_path), "baseline_kind": kind, "generalisation": gate.doc,
                           "data": {"source": source, "samples": int(all_q.shape[0]), "rate_hz": rate}
                           | ({} if pieces is None else {"pieces": pieces}),
                           # what `rig runs` lists for this run
                           "summary": {"verdict": result["verdict"], "effects": " ".join(kept) or "none"}})
            if parameters["plots"]:
                structured = [d for d in result["detection"]["final"] if d["structured"]]
                result["plots"] = figures(pairs, structured, w, gate.doc, rn.dir)
            rn.finish(result)
    return rn.result


def _load(parameters: dict, run_dir, rate: float, settings):
    """(q, dq, tau, source, breaks, pieces) of a CSV, or of a run's recording in pieces."""
    from calibration.datasets import load_csv

    if parameters["csv"]:
        data = load_csv(parameters["csv"], rate, parameters["joints"])
        return data.q, data.dq, data.tau, str(parameters["csv"]), [], None
    record = load_run_pieces(run_dir, parameters["arm"], rate, settings)
    pieces = {"seconds": record.pieces, "dropped_seconds": record.dropped, "breaks": record.breaks,
              "pause_longer_than_s": PAUSE_CUTOFF_PERIODS / settings.cutoff}
    return record.q, record.dq, record.tau, record.source, record.breaks, pieces


def _save_written(rn, written, plain, gate, heldout: dict, given: bool, source: str):
    """The model the gate chose, with its effects, written to the run folder (model.json)."""
    from calibration.effects import describe
    from rig.model.model_file import save_model
    from rig.runs.model_results import provenance

    return save_model(
        rn.dir / "model.json", standard=written.standard, names=plain.names, slope=written.slope,
        gravity=written.gravity, stribeck=written.stribeck,
        gravity_source="given model" if given else "estimated",
        validation={"other_motion": gate.doc["method"], "choice": gate.doc["choice"],
                    "relative_error_plain": gate.doc["relative_error"]["plain"],
                    "relative_error_written": gate.doc["relative_error"]["written"],
                    "heldout_rms_plain": heldout["rms_plain"], "heldout_rms_written": heldout["rms_written"],
                    "note": "plain: the model `rig identify` fits on the same training data (or the given "
                            "model); written: this file; relative errors on the other motion"},
        provenance_info=provenance(source, rn.dir, {"procedure": PROCEDURE}),
        extra={"effects": written.effects, "effects_catalogue": describe()["version"],
               "plain_model": str(plain.path),
               "effects_note": "torques of the effects add to the rigid-body model: "
                               "calibration.effects.effects_torque(effects, q, dq, tau_model)"})


def _heldout_figures(gate, result, workflow_result: dict) -> dict:
    """The plain and the written model on the training record's held-out block (the block
    the workflow's figures are on): RMS (N m, N m, N) and relative error per joint (the
    workflow's own model, when written: its RMS as written, no relative error)."""
    from calibration.generalisation import IDENTIFIED_CHOICE

    w = gate.w
    out = {"rms_plain": w.heldout_rms(w.fixed).tolist(), "rel_plain": w.heldout_rel(w.fixed).tolist()}
    if result.doc["choice"] == IDENTIFIED_CHOICE:
        pred = gate.predicted(result.model)
        return out | {"rms_written": w.heldout_rms(pred).tolist(), "rel_written": w.heldout_rel(pred).tolist()}
    if result.model is not None:
        sc = workflow_result.get("standard_consistency") or {}
        return out | {"rms_written": sc.get("heldout_rms", workflow_result["final"]["heldout_rms"]),
                      "rel_written": None}
    pred = gate.fit(result.kept, result.refit_joints)["pred"]
    return out | {"rms_written": w.heldout_rms(pred).tolist(), "rel_written": w.heldout_rel(pred).tolist()}


def _generalisation_figure(doc: dict, path_dir: Path) -> dict:
    """Bar chart: relative error per joint of the plain and the written model on the other
    motion (or cross-validated), the effects that were not confirmed named."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out: dict = {}
    plain, written = doc["relative_error"]["plain"], doc["relative_error"]["written"]
    x = np.arange(3)
    fig, ax = plt.subplots(figsize=(7, 4.2))
    ax.bar(x - 0.2, plain, 0.4, label="plain (rig identify's model)")
    refit = "".join(f", friction {j} refitted" for j in doc.get("friction_refitted_alone_on_joints", []))
    ax.bar(x + 0.2, written, 0.4, label="written (+ " + (", ".join(doc["kept"]) or "no effect") + refit + ")")
    ax.set_xticks(x, ["joint 1", "joint 2", "joint 3"])
    ax.set_ylabel("relative error on the other motion")
    dropped = ", ".join(f"{d['effect']}@{d['joint']}" for d in doc["not_confirmed"])
    ax.set_title(doc["method"][:70] + ("\nnot confirmed: " + dropped if dropped else ""), fontsize=9)
    ax.legend()
    ax.grid(alpha=0.3, axis="y")
    _save(fig, path_dir, "generalisation.png", out)
    return out


@procedure_command(PROCEDURE, STEPS, PARAMETERS, steps_help="List the steps and exit.", yes=False, context=False)
@click.argument("run_dir", required=False)
def command(run_dir, parameters, as_json: bool) -> None:
    """Find where the model and the measurement disagree, name the missing effect from the
    catalogue, add it and show the held-out gap shrink. RUN_DIR or --csv FILE.
    """
    if bool(run_dir) == bool(parameters["csv"]):
        raise click.UsageError("give either RUN_DIR or --csv FILE")
    from calibration.base_params import RankDeficientError
    from calibration.datasets import DataError
    from calibration.discrepancy.settings import DiscrepancyError
    from calibration.prediction import PredictionError
    from calibration.signals import SignalError
    from rig.model.model_file import ModelFileError
    from rig.runs.recorded_run import ExportError

    try:
        result = run(parameters, run_dir)
    except (DataError, SignalError, RankDeficientError, DiscrepancyError, ModelFileError, ExportError,
            PredictionError) as exc:
        click.echo(f"rig {PROCEDURE}: {exc}", err=True)
        sys.exit(EXIT_INPUT)  # the data or the model named cannot carry the analysis
    emit_result(result, as_json, report(result))
