"""One BLAS thread per run process (issue 16: compute per placement cycle).

numpy and scipy each load their own OpenBLAS, which starts one thread per core. The executive's arrays are small
(hundreds of points by 3, 6x6 solves): the extra threads split them and then busy-wait for the next call, which is
process CPU spent on nothing. The first perception of a development scan took 4.8 s of CPU with the default
threads and 4.2 s with one, the same poses bit for bit. One thread also makes a matrix product's rounding the same
on every computer, whatever its number of cores.

Hand-written with ctypes (about what ``threadpoolctl.threadpool_limits(1, "blas")`` does, but threadpoolctl is not
a dependency): the libraries already loaded get OpenBLAS's own ``*_set_num_threads``; one loaded later (scipy
loads its copy when scipy.linalg is first imported) reads OPENBLAS_NUM_THREADS, set here. A value the user set in
OPENBLAS_NUM_THREADS is kept.
"""

from __future__ import annotations

import ctypes
import os

# OpenBLAS's setter / getter, by build: plain, scipy's wheels (scipy-openblas), scipy's 64-bit-integer build (numpy)
_SUFFIXES = ("openblas_{}", "scipy_openblas_{}", "scipy_openblas_{}64_", "openblas_{}64_")


def _loaded_openblas() -> list[ctypes.CDLL]:
    """The OpenBLAS libraries this process has loaded (from /proc/self/maps; none where there is no /proc)."""
    try:
        with open("/proc/self/maps") as f:
            paths = sorted({line.split(None, 5)[-1].strip() for line in f if "openblas" in line.lower()})
    except OSError:
        return []
    out = []
    for p in paths:
        if p.startswith("/") and os.path.exists(p):
            try:
                out.append(ctypes.CDLL(p))  # already loaded: the same handle, nothing runs
            except OSError:
                pass
    return out


def _symbol(lib: ctypes.CDLL, what: str):
    for pattern in _SUFFIXES:
        fn = getattr(lib, pattern.format(what), None)
        if fn is not None:
            return fn
    return None


def blas_threads() -> list[int]:
    """The thread count of each loaded OpenBLAS."""
    out = []
    for lib in _loaded_openblas():
        fn = _symbol(lib, "get_num_threads")
        if fn is not None:
            fn.restype = ctypes.c_int
            out.append(int(fn()))
    return out


def limit_blas_threads() -> int:
    """Every OpenBLAS of this process (loaded now or later) to OPENBLAS_NUM_THREADS threads, 1 unless the user set
    it. Returns the thread count."""
    n = os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    try:
        n_threads = max(1, int(n))
    except ValueError:
        n_threads = 1
    for lib in _loaded_openblas():
        fn = _symbol(lib, "set_num_threads")
        if fn is not None:
            fn.argtypes = [ctypes.c_int]
            fn(n_threads)
    return n_threads


__all__ = ["blas_threads", "limit_blas_threads"]
