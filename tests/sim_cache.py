"""Simulated recordings made once per machine and code, shared by the tests on disk.

Why. The science tests (tests/calibration, tests/procedures) record the same hidden-effect
cases of the simulated arm (`calibration.hidden_effects.generate`, seconds of CPU each) file
by file: the same case, seed and trajectory in several files, and under `-n 2 --dist
loadfile` in both workers. `recorded(case, **options)` makes each one once: the first
process that wants it takes an exclusive flock on the entry's lock file, simulates and
writes it; any other (the other worker, a later run of the same code) waits on the lock
and reads the file. The key is the arguments and a hash of the code a recording comes from
(calibration/, rig/: an edit there makes new entries); folders of other code untouched for
a day are removed.

Where: $RIG_TEST_CACHE, else `<tmp>/dvrk-rig-test-cache-<uid>`, made mode 0700: entries are
pickles read back, so nobody else may write there.
"""

from __future__ import annotations

import fcntl
import functools
import hashlib
import os
import pickle
import shutil
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
#: the packages whose code makes a recording (the simulator, the model, the hidden effects)
SOURCES = ("calibration", "rig")
#: s, age past which another code's folder is removed
STALE = 86400.0


@functools.lru_cache(maxsize=1)
def code_hash() -> str:
    """A hash of every .py file under SOURCES (paths and contents)."""
    h = hashlib.sha256()
    for package in SOURCES:
        for path in sorted((REPO / package).rglob("*.py")):
            h.update(str(path.relative_to(REPO)).encode())
            h.update(path.read_bytes())
    return h.hexdigest()[:16]


@functools.lru_cache(maxsize=1)
def folder() -> Path:
    """This code's folder of the cache (made; other code's stale folders removed)."""
    root = Path(os.environ.get("RIG_TEST_CACHE") or Path(tempfile.gettempdir()) / f"dvrk-rig-test-cache-{os.getuid()}")
    root.mkdir(mode=0o700, parents=True, exist_ok=True)
    if root.stat().st_uid != os.getuid() or root.stat().st_mode & 0o022:
        raise RuntimeError(f"{root}: the test cache must be this user's own folder, writable by nobody else")
    mine = root / code_hash()
    mine.mkdir(exist_ok=True)
    os.utime(mine)
    for other in root.iterdir():
        if other != mine and other.is_dir() and time.time() - other.stat().st_mtime > STALE:
            shutil.rmtree(other, ignore_errors=True)
    return mine


def cached(kind: str, make, *args, **kwargs):
    """`make(*args, **kwargs)`, made once per machine and code (see the module docstring)."""
    key = hashlib.sha256(pickle.dumps((kind, args, sorted(kwargs.items())))).hexdigest()[:24]
    path = folder() / f"{kind}-{key}.pickle"
    with open(path.with_suffix(".lock"), "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes (or the process dies)
        if path.exists():
            return pickle.loads(path.read_bytes())
        value = make(*args, **kwargs)
        partial = path.with_suffix(f".{os.getpid()}.part")
        partial.write_bytes(pickle.dumps(value))
        os.replace(partial, path)  # whole or absent, whoever reads it
        return value


def recorded(case, **options):
    """`calibration.hidden_effects.generate(case, **options)` from the cache: (Recorded, Truth)."""
    from calibration.hidden_effects import generate

    return cached("generate", generate, case, **options)
