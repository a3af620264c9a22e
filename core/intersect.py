"""Forward intersection: 3-D points from their image points in two or more cameras.

Linear start (DLT on undistorted, normalised image coordinates), then Gauss–Newton on
the reprojection error in pixels, batched over all points (no Python loop per point;
the loops run over cameras and iterations).  The covariance of each point follows
from the normal matrix of the last iteration and the a-priori σ of an image
coordinate: ``cov = σ² (JᵀJ)⁻¹``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .camera import Camera, pack_camera, project_params


@dataclass
class Intersection:
    """Result of :func:`triangulate` for N points.

    Attributes
    ----------
    xyz : ndarray, shape (N, 3)
        World points, metres (NaN where fewer than two cameras see the point).
    cov : ndarray, shape (N, 3, 3)
        Covariance of ``xyz``, m², from the a-priori image σ (NaN where not ok).
    rms : ndarray, shape (N,)
        Reprojection RMS per image coordinate, pixels.
    n_views : ndarray, shape (N,), int
        Number of cameras that saw the point.
    ok : ndarray, shape (N,), bool
        Two or more views, finite solution in front of every camera used, well
        conditioned normal matrix.
    """

    xyz: np.ndarray
    cov: np.ndarray
    rms: np.ndarray
    n_views: np.ndarray
    ok: np.ndarray

    @property
    def sigma(self) -> np.ndarray:
        """Standard deviations of x, y, z (N, 3), metres."""
        return np.sqrt(np.abs(np.diagonal(self.cov, axis1=1, axis2=2)))


def _dlt(cameras: list[Camera], uv: np.ndarray, seen: np.ndarray) -> np.ndarray:
    """Linear triangulation, (N, C, 2) -> (N, 3), on normalised ideal coordinates."""
    n, c = uv.shape[:2]
    A = np.zeros((n, 2 * c, 4))
    for j, cam in enumerate(cameras):
        with np.errstate(over="ignore", invalid="ignore"):
            xy = cam.undistort_points(np.where(seen[:, j, None], uv[:, j], 0.0))
        good = seen[:, j] & np.all(np.isfinite(xy), axis=1) & np.all(np.abs(xy) < 1e6, axis=1)
        xy = np.where(good[:, None], xy, 0.0)
        Rt = np.hstack([cam.R, cam.t[:, None]])  # (3, 4)
        w = good[:, None].astype(float)
        A[:, 2 * j] = w * (xy[:, 0, None] * Rt[2] - Rt[0])
        A[:, 2 * j + 1] = w * (xy[:, 1, None] * Rt[2] - Rt[1])
    # Row scaling does not change the solution but keeps the SVD well conditioned.
    norm = np.linalg.norm(A, axis=2, keepdims=True)
    A = A / np.where(norm > 0, norm, 1.0)
    _, _, vt = np.linalg.svd(A)
    X = vt[:, -1]
    with np.errstate(divide="ignore", invalid="ignore"):
        return X[:, :3] / X[:, 3:4]


def triangulate(
    cameras: list[Camera],
    uv: np.ndarray,
    sigma_px: float = 0.1,
    iterations: int = 10,
    tol_m: float = 1e-10,
) -> Intersection:
    """Forward intersection of N points seen in C cameras.

    Parameters
    ----------
    cameras : list of Camera, length C
    uv : ndarray, shape (N, C, 2) (or (C, 2) for one point)
        Image points in pixels, NaN where a camera does not see the point.
    sigma_px : float
        A-priori standard deviation of one image coordinate, pixels.
    iterations : int
        Maximum Gauss–Newton iterations.
    tol_m : float
        Stop when every point moved less than this (metres).

    Returns
    -------
    Intersection
    """
    uv = np.asarray(uv, dtype=float)
    single = uv.ndim == 2
    if single:
        uv = uv[None]
    if uv.ndim != 3 or uv.shape[2] != 2 or uv.shape[1] != len(cameras):
        raise ValueError(f"uv must have shape (N, {len(cameras)}, 2), got {uv.shape}")
    n, c = uv.shape[:2]
    seen = np.all(np.isfinite(uv), axis=2)
    n_views = seen.sum(axis=1)
    enough = n_views >= 2
    params = np.stack([pack_camera(cam) for cam in cameras])  # (C, 15)

    xyz = np.full((n, 3), np.nan)
    if np.any(enough):
        xyz[enough] = _dlt(cameras, uv[enough], seen[enough])
    xyz[~np.all(np.isfinite(xyz) & (np.abs(xyz) < 1e9), axis=1)] = np.nan
    active = enough & np.all(np.isfinite(xyz), axis=1)
    N = np.zeros((n, 3, 3))
    res = np.zeros((n, c, 2))
    front = np.ones((n, c), dtype=bool)
    it, last = 0, False
    while True:
        idx = np.flatnonzero(active)
        if idx.size == 0:
            break
        J = np.zeros((idx.size, c, 2, 3))
        r = np.zeros((idx.size, c, 2))
        for j in range(c):
            with np.errstate(over="ignore", invalid="ignore"):
                pred, _, J_xyz = project_params(params[j], xyz[idx], camera_jacobian=False)
            ok_j = (
                seen[idx, j]
                & np.all(np.isfinite(pred), axis=1)
                & np.all(np.isfinite(J_xyz), axis=(1, 2))
            )
            front[idx, j] = ok_j | ~seen[idx, j]
            r[:, j] = np.where(ok_j[:, None], uv[idx, j] - pred, 0.0)
            J[:, j] = np.where(ok_j[:, None, None], J_xyz, 0.0)
        N[idx] = np.einsum("ncki,nckj->nij", J, J)
        res[idx] = r
        if last:
            break
        g = np.einsum("ncki,nck->ni", J, r)
        good = np.abs(np.linalg.det(N[idx])) > 1e-30
        step = np.zeros((idx.size, 3))
        step[good] = np.linalg.solve(N[idx][good], g[good][..., None])[..., 0]
        step[~np.all(np.isfinite(step), axis=1)] = 0.0
        xyz[idx] += step
        it += 1
        # One more pass after convergence refreshes N and the residuals.
        last = it >= iterations or not np.any(np.linalg.norm(step, axis=1) > tol_m)
    rms = np.full(n, np.nan)
    cnt = np.maximum(2 * n_views, 1)
    rms[enough] = np.sqrt(np.sum(res[enough] ** 2, axis=(1, 2)) / cnt[enough])
    cov = np.full((n, 3, 3), np.nan)
    cond_ok = np.zeros(n, dtype=bool)
    if np.any(active):
        Na = N[active]
        cond = np.linalg.cond(Na)
        cond_ok[active] = np.isfinite(cond) & (cond < 1e12)
        inv_ok = np.flatnonzero(active)[cond_ok[active]]
        cov[inv_ok] = sigma_px**2 * np.linalg.inv(N[inv_ok])
    ok = active & cond_ok & np.all(front, axis=1) & np.all(np.isfinite(xyz), axis=1)
    xyz[~active] = np.nan
    out = Intersection(xyz=xyz, cov=cov, rms=rms, n_views=n_views.astype(int), ok=ok)
    if single:
        return Intersection(out.xyz[0], out.cov[0], out.rms[0], out.n_views[0], out.ok[0])
    return out
