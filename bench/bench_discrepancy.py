"""Benchmark of the discrepancy workflow (issue 7): confusion matrix over seeded hidden cases,
null false discoveries, held-out gap against the rig's noise floor, time, real data.

    python bench/bench_discrepancy.py [--seeds 2] [--workers 2]

Every catalogue effect on each joint (1-3) is hidden in the simulated rig (seeds 0..S-1,
`calibration.hidden_effects`); the workflow sees only the recorded arrays. Effects a model
identified on the same data already contains (payload, torque offset, Coulomb asymmetry:
see calibration.effects) are run against a model identified beforehand on other null runs
(--model; `calibration.hidden_effects.reference_runs`: an optimised excitation and a
multi-sine); the others against the thesis model identified on the training block. The noise
floor of a case is the same baseline's held-out RMS on its twin (same seed, trajectory, sensor
noise and plant set-up, the effect's size 0: `generate(..., twin=True)`). Null seeds 100.. are
disjoint from the threshold calibration's.

Two-motion null records are what `rig identify` records: its optimised excitation, then its
validation trajectory (a random one per seed), both at its defaults, each its own recording,
put end to end with the join given to the workflow; their given model is identified on
another such record (seeds 300..). The thresholds are calibrated on one-motion records only,
so their false discoveries are reported, not held to the 5 % target: calibrated over both
kinds (tried in November 2026), joint 3's thresholds more than doubled (Ljung-Box 71 -> 152,
delta BIC 40 -> 150 identified) and two true detections were lost (backlash@3 seed 0 and the
spring of spring@1+hysteresis@3 seed 1), while 2 of these 20 records were still flagged.

The held-out target's misses are sorted into weak cases (a baseline under twice the floor
cannot be halved without going below the floor), cases where the effect's true law, given the
truth, also stays above 1.2 x the floor (`bench/bench_discrepancy_oracle.py`, for backlash
and stiction), and the rest.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from multiprocessing import Pool
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench._table import print_table  # noqa: E402

#: The WPI PSM data beside the repository (../shared), as the other benches find it.
REAL = Path(__file__).resolve().parents[2] / "shared" / "data" / "wpi-psm" / "one_results.csv"
EQUIVALENT = {"coulomb_asymmetry": "torque_offset", "torque_offset": "torque_offset"}
NULL_SEEDS_BASE = 100


def _mode_for(effects) -> str:
    from calibration.effects import CATALOGUE

    return "given_model" if any(e in CATALOGUE and CATALOGUE[e].in_rigid_body_model for e, _ in effects) \
        else "identified"


def run_case(args):
    """(label, effects, seed, mode) -> figures of one case (runs in a worker)."""
    effects, seed, mode = args
    from calibration.discrepancy.settings import Settings
    from calibration.discrepancy.workflow import Discrepancy
    from calibration.discrepancy_null import reference_model, sim_model_and_base
    from calibration.hidden_effects import HiddenCase, generate

    model, base = sim_model_and_base()
    given = None
    if mode == "given_model":
        given, slope = reference_model(model, base, seed)
        model.slope = slope
    rec, truth = generate(HiddenCase(tuple(effects), seed))
    t0 = time.perf_counter()
    w = Discrepancy(model, base, rec.q, rec.dq, rec.tau, rec.rate, given, Settings())
    res = w.run()
    seconds = time.perf_counter() - t0
    floor = None
    if effects:
        nrec, _ = generate(HiddenCase(tuple(effects), seed), twin=True)
        wn = Discrepancy(model, base, nrec.q, nrec.dq, nrec.tau, nrec.rate, given, Settings())
        floor = wn.heldout_rms().tolist()
    return {"effects": effects, "seed": seed, "mode": mode, "verdict": res["verdict"],
            "found": [(e["name"], e["joint"]) for e in res["effects"]],
            "baseline_rms": res["baseline"]["heldout_rms"], "final_rms": res["final"]["heldout_rms"],
            "floor": floor, "seconds": seconds, "truth": truth.params}


TWO_MOTION_SEEDS_BASE = 300


def identify_excitation() -> dict:
    """The excitation `rig identify` designs at its defaults (procedures.identify.
    design_excitation's design, without its wall-clock budget so that every machine gets the
    same one; ~1 min), as a dict."""
    from calibration.base_params import base_parameters_of
    from calibration.excitation import ExcitationDesigner
    from calibration.identification import make_model
    from procedures.identify import PARAMETERS
    from rig.commands.parameters import resolve
    from rig.model.psm_kinematics import DQ_MAX, Q_MAX, Q_MIN

    d = resolve(PARAMETERS, {})
    model = make_model(np.array([0.0, 0.0, -9.81]), 400.0)
    base = base_parameters_of(model.regressor_batch, model, Q_MIN, Q_MAX, DQ_MAX)
    designer = ExcitationDesigner(model.regressor_batch, base.independent, Q_MIN, Q_MAX,
                                  d["velocity_fraction"] * DQ_MAX, frequency_hz=d["frequency"],
                                  harmonics=d["harmonics"], duration=d["duration"], rate=200.0)
    return designer.optimise(n_starts=d["starts"], seed=d["design_seed"], maxiter=d["iterations"],
                             time_budget=1e9).trajectory.to_dict()


def _two_motions(excitation, excitation_seed: int, validation_seed: int, design_seed: int):
    """``excitation`` streamed on the null plant (noise seed ``excitation_seed``), then `rig
    identify`'s validation trajectory of ``design_seed`` (noise seed ``validation_seed``)."""
    from calibration.hidden_effects import HiddenCase, generate
    from procedures.identify import PARAMETERS
    from procedures.identify_trajectories import validation_trajectory
    from rig.commands.parameters import resolve

    d = resolve(PARAMETERS, {})
    validation = validation_trajectory(d["validation_frequency"], d["duration"], d["harmonics"], design_seed, d["fill"])
    first, _ = generate(HiddenCase((), excitation_seed), excitation=excitation)
    second, _ = generate(HiddenCase((), validation_seed), excitation=validation)
    return first, second


def run_two_motion_null(args):
    """(seed, mode, excitation as a dict) -> figures of one two-motion null record (runs in a worker)."""
    seed, mode, excitation = args
    from calibration.discrepancy.settings import Settings
    from calibration.discrepancy.workflow import Discrepancy, identify_on_runs
    from calibration.discrepancy_null import sim_model_and_base
    from calibration.excitation import FourierTrajectory

    excitation = FourierTrajectory.from_dict(excitation)
    model, base = sim_model_and_base()
    given = None
    if mode == "given_model":
        # a lab's earlier `rig identify` on the same rig: other noise and another validation trajectory
        runs = _two_motions(excitation, 4_000_003 + seed, 5_000_003 + seed, 6_000_003 + seed)
        given, slope = identify_on_runs(model, base, [(r.q, r.dq, r.tau, r.rate) for r in runs])
        model.slope = slope
    first, second = _two_motions(excitation, 7_000_003 + seed, 3_000_003 + seed, seed)
    q, dq, tau = (np.vstack([getattr(first, k), getattr(second, k)]) for k in ("q", "dq", "tau"))
    t0 = time.perf_counter()
    w = Discrepancy(model, base, q, dq, tau, first.rate, given, Settings(), breaks=[len(first.q)])
    res = w.run()
    return {"effects": [], "seed": seed, "mode": mode, "verdict": res["verdict"],
            "found": [(e["name"], e["joint"]) for e in res["effects"]],
            "detection": [(round(x["ljung_box"], 1), round(x["library_r2"], 3)) for x in res["detection"]["initial"]],
            "seconds": time.perf_counter() - t0}


def predicted_label(r) -> str:
    if r["found"]:
        e, j = r["found"][0]
        return f"{e}@{j}"
    return r["verdict"]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--null-seeds", type=int, default=20)
    ap.add_argument("--two-motion-seeds", type=int, default=10,
                    help="two-motion null records (as `rig identify` records) per baseline")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--effects", nargs="+", default=None,
                    help="only these catalogue effects (rows); skips the two-effect and outside cases")
    a = ap.parse_args(argv)
    from calibration.effects import IDS
    from calibration.hidden_effects import OUTSIDE_CASES

    jobs = []
    for s in range(a.seeds):
        for e in (a.effects or IDS):
            for j in (1, 2, 3):
                jobs.append(([(e, j)], s, _mode_for([(e, j)])))
    nulls = [([], NULL_SEEDS_BASE + k, mode) for k in range(a.null_seeds) for mode in ("identified", "given_model")]
    pairs = [([("spring", 1), ("hysteresis", 3)], s, "identified") for s in range(a.seeds)] + \
            [([("time_delay", 2), ("viscous_nonlinear", 3)], s, "identified") for s in range(a.seeds)]
    outside = [([(o, j)], s, "identified") for o in OUTSIDE_CASES for j in (1, 3) for s in range(a.seeds)]
    two_motion = [(TWO_MOTION_SEEDS_BASE + k, mode) for k in range(a.two_motion_seeds)
                  for mode in ("identified", "given_model")]
    if a.effects:
        pairs, outside, two_motion = [], [], []
    t0 = time.perf_counter()
    if two_motion:
        excitation = identify_excitation()   # ~1 min, once
        two_motion = [(s, mode, excitation) for s, mode in two_motion]
    with Pool(a.workers) as pool:
        results = pool.map(run_case, jobs + nulls + pairs + outside, chunksize=1)
        nul2 = pool.map(run_two_motion_null, two_motion, chunksize=1)
    wall = time.perf_counter() - t0
    cat = results[:len(jobs)]
    nul = results[len(jobs):len(jobs) + len(nulls)]
    two = results[len(jobs) + len(nulls):len(jobs) + len(nulls) + len(pairs)]
    out = results[len(jobs) + len(nulls) + len(pairs):]

    # Confusion matrix: truth effect (any joint) x predicted effect; joint correctness separately.
    labels = list(IDS) + ["none", "unexplained"]
    conf = {t: {p: 0 for p in labels} for t in IDS}
    strict = equiv = 0
    gap_ok = gap_n = 0
    clear_ok = clear_n = 0
    rows_gap = []
    for r in cat:
        (e, j), = r["effects"]
        pe = r["found"][0][0] if r["found"] else r["verdict"]
        conf[e][pe] += 1
        ok = bool(r["found"]) and r["found"][0] == (e, j)
        ok_eq = bool(r["found"]) and r["found"][0][1] == j and (
            r["found"][0][0] == e or (e in EQUIVALENT and EQUIVALENT.get(r["found"][0][0]) == EQUIVALENT[e]))
        strict += ok
        equiv += ok_eq
        if ok_eq:
            b, f, fl = r["baseline_rms"][j - 1], r["final_rms"][j - 1], r["floor"][j - 1]
            good = f <= 0.5 * b and f <= 1.2 * fl
            gap_n += 1
            gap_ok += good
            # With a baseline under twice the floor, halving it means going below the floor.
            if b >= 2.0 * fl:
                clear_n += 1
                clear_ok += good
            rows_gap.append((e, j, r["seed"], b, f, fl, good))
    n = len(cat)
    fd = [r for r in nul if r["verdict"] != "none"]
    fd2 = [r for r in nul2 if r["verdict"] != "none"]
    two_ok = sum(set(map(tuple, r["effects"])) <= set(r["found"]) for r in two)
    two_some = sum(bool(set(map(tuple, r["effects"])) & set(r["found"])) for r in two)
    out_ok = sum(r["verdict"] == "unexplained" for r in out)
    out_named = sum(r["verdict"] == "explained" for r in out)
    tmax = max(r["seconds"] for r in results)
    tmax2 = max([r["seconds"] for r in nul2], default=0.0)

    print("\nConfusion matrix (rows: hidden effect, any joint; columns: first effect named or verdict)")
    short = {k: k[:9] for k in labels}
    print(f"{'hidden':>18} " + " ".join(f"{short[p]:>9}" for p in labels))
    for t in IDS:
        print(f"{t:>18} " + " ".join(f"{conf[t][p]:>9}" for p in labels))
    print("\nPer case (hidden -> found, verdict):")
    for r in cat:
        (e, j), = r["effects"]
        print(f"  {e}@{j} seed {r['seed']} [{r['mode']}]: {predicted_label(r)} ({r['verdict']}) "
              f"rms {np.round(r['baseline_rms'][j - 1], 4)} -> {np.round(r['final_rms'][j - 1], 4)} "
              f"floor {np.round(r['floor'][j - 1], 4)} (final/floor {r['final_rms'][j - 1] / r['floor'][j - 1]:.2f}) "
              f"{r['seconds']:.1f} s")
    for r in two + out:
        print(f"  {'+'.join(f'{e}@{j}' for e, j in r['effects'])} seed {r['seed']}: found {r['found']} ({r['verdict']}) "
              f"{r['seconds']:.1f} s")
    slowest = max(results, key=lambda r: r["seconds"])
    print(f"  slowest: {'+'.join(f'{e}@{j}' for e, j in slowest['effects']) or 'null'} seed {slowest['seed']} "
          f"[{slowest['mode']}] {slowest['seconds']:.1f} s (workflow only, under the bench's workers)")
    for r in fd:
        print(f"  null seed {r['seed']} [{r['mode']}]: false discovery {r['found']} ({r['verdict']})")
    for r in nul2:
        print(f"  two-motion null seed {r['seed']} [{r['mode']}]: {r['verdict']} {r['found']} "
              f"(Ljung-Box, library R^2 per joint {r['detection']}) {r['seconds']:.1f} s")

    # The misses of the held-out target: weak cases (baseline under twice the floor) cannot
    # halve the baseline without going below the floor; for the others with an oracle
    # (bench_discrepancy_oracle: the true law, given the truth), does even the truth reach it?
    from bench.bench_discrepancy_oracle import ORACLE_EFFECTS, TARGET

    misses = [row for row in rows_gap if not row[6]]
    weak = [row for row in misses if row[3] < 2.0 * row[5]]
    strong = [row for row in misses if row[3] >= 2.0 * row[5]]
    checked = [row for row in strong if row[0] in ORACLE_EFFECTS]
    with Pool(a.workers) as pool:
        ratios = pool.map(_oracle_job, [(e, j, seed) for e, j, seed, *_ in checked])
    beyond = sum(x > TARGET for x in ratios)
    for (e, j, seed, b, f, fl, _), x in zip(checked, ratios):
        print(f"  miss {e}@{j} seed {seed}: final/floor {f / fl:.2f}; the true law given the truth {x:.2f}")
    miss_text = (f"{len(weak)} weak; {beyond}/{len(checked)} where the true law also stays above {TARGET} x floor; "
                 f"{len(strong) - len(checked)} without an oracle")

    real = real_data()
    # The bench's 40 null runs are few for a 5 % rate; the calibration's own runs, each tested
    # against thresholds set on the others, are a second estimate of the same rate.
    from calibration.discrepancy.settings import THRESHOLDS_PATH
    from calibration.discrepancy_null import leave_one_out

    loo = leave_one_out(json.loads(THRESHOLDS_PATH.read_text()))
    loo_flagged, loo_n = sum(v[0] for v in loo.values()), sum(v[1] for v in loo.values())
    loo_rate = loo_flagged / loo_n
    loo_text = f"{loo_flagged}/{loo_n} = {loo_rate:.0%} (" + ", ".join(f"{m} {f}/{k}" for m, (f, k) in loo.items()) + ")"
    rows = [
        ("correct name and joint (strict)", f"{strict}/{n} = {strict / n:.0%}", ">= 90%", strict / n >= 0.9),
        ("correct name and joint (coulomb_asymmetry = torque_offset)", f"{equiv}/{n} = {equiv / n:.0%}", ">= 90%",
         equiv / n >= 0.9),
        ("null false discoveries", f"{len(fd)}/{len(nul)}" + (f" = {len(fd) / len(nul):.0%}" if nul else ""),
         "<= 5%", bool(nul) and len(fd) / len(nul) <= 0.05),
        ("null false discoveries, leave-one-out over the calibration runs", loo_text, "<= 5%", loo_rate <= 0.05),
        ("two-motion null records (as rig identify records): false discoveries",
         f"{len(fd2)}/{len(nul2)}" + (f" = {len(fd2) / len(nul2):.0%} (" if nul2 else "")
         + ", ".join(f"{m} {sum(r['mode'] == m for r in fd2)}/{sum(r['mode'] == m for r in nul2)}"
                     for m in ("identified", "given_model")) + (")" if nul2 else ""), "report", True),
        ("held-out RMS <= 50% baseline and <= 1.2 x floor (correct cases)",
         f"{gap_ok}/{gap_n}" + (f" = {gap_ok / gap_n:.0%}" if gap_n else ""), "all", gap_n > 0 and gap_ok == gap_n),
        ("  of which the effect stands out (baseline >= 2 x floor)",
         f"{clear_ok}/{clear_n}" + (f" = {clear_ok / clear_n:.0%}" if clear_n else ""), "all",
         clear_n > 0 and clear_ok == clear_n),
        ("  the misses: weak / beyond the true law (bench_discrepancy_oracle) / other", miss_text, "report", True),
        ("two effects: both named", f"{two_ok}/{len(two)} (one of two: {two_some})", "all", bool(two) and two_ok == len(two)),
        ("outside the catalogue: verdict unexplained", f"{out_ok}/{len(out)} (wrongly explained: {out_named})",
         "all", bool(out) and out_ok == len(out)),
        ("workflow time, 6000 x 3 (max over cases)", f"{tmax:.1f} s", "< 60 s", tmax < 60),
        ("workflow time, two-motion records 12000 x 3 (max)", f"{tmax2:.1f} s", "report", True),
        ("real data: verdict / effects", real["summary"], "report", True),
        ("real data: held-out RMS baseline -> final (N m, N m, N)", real["gap"], "report", True),
    ]
    print()
    ok = print_table("Discrepancy workflow (issue 7)", rows)
    print(f"\nbench wall time {wall:.0f} s on {a.workers} workers; {len(results) + len(nul2)} cases")
    return 0 if ok else 1


def _oracle_job(args) -> float:
    from bench.bench_discrepancy_oracle import oracle_ratio

    return oracle_ratio(*args)


def real_data() -> dict:
    from procedures.discrepancy import PARAMETERS, run
    from rig.commands.parameters import resolve
    import tempfile

    if not REAL.exists():
        return {"summary": f"not run: {REAL} not found", "gap": "not run"}
    params = dict(resolve(PARAMETERS, {"csv": str(REAL), "plots": False}))
    root = Path(tempfile.mkdtemp())
    r = run(params, run_root=root, progress=False)
    eff = ", ".join(f"{e['name']}@{e['joint']}" for e in r["effects"]) or "no effect"
    b, f = r["baseline"]["heldout_rms"], r["final"]["heldout_rms"]
    gap = " / ".join(f"{x:.4f} -> {y:.4f} ({(y / x - 1) * 100:+.0f}%)" for x, y in zip(b, f))
    return {"summary": f"{r['verdict']}: {eff}", "gap": gap}


if __name__ == "__main__":
    sys.exit(main())
