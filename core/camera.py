"""Pinhole camera with OpenCV-style distortion.

Frames and units
----------------
* World: Z up, metres.
* Camera: OpenCV convention, x right, y down, z forward (the viewing direction).
  A world point ``xyz`` maps to camera coordinates ``R @ xyz + t``.
* Image: pixels, origin at the centre of the top-left pixel, ``u`` right, ``v`` down.

Interior orientation: ``K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` with pixel aspect
``fx / fy`` (pixel height over width: 2 for one field of an interlaced camera, whose
rows are twice as far apart), and distortion ``dist = (k1, k2, p1, p2, k3)`` in
OpenCV's order and model (radial k1..k3, decentring p1, p2).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


def rodrigues_to_matrix(rvec: np.ndarray) -> np.ndarray:
    """Rotation vector (3,) radians -> rotation matrix (3, 3)."""
    rvec = np.asarray(rvec, dtype=float).reshape(3)
    theta = float(np.linalg.norm(rvec))
    if theta < 1e-12:
        return np.eye(3)
    k = rvec / theta
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + np.sin(theta) * kx + (1.0 - np.cos(theta)) * (kx @ kx)


def matrix_to_rodrigues(R: np.ndarray) -> np.ndarray:
    """Rotation matrix (3, 3) -> rotation vector (3,) radians (angle in [0, pi])."""
    R = np.asarray(R, dtype=float)
    cos = np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)
    theta = float(np.arccos(cos))
    if theta < 1e-12:
        return np.zeros(3)
    if np.pi - theta < 1e-6:
        # Near pi: axis from the largest diagonal of (R + I) / 2.
        B = (R + np.eye(3)) / 2.0
        i = int(np.argmax(np.diag(B)))
        axis = B[:, i] / np.sqrt(B[i, i])
        return axis * theta
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    return w * (theta / (2.0 * np.sin(theta)))


@dataclass
class Camera:
    """One calibrated camera.

    Attributes
    ----------
    name : str
        Camera name, e.g. ``"cam01"`` (the folder name under ``images/``).
    size : tuple of int
        ``(width, height)`` in pixels.
    K : ndarray, shape (3, 3)
        Intrinsic matrix in pixels.
    dist : ndarray, shape (5,)
        ``(k1, k2, p1, p2, k3)``, OpenCV's distortion model.
    R : ndarray, shape (3, 3)
        Rotation world -> camera.
    t : ndarray, shape (3,)
        Translation world -> camera, metres.
    """

    name: str
    size: tuple[int, int]
    K: np.ndarray
    dist: np.ndarray = field(default_factory=lambda: np.zeros(5))
    R: np.ndarray = field(default_factory=lambda: np.eye(3))
    t: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self):
        self.size = (int(self.size[0]), int(self.size[1]))
        self.K = np.asarray(self.K, dtype=float).reshape(3, 3)
        d = np.zeros(5)
        given = np.asarray(self.dist, dtype=float).ravel()
        d[: min(5, given.size)] = given[:5]
        self.dist = d
        self.R = np.asarray(self.R, dtype=float).reshape(3, 3)
        self.t = np.asarray(self.t, dtype=float).reshape(3)

    # -- derived quantities -------------------------------------------------------
    @property
    def center(self) -> np.ndarray:
        """Projection centre in world coordinates, shape (3,), metres."""
        return -self.R.T @ self.t

    @property
    def aspect(self) -> float:
        """Pixel aspect ``fx / fy`` (pixel height over width; 2 for a single field)."""
        return float(self.K[0, 0] / self.K[1, 1])

    @property
    def P(self) -> np.ndarray:
        """Projection matrix ``K [R | t]``, shape (3, 4) (ignores distortion)."""
        return self.K @ np.hstack([self.R, self.t[:, None]])

    @property
    def rvec(self) -> np.ndarray:
        """Rotation world -> camera as a Rodrigues vector, shape (3,)."""
        return matrix_to_rodrigues(self.R)

    # -- projection ---------------------------------------------------------------
    def to_camera(self, xyz: np.ndarray) -> np.ndarray:
        """World points (..., 3) -> camera-frame points (..., 3), metres."""
        xyz = np.asarray(xyz, dtype=float)
        return xyz @ self.R.T + self.t

    def distort(self, xy: np.ndarray) -> np.ndarray:
        """Normalised ideal coordinates (..., 2) -> distorted normalised coordinates."""
        k1, k2, p1, p2, k3 = self.dist
        x, y = xy[..., 0], xy[..., 1]
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
        yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
        return np.stack([xd, yd], axis=-1)

    def project(self, xyz: np.ndarray) -> np.ndarray:
        """World points (..., 3), metres -> image points ``uv`` (..., 2), pixels.

        Points behind the camera get NaN.
        """
        pc = self.to_camera(xyz)
        z = pc[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            xy = pc[..., :2] / z[..., None]
        xy = np.where((z > 1e-9)[..., None], xy, np.nan)
        xd = self.distort(xy)
        u = self.K[0, 0] * xd[..., 0] + self.K[0, 1] * xd[..., 1] + self.K[0, 2]
        v = self.K[1, 1] * xd[..., 1] + self.K[1, 2]
        return np.stack([u, v], axis=-1)

    def undistort_points(self, uv: np.ndarray, iterations: int = 20) -> np.ndarray:
        """Image points (..., 2) px -> ideal normalised coordinates (..., 2).

        Fixed-point inversion of :meth:`distort`, accurate to ~1e-10 for the
        distortions of real lenses.
        """
        uv = np.asarray(uv, dtype=float)
        fx, s, cx = self.K[0]
        fy, cy = self.K[1, 1], self.K[1, 2]
        yd = (uv[..., 1] - cy) / fy
        xd = (uv[..., 0] - cx - s * yd) / fx
        target = np.stack([xd, yd], axis=-1)
        if not np.any(self.dist):
            return target
        xy = target.copy()
        for _ in range(iterations):
            xy = xy + (target - self.distort(xy))
        return xy

    def rays(self, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Viewing rays of image points: origin (3,) and unit directions (..., 3), world."""
        xy = self.undistort_points(uv)
        d_cam = np.concatenate([xy, np.ones(xy.shape[:-1] + (1,))], axis=-1)
        d = d_cam @ self.R  # R.T @ d for each row
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
        return self.center, d

    def copy(self) -> Camera:
        return Camera(self.name, self.size, self.K.copy(), self.dist.copy(), self.R.copy(),
                      self.t.copy())
