"""`rig sim` SIGKILLed at a random moment of a cooperative run, again and again (issue 37).

One `rig sim` in its own folder (tests/hil/harness.py) with the load cell calibrated, the
arms registered and an identified model of the simulated plant (`rig identify` on the
built-in rig, passed with --force-model). Each run is a `rig cooperative --json` process, as
a lab runs it; once it holds the object, rig sim is killed after a random delay (0 to
`--window` s), and a fresh rig sim is started for the next run. A run ends cleanly when the
procedure itself was not killed by a signal, printed no traceback, exited 3 (aborted), ended
its stderr with one `rig cooperative: aborted: ...` line, and its recording is finalised
with the reason. `--burners N` starts N CPU-burning processes for the whole bench.

    .venv/bin/python bench/bench_kill.py [--runs 200] [--burners 2] [--window 4] [--seed 0]

Prints the table (runs, signals, tracebacks, exit 3, one line, recording closed against
their targets) and, for every run that did not end cleanly, its exit and last lines. A run
that ended before it held the object (a connect failure on a starved machine) had no kill:
it is counted on its own row and left out of the others. `--keep DIR` writes the whole
stderr of every run that ended badly; with `ulimit -c unlimited` the cores of a crash are
what gdb reads (drivers/common/ros_exit.py tells what one showed).
"""

from __future__ import annotations

import argparse
import os
import random
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent))
from _table import print_table  # noqa: E402

from bench_cooperative_wire import _model  # noqa: E402  (an identified model of the simulated plant)
from tests.hil.harness import ServedRig, lab_toml  # noqa: E402

#: the step whose progress bar says the object is held and the master moves
HOLDING = "hold the tension while moving ["


def judge(out, run_dir: str | None) -> list[str]:
    """What was not clean about one run's ending (empty: clean)."""
    from rig.runs.recording import read_recording

    problems = []
    if out.code < 0:
        problems.append(f"killed by signal {-out.code} ({signal.Signals(-out.code).name})")
    if "Traceback" in out.stderr or "Fatal Python error" in out.stderr:
        problems.append("a traceback or a fatal error on stderr")
    if out.code != 3:
        problems.append(f"exit {out.code}, not 3")
    if not out.last_line.startswith("rig cooperative: aborted: "):
        problems.append(f"last line: {out.last_line[:160]!r}")
    if run_dir is None:
        problems.append("no run folder")
    else:
        rec = read_recording(os.path.join(run_dir, "run.mcap"))
        if not rec.finalised or rec.stop is None or rec.stop.get("status") != "aborted" or not rec.stop.get("error"):
            problems.append(f"recording not closed with the reason ({rec.problem or rec.stop})")
    return problems


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=200)
    ap.add_argument("--burners", type=int, default=0)
    ap.add_argument("--window", type=float, default=4.0, help="s: rig sim dies up to this long into the hold")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--keep", default=None, help="folder to write the whole stderr of every run that ended badly")
    args = ap.parse_args()
    rng = random.Random(args.seed)
    burners: list[subprocess.Popen] = []  # started once the rig is prepared: the load is on the kills
    rows_bad: list[tuple[int, float, list[str], str]] = []
    counts = {"signal": 0, "traceback": 0, "exit3": 0, "one_line": 0, "closed": 0, "before": 0}
    t0 = time.monotonic()
    try:
        with tempfile.TemporaryDirectory(prefix="bench-kill-") as tmp:
            folder = Path(tmp)
            model = _model(folder / "model")
            lab = folder / "lab"
            with ServedRig(lab, toml=lab_toml(lab), sim_args=("--ros-period", "0.002")) as rig:
                for what in (("loadcell-calibrate", "--seconds", "0.5"), ("register", "--points", "6")):
                    out = rig.run(*what)
                    if out.code:
                        print(f"{what[0]} failed: {out.last_line}")
                        return 2
                burners += [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(args.burners)]
                for i in range(args.runs):
                    if not rig.running:
                        rig.restart()
                    delay = rng.uniform(0.0, args.window)
                    fired: list[bool] = []

                    def kill(d=delay) -> None:
                        fired.append(True)
                        time.sleep(d)
                        rig.kill(signal.SIGKILL)

                    out = rig.run("cooperative", "--force", "5", "--move", "0.03,0,0", "--duration", "6",
                                  "--settle", "1.5", "--hold-after", "1", "--model", str(model), "--force-model",
                                  when=(HOLDING, kill))
                    run_dir = (out.doc or {}).get("run_dir")
                    if not fired:  # it ended before holding the object: no kill was tested
                        counts["before"] += 1
                        print(f"run {i + 1}/{args.runs}: ended before the hold, exit {out.code}: {out.last_line[:160]}",
                              flush=True)
                        if out.code < 0 or "Traceback" in out.stderr:
                            rows_bad.append((i + 1, delay, [f"exit {out.code} before the kill"], out.stderr[-1500:]))
                        continue
                    problems = judge(out, run_dir)
                    counts["signal"] += out.code < 0
                    counts["traceback"] += "Traceback" in out.stderr or "Fatal Python error" in out.stderr
                    counts["exit3"] += out.code == 3
                    counts["one_line"] += out.last_line.startswith("rig cooperative: aborted: ")
                    counts["closed"] += not any(p.startswith("recording") or p == "no run folder" for p in problems)
                    print(f"run {i + 1}/{args.runs}: killed {delay:.2f} s into the hold: "
                          + ("clean" if not problems else "; ".join(problems))
                          + f" [{out.last_line[:120]}]", flush=True)
                    if problems:
                        rows_bad.append((i + 1, delay, problems, out.stderr[-1500:]))
                        if args.keep:  # the whole stderr (a fatal error's thread stacks come first)
                            Path(args.keep).mkdir(parents=True, exist_ok=True)
                            (Path(args.keep) / f"run{i + 1}.stderr").write_text(out.stderr)
    finally:
        for b in burners:
            b.kill()
    n = args.runs - counts["before"]  # the runs in which rig sim was killed
    load = f"{args.burners} CPU burner(s)" if args.burners else "quiet"
    ok = print_table(f"rig sim SIGKILLed mid-cooperative: {n} runs killed of {args.runs}, {load}, "
                     f"{time.monotonic() - t0:.0f} s", [
        ("runs that ended before the hold (no kill: not counted below)", str(counts["before"]), "0",
         counts["before"] == 0),
        ("runs killed by a signal", str(counts["signal"]), "0", counts["signal"] == 0),
        ("runs with a traceback", str(counts["traceback"]), "0", counts["traceback"] == 0),
        ("runs that exited 3", str(counts["exit3"]), str(n), counts["exit3"] == n),
        ("runs ending in one 'aborted:' line", str(counts["one_line"]), str(n), counts["one_line"] == n),
        ("recordings closed with the reason", str(counts["closed"]), str(n), counts["closed"] == n),
    ])
    for i, delay, problems, tail in rows_bad:
        print(f"\nrun {i} (killed {delay:.2f} s into the hold): {'; '.join(problems)}\n{tail}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
