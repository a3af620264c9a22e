"""Constant-velocity Kalman filters for tracked 3-D points and their image prediction.

Every tracked surface point carries a filter (:class:`PointFilter`, batched over all
points); its one-frame prediction, projected into a camera (:func:`predict_in_image`),
gives the start and the size of the NCC search box of :func:`core.tracking.track`, and
its Mahalanobis distance gates the forward intersection of the new matches.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .camera import Camera
from .nan_median import nanmedian

#: Added to every point covariance in the filters: model error of a surface point
#: (LSM bias on curved skin, texture slipping), m².
COV_FLOOR = np.eye(3) * 0.002**2


@dataclass
class PointFilter:
    """Constant-velocity Kalman filters for P independent 3-D points, batched.

    State per point ``[xyz, rate]`` (metres and metres per frame); system model
    ``xyz <- xyz + rate``, ``rate <- damping * rate`` with white acceleration noise of
    standard deviation ``accel_sigma`` (m / frame², the discretised white-noise
    acceleration ``Q`` of :class:`core.ekf.EKF`, per axis).  The measurement is the
    forward intersection of the point (linear in the state), so the update is that of
    a plain Kalman filter; the image-space prediction is its projection
    (:func:`predict_in_image`), which is where the model becomes non-linear.

    Attributes
    ----------
    x : ndarray, shape (P, 6)
    P : ndarray, shape (P, 6, 6)
    accel_sigma : float
    damping : float
    """

    x: np.ndarray
    P: np.ndarray
    accel_sigma: float = 0.01
    damping: float = 1.0

    @classmethod
    def start(
        cls,
        xyz: np.ndarray,
        cov: np.ndarray,
        rate: np.ndarray | None = None,
        rate_sigma: np.ndarray | float = 0.03,
        accel_sigma: float = 0.01,
        damping: float = 1.0,
    ) -> PointFilter:
        """Filters at ``xyz`` (P, 3) with position covariance ``cov`` (P, 3, 3), m², and
        rate ``rate`` (P, 3), m/frame (default 0) of standard deviation ``rate_sigma``."""
        xyz = np.asarray(xyz, float).reshape(-1, 3)
        n = len(xyz)
        rate = np.zeros((n, 3)) if rate is None else np.asarray(rate, float)
        P = np.zeros((n, 6, 6))
        P[:, :3, :3] = cov
        P[:, 3:, 3:] = np.eye(3) * (np.broadcast_to(rate_sigma, (n,)) ** 2)[:, None, None]
        return cls(np.concatenate([xyz, rate], axis=1), P, float(accel_sigma), float(damping))

    def __len__(self) -> int:
        return len(self.x)

    def append(self, other: PointFilter) -> None:
        self.x = np.concatenate([self.x, other.x])
        self.P = np.concatenate([self.P, other.P])

    def _F(self) -> np.ndarray:
        F = np.eye(6)
        F[:3, 3:] = np.eye(3)
        F[3:, 3:] *= self.damping
        return F

    def _Q(self) -> np.ndarray:
        a2 = self.accel_sigma**2
        return np.kron(np.array([[a2 / 4, a2 / 2], [a2 / 2, a2]]), np.eye(3))

    def predicted(self) -> tuple[np.ndarray, np.ndarray]:
        """Prediction one frame ahead without changing the filters: xyz (P, 3), cov (P, 3, 3)."""
        F = self._F()
        x = self.x @ F.T
        P = F @ self.P @ F.T + self._Q()
        return x[:, :3], P[:, :3, :3]

    def predict(self) -> None:
        """Advance every filter one frame (in place)."""
        F = self._F()
        self.x = self.x @ F.T
        self.P = F @ self.P @ F.T + self._Q()

    def mahalanobis2(self, z: np.ndarray, R: np.ndarray) -> np.ndarray:
        """Squared Mahalanobis distance of measurements ``z`` (P, 3) with covariance
        ``R`` (P, 3, 3) from the current (predicted) positions; NaN where z is NaN."""
        d = z - self.x[:, :3]
        S = self.P[:, :3, :3] + R
        ok = np.all(np.isfinite(d), axis=1) & np.all(np.isfinite(S), axis=(1, 2))
        out = np.full(len(d), np.nan)
        if ok.any():
            out[ok] = np.einsum("ni,ni->n", d[ok], np.linalg.solve(S[ok], d[ok][..., None])[..., 0])
        return out

    def update(self, z: np.ndarray, R: np.ndarray, rows: np.ndarray) -> None:
        """Measurement update of the filters ``rows`` (K,) int with xyz ``z`` (K, 3), m,
        of covariance ``R`` (K, 3, 3), m² (in place, Joseph form)."""
        if len(rows) == 0:
            return
        x, P = self.x[rows], self.P[rows]
        H = np.zeros((3, 6))
        H[:, :3] = np.eye(3)
        S = P[:, :3, :3] + R
        G = np.linalg.solve(S, P[:, :3, :]).transpose(0, 2, 1)  # (K, 6, 3) = P Hᵀ S⁻¹
        x = x + np.einsum("kij,kj->ki", G, z - x[:, :3])
        I_GH = np.eye(6) - G @ H
        P = I_GH @ P @ I_GH.transpose(0, 2, 1) + G @ R @ G.transpose(0, 2, 1)
        self.x[rows], self.P[rows] = x, 0.5 * (P + P.transpose(0, 2, 1))


def predict_in_image(
    cam: Camera, xyz: np.ndarray, cov: np.ndarray, eps: float = 1e-3
) -> tuple[np.ndarray, np.ndarray]:
    """Project points (P, 3) with covariance (P, 3, 3) into a camera.

    Returns ``uv`` (P, 2), pixels, and the largest standard deviation of the projected
    covariance ``J Σ Jᵀ`` (P,), pixels (``J`` by forward differences of ``eps`` metres).
    """
    uv = cam.project(xyz)
    J = np.stack([(cam.project(xyz + eps * e) - uv) / eps for e in np.eye(3)], axis=-1)
    S = J @ cov @ J.transpose(0, 2, 1)
    a, b, d = S[:, 0, 0], S[:, 0, 1], S[:, 1, 1]
    lam = 0.5 * (a + d) + np.sqrt(np.maximum(0.25 * (a - d) ** 2 + b * b, 0.0))
    return uv, np.sqrt(np.maximum(lam, 0.0))


def neighbour_rates(
    xyz: np.ndarray, rate: np.ndarray, new_xyz: np.ndarray, radius_m: float = 0.05, k: int = 8
) -> tuple[np.ndarray, np.ndarray]:
    """Start rates (K, 3) of new points: the median filtered rate of up to ``k`` measured
    points within ``radius_m``; their σ (K,) is 1 cm/frame there, 3 cm/frame elsewhere."""
    out = np.zeros((len(new_xyz), 3))
    sig = np.full(len(new_xyz), 0.03)
    ok = np.all(np.isfinite(xyz), axis=1) & np.all(np.isfinite(rate), axis=1)
    if ok.sum() < k:
        return out, sig
    tree = cKDTree(xyz[ok])
    d, idx = tree.query(new_xyz, k=k, distance_upper_bound=radius_m)
    have = np.isfinite(d)
    vals = np.where(have[..., None], rate[ok][np.minimum(idx, ok.sum() - 1)], np.nan)
    enough = have.sum(axis=1) >= 3
    out[enough] = nanmedian(vals[enough], axis=1)
    sig[enough] = 0.01
    return out, sig
