"""Normalised cross-correlation maps of a batch of windows: numpy (FFT), or compiled.

:func:`core.ncc.search` correlates each point's ``k × k`` zero-mean template with every
integer offset of its ``K × K`` search window (``K = k + 2r``).  The numpy path does the
numerator as one FFT convolution over the batch and the window sums by integral
images; at the tracker's search radii (3–16 px, ``k`` = 13) most of that work is the
FFTs of padded windows, 60 % of ``core track`` on the default scene.  The compiled path
sums the ``(2r+1)² · k²`` products directly, point by point, with the window sums from
one integral image per point: fewer operations at these sizes, and no temporaries.
``core track`` of the walk: 113.3 → 64.5 s (median of 3 paired runs), its tracks bit for
bit the same.

The two paths round differently (they differ by ~1e-14 in the correlation); the
test suite holds them within 1e-9.  Optional at run time like :mod:`core.field_kernel`
(whose :func:`~core.field_kernel.run` and :func:`~core.field_kernel.enabled` it shares):
without numba, with ``SOMACAP_NO_NUMBA=1``, or after a failed first compile, the numpy
path runs.
"""

from __future__ import annotations

import numpy as np
from scipy.signal import fftconvolve

from .field_kernel import enabled, run
from .lsm_kernel_jit import jit

#: Denominators below this count as no grey-level variation (score -1 there).
TINY = 1e-6


def ncc_maps(S: np.ndarray, T0: np.ndarray, tnorm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Correlation coefficient of every template at every offset of its window.

    Parameters
    ----------
    S : ndarray, shape (n, K, K), float64
        Search windows, grey levels.
    T0 : ndarray, shape (n, k, k), float64
        Templates less their mean, grey levels (``k <= K``).
    tnorm : ndarray, shape (n,)
        ``sqrt(sum(T0²))`` per template.

    Returns
    -------
    ncc : ndarray, shape (n, w, w), ``w = K − k + 1``
        Correlation coefficient in [-1, 1] at offset (row, column) from the window's
        corner; -1 where the window or the template has no variation.
    textured : ndarray, shape (n,), bool
        Whether any offset's window has variation (``den > TINY``).
    """
    S = np.ascontiguousarray(S, dtype=np.float64)
    T0 = np.ascontiguousarray(T0, dtype=np.float64)
    tnorm = np.ascontiguousarray(tnorm, dtype=np.float64)
    n, K, k = len(S), S.shape[1], T0.shape[1]
    w = K - k + 1
    if enabled() and n:
        ncc = np.empty((n, w, w))
        textured = np.zeros(n, np.bool_)
        if run(_ncc_loops, S, T0, tnorm, ncc, textured):
            return ncc, textured
    return ncc_maps_numpy(S, T0, tnorm)


def _box_sums(a: np.ndarray, k: int) -> np.ndarray:
    """Sums over all k × k windows of a batch (N, H, W) -> (N, H-k+1, W-k+1)."""
    c = np.cumsum(np.cumsum(a, axis=1), axis=2)
    c = np.pad(c, ((0, 0), (1, 0), (1, 0)))
    return c[:, k:, k:] - c[:, :-k, k:] - c[:, k:, :-k] + c[:, :-k, :-k]


def ncc_maps_numpy(
    S: np.ndarray, T0: np.ndarray, tnorm: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`ncc_maps` by FFT convolution and integral images: the reference."""
    k = T0.shape[1]
    npx = k * k
    num = fftconvolve(S, T0[:, ::-1, ::-1], mode="valid", axes=(1, 2))
    s1 = _box_sums(S, k)
    s2 = _box_sums(S * S, k)
    var = np.maximum(s2 - s1 * s1 / npx, 0.0)
    den = tnorm[:, None, None] * np.sqrt(var)
    with np.errstate(divide="ignore", invalid="ignore"):
        ncc = np.where(den > TINY, num / den, -1.0)
    return ncc, np.any(den > TINY, axis=(1, 2))


@jit()
def _ncc_loops(S, T0, tnorm, ncc, textured):  # pragma: no cover - compiled
    n, K = S.shape[0], S.shape[1]
    k = T0.shape[1]
    w = K - k + 1
    npx = k * k
    c1 = np.zeros((K + 1, K + 1))
    c2 = np.zeros((K + 1, K + 1))
    for i in range(n):
        for y in range(K):  # integral images of the window and its square
            r1 = 0.0
            r2 = 0.0
            for x in range(K):
                v = S[i, y, x]
                r1 += v
                r2 += v * v
                c1[y + 1, x + 1] = c1[y, x + 1] + r1
                c2[y + 1, x + 1] = c2[y, x + 1] + r2
        for y in range(w):
            acc = np.zeros(w)  # the numerators of this row of offsets
            for a in range(k):
                for b in range(k):
                    t = T0[i, a, b]
                    for x in range(w):
                        acc[x] += S[i, y + a, x + b] * t
            for x in range(w):
                s1 = c1[y + k, x + k] - c1[y, x + k] - c1[y + k, x] + c1[y, x]
                s2 = c2[y + k, x + k] - c2[y, x + k] - c2[y + k, x] + c2[y, x]
                var = max(s2 - s1 * s1 / npx, 0.0)
                den = tnorm[i] * np.sqrt(var)
                if den > TINY:
                    ncc[i, y, x] = acc[x] / den
                    textured[i] = True
                else:
                    ncc[i, y, x] = -1.0
