"""The fault matrix over the wire: every procedure x every fault (issue 37).

One `rig sim` in its own folder (tests/hil/harness.py) from a lab's rig.toml, prepared once
(load cell calibrated, arms registered, PSM1 identified and friction-ramped; the three-arm
triangle on a second rig sim with PSM3 and a cell per element); then per
procedure and fault a `rig <procedure> --json` process as a lab runs it, the fault injected
when the procedure's step begins, and the ending judged: tests/hil/fault_matrix.py says
which faults, how they are injected and what a clean ending is. rig sim is restarted after
a fault that leaves it broken. `--burners N` starts N CPU-burning processes once the rig is
prepared.

    .venv/bin/python bench/bench_faults.py [--procedures identify,cooperative] [--faults SIGINT,SIGTERM] [--burners 2] [--keep DIR]

Prints the table (procedure x fault: green or what failed, the last line, arms held,
recording status, seconds from the fault to the procedure's end).
"""

from __future__ import annotations

import argparse
import contextlib
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent))
from _table import print_table  # noqa: E402

from tests.hil.fault_matrix import FAULTS, PROCEDURES, cell, lab, prepare, sim_args  # noqa: E402
from tests.hil.harness import ServedRig  # noqa: E402

def _lab(folder: Path, three: bool, names: list[str], faults: list[str], n_burners: int,
         burners: list, results: dict) -> bool:
    """One lab's rig sim, prepared, then its procedures x faults into `results`; the
    burners start once the first lab is prepared. False if preparing failed."""
    with ServedRig(folder, toml=lab(folder, three), sim_args=sim_args(three)) as rig:
        problem = prepare(rig, three)
        if problem:
            print(f"preparing: {problem}")
            return False
        if not burners:
            burners += [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n_burners)]
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
    return True


@contextlib.contextmanager
def _folder(keep: str | None):
    """`keep` made if missing (and kept), or a temporary folder removed after."""
    if keep:
        Path(keep).mkdir(parents=True, exist_ok=True)
        yield keep
        return
    with tempfile.TemporaryDirectory(prefix="bench-faults-") as tmp:
        yield tmp


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--procedures", default=",".join(PROCEDURES))
    ap.add_argument("--faults", default=",".join(FAULTS))
    ap.add_argument("--burners", type=int, default=0)
    ap.add_argument("--keep", metavar="DIR", help="run the labs in DIR (made if missing) and keep them, "
                    "run folders and recordings included, to read after; default: a temporary folder")
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
        with _folder(args.keep) as tmp:
            for three in (False, True):  # the two-arm lab, then the three-arm one
                on_lab = [n for n in names if PROCEDURES[n].three_arms == three]
                if on_lab and not _lab(Path(tmp) / ("lab3" if three else "lab"), three, on_lab, faults,
                                       args.burners, burners, results):
                    return 2
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
