"""Bad-blob detection for the wand bundle adjustment.

Before the adjustment, leave-one-out forward intersection flags the views that do not
fit the rest (:func:`flag_by_intersection`); during it, residual lengths decide the
flags afresh each round with hysteresis (:func:`flag_observations`), and A/B label
exchanges are found by comparing both labellings (:func:`label_swaps`).
"""

from __future__ import annotations

import numpy as np

from .camera import project_params
from .intersect import triangulate


def flag_by_intersection(cameras, uv, seen, thr):
    """Bad blobs by leave-one-out forward intersection of every target.

    A target seen in ≥ 3 cameras whose full intersection leaves a residual above
    ``thr`` (px) gets the one camera flagged whose removal makes the rest fit; if no
    single removal does, every view off the best fit is flagged.  A target seen in two
    cameras that do not fit each other cannot tell which is wrong: both are flagged.

    Parameters: ``uv`` (F, C, 2, 2), ``seen`` (F, C, 2) bool.  Returns (F, C, 2) bool.
    """
    F, C = uv.shape[:2]
    pts = np.where(seen[..., None], uv, np.nan).transpose(0, 2, 1, 3).reshape(F * 2, C, 2)
    n = np.isfinite(pts[..., 0]).sum(axis=1)

    def residuals(mask_cam):
        p = pts.copy()
        if mask_cam is not None:
            p[:, mask_cam] = np.nan
        xyz = triangulate(cameras, p, iterations=5).xyz
        pred = np.stack([c.project(xyz) for c in cameras], axis=1)
        return np.linalg.norm(pred - pts, axis=2)  # (G, C), NaN unseen

    with np.errstate(invalid="ignore"):
        full = residuals(None)
        bad_full = np.nanmax(np.where(np.isfinite(full), full, -1.0), axis=1) > thr
        flags = np.zeros((F * 2, C), dtype=bool)
        best_rest = np.full(F * 2, np.inf)
        best_cam = np.full(F * 2, -1)
        loo = []
        for j in range(C):  # one pass per camera, all targets at once
            res_j = residuals(j)
            rest = np.where(np.arange(C) == j, -1.0, np.where(np.isfinite(res_j), res_j, -1.0))
            worst = rest.max(axis=1)
            better = (n >= 3) & np.isfinite(pts[:, j, 0]) & (worst < best_rest)
            best_rest[better], best_cam[better] = worst[better], j
            loo.append(res_j)
        loo = np.stack(loo, axis=1)  # (G, Cmask, C)
        single = bad_full & (best_rest <= thr) & (best_cam >= 0)
        g = np.flatnonzero(single)
        flags[g, best_cam[g]] = True
        rest = bad_full & ~single
        g = np.flatnonzero(rest & (best_cam >= 0))
        off = loo[g, best_cam[g]] > thr
        flags[g] = off | (np.arange(C) == best_cam[g][:, None])
        g = np.flatnonzero(rest & (best_cam < 0))
        flags[g] = np.isfinite(pts[g, :, 0])
    return flags.reshape(F, 2, C).transpose(0, 2, 1) & seen


#: Weight of a flagged observation's residual pair: it stays in the adjustment, so that
#: its residual is predicted by the other observations, with (almost) no influence.
FLAG_WEIGHT = 1e-4


def intersect_targets(cameras, uv, use):
    """Targets (F, 2, 3), metres, intersected from the observations ``use`` (F, C, 2).

    NaN where fewer than two observations are used or the intersection is not ok
    (e.g. behind a camera).
    """
    F, C = uv.shape[:2]
    pts = np.where(use[..., None], uv, np.nan).transpose(0, 2, 1, 3).reshape(F * 2, C, 2)
    with np.errstate(invalid="ignore", over="ignore"):
        tri = triangulate(cameras, pts, iterations=5)
    return np.where(tri.ok[:, None], tri.xyz, np.nan).reshape(F, 2, 3)


def residual_norms(params, xyz, uv, seen):
    """Residual length |projection − observation| (F, C, 2), px, of every seen observation.

    ``params`` (C, 15) packed cameras, ``xyz`` (F, 2, 3) targets.  NaN where not seen,
    where the target is NaN, or where it lies behind the camera.
    """
    F, C = uv.shape[:2]
    idx = np.argwhere(seen & np.all(np.isfinite(xyz), axis=-1)[:, None, :])
    out = np.full((F, C, 2), np.nan)
    if idx.size:
        pred = project_params(params[idx[:, 1]], xyz[idx[:, 0], idx[:, 2]], jacobian=False)
        out[tuple(idx.T)] = np.linalg.norm(pred - uv[tuple(idx.T)], axis=1)
    return out


def robust_scale(rn: np.ndarray) -> float:
    """σ of one image coordinate from residual lengths (any shape, NaN ignored), px.

    For Gaussian coordinates with σ the length is Rayleigh distributed with median
    ``σ √(2 ln 2) = 1.1774 σ``; the median makes the estimate insensitive to bad blobs.
    """
    rn = rn[np.isfinite(rn)]
    return float(np.median(rn) / np.sqrt(2.0 * np.log(2.0))) if rn.size else np.nan


def label_swaps(params, xyz, uv, seen, rn, cap):
    """Images (F, C) whose A/B labels fit the adjusted targets better exchanged.

    Each image with both targets measured compares ``min(r, cap)`` summed over its two
    observations for the labels as they are (``rn``) and exchanged; the cap keeps one
    bad blob from deciding.  Exchanged only when that is clearly better (by ``cap/2``).
    """
    both = np.all(seen, axis=2) & np.all(np.isfinite(rn), axis=2)
    rs = residual_norms(params, xyz[:, ::-1], uv, seen)
    with np.errstate(invalid="ignore"):
        keep = np.minimum(rn, cap).sum(axis=2)
        swap = np.minimum(rs, cap).sum(axis=2)
    return both & (swap < keep - 0.5 * cap)


def flag_observations(
    rn: np.ndarray, seen: np.ndarray, thr: float, previous: np.ndarray
) -> np.ndarray:
    """Bad-blob flags (F, C, 2) from residual lengths ``rn`` (F, C, 2), px.

    Flags are decided afresh every round, so an observation comes back as soon as its
    residual is small again (no monotonic growth): flagged when ``rn > thr``; one
    flagged before is re-admitted only below ``0.8 thr`` (hysteresis against
    oscillation); a NaN residual (the target cannot be intersected in front of the
    cameras from its views) flags the observation for this round.
    A target seen in exactly two cameras cannot tell which of the two is wrong: when
    either is flagged, both are (the epipolar and bar-length misfit of the location
    is what flagged it; with more redundancy the single bad view stands out).
    """
    with np.errstate(invalid="ignore"):
        new = np.where(previous, ~(rn < 0.8 * thr), rn > thr)
    new = np.where(np.isfinite(rn), new, True) & seen
    two = seen.sum(axis=1) == 2  # (F, 2) targets
    either = np.any(new, axis=1) & two
    return new | (either[:, None, :] & seen)
