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


def depth_deviation(
    xyz: np.ndarray, viewpoint: np.ndarray, ref: np.ndarray, k: int = 8, exclude_self: bool = False
) -> np.ndarray:
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
    nb = nb.reshape(len(x), -1)[:, int(exclude_self) :]
    ray = x - np.asarray(viewpoint, float)
    ray /= np.linalg.norm(ray, axis=1, keepdims=True)
    depth = np.einsum("pi,pi->p", x, ray)
    depth_nb = np.einsum("pki,pi->pk", ref[nb], ray)
    out[fin] = depth - np.median(depth_nb, axis=1)
    return out


def depth_outliers(
    xyz: np.ndarray, viewpoint: np.ndarray, tol_m: float, k: int = 8, min_points: int = 4
) -> np.ndarray:
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
