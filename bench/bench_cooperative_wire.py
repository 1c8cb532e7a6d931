"""`rig cooperative` over the wire, per object x ROS period x clock x load (issues 35, 44).

For each ROS period `rig sim` serves (0.01 s = the dVRK's default, 0.002, 0.001) one
`rig sim` in its own folder (tests/hil/harness.py): the load cell calibrated, the arms
registered, then `--runs` cooperative runs per object (spring, string; the three-arm
triangle on a rig sim of its own) with a 3 cm move, each a separate `rig cooperative
--json` process as a lab runs it. The model: `rig identify` on the built-in simulated rig
(the same plant rig sim serves), passed with --force-model, so this bench measures the
force loop, not the identification. `--burners N` starts N CPU-burning processes for the
whole bench. `--clocks sim,wall`: `rig sim --sim-time` with the procedures in lockstep
([ros] use_sim_time; the default), and the wall clock, as against a real console.

    .venv/bin/python bench/bench_cooperative_wire.py [--runs 5] [--burners 2] [--periods 0.01,0.002,0.001] \
        [--clocks sim,wall] [--sources cell,model]

Prints per object x period: completed runs, false aborts, worst max |F - 5 N| during the
move and worst overshoot against 0.25 N and 0.5 N, the loop's rate and period (median /
p99 / max), and a refusal (with its line) where the procedure refuses the period.

Tuning log of procedures.cooperative's loop rates, on a 2-core machine shared with other
work (quiet, 3 runs each unless said):

- ARM_LOOP_MIN_RATE: at 100 Hz streams the spring held 0.18-0.43 N, but the string
  aborted 1 of 3 on the tension ceiling (2.6-5.3 N in the others) and the triangle 3 of 3;
  at 500 Hz streams neither aborted (string 0.85-1.9 N, triangle 0.47-1.8 N): they need
  the faster console (spring 100 Hz, string and triangle 500 Hz).
- ARM_LOOP_MAX_RATE: a tick with one slave costs 3-5 ms of Python (controller 1.5-2 ms,
  the servo_ci goal and message 0.4 ms, publishing and recording the rest). With both
  processes at 80-90 % of a core, 200 Hz starved the loop (periods to 30-70 ms at
  p99/max, the tension older than 10 ms on 8-18 % of ticks): 0.34-2.2 N while moving and
  aborts; 100 Hz: 0.25-0.68 N, no aborts in those runs.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent))
from _table import print_table  # noqa: E402

from tests.hil.harness import ServedRig, lab_toml  # noqa: E402

MOVE = ["--force", "5", "--move", "0.03,0,0", "--duration", "2", "--settle", "2", "--hold-after", "0.5"]


def _model(folder: Path) -> Path:
    """An identified model of the simulated plant (the built-in rig, in-process)."""
    env = dict(os.environ, RIG_LOGS=str(folder / "logs"))
    env.pop("RIG_CONFIG", None)
    folder.mkdir(parents=True, exist_ok=True)
    subprocess.run([sys.executable, "-m", "rig.cli", "identify", "--arm", "PSM1", "--duration", "10", "--starts", "1",
                    "--iterations", "5", "--no-plots", "--json"], cwd=folder, env=env, check=True,
                   capture_output=True, text=True)
    return sorted((folder / "logs").glob("*-identify/model.json"))[-1]


def _prepare(rig: ServedRig, cells: int) -> str | None:
    for k in range(cells):
        out = rig.run("loadcell-calibrate", "--seconds", "0.5", *(["--element", str(k)] if cells > 1 else []))
        if out.code:
            return f"loadcell-calibrate: {out.last_line}"
    out = rig.run("register", "--points", "6")
    return None if out.code == 0 else f"register: {out.last_line}"


def _runs(rig: ServedRig, label: str, args: list[str], n: int) -> dict:
    """n runs: the documents of those that ran to the end (completed, or failed on the
    tolerance), the lines of those that aborted, and a refusal's line."""
    docs, aborts, refused = [], [], None
    for i in range(n):
        out = rig.run("cooperative", *args)
        doc = out.doc or {}
        status = doc.get("status", f"exit {out.code}")
        line = doc.get("error") or ("" if out.code == 0 else out.last_line)
        print(f"  {label} run {i + 1}: {status}"
              + (f", {doc['max_error_during_motion']:.3f} N moving, overshoot {doc['overshoot']:.3f} N"
                 if doc.get("max_error_during_motion") is not None else "") + (f" ({line[:160]})" if line else ""),
              flush=True)
        if "heard at" in line and "needs" in line:
            refused = line
            break
        if doc.get("max_error_during_motion") is not None:
            docs.append(doc)
        elif status != "completed":
            aborts.append(line or status)
    return {"docs": docs, "aborts": aborts, "refused": refused}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=5, help="runs per object and period")
    ap.add_argument("--burners", type=int, default=0, help="CPU-burning processes beside the rig")
    ap.add_argument("--periods", default="0.01,0.002,0.001", help="rig sim --ros-period values, s")
    ap.add_argument("--objects", default="spring,string,three", help="spring, string, three (the triangle)")
    ap.add_argument("--clocks", default="sim", help="sim (rig sim --sim-time, lockstep), wall, or both: sim,wall")
    ap.add_argument("--sources", default="cell", help="what the force loop closes on: cell, model (issue 47's "
                    "estimate; the cell only records and judges), or both: cell,model")
    a = ap.parse_args()
    burners = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(a.burners)]
    rows = []
    try:
        with tempfile.TemporaryDirectory(prefix="bench-coop-wire-") as tmp:
            tmp = Path(tmp)
            model = _model(tmp / "model")
            common = MOVE + ["--model", str(model), "--force-model"]
            cases = [(c, p, o, src) for c in a.clocks.split(",") for p in a.periods.split(",")
                     for o in a.objects.split(",") for src in a.sources.split(",")]
            for clock, period, obj, source in cases:
                    sim_time = clock == "sim"
                    three = obj == "three"
                    folder = tmp / f"{obj}-{period}-{clock}-{source}"
                    domain = 170 + (os.getpid() + len(rows)) % 30
                    label = f"{obj} @ {period} s, {clock}" + (", loop on the model" if source == "model" else "")
                    # the loop on the estimate is judged on the cell against the thesis'
                    # hardware figure (issue 47), the loop on the cell against issue 35's
                    target = 0.5 if source == "model" else 0.25
                    print(f"{obj} at --ros-period {period} on the {clock} clock ({a.burners} burners):", flush=True)
                    # [rig] rate no faster than the arms publish (every procedure refuses a
                    # slower stream than its loop needs: rig.devices.factory.check_stream_rates); rig
                    # sim's arms keep their 500 Hz servo (--rate), as a console's do at any -p
                    rate = min(500.0, round(1.0 / float(period)))
                    with ServedRig(folder, domain, toml=lab_toml(folder, three_arms=three, rate=rate, sim_time=sim_time),
                                   sim_args=("--rate", "500", "--ros-period", period), sim_time=sim_time) as rig:
                        problem = _prepare(rig, 3 if three else 1)
                        if problem:
                            rows.append((f"{label}: set-up", problem[:80], "completes", False))
                            continue
                        args = common + (["--arms", "PSM1,PSM2,PSM3", "--object", "spring"] if three
                                         else ["--object", obj]) + ["--tension-source", source]
                        r = _runs(rig, obj, args, a.runs)
                        said = rig.stop(keep_domain=True)
                    factor = next((ln.split("real-time factor followed ")[1].split(")")[0] for ln in said.splitlines()
                                   if "real-time factor followed" in ln), None)
                    if r["refused"]:
                        rows.append((f"{label}: refused", r["refused"][:100], "one line", True))
                        continue
                    docs = r["docs"]
                    worst = max((d["max_error_during_motion"] for d in docs), default=float("nan"))
                    over = max((d["overshoot"] for d in docs), default=float("nan"))
                    done = sum(d.get("status") == "completed" for d in docs)
                    rows.append((f"{label}: completed / failed (0.5 N) / aborted",
                                 f"{done} / {len(docs) - done} / {len(r['aborts'])}", f"{a.runs} / 0 / 0",
                                 done == a.runs and not r["aborts"]))
                    rows.append((f"{label}: worst max |F - 5 N| moving / overshoot",
                                 f"{worst:.3f} / {over:.3f} N", f"<= {target:g} / 0.5", worst <= target and over <= 0.5))
                    ests = [d["tension_estimate"] for d in docs if d.get("tension_estimate")]
                    if ests:
                        rows.append((f"{label}: estimate vs cell moving, worst RMS / max",
                                     f"{max(e['rms_difference'] for e in ests):.3f} / "
                                     f"{max(e['max_difference'] for e in ests):.3f} N", "<= 0.3 / 0.6",
                                     max(e["rms_difference"] for e in ests) <= 0.3
                                     and max(e["max_difference"] for e in ests) <= 0.6))
                    if docs:
                        lt = docs[-1]["loop_timing"]
                        rows.append((f"{label}: loop rate, period median / p99 / max",
                                     f"{lt['rate_hz']:g} Hz, {lt['period_ms_median']:.2f} / {lt['period_ms_p99']:.1f}"
                                     f" / {lt['period_ms_max']:.0f} ms", "reported", True))
                        tick = docs[-1].get("loop_tick") or {}
                        if tick:
                            rows.append((f"{label}: tick median / p99 against the period",
                                         f"{tick['tick_median_ms']:.2f} / {tick['tick_p99_ms']:.2f} of "
                                         f"{tick['period_ms']:.1f} ms", "reported", True))
                    if factor is not None:
                        rows.append((f"{label}: rig sim's real-time factor while followed", factor, "> 1 quiet",
                                     a.burners > 0 or float(factor) > 1.0))
    finally:
        for b in burners:
            b.kill()
    ok = print_table(f"rig cooperative over the wire, {a.runs} runs each, {a.burners} CPU burners", rows)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
