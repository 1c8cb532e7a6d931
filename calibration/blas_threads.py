"""Limit the BLAS threads of the numerical work: on a busy machine they cost 100 times.

numpy and scipy ship OpenBLAS, which starts one thread per core and, between calls, lets
them spin waiting for the next. On the lab's 2-core machine with the rig's own processes
(or two CPU burners) beside it, an SVD of a 1200 x 40 regressor took 0.28 s with the default
threads and 0.0026 s with one: the excitation design is thousands of those. Small
matrices gain nothing from the extra threads anyway, so the design and the fit run with one.

`threadpoolctl` does this in general; it is not a dependency, and OpenBLAS's own
``*_set_num_threads`` entry points (found in the libraries this process has loaded) are
all that is needed.
"""

from __future__ import annotations

import ctypes
from contextlib import contextmanager
from typing import Iterator


def _openblas() -> list[tuple[object, object]]:
    """(set, get) of every OpenBLAS this process has loaded (numpy's and scipy's may differ)."""
    paths = set()
    try:
        with open("/proc/self/maps") as f:
            for line in f:
                path = line.split()[-1] if len(line.split()) >= 6 else ""
                if "openblas" in path.lower() and ".so" in path:
                    paths.add(path)
    except OSError:
        return []
    found = []
    for path in sorted(paths):
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for prefix in ("scipy_openblas", "openblas"):
            for suffix in ("64_", ""):
                setter = getattr(lib, f"{prefix}_set_num_threads{suffix}", None)
                getter = getattr(lib, f"{prefix}_get_num_threads{suffix}", None)
                if setter is not None and getter is not None:
                    setter.argtypes, setter.restype, getter.restype = [ctypes.c_int], None, ctypes.c_int
                    found.append((setter, getter))
                    break
            else:
                continue
            break
    return found


@contextmanager
def blas_threads(n: int = 1) -> Iterator[None]:
    """Run the block with at most `n` OpenBLAS threads, then restore what was set."""
    import numpy  # noqa: F401  - load the libraries before looking for them
    import scipy.linalg  # noqa: F401

    libs = _openblas()
    before = [get() for _, get in libs]
    for set_, _ in libs:
        set_(int(n))
    try:
        yield
    finally:
        for (set_, _), old in zip(libs, before):
            set_(old)
