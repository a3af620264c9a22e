"""Limit the BLAS threads of numpy's bundled OpenBLAS around batched small-matrix work.

Batched matching (:mod:`core.lsm`) issues many skinny GEMMs (e.g. (10000, 169) @
(169, 3)) and small LAPACK calls.  OpenBLAS splits each over its threads, whose
synchronisation and busy-waiting (``sched_yield``) cost more than the split gains:
on 2 cores, a 2000-patch LSM call took 1.5-3× the CPU time and ~10× the system
time with 2 BLAS threads than with one.  :func:`single_blas_thread` sets OpenBLAS
to one thread for the duration of a block and restores the previous count.

Only numpy's own OpenBLAS is touched (found among the loaded libraries, or next to
numpy); where none is found (another BLAS, another platform) this is a no-op.
"""

from __future__ import annotations

import contextlib
import ctypes
import glob
import os
import threading

import numpy as np

_LOCK = threading.Lock()
_STATE = {"api": None, "searched": False, "depth": 0, "saved": None}


def _candidates() -> list[str]:
    paths = []
    try:
        with open("/proc/self/maps") as fh:
            for line in fh:
                p = line.split()[-1] if "/" in line else ""
                if "openblas" in os.path.basename(p).lower() and p not in paths:
                    paths.append(p)
    except OSError:
        pass
    base = os.path.dirname(os.path.dirname(np.__file__))
    for sub in ("numpy.libs", "numpy/.dylibs", "numpy/.libs"):
        paths += sorted(glob.glob(os.path.join(base, sub, "*openblas*")))
    # numpy's copy first: scipy's (scipy.libs) serves no numpy call.
    return sorted(paths, key=lambda p: "numpy" not in p)


def _api():
    """(get, set) ctypes functions of numpy's OpenBLAS, or None."""
    if _STATE["searched"]:
        return _STATE["api"]
    _STATE["searched"] = True
    for path in _candidates():
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for sfx in ("64_", "", "_64"):
            get = getattr(lib, "openblas_get_num_threads" + sfx, None)
            set_ = getattr(lib, "openblas_set_num_threads" + sfx, None)
            if get is not None and set_ is not None:
                get.restype = ctypes.c_int
                set_.argtypes = [ctypes.c_int]
                _STATE["api"] = (get, set_)
                return _STATE["api"]
    return None


@contextlib.contextmanager
def single_blas_thread():
    """Run the block with OpenBLAS on one thread (nested and thread-safe use allowed)."""
    api = _api()
    if api is None:
        yield
        return
    get, set_ = api
    with _LOCK:
        if _STATE["depth"] == 0:
            _STATE["saved"] = get()
            if _STATE["saved"] != 1:
                set_(1)
        _STATE["depth"] += 1
    try:
        yield
    finally:
        with _LOCK:
            _STATE["depth"] -= 1
            if _STATE["depth"] == 0 and _STATE["saved"] not in (None, 1):
                set_(_STATE["saved"])


def blas_threads() -> int | None:
    """The current OpenBLAS thread count of numpy, or None where unknown."""
    api = _api()
    return None if api is None else int(api[0]())
