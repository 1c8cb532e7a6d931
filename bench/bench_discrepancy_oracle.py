"""How close to the noise floor can the held-out residual of a hidden case get at all?

    python bench/bench_discrepancy_oracle.py [--seeds 3] [--cases backlash:1,stiction:3]

bench_discrepancy's held-out target asks the augmented model to come within 1.2 x the case's
noise floor. For the cases that miss it, this bench asks the question with the truth in hand
(the scorer's side; the workflow never sees it):

* "true model": the baseline is the simulated plant's own standard parameters (`generate`'s
  plant, its rigid body and drive friction exactly), as a given model, at the smooth-sign
  slope that predicts the case's twin best on the effect's joint; the floor is that model's
  held-out RMS on the twin (same seed, trajectory and noise draws, the effect's size 0);
* "identified": the thesis model identified on the training block together with the true
  column (the workflow's re-identification, with the effect's law given), at the slope the
  workflow chooses; the floor is bench_discrepancy's (the identified baseline on the twin).
  Re-identifying lets the other parameters absorb part of what the law misses, so this one
  can beat the true model;
* stiction: the catalogue's Stribeck column at the true Stribeck velocity, with the true
  excess dFs, and with dFs fitted on the training block;
* backlash: the column the play makes given the simulator's own joint-side velocity
  (`Truth.joint_velocity`, which the encoder does not see): effort - model on the motor side
  = -(L (dq_motor - dq_joint))' + friction(dq_joint) - friction(dq_motor), with L = M_jj less
  the motor side's inertia and the derivative taken as the baseline's inertial term takes it;
  fitted scale (1 if the law were exact) on the training block.

The figure per case is the better oracle's held-out RMS over its floor. Where it stays above 1.2,
the effect's law cannot meet bench_discrepancy's target on that case even with the truth in
hand. What is left is, we think, what a 200 Hz record does not carry: a play's contact ringing
at ~100 Hz and the joint side's stuck spells while it is open, or the friction's change
inside one sample during a stick-slip burst. The table's target row is that the oracle reaches
1.2 x floor; a FAIL there is the finding, not a defect of the workflow.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench._table import print_table  # noqa: E402

TARGET = 1.2
#: Effects this bench has an oracle for.
ORACLE_EFFECTS = ("backlash", "stiction")


def _joint_derivative(w, x: np.ndarray, j: int) -> np.ndarray:
    """d/dt of a raw per-sample signal the way the baseline's inertial term on joint j takes
    the measured velocity's (`Discrepancy._chains`)."""
    from calibration.signals import differentiate, lowpass

    p = w.p
    if w.inertia[j] == "measured":
        return differentiate(x, p.rate, "central4")
    return np.gradient(lowpass(x, p.rate, p.cutoff, p.order), 1.0 / p.rate)


def _fit(w, col_raw: np.ndarray, j: int, scale: float | None) -> tuple[float, float]:
    """(scale, held-out RMS on joint j) of the model plus scale x col (fitted on training if None)."""
    raw = np.zeros((len(col_raw), 3, 1))
    raw[:, j, 0] = col_raw
    E = w.p.filt_rows(raw).reshape(-1)
    if scale is None:
        tr = w.rows_tr
        r = w.y - w.pred
        scale = float(E[tr] @ r[tr] / (E[tr] @ E[tr]))
    return scale, float(w.heldout_rms(w.pred + scale * E)[j])


def _identified(model, base, rec, twin, joint: int, column) -> tuple[float, float, float]:
    """(floor, baseline, with the column) held-out RMS on the joint, the thesis model identified
    on the training block with ``column(w)`` (raw per-sample, joint's rows) added."""
    from calibration.discrepancy.refinement import Added
    from calibration.discrepancy.settings import Settings
    from calibration.discrepancy.workflow import Discrepancy

    j = joint - 1
    floor = float(Discrepancy(model, base, twin.q, twin.dq, twin.tau, twin.rate, None, Settings()).heldout_rms()[j])
    w = Discrepancy(model, base, rec.q, rec.dq, rec.tau, rec.rate, None, Settings())
    baseline = float(w.heldout_rms()[j])
    raw = np.zeros((len(rec.q), 3, 1))
    raw[:, j, 0] = column(w)
    w.added.append(Added("oracle", joint, None, w.p.filt_rows(raw), raw, np.ones(1, bool)))
    w._fit_current()
    return floor, baseline, float(w.heldout_rms()[j])


def run_case(effect: str, joint: int, seed: int) -> dict:
    from calibration.discrepancy.settings import SLOPES, Settings
    from calibration.discrepancy.workflow import Discrepancy
    from calibration.discrepancy_null import sim_model_and_base
    from calibration.effects import CATALOGUE
    from calibration.hidden_effects import HiddenCase, case_plant, generate

    t0 = time.perf_counter()
    j = joint - 1
    model, base = sim_model_and_base()
    case = HiddenCase(((effect, joint),), seed)
    rec, truth = generate(case)
    twin, _ = generate(case, twin=True)
    params, eff = case_plant(case)
    given = params.standard_vector()
    best = None
    for a in SLOPES:
        model.slope = a
        wt = Discrepancy(model, base, twin.q, twin.dq, twin.tau, twin.rate, given, Settings())
        floor = float(wt.heldout_rms()[j])
        if best is None or floor < best[0]:
            best = (floor, a)
    floor, model.slope = best
    w = Discrepancy(model, base, rec.q, rec.dq, rec.tau, rec.rate, given, Settings())
    baseline = float(w.heldout_rms()[j])
    tp = truth.params[0]
    out = {"case": f"{effect}@{joint} seed {seed}", "slope": model.slope, "floor": floor, "baseline": baseline,
           "chain": w.inertia[j]}
    if effect == "stiction":
        def column(w):
            return w._columns(CATALOGUE["stiction"], joint, tp["stribeck_velocity"], unfiltered=True)[:, j, 0]
        col = column(w)
        out["true"] = _fit(w, col, j, tp["size"])
        out["fitted"] = _fit(w, col, j, None)
    elif effect == "backlash":
        t = np.arange(len(rec.q)) / rec.rate
        v_joint = np.interp(t - Settings().effort_lag, t, truth.joint_velocity[:, j])
        motor = eff.backlash_motor_inertia[j]
        motor = 0.5 * params.drive.Ia[j] if np.isnan(motor) else motor

        def column(w):
            # The model's own M_jj, Coulomb level and viscous coefficient (the true plant's
            # for the true model, the current fit's when identified).
            fc, fv = np.nan_to_num(w._friction())[j]
            rel = w.p.dq[:, j] - v_joint
            sig = lambda v: np.tanh(0.5 * w.slope * v)   # noqa: E731
            return (-_joint_derivative(w, (w._mass_diag()[:, j] - motor) * rel, j)
                    + fc * (sig(v_joint) - sig(w.p.dq[:, j])) - fv * rel)
        out["fitted"] = _fit(w, column(w), j, None)
    else:
        raise ValueError(f"no oracle for {effect!r}: {', '.join(ORACLE_EFFECTS)} only")
    out["identified"] = _identified(model, base, rec, twin, joint, column)
    out["seconds"] = time.perf_counter() - t0
    return out


def best_ratio(r: dict) -> float:
    """The better oracle's held-out RMS over its floor (true model or identified)."""
    return min(min(r[k][1] for k in ("true", "fitted") if k in r) / r["floor"],
               r["identified"][2] / r["identified"][0])


def oracle_ratio(effect: str, joint: int, seed: int) -> float:
    return best_ratio(run_case(effect, joint, seed))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=3, help="seeds 0..S-1 per case (default 3)")
    ap.add_argument("--cases", default="backlash:1,backlash:2,backlash:3,stiction:3",
                    help="comma-separated effect:joint (default: the cases bench_discrepancy misses)")
    args = ap.parse_args()
    if args.seeds < 1:
        ap.error(f"--seeds {args.seeds}: at least 1")
    for spec in args.cases.split(","):
        effect, _, joint = spec.partition(":")
        if effect not in ORACLE_EFFECTS or joint not in ("1", "2", "3"):
            ap.error(f"--cases: {spec!r} is not effect:joint with effect one of {', '.join(ORACLE_EFFECTS)} "
                     "and joint 1-3")
    t0 = time.perf_counter()
    results = []
    print("case: true model: slope (s/rad or s/m), inertia chain | floor, baseline | oracle: scale -> "
          "held-out RMS (x floor) || identified with the true column: floor, baseline -> oracle (x floor)")
    for spec in args.cases.split(","):
        effect, joint = spec.split(":")
        for seed in range(args.seeds):
            r = run_case(effect, int(joint), seed)
            results.append(r)
            line = (f"  {r['case']}: slope {r['slope']:g}, {r['chain']} | floor {r['floor']:.4f}, baseline "
                    f"{r['baseline']:.4f} ({r['baseline'] / r['floor']:.2f}x)")
            for key in ("true", "fitted"):
                if key in r:
                    s, rms = r[key]
                    line += f" | {key} scale {s:.3f} -> {rms:.4f} ({rms / r['floor']:.2f}x)"
            fl, b, f = r["identified"]
            line += f" || identified: floor {fl:.4f}, baseline {b / fl:.2f}x -> {f / fl:.2f}x"
            print(line + f" | {r['seconds']:.0f} s", flush=True)
    rows = []
    for spec in args.cases.split(","):
        effect, joint = spec.split(":")
        mine = [r for r in results if r["case"].startswith(f"{effect}@{joint} ")]
        ratios = [best_ratio(r) for r in mine]
        ok = sum(x <= TARGET for x in ratios)
        rows.append((f"{effect}@{joint}: oracle held-out RMS <= {TARGET} x floor",
                     f"{ok}/{len(mine)} (best {min(ratios):.2f}x, worst {max(ratios):.2f}x)", "all", ok == len(mine)))
    rows.append(("bench wall time", f"{time.perf_counter() - t0:.0f} s", "report", True))
    ok = print_table("What the truth itself reaches on the cases bench_discrepancy misses (issue 7)", rows)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
