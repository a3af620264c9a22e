"""The optional numba dependency of :mod:`core.lsm_kernel`: import and decorator.

``numba`` is None where it cannot be imported (Blender's Python: the add-on does not
bundle it; or a numba that fails to import with this numpy), and when the environment
variable ``SOMACAP_NO_NUMBA`` is true at import time (then numba is not even imported:
~0.2 s less start-up); :func:`jit` then leaves functions as plain Python (the callers
check :func:`core.lsm_kernel.enabled` and use the numpy path instead).
"""

from __future__ import annotations

import os

ENV_OFF = "SOMACAP_NO_NUMBA"


def env_off() -> bool:
    """Whether ``SOMACAP_NO_NUMBA`` is set to a true value (anything but "", 0, false, no)."""
    return os.environ.get(ENV_OFF, "").strip().lower() not in ("", "0", "false", "no")


numba = None
if not env_off():
    try:  # numba is optional (not in the add-on)
        import numba
    except Exception:  # pragma: no cover - missing or broken
        numba = None


def jit(fastmath=False):
    """``numba.njit(cache=True, nogil=True)`` as a decorator (identity without numba).

    Compiled code is cached on disk next to the module (``__pycache__``), or in
    numba's user-wide cache directory (``NUMBA_CACHE_DIR``, else the user cache)
    when the package directory is not writable; where numba finds no writable
    location at all it raises at decoration time, and the function is compiled per
    process instead.  ``fastmath`` as numba's (a set of LLVM flags: this package uses
    ``{"reassoc"}`` only, for vectorised sums, never finite-math assumptions).
    """

    def deco(fn):
        if numba is None:
            return fn
        try:
            return numba.njit(cache=True, nogil=True, fastmath=fastmath)(fn)
        except RuntimeError:  # no cache locator: compile per process
            return numba.njit(cache=False, nogil=True, fastmath=fastmath)(fn)

    return deco
