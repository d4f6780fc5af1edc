"""One BLAS thread for the compression's matrix products, wherever it runs: OpenBLAS sums a
product in a different order with a different number of threads (a 50 000 x 160 Gram matrix
differs in its last bits between 1 and 2 threads), so a build's compact textures depended on
the baking machine's core count, and a Dask worker (which starts with
``OPENBLAS_NUM_THREADS=1``) wrote other bytes than the baking process. With one thread both
write the same bytes on any number of cores.

numpy's own OpenBLAS is reached through ctypes (its ``openblas_set_num_threads``, as
threadpoolctl does); with another BLAS (MKL, Accelerate) nothing is changed and
:func:`set_blas_threads` returns None.
"""

from __future__ import annotations

import contextlib
import ctypes
import functools
from pathlib import Path

# Prefixed (numpy's wheels: scipy-openblas) and plain OpenBLAS builds.
_PREFIXES = ("scipy_openblas_", "openblas_")
_SUFFIXES = ("64_", "_64_", "")


@functools.cache
def _openblas():
    """(set_num_threads, get_num_threads) of the OpenBLAS numpy loaded, or None."""
    import numpy  # noqa: F401  (loads its BLAS)

    try:
        maps = Path("/proc/self/maps").read_text()
    except OSError:
        return None
    paths = sorted({line.split()[-1] for line in maps.splitlines() if "openblas" in line})
    for path in paths:
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for prefix in _PREFIXES:
            for suffix in _SUFFIXES:
                setter = getattr(lib, f"{prefix}set_num_threads{suffix}", None)
                getter = getattr(lib, f"{prefix}get_num_threads{suffix}", None)
                if setter is not None and getter is not None:
                    setter.argtypes, setter.restype = [ctypes.c_int], None
                    getter.argtypes, getter.restype = [], ctypes.c_int
                    return setter, getter
    return None


def blas_threads() -> int | None:
    """OpenBLAS's number of threads in this process, or None without OpenBLAS."""
    found = _openblas()
    return None if found is None else int(found[1]())


def set_blas_threads(count: int) -> int | None:
    """Set OpenBLAS's number of threads for the whole process; the previous number, or None
    without OpenBLAS (nothing changed)."""
    found = _openblas()
    if found is None:
        return None
    before = int(found[1]())
    found[0](int(count))
    return before


@contextlib.contextmanager
def one_blas_thread():
    """OpenBLAS single-threaded inside the block (the whole process), restored after."""
    before = set_blas_threads(1)
    try:
        yield
    finally:
        if before is not None:
            set_blas_threads(before)
