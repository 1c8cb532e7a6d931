"""The fault matrix over the wire: every procedure x every fault (issue 37).

One `rig sim` in its own folder (tests/hil/harness.py) from a lab's rig.toml (ROS arms, the
serial load cell on rig sim's pty, ROS mocap, rig sim's simulated operator with a 5 s
answer limit), prepared once (load cell calibrated, arms registered, PSM1 identified and
friction-ramped, so every procedure finds what it needs). Then, per procedure and fault, a
`rig <procedure> --json` process as a lab runs it; the fault lands when the procedure's
step named in PROCEDURES begins:

* server killed: rig sim SIGKILLed (the arms' console, its load cell and mocap die with it)
* load-cell pty closed, mocap stopped: the simulated person pulls that cable
* operator gone: the simulated person walks away (requests go unanswered)
* arm FAULT: PSM1 pushed past its joint-1 limit (the arm faults, as a dVRK's does)
* SIGINT, SIGTERM: sent to the procedure

A fault that cannot reach the procedure (it does not use that device after the fault) must
leave it completing as if nothing happened ("unused"). Otherwise the cell is green when the
procedure ends with one line on stderr, no traceback, no signal, the documented exit
(3 aborted; 130 for SIGINT), every arm it moved held (an arm in FAULT obeys nothing: it is
reported not held), and its recording closed with the reason. rig sim is restarted after a
fault that leaves it broken.

    .venv/bin/python bench/bench_faults.py [--procedures identify,cooperative] [--faults SIGINT,SIGTERM] [--burners 2]

Prints the table (procedure x fault: green or what failed, the last line, arms held,
recording status, seconds from the fault to the procedure's end).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent))
from _table import print_table  # noqa: E402

from tests.hil.fault_matrix import FAULTS, PROCEDURES, cell, lab, prepare  # noqa: E402
from tests.hil.harness import ServedRig  # noqa: E402

def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--procedures", default=",".join(PROCEDURES))
    ap.add_argument("--faults", default=",".join(FAULTS))
    ap.add_argument("--burners", type=int, default=0)
    args = ap.parse_args()
    names = [n.strip() for n in args.procedures.split(",") if n.strip()]
    faults = [f.strip() for f in args.faults.split(",") if f.strip()]
    for n in names:
        if n not in PROCEDURES:
            ap.error(f"no procedure {n!r}; procedures: {', '.join(PROCEDURES)}")
    for f in faults:
        if f not in FAULTS:
            ap.error(f"no fault {f!r}; faults: {', '.join(FAULTS)}")
    burners: list[subprocess.Popen] = []
    results: dict[tuple[str, str], dict] = {}
    t0 = time.monotonic()
    try:
        with tempfile.TemporaryDirectory(prefix="bench-faults-") as tmp:
            folder = Path(tmp) / "lab"
            with ServedRig(folder, toml=lab(folder), sim_args=("--ros-period", "0.002")) as rig:
                problem = prepare(rig)
                if problem:
                    print(f"preparing: {problem}")
                    return 2
                burners = [subprocess.Popen([sys.executable, "-c", "while True: pass"])
                           for _ in range(args.burners)]
                for n in names:
                    for f in faults:
                        if not rig.running or rig.faulted:
                            rig.restart()
                        r = cell(rig, n, f)
                        results[(n, f)] = r
                        print(f"{n} x {f}: {'green' if r['ok'] else 'RED: ' + '; '.join(r['problems'])}"
                              f"{' (unused: completed)' if r['unused'] and r['ok'] else ''}; "
                              f"{r['line'][:150]}", flush=True)
                        if FAULTS[f][2] and rig.running:
                            rig.stop(keep_domain=True)  # its cable stays pulled: a fresh one next
    finally:
        for b in burners:
            b.kill()
    rows = []
    for (n, f), r in results.items():
        detect = f"{r['detect_s']:.2f} s" if r["detect_s"] is not None else "-"
        value = ("unused, " + r["status"]) if r["unused"] else (
            f"exit ok, held {','.join(r['held']) or '-'}, rec {r['recording']}, {detect}" if r["ok"]
            else "; ".join(r["problems"]))
        rows.append((f"{n} x {f}", value, "one line, held, closed", r["ok"]))
    load = f"{args.burners} CPU burner(s)" if args.burners else "quiet"
    ok = print_table(f"fault matrix over the wire ({load}, {time.monotonic() - t0:.0f} s)", rows)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
