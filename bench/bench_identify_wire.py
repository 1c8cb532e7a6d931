"""`rig identify` over the wire at its defaults, N runs: does every one complete?

    .venv/bin/python bench/bench_identify_wire.py [--runs 10] [--burners 2] [--domain 150]
                                                  [--cache DIR] [--period 0.001] [-- extra identify options]

`rig sim` serves the lab's rig (tests/hil/harness.py's ServedRig: ROS arms, a private
ROS_DOMAIN_ID, localhost discovery) and `rig identify --arm PSM1 --json` runs N times as
its own process, at its defaults unless options follow `--`. --burners K starts K
CPU-burning processes for the whole bench (the issue's loaded machine; they are ended at
the end). The excitation design is cached in --cache (default: a fresh folder, so the
first run designs it and the others find it, as in a lab; give the user cache to reuse
one): the first run's design time and the later runs' cache-hit time are reported.

Per run: status, the line it ended on, joint 1-3 validation errors (SDP, all samples and
moving samples), the excitation's margins (position and velocity, per joint, measured on
the simulated plant) against the largest tracking error the run met, and the closest the
measured joints came to their limits. Targets (issue 35, item 4): every run completes;
joint 1 validation error <= 0.1. Exits 1 when a row fails.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent))
from _table import print_table  # noqa: E402

from tests.hil.harness import ServedRig  # noqa: E402

TARGET_J1 = 0.1


def fmt(v, d=3) -> str:
    return " / ".join(f"{x:.{d}f}" for x in v)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=10, help="identify runs (default 10)")
    ap.add_argument("--burners", type=int, default=0, help="CPU-burning processes beside the rig (default 0)")
    ap.add_argument("--domain", type=int, default=150, help="ROS_DOMAIN_ID of the served rig (default 150)")
    ap.add_argument("--cache", default="", help="excitation design cache (RIG_CACHE; default a fresh folder)")
    ap.add_argument("--period", default="0.001", help="rig sim --ros-period, s (default 0.001)")
    ap.add_argument("extra", nargs="*", help="identify options after --")
    a = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="bench-identify-wire-"))
    cache = a.cache or str(tmp / "cache")
    burners = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(a.burners)]
    docs, rows = [], []
    try:
        with ServedRig(tmp / "wire", a.domain, sim_args=("--ros-period", a.period)) as rig:
            env = rig.env(RIG_CACHE=cache)
            print(f"rig sim on ROS_DOMAIN_ID={a.domain}, --ros-period {a.period}, {a.burners} CPU burners; "
                  f"runs in {rig.folder / 'logs'}, cache {cache}", flush=True)
            for k in range(a.runs):
                out = rig.run("identify", "--arm", "PSM1", *a.extra, env=env, timeout=900.0)
                doc = out.doc or {}
                docs.append((out, doc))
                exc = doc.get("excitation", {})
                print(f"  run {k + 1}: {doc.get('status', 'exit ' + str(out.code))} in {out.seconds:.0f} s"
                      + (f", j1..j3 validation {fmt(doc['validation']['sdp'])}" if "validation" in doc else "")
                      + (f", design {exc.get('design_seconds', 0):.1f} s ({'cache hit' if exc.get('cached') else 'designed'}"
                         f" {exc.get('lookup_seconds', float('nan')):.3f} s)" if exc else "")
                      + ("" if out.code == 0 else f": {doc.get('error') or out.last_line}"), flush=True)
    finally:
        for b in burners:
            b.terminate()
            b.wait()
    done = [d for o, d in docs if o.code == 0 and d.get("status") == "completed"]
    tb = sum("Traceback" in o.stderr for o, _ in docs)
    rows.append((f"runs completed ({a.burners} burners)", f"{len(done)} of {len(docs)}", f"{len(docs)} of {len(docs)}",
                 len(done) == len(docs)))
    for o, d in docs:
        if not (o.code == 0 and d.get("status") == "completed"):
            rows.append(("  ended on", (d.get("error") or o.last_line)[:110], "", False))
    rows.append(("tracebacks", str(tb), "0", tb == 0))
    if done:
        j1 = np.array([d["validation"]["sdp"][0] for d in done])
        j1m = np.array([d["validation_moving"]["sdp"][0] for d in done])
        rows.append(("joint 1 validation error, SDP (worst / median)", f"{j1.max():.3f} / {np.median(j1):.3f}",
                     f"<= {TARGET_J1}", bool(j1.max() <= TARGET_J1)))
        rows.append(("joint 1 validation error, moving samples (worst)", f"{j1m.max():.3f}", "report", True))
        worst = np.max([d["validation"]["sdp"] for d in done], axis=0)
        rows.append(("validation error j1/j2/j3, worst run", fmt(worst), "report", True))
        for label, mk, tk in (("excitation", ("excitation", "margin"), ("excitation", "met")),
                              ("validation", ("validation_margin",), ("validation_met",))):
            def get(d, path):
                for p in path:
                    d = d[p]
                return d
            m = get(done[0], mk)
            mets = [get(d, tk) for d in done]
            over = np.max([x["overshoot"] for x in mets], axis=0)
            vex = np.max([x["velocity_excess"] for x in mets], axis=0)
            closest = np.min([x["closest_to_position_limit"] for x in mets], axis=0)
            peak = np.max([x["peak_velocity_fraction"] for x in mets], axis=0)
            held = max(x.get("periods_waited_for_the_arm", 0) for x in mets)
            rows += [
                (f"{label}: margin position j1/j2/j3 [rad, rad, mm]", fmt(np.array(m["position"]) * [1, 1, 1e3], 4),
                 f"{m['safety']:g} x plant + sensor", True),
                (f"{label}: margin velocity [rad/s, rad/s, m/s]", fmt(m["velocity"], 4), "measured on the plant", True),
                (f"{label}: met beyond commanded range (worst run) [rad, rad, mm]", fmt(over * [1, 1, 1e3], 4),
                 "< margin", bool(np.all(over < np.array(m["position"])))),
                (f"{label}: met speed above commanded peak (worst run)", fmt(vex, 4), "< margin",
                 bool(np.all(vex < np.array(m["velocity"])))),
                (f"{label}: closest to a position limit [rad, rad, mm]", fmt(closest * [1, 1, 1e3], 4), "> 0",
                 bool(np.all(closest > 0))),
                (f"{label}: peak speed / Table 4.2 limit", fmt(peak, 3), "< 1", bool(np.all(peak < 1))),
                (f"{label}: periods the trajectory waited for the arm (worst run)", str(held), "report", True),
            ]
        first = docs[0][1].get("excitation", {})
        hits = [d["excitation"]["lookup_seconds"] for d in done if d["excitation"].get("cached")]
        if first:
            rows.append(("excitation design, first run [s]", f"{first.get('design_seconds', 0):.1f}"
                         + (" (cached before)" if first.get("cached") else ""), "report", True))
        if hits:
            rows.append(("excitation design cache hit [s] (worst)", f"{max(hits):.3f}", "report", True))
        rows.append(("whole run [s] (median)", f"{np.median([o.seconds for o, d in docs if d in done]):.0f}", "report",
                     True))
    ok = print_table(f"rig identify over the wire at its defaults ({a.runs} runs, {a.burners} CPU burners)", rows)
    print(f"\nruns in {tmp / 'wire' / 'logs'}")
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
