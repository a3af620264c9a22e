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
        return Camera(
            self.name, self.size, self.K.copy(), self.dist.copy(), self.R.copy(), self.t.copy()
        )


# -- parameter packing and analytic Jacobians ----------------------------------------
#: Interior parameters in the order of a packed camera vector (after rvec, t).
#: ``f`` = fx (px), ``aspect`` = fx / fy, ``cx``, ``cy`` (px), radial k1..k3,
#: decentring p1, p2 (OpenCV's model).
INTRINSIC_NAMES = ("f", "aspect", "cx", "cy", "k1", "k2", "k3", "p1", "p2")
#: Exterior parameters: Rodrigues vector world -> camera, translation (m).
EXTRINSIC_NAMES = ("rx", "ry", "rz", "tx", "ty", "tz")
#: Names of the 15 entries of a packed camera vector (see :func:`pack_camera`).
PARAM_NAMES = EXTRINSIC_NAMES + INTRINSIC_NAMES
N_PARAMS = len(PARAM_NAMES)


def pack_camera(cam: Camera) -> np.ndarray:
    """Camera -> parameter vector (15,) in the order of :data:`PARAM_NAMES`.

    The skew ``K[0, 1]`` is not a parameter (taken as zero).
    """
    k1, k2, p1, p2, k3 = cam.dist
    fx, fy = cam.K[0, 0], cam.K[1, 1]
    return np.concatenate(
        [cam.rvec, cam.t, [fx, fx / fy, cam.K[0, 2], cam.K[1, 2], k1, k2, k3, p1, p2]]
    )


def unpack_camera(p: np.ndarray, name: str, size: tuple[int, int]) -> Camera:
    """Parameter vector (15,) (see :data:`PARAM_NAMES`) -> :class:`Camera`."""
    p = np.asarray(p, dtype=float).reshape(N_PARAMS)
    f, aspect, cx, cy, k1, k2, k3, p1, p2 = p[6:]
    K = np.array([[f, 0.0, cx], [0.0, f / aspect, cy], [0.0, 0.0, 1.0]])
    return Camera(name, size, K, np.array([k1, k2, p1, p2, k3]), rodrigues_to_matrix(p[:3]), p[3:6])


def _skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrices of vectors (..., 3) -> (..., 3, 3)."""
    z = np.zeros(v.shape[:-1])
    return np.stack(
        [
            np.stack([z, -v[..., 2], v[..., 1]], -1),
            np.stack([v[..., 2], z, -v[..., 0]], -1),
            np.stack([-v[..., 1], v[..., 0], z], -1),
        ],
        -2,
    )


def rodrigues_batch(
    rvec: np.ndarray, derivative: bool = True
) -> tuple[np.ndarray, np.ndarray | None]:
    """Rotation vectors (M, 3) -> matrices R (M, 3, 3) and dR/drvec (M, 3, 3, 3).

    ``dR[m, i]`` is the derivative of ``R[m]`` with respect to ``rvec[m, i]``
    (Gallego & Yezzi 2015, "A compact formula for the derivative of a 3-D rotation in
    exponential coordinates", eq. 9); near zero it tends to the skew matrix of e_i.
    Without ``derivative`` dR is None (and R the same, bit for bit).
    """
    rvec = np.asarray(rvec, dtype=float).reshape(-1, 3)
    theta = np.linalg.norm(rvec, axis=1)
    small = theta < 1e-9
    th = np.where(small, 1.0, theta)
    k = rvec / th[:, None]
    Kx = _skew(k)
    s, c = np.sin(theta)[:, None, None], np.cos(theta)[:, None, None]
    R = np.eye(3) + s * Kx + (1.0 - c) * (Kx @ Kx)
    R[small] = np.eye(3) + _skew(rvec[small])
    if not derivative:
        return R, None
    eye = np.eye(3)
    Vx = _skew(rvec)  # (M, 3, 3)
    ImR = eye - R  # (M, 3, 3)
    dR = np.empty(rvec.shape[:1] + (3, 3, 3))
    for i in range(3):  # three components, not a loop over points
        cross = np.cross(rvec, ImR[:, :, i])  # v x ((I - R) e_i)
        A = rvec[:, i, None, None] * Vx + _skew(cross)
        dR[:, i] = (A / (th**2)[:, None, None]) @ R
    dR[small] = _skew(np.broadcast_to(eye, (int(small.sum()), 3, 3)))
    return R, dR


def project_params(
    params: np.ndarray, xyz: np.ndarray, jacobian: bool = True, camera_jacobian: bool = True
):
    """Project points with per-point camera parameter vectors, with Jacobians.

    Parameters
    ----------
    params : ndarray, shape (M, 15) or (15,)
        Packed camera vectors (:data:`PARAM_NAMES`), one per point or one for all.
    xyz : ndarray, shape (M, 3)
        World points, metres.
    jacobian : bool
        Also return the analytic Jacobians.
    camera_jacobian : bool
        With ``jacobian``: also ``J_cam`` (else None in its place).

    Returns
    -------
    uv : ndarray, shape (M, 2)
        Image points, pixels (NaN behind the camera).
    J_cam : ndarray, shape (M, 2, 15)
        d uv / d params (only when ``jacobian``; None unless ``camera_jacobian``).
    J_xyz : ndarray, shape (M, 2, 3)
        d uv / d xyz (only when ``jacobian``).
    """
    return _project(params, xyz, jacobian, camera_jacobian, one_camera=False)


def _project(params, xyz, jacobian, camera_jacobian, one_camera, rotation=None):
    """:func:`project_params`; ``one_camera`` (params (15,)): the rotation computed
    once for all points and applied as one matrix product — equal to the per-point path
    to rounding (the calibration and the intersection keep the per-point path, whose
    last bits the tracker's results follow).  The per-point path with one camera's
    params (15,) also computes the rotation once, then applies it point by point as
    before: the same bits.  ``rotation`` (1, 3, 3): that one camera's rotation as
    ``rodrigues_batch(params[None, :3])`` gives it, computed before (not with
    ``camera_jacobian``)."""
    xyz = np.asarray(xyz, dtype=float).reshape(-1, 3)
    params = np.asarray(params, dtype=float)
    need_dR = jacobian and camera_jacobian
    if one_camera:
        if rotation is not None and not need_dR:
            R, dR = rotation, None
        else:
            R, dR = rodrigues_batch(params[None, :3], need_dR)
        t = params[None, 3:6]
        f, a, cx, cy, k1, k2, k3, p1, p2 = params[6:]
        pc = xyz @ R[0].T + t
    else:
        shared = params.ndim == 1  # one camera for every point
        params = np.broadcast_to(params, (xyz.shape[0], N_PARAMS))
        if shared:  # its rotation once: the same bits as one per point, without the cost
            R, dR = rodrigues_batch(params[:1, :3], need_dR)
            R = np.broadcast_to(R, (xyz.shape[0], 3, 3))
            dR = None if dR is None else np.broadcast_to(dR, (xyz.shape[0], 3, 3, 3))
        else:
            R, dR = rodrigues_batch(params[:, :3], need_dR)
        t = params[:, 3:6]
        f, a, cx, cy, k1, k2, k3, p1, p2 = params[:, 6:].T
        pc = np.einsum("mij,mj->mi", R, xyz) + t
    fy = f / a
    z = pc[:, 2]
    front = z > 1e-9
    zs = np.where(front, z, np.nan)
    x, y = pc[:, 0] / zs, pc[:, 1] / zs
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    uv = np.stack([f * xd + cx, fy * yd + cy], axis=-1)
    if not jacobian:
        return uv
    # d(xd, yd) / d(x, y)
    D = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)
    dxd_dx = radial + 2.0 * x * x * D + 2.0 * p1 * y + 6.0 * p2 * x
    dxd_dy = 2.0 * x * y * D + 2.0 * p1 * x + 2.0 * p2 * y
    dyd_dx = dxd_dy
    dyd_dy = radial + 2.0 * y * y * D + 6.0 * p1 * y + 2.0 * p2 * x
    J_d = np.empty(x.shape + (2, 2))  # filled, not stacked: the same values, less time
    J_d[:, 0, 0], J_d[:, 0, 1] = f * dxd_dx, f * dxd_dy
    J_d[:, 1, 0], J_d[:, 1, 1] = fy * dyd_dx, fy * dyd_dy
    J_n = np.zeros(x.shape + (2, 3))
    J_n[:, 0, 0] = J_n[:, 1, 1] = 1.0 / zs
    J_n[:, 0, 2], J_n[:, 1, 2] = -x / zs, -y / zs
    J_pc = J_d @ J_n  # d uv / d pc
    J_xyz = J_pc @ R
    if not camera_jacobian:
        return uv, None, J_xyz
    if one_camera:
        dpc_dr = np.einsum("kij,mj->mik", dR[0], xyz)  # (M, 3, 3)
    else:
        dpc_dr = np.einsum("mkij,mj->mik", dR, xyz)
    J_cam = np.zeros((xyz.shape[0], 2, N_PARAMS))
    J_cam[:, :, 0:3] = J_pc @ dpc_dr
    J_cam[:, :, 3:6] = J_pc
    one = np.ones_like(x)
    J_cam[:, 0, 6], J_cam[:, 1, 6] = xd, yd / a
    J_cam[:, 1, 7] = -fy * yd / a
    J_cam[:, 0, 8], J_cam[:, 1, 9] = one, one
    r4 = r2 * r2
    for j, rp in enumerate((r2, r4, r4 * r2)):
        J_cam[:, 0, 10 + j] = f * x * rp
        J_cam[:, 1, 10 + j] = fy * y * rp
    J_cam[:, 0, 13], J_cam[:, 1, 13] = f * 2.0 * x * y, fy * (r2 + 2.0 * y * y)
    J_cam[:, 0, 14], J_cam[:, 1, 14] = f * (r2 + 2.0 * x * x), fy * 2.0 * x * y
    return uv, J_cam, J_xyz


def camera_project_jacobians(cam: Camera, xyz: np.ndarray, camera_jacobian: bool = False):
    """``cam.project`` of points (M, 3) with d uv / d xyz (M, 2, 3): ``(uv, J_cam,
    J_xyz)``, ``J_cam`` d uv / d params (M, 2, 15) only when ``camera_jacobian`` (else
    None).

    See :func:`project_params`; ``cam.K[0, 1]`` (skew) must be zero.
    """
    if camera_jacobian:
        return _project(pack_camera(cam), xyz, True, True, one_camera=True)
    params, R = _packed(cam)
    return _project(params, xyz, True, False, one_camera=True, rotation=R)


#: :func:`_packed`'s cache: a camera's contents (bytes) -> (params (15,), R (1, 3, 3))
_PACKED: dict = {}


def _packed(cam: Camera) -> tuple[np.ndarray, np.ndarray]:
    """:func:`pack_camera` of ``cam`` and the rotation ``rodrigues_batch`` makes of its
    vector (1, 3, 3), remembered by the camera's contents: the fit projects through the
    same few cameras some hundred thousand times (the silhouette limb search above all),
    and the Rodrigues round trip cost more than the projection.  The same bits as
    computing both anew; a camera changed in place gets a new entry."""
    key = (cam.R.tobytes(), cam.t.tobytes(), cam.K.tobytes(), cam.dist.tobytes())
    hit = _PACKED.get(key)
    if hit is None:
        if len(_PACKED) >= 256:  # e.g. a calibration's many trial cameras
            _PACKED.clear()
        params = pack_camera(cam)
        params.flags.writeable = False
        R = rodrigues_batch(params[None, :3], False)[0]
        R.flags.writeable = False
        hit = _PACKED[key] = (params, R)
    return hit
