"""Trajectory post-processing: gap filling and the paper's trajectory filters.

:func:`fill_gaps` bridges short gaps between measured positions (cubic Hermite with the
filtered rates); :func:`filter_trajectories` applies the thresholds on velocity and
acceleration and the local uniformity test (velocity against the median velocity of
the spatial neighbours over frames i-1..i+1; the median instead of the mean keeps a
false neighbour from hiding itself); flagged trajectories are truncated before their
first bad frame and removed when too little remains (D'Apuzzo et al. 1999, 2.4).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .nan_median import nanmedian


def derivative(x: np.ndarray, fps: float) -> np.ndarray:
    """Time derivative of ``x`` (F, ...) per second: central differences, one-sided
    at the ends and next to gaps; NaN where unknown."""
    v = np.full_like(x, np.nan)
    v[1:-1] = (x[2:] - x[:-2]) * (fps / 2.0)
    fwd = (x[1:] - x[:-1]) * fps
    v[1:-1] = np.where(
        np.isfinite(v[1:-1]), v[1:-1], np.where(np.isfinite(fwd[1:]), fwd[1:], fwd[:-1])
    )
    v[0], v[-1] = fwd[0], fwd[-1]
    return v


def fill_gaps(xyz: np.ndarray, rate: np.ndarray, max_gap: int) -> np.ndarray:
    """Fill gaps of at most ``max_gap`` frames between measured positions.

    Cubic Hermite interpolation between the measured ends with the filtered rates
    there; longer gaps and the frames after a trajectory's last measurement stay NaN.

    Parameters
    ----------
    xyz : ndarray, shape (F, P, 3)
        Measured positions, metres, NaN where unmeasured.
    rate : ndarray, shape (F, P, 3)
        Filtered rates at the measured frames, metres per frame.
    max_gap : int
        Longest gap to fill, frames.

    Returns
    -------
    ndarray, shape (F, P, 3)
    """
    F, P, _ = xyz.shape
    m = np.all(np.isfinite(xyz), axis=2)
    idx = np.where(m, np.arange(F)[:, None], -1)
    a = np.maximum.accumulate(idx, axis=0)  # last measured <= f
    b = np.where(m, np.arange(F)[:, None], F)
    b = np.minimum.accumulate(b[::-1], axis=0)[::-1]  # next measured >= f
    gap = ~m & (a >= 0) & (b < F) & (b - a - 1 <= max_gap)
    out = xyz.copy()
    f, p = np.nonzero(gap)
    if len(f) == 0:
        return out
    fa, fb = a[f, p], b[f, p]
    h = (fb - fa).astype(float)
    s = ((f - fa) / h)[:, None]
    ra = np.nan_to_num(rate[fa, p]) * h[:, None]
    rb = np.nan_to_num(rate[fb, p]) * h[:, None]
    h00, h10 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s
    h01, h11 = -2 * s**3 + 3 * s**2, s**3 - s**2
    out[f, p] = h00 * xyz[fa, p] + h10 * ra + h01 * xyz[fb, p] + h11 * rb
    return out


def bridge_gaps(xyz: np.ndarray, pred: np.ndarray) -> np.ndarray:
    """Fill the gaps of re-acquired trajectories from per-frame predictions.

    A gap between measured frames ``a`` and ``b`` is filled where a prediction exists
    in every frame ``a < g <= b`` (the dormant point's neighbour-motion prediction,
    :func:`core.track_reacquire.neighbour_motion`): ``pred[g]`` plus the discrepancy
    at the re-acquisition ``xyz[b] - pred[b]`` spread linearly over the gap (zero at
    ``a``, where the prediction starts from the measured position).

    Parameters
    ----------
    xyz : ndarray, shape (F, P, 3)
        Measured positions, metres, NaN where unmeasured.
    pred : ndarray, shape (F, P, 3)
        Predicted positions in the frames where each point was dormant, metres, NaN
        elsewhere.

    Returns
    -------
    ndarray, shape (F, P, 3)
    """
    F = xyz.shape[0]
    m = np.all(np.isfinite(xyz), axis=2)
    have = np.all(np.isfinite(pred), axis=2)
    fr = np.arange(F)[:, None]
    a = np.maximum.accumulate(np.where(m, fr, -1), axis=0)  # last measured <= f
    b = np.minimum.accumulate(np.where(m, fr, F)[::-1], axis=0)[::-1]  # next measured >= f
    # predictions missing since the last measurement: count them up to each frame
    miss = np.cumsum(~have & ~m, axis=0)
    miss_a = np.take_along_axis(miss, np.maximum(a, 0), axis=0)
    gap = ~m & (a >= 0) & (b < F)
    f, p = np.nonzero(gap)
    out = xyz.copy()
    if len(f) == 0:
        return out
    fa, fb = a[f, p], b[f, p]
    complete = (miss[fb, p] - miss_a[f, p] == 0) & have[fb, p]
    f, p, fa, fb = f[complete], p[complete], fa[complete], fb[complete]
    s = ((f - fa) / (fb - fa))[:, None]
    out[f, p] = pred[f, p] + s * (xyz[fb, p] - pred[fb, p])
    return out


@dataclass
class FilterResult:
    """Outcome of :func:`filter_trajectories`.

    Attributes
    ----------
    xyz : ndarray, shape (F, P, 3)
        Filtered trajectories (NaN after truncation / for removed ones).
    bad : ndarray, shape (F, P) bool
        Frames flagged by any filter.
    removed : ndarray, shape (P,) bool
        Trajectories removed entirely.
    truncated : ndarray, shape (P,) bool
        Trajectories cut before their first bad frame (and not removed).
    """

    xyz: np.ndarray
    bad: np.ndarray
    removed: np.ndarray
    truncated: np.ndarray


def filter_trajectories(
    xyz: np.ndarray,
    fps: float,
    *,
    max_speed: float = 6.0,
    max_accel: float = 150.0,
    radius_m: float = 0.05,
    max_dev: float = 0.3,
    min_neighbours: int = 3,
    min_length: int = 5,
) -> FilterResult:
    """Velocity / acceleration thresholds and local uniformity in space and time.

    Parameters
    ----------
    xyz : ndarray, shape (F, P, 3)
        Trajectories, metres (NaN where unknown).
    fps : float
        Frame rate, frames per second.
    max_speed, max_accel : float
        Thresholds, m/s and m/s².
    radius_m : float
        Neighbourhood radius for the uniformity test, metres.
    max_dev : float
        Largest difference between a point's velocity and the median velocity of its
        neighbours (over frames i-1..i+1), m/s.
    min_length : int
        Trajectories shorter than this after truncation are removed, frames.
    """
    F, P, _ = xyz.shape
    v = derivative(xyz, fps)
    a = np.full_like(xyz, np.nan)
    a[1:-1] = (xyz[2:] - 2 * xyz[1:-1] + xyz[:-2]) * fps**2
    speed = np.linalg.norm(v, axis=2)
    acc = np.linalg.norm(a, axis=2)
    bad = (speed > max_speed) | (acc > max_accel)
    for f in range(F):  # loop over frames; points are batched
        ok = np.all(np.isfinite(xyz[f]), axis=1) & np.all(np.isfinite(v[f]), axis=1)
        idx = np.flatnonzero(ok)
        if len(idx) < min_neighbours + 1:
            continue
        tree = cKDTree(xyz[f, idx])
        nb = tree.query_ball_point(xyz[f, idx], radius_m, return_sorted=False)
        counts = np.array([len(x) for x in nb])
        kmax = int(counts.max())
        table = np.full((len(idx), kmax), -1)
        for j, x in enumerate(nb):  # ragged neighbour lists -> padded table
            table[j, : len(x)] = x
        # Neighbour velocities over frames f-1, f, f+1, median per component.
        frames = [g for g in (f - 1, f, f + 1) if 0 <= g < F]
        vals = []
        for g in frames:
            vg = v[g, idx]
            nv = np.where((table >= 0)[..., None], vg[np.maximum(table, 0)], np.nan)
            nv[table == np.arange(len(idx))[:, None]] = np.nan  # exclude the point itself
            vals.append(nv)
        vals = np.concatenate(vals, axis=1)
        enough = np.sum(np.isfinite(vals[..., 0]), axis=1) >= min_neighbours * len(frames)
        med = np.full((len(idx), 3), np.nan)
        if enough.any():
            med[enough] = nanmedian(vals[enough], axis=1)
        dev = np.linalg.norm(v[f, idx] - med, axis=1)
        bad[f, idx[enough & (dev > max_dev)]] = True
    alive = np.all(np.isfinite(xyz), axis=2)
    bad &= alive
    out = xyz.copy()
    removed = np.zeros(P, bool)
    truncated = np.zeros(P, bool)
    any_bad = bad.any(axis=0)
    first_bad = np.where(any_bad, np.argmax(bad, axis=0), F)
    frame_idx = np.arange(F)[:, None]
    cut = frame_idx >= first_bad[None, :]
    out[cut] = np.nan
    remaining = np.sum(np.all(np.isfinite(out), axis=2), axis=0)
    removed = any_bad & (remaining < min_length)
    truncated = any_bad & ~removed
    out[:, removed] = np.nan
    return FilterResult(xyz=out, bad=bad, removed=removed, truncated=truncated)
