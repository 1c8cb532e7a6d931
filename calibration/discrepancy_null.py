"""Thresholds of the discrepancy workflow, set on null simulations (issue 7).

The residual of a correct model on filtered data is not white (the filter colours it, and
the plant's hard stick-slip switching leaves a small mismatch no smooth model removes), so
textbook chi-square quantiles would flag every data set. Instead the statistics are
measured on simulated data WITHOUT any hidden effect (the null), per joint, over seeded
runs of the generator (`calibration.hidden_effects`), and each threshold is set above the
largest null value with a margin:

* Ljung-Box Q:           1.25 x max over null seeds;
* library R^2:           max over null seeds + 0.05 (at least 0.05);
* candidate gain:        max over null seeds of the best sane catalogue candidate's held-out
                         variance removal on that joint + 0.05;
* delta BIC:             max over null seeds of the best sane candidate's BIC gain on the joint + 10.

Both baselines are calibrated: "identified" (the thesis model fitted on the training block)
and "given_model" (a model identified beforehand on other null runs of the same rig, as a
lab's earlier `rig identify`: `calibration.hidden_effects.reference_runs`, an optimised
excitation and a multi-sine, with their own seeds). Run ``python -m calibration.discrepancy_null [n_seeds [workers]]`` to regenerate
``discrepancy_thresholds.json``; the file records the seeds, the per-seed statistics and the
rule. Seeds used here (1000 + k) are disjoint from the test and bench seeds.
"""

from __future__ import annotations

import json
import sys
import time
from datetime import datetime, timezone

import numpy as np

from calibration.discrepancy.settings import THRESHOLDS_PATH, Settings
from calibration.discrepancy.workflow import Discrepancy, identify_on_runs

NULL_SEED_BASE = 1000
_HUGE = {"ljung_box": [1e12] * 3, "library_r2": [1e12] * 3, "gain": [1e12] * 3, "delta_bic": [1e12] * 3}


def sim_model_and_base():
    """The model of the simulated rig's arm (frame-0 gravity of an untilted base) and its
    base parameters."""
    from calibration.base_params import base_parameters_of
    from rig.model.psm_dynamics import PSMDynamics
    from rig.model.psm_kinematics import DQ_MAX, Q_MAX, Q_MIN

    model = PSMDynamics()
    return model, base_parameters_of(model.regressor_batch, model, Q_MIN, Q_MAX, DQ_MAX)


def reference_model(model, base, seed: int) -> tuple[np.ndarray, float]:
    """Standard parameters and Coulomb slope identified on the reference (null) runs that go
    with ``seed`` (`calibration.hidden_effects.reference_runs`: the optimised excitation and a
    multi-sine, all their samples). ``model.slope`` is set to that slope."""
    from calibration.hidden_effects import reference_runs

    return identify_on_runs(model, base, [(r.q, r.dq, r.tau, r.rate) for r in reference_runs(seed)])


def null_statistics(model, base, seed: int, mode: str) -> dict:
    """Detection statistics and the best sane candidate per joint on one null run."""
    from calibration.hidden_effects import HiddenCase, generate

    given = None
    if mode == "given_model":
        given, slope = reference_model(model, base, seed)
        model.slope = slope
    rec, _ = generate(HiddenCase((), seed))
    w = Discrepancy(model, base, rec.q, rec.dq, rec.tau, rec.rate, given,
                    Settings(thresholds={"identified": _HUGE, "given_model": _HUGE}))
    det = w.detect()
    cands = [c for c in w.candidates([1, 2, 3]) if not c["absorbed"] and c["sanity"] is None]
    best = {}
    for j in (1, 2, 3):
        on = [c for c in cands if c["joint"] == j]
        best[j] = {"gain": max([c["heldout_gain"] for c in on], default=0.0),
                   "delta_bic": max([c["delta_bic"] for c in on], default=0.0),
                   "best": max(on, key=lambda c: c["delta_bic"])["effect"] if on else None}
    return {"seed": seed, "ljung_box": [d["ljung_box"] for d in det], "library_r2": [d["library_r2"] for d in det],
            "gain": [best[j]["gain"] for j in (1, 2, 3)], "delta_bic": [best[j]["delta_bic"] for j in (1, 2, 3)],
            "best_candidate": [best[j]["best"] for j in (1, 2, 3)], "heldout_rms": w.heldout_rms().tolist()}


def thresholds_from(stats: list[dict]) -> dict:
    a = {k: np.array([s[k] for s in stats]) for k in ("ljung_box", "library_r2", "gain", "delta_bic")}
    return {"ljung_box": (1.25 * a["ljung_box"].max(0)).tolist(),
            "library_r2": np.maximum(a["library_r2"].max(0) + 0.05, 0.05).tolist(),
            "gain": (a["gain"].max(0) + 0.05).tolist(),
            "delta_bic": (a["delta_bic"].max(0) + 10.0).tolist()}


def leave_one_out(doc: dict) -> dict:
    """Null false-discovery rate the threshold rule gives, estimated on the calibration runs
    themselves: each run is tested against thresholds set on the others (the detection step
    is what turns a null verdict from "none": Ljung-Box or library R^2 over its threshold on
    any joint, or a catalogue candidate over both the BIC and the held-out gain thresholds;
    the runs store each joint's largest BIC gain and largest held-out gain, which may come
    from two candidates, so this count is an upper bound). Per baseline: (flagged runs, runs)."""
    out = {}
    for mode, stats in doc["null_runs"].items():
        flagged = 0
        for i in range(len(stats)):
            th = thresholds_from(stats[:i] + stats[i + 1:])
            st = stats[i]
            flagged += any(st["ljung_box"][j] > th["ljung_box"][j] or st["library_r2"][j] > th["library_r2"][j]
                           or (st["delta_bic"][j] > th["delta_bic"][j] and st["gain"][j] >= th["gain"][j])
                           for j in range(3))
        out[mode] = (flagged, len(stats))
    return out


def _null_job(args) -> dict:
    seed, mode = args
    model, base = sim_model_and_base()
    model.slope = 400.0
    return null_statistics(model, base, seed, mode)


def calibrate(n_seeds: int = 40, progress=print, workers: int = 2) -> dict:
    """Null statistics on ``n_seeds`` seeds for both baselines (``workers`` processes) and the
    thresholds from them."""
    from multiprocessing import Pool

    t0 = time.perf_counter()
    out = {"thresholds": {}, "null_runs": {}}
    seeds = [NULL_SEED_BASE + k for k in range(n_seeds)]
    jobs = [(s, mode) for mode in ("identified", "given_model") for s in seeds]
    with Pool(workers) as pool:
        stats = []
        for (s, mode), st in zip(jobs, pool.imap(_null_job, jobs)):
            stats.append(st)
            progress(f"{mode} seed {s}: LB {np.round(st['ljung_box'], 1).tolist()} "
                     f"R2 {np.round(st['library_r2'], 3).tolist()} gain {np.round(st['gain'], 3).tolist()} "
                     f"dBIC {np.round(st['delta_bic'], 1).tolist()} {st['best_candidate']}")
    for i, mode in enumerate(("identified", "given_model")):
        out["null_runs"][mode] = stats[i * n_seeds:(i + 1) * n_seeds]
        out["thresholds"][mode] = thresholds_from(out["null_runs"][mode])
    from calibration.effects import CATALOGUE_VERSION
    from calibration.hidden_effects import GENERATOR_VERSION, N_SAMPLES, RATE

    out["method"] = {"summary": f"null simulations, {n_seeds} seeds x 2 baselines",
                     "rule": __doc__.split("* Ljung-Box")[1].split("Both baselines")[0].strip(),
                     "seeds": seeds, "generator_version": GENERATOR_VERSION, "catalogue_version": CATALOGUE_VERSION,
                     "samples": N_SAMPLES, "rate_hz": RATE,
                     "settings": vars(Settings()) | {"thresholds": None},
                     "date": datetime.now(timezone.utc).isoformat(), "seconds": time.perf_counter() - t0}
    return out


if __name__ == "__main__":
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 40
    doc = calibrate(n, workers=int(sys.argv[2]) if len(sys.argv) > 2 else 2)
    THRESHOLDS_PATH.write_text(json.dumps(doc, indent=1) + "\n")
    print(json.dumps(doc["thresholds"], indent=1))
