"""Median ignoring NaN along one axis, equal to ``np.nanmedian`` bit for bit, faster.

numpy computes a median over an axis shorter than 600 through masked arrays
(``np.ma.median``), which dominates where it is called on many short rows: the
trajectory filters' neighbour velocities (4.7 s of ``core track``'s 61 s on the walk),
the background model's image stacks.  Here one sort puts NaN last and each row's
median is the mean of its two middle finite values, as ``np.ma.median`` takes it
(``(low + high) / 2``; for an odd count low and high are the same value).
"""

from __future__ import annotations

import warnings

import numpy as np


def nanmedian(a: np.ndarray, axis: int = 0) -> np.ndarray:
    """``np.nanmedian(a, axis)`` (all-NaN slices give NaN, without a warning).

    Parameters
    ----------
    a : ndarray, float
    axis : int
        The axis reduced.

    Returns
    -------
    ndarray, ``a``'s shape without ``axis``, ``a``'s dtype.
    """
    a = np.moveaxis(np.asarray(a), axis, 0)
    if not len(a):
        return np.full(a.shape[1:], np.nan, dtype=a.dtype)
    srt = np.sort(a, axis=0)
    n = np.sum(~np.isnan(a), axis=0)
    lo = np.take_along_axis(srt, np.maximum((n - 1) // 2, 0)[None], 0)[0]
    hi = np.take_along_axis(srt, (n // 2)[None], 0)[0]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        mid = np.mean(np.stack([lo, hi]), axis=0)  # numpy's mean of the two middle values
    return np.where(n > 0, mid, np.nan).astype(mid.dtype, copy=False)
