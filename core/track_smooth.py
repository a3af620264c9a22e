"""Depth outliers of a measured point cloud: the point against its neighbours' median.

A point intersected from two adjacent cameras of a line rig (~20° apart) has no
redundancy along the epipolar line: a match off by half a pixel there moves it ~1 cm
in depth while its reprojection stays perfect.  The skin is smooth on the scale of
the point spacing (1–2 cm), so such a point stands out from its neighbours:
:func:`depth_outliers` compares each point's depth along its viewing ray with the
median depth of its ``k`` nearest neighbours (in 3-D, so that a limb in front of the
trunk does not mix with it) along the same ray — a median filter on depth over the
measured grid.

On walk_line3 frame 0 (2,124 points, ``k=8``): 1 cm keeps 94 % of the points and
lowers the 95th percentile of the distance to the true mesh from 8.5 to 6.9 mm.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree


def depth_deviation(xyz: np.ndarray, viewpoint: np.ndarray, ref: np.ndarray,
                    k: int = 8, exclude_self: bool = False) -> np.ndarray:
    """Depth of points against the median depth of their nearest reference points.

    Parameters
    ----------
    xyz : ndarray, shape (Q, 3)
        Points to test, metres (NaN rows give NaN).
    viewpoint : ndarray, shape (3,)
        Where the depth is measured from, metres.
    ref : ndarray, shape (M, 3)
        Reference cloud (finite rows only), metres; needs more than ``k`` points.
    k : int
        Neighbours per point.
    exclude_self : bool
        ``xyz`` are rows of ``ref`` in the same order: the nearest neighbour (the point
        itself) is skipped.

    Returns
    -------
    ndarray, shape (Q,)
        Signed depth minus the neighbours' median depth, both along the point's
        viewing ray from ``viewpoint``, metres.
    """
    xyz = np.asarray(xyz, float).reshape(-1, 3)
    out = np.full(len(xyz), np.nan)
    fin = np.flatnonzero(np.all(np.isfinite(xyz), axis=1))
    if len(fin) == 0:
        return out
    x = xyz[fin]
    _, nb = cKDTree(ref).query(x, k=k + int(exclude_self))
    nb = nb.reshape(len(x), -1)[:, int(exclude_self):]
    ray = x - np.asarray(viewpoint, float)
    ray /= np.linalg.norm(ray, axis=1, keepdims=True)
    depth = np.einsum("pi,pi->p", x, ray)
    depth_nb = np.einsum("pki,pi->pk", ref[nb], ray)
    out[fin] = depth - np.median(depth_nb, axis=1)
    return out


def depth_outliers(xyz: np.ndarray, viewpoint: np.ndarray, tol_m: float, k: int = 8,
                   min_points: int = 4) -> np.ndarray:
    """Points whose depth differs from their neighbours' median by more than ``tol_m``.

    Parameters
    ----------
    xyz : ndarray, shape (P, 3)
        Points, metres (NaN rows are ignored and never flagged).
    viewpoint : ndarray, shape (3,)
        Where the depth is measured from (e.g. the mean of the camera centres), metres.
    tol_m : float
        Largest |depth − median depth of the neighbours| along the point's viewing ray.
    k : int
        Neighbours per point.
    min_points : int
        Clouds smaller than ``k + 1`` or than this are not tested.

    Returns
    -------
    ndarray, shape (P,), bool
    """
    xyz = np.asarray(xyz, float).reshape(-1, 3)
    out = np.zeros(len(xyz), bool)
    fin = np.flatnonzero(np.all(np.isfinite(xyz), axis=1))
    if len(fin) < max(k + 1, min_points):
        return out
    dev = depth_deviation(xyz[fin], viewpoint, xyz[fin], k=k, exclude_self=True)
    out[fin] = np.abs(dev) > tol_m
    return out


def drop_one_camera(cameras, uv: np.ndarray, viewpoint: np.ndarray, ref: np.ndarray,
                    tol_m: float, *, max_rms_px: float = 1.0, k: int = 8,
                    sigma_px: float = 0.3):
    """Depth outliers measured in three or more cameras, intersected again without one.

    A single wrong match among three cameras moves the intersection in depth; the
    other two may still agree with the neighbours.  Every subset that leaves out one
    camera is intersected, and the one whose depth lies closest to the median depth of
    its ``k`` nearest reference points (and within ``tol_m``) is kept.

    Parameters
    ----------
    cameras : list of Camera, length C
    uv : ndarray, shape (Q, C, 2)
        Image points of the outliers, pixels (NaN where not matched).
    viewpoint : ndarray, shape (3,)
        Where depth is measured from, metres.
    ref : ndarray, shape (M, 3)
        The measured points of the frame that passed the depth test, metres.
    tol_m : float
        Largest depth deviation of the kept subset, metres.
    max_rms_px : float
        Largest reprojection RMS of the kept subset's intersection, pixels.

    Returns
    -------
    uv : ndarray, shape (Q, C, 2)
        The kept subset's image points (one camera set to NaN), pixels.
    xyz : ndarray, shape (Q, 3)
        Its intersection, metres.
    cov : ndarray, shape (Q, 3, 3)
        Its covariance, m².
    ok : ndarray, shape (Q,), bool
        A subset was kept.
    """
    from .intersect import triangulate

    q, c = uv.shape[:2]
    best = np.full(q, np.inf)
    uv_out = np.full_like(uv, np.nan)
    xyz_out = np.full((q, 3), np.nan)
    cov_out = np.full((q, 3, 3), np.nan)
    seen = np.all(np.isfinite(uv), axis=2)
    if q == 0 or len(ref) <= k:
        return uv_out, xyz_out, cov_out, np.zeros(q, bool)
    for j in range(c):                               # loop over cameras, points batched
        rows = np.flatnonzero(seen[:, j] & (seen.sum(axis=1) >= 3))
        if len(rows) == 0:
            continue
        cand = uv[rows].copy()
        cand[:, j] = np.nan
        inter = triangulate(cameras, cand, sigma_px=sigma_px)
        dev = np.abs(depth_deviation(inter.xyz, viewpoint, ref, k=k))
        good = (inter.ok & (inter.rms < max_rms_px) & (np.nan_to_num(dev, nan=np.inf) < tol_m)
                & (dev < best[rows]))
        r = rows[good]
        best[r] = dev[good]
        uv_out[r], xyz_out[r], cov_out[r] = cand[good], inter.xyz[good], inter.cov[good]
    return uv_out, xyz_out, cov_out, np.isfinite(best)
