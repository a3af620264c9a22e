"""Occlusion of tracked points by the tracked cloud itself, per camera.

A surface point that an arm swings in front of (or that turns to the far side of a
limb) is still "found" by a temporal LSM that follows whatever texture moves across
its patch; its trajectory then carries the occluder's motion in that camera.  The
live points themselves say where the body is: :func:`occluded` projects them into
each camera, keeps a coarse depth buffer (cells of ``cell_px``) of their distances to
the camera, and flags a point whose own distance lies more than ``margin_m`` behind
the surface in front of it there.  The buffer holds the ``rank``-th nearest point of
each cell (not the nearest), so a single point with a wrong depth does not hide its
neighbours.
"""

from __future__ import annotations

import numpy as np

from .camera import Camera


def occluded(
    cameras: list[Camera],
    xyz: np.ndarray,
    *,
    cell_px: float = 4.0,
    margin_m: float = 0.03,
    rank: int = 2,
    dilate_all: bool = True,
) -> np.ndarray:
    """Which points lie behind the cloud's surface in each camera.

    Parameters
    ----------
    cameras : list of Camera, length C
    xyz : ndarray, shape (P, 3)
        Points, metres (NaN rows are ignored and never flagged).
    cell_px : float
        Side of a depth-buffer cell, pixels; the surface in front of a point is the
        nearest cell value within the 3 × 3 cells around it.
    margin_m : float
        A point is occluded when it lies farther than this behind that surface, metres.
    rank : int
        The buffer holds the ``rank``-th nearest point of each cell (1: the nearest).
    dilate_all : bool
        The surface in front is the nearest of the 3 × 3 cells (True), or the point's
        own cell where that holds a value and the 3 × 3 only where it is empty (False:
        near a limb's silhouette the neighbouring cells hold the limb's front, which
        lies far in front of the visible side of the limb).

    Returns
    -------
    ndarray, shape (P, C), bool
    """
    xyz = np.asarray(xyz, float).reshape(-1, 3)
    p = len(xyz)
    out = np.zeros((p, len(cameras)), bool)
    fin = np.flatnonzero(np.all(np.isfinite(xyz), axis=1))
    if len(fin) == 0:
        return out
    for j, cam in enumerate(cameras):
        w, h = cam.size
        q = cam.project(xyz[fin])
        d = np.linalg.norm(xyz[fin] - cam.center, axis=1)
        gw, gh = int(w // cell_px) + 1, int(h // cell_px) + 1
        with np.errstate(invalid="ignore"):
            gu = np.floor(q[:, 0] / cell_px)
            gv = np.floor(q[:, 1] / cell_px)
        ins = np.isfinite(gu) & np.isfinite(gv) & (gu >= 0) & (gu < gw) & (gv >= 0) & (gv < gh)
        k = np.flatnonzero(ins)
        if len(k) == 0:
            continue
        cellid = gv[k].astype(int) * gw + gu[k].astype(int)
        order = np.lexsort((d[k], cellid))
        cs = cellid[order]
        first = np.r_[0, np.flatnonzero(np.diff(cs)) + 1]
        pos = np.arange(len(cs)) - np.repeat(first, np.diff(np.r_[first, len(cs)]))
        pick = pos == rank - 1
        zb = np.full((gh + 2) * (gw + 2), np.inf)
        c2 = cs[pick]
        zb[(c2 // gw + 1) * (gw + 2) + c2 % gw + 1] = d[k][order][pick]
        zb = zb.reshape(gh + 2, gw + 2)
        own = zb[1:-1, 1:-1].copy()
        zm = own.copy()
        for du in (-1, 0, 1):
            for dv in (-1, 0, 1):
                zm = np.minimum(zm, zb[1 + dv : gh + 1 + dv, 1 + du : gw + 1 + du])
        if not dilate_all:
            zm = np.where(np.isfinite(own), own, zm)
        front = zm[gv[k].astype(int), gu[k].astype(int)]
        out[fin[k], j] = d[k] > front + margin_m
    return out
