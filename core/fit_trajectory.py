"""Tracked trajectories as rigid-motion observations of the body parts (issue 5, item 5).

An attractor point (:mod:`core.attractor`) only says that a point lies *on* its part's
surface: a part may slide or twist under its points (a limb or the trunk turning about
its own long axis hardly changes its surface) without any change of the attractor
residuals.  A tracked trajectory is more: the tracker follows the same *material* point
from frame to frame, so a point that lay at ``q0`` in its bone's frame in the previous
fitted frame should lie at ``q0`` in that bone's frame now (the part moves rigidly).
Per point ``i`` of part ``b_i`` three observation equations (metres)

    r_i = x_i(θ, root, s) − z_i,     x_i = p_b(θ, root, s) + R_b(θ) q0_i,

``z_i`` the tracked position in this frame, each divided by its a-priori σ (the two
frames' point σ and a ``slip_m`` for skin and cloth that does not move rigidly with the
bone, added in quadrature) and weighted by a Cauchy weight of the point's residual norm
in σ units (knee ``robust_scale``), frozen per re-weighting round like the attractor
weights.  ``q0`` is held (set from the previous frame's fit), so the analytic Jacobian
(:func:`core.skeleton.point_jacobians`) is exact.

Frames: world Z up, metres; bone frames as :func:`core.skeleton.bone_frames`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .skeleton import Skeleton, bone_frames, forward, point_jacobians


def cauchy_row_weights(r: np.ndarray, sigma: np.ndarray, robust_scale: float) -> np.ndarray:
    """Row weights ``cauchy / σ`` (K,) of vector residuals ``r`` (K, d) with a-priori
    σ (K,) in the same unit: the Cauchy weight of ``|r| / σ`` with knee ``robust_scale``
    (0: none)."""
    w = 1.0 / sigma
    if robust_scale:
        u = np.linalg.norm(r, axis=1) / sigma
        w = w / np.sqrt(1.0 + (u / robust_scale) ** 2)
    return w


def bone_local(
    skel: Skeleton,
    theta: np.ndarray,
    root: np.ndarray,
    s: np.ndarray,
    xyz: np.ndarray,
    bone: np.ndarray,
) -> np.ndarray:
    """Coordinates (N, 3) metres of world points ``xyz`` (N, 3) in the anatomical frames
    of their bones ``bone`` (N,) at the pose ``theta`` (n,) radians, ``root`` (3,) metres,
    bone scales ``s`` (G,)."""
    pose = forward(skel, np.asarray(theta, float)[None], np.asarray(root, float)[None], s)
    Rb, pb = bone_frames(skel, pose)
    bone = np.asarray(bone, int)
    return np.einsum("nji,nj->ni", Rb[0, bone], np.asarray(xyz, float) - pb[0, bone])


@dataclass
class TrajectoryObs:
    """One frame's trajectory observations (K points).

    Attributes
    ----------
    bone : (K,) int — the part (bone index) of each point
    q0 : (K, 3) the point in its bone's frame at the previous fitted frame, metres
    xyz : (K, 3) its tracked world position in this frame, metres
    sigma : (K,) a-priori σ of each coordinate, metres
    robust_scale : knee of the Cauchy weights, in σ units (0: none)
    weights : (K,) row weights ``cauchy / σ`` (set by :meth:`freeze`)
    """

    bone: np.ndarray
    q0: np.ndarray
    xyz: np.ndarray
    sigma: np.ndarray
    robust_scale: float = 3.0
    weights: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.bone)

    def residuals(self, skel: Skeleton, theta, root, s, anc=None, jacobians: bool = True):
        """Unweighted ``x − z`` (K, 3) metres and, with ``jacobians``, ``∂x/∂θ``
        (K, 3, n) and ``∂x/∂s`` (K, 3, G) (``∂x/∂root`` is the identity)."""
        pose = forward(skel, np.asarray(theta, float)[None], np.asarray(root, float)[None], s)
        grp = np.full(len(self.bone), -1)
        if not jacobians:
            Rb, pb = bone_frames(skel, pose)
            x = pb[0, self.bone] + np.einsum("nij,nj->ni", Rb[0, self.bone], self.q0)
            return x - self.xyz, None, None
        x, Jt, Js = point_jacobians(skel, pose, self.bone, self.q0, grp, s, anc)
        return x[0] - self.xyz, Jt[0], Js[0]

    def freeze(self, skel: Skeleton, theta, root, s) -> None:
        """Fix the row weights at this state (IRLS)."""
        r, _, _ = self.residuals(skel, theta, root, s, jacobians=False)
        self.weights = cauchy_row_weights(r, self.sigma, self.robust_scale)

    def block(self, skel: Skeleton, theta, root, s, anc=None, n_shape: int | None = None):
        """Weighted rows ``(r (3K,), J_theta (3K, n), J_root (3K, 3), J_s (3K, G),
        J_radii, J_centers)``; the last two zero (3K, n_shape) or None without
        ``n_shape`` (pose-only solves)."""
        if self.weights is None:
            self.freeze(skel, theta, root, s)
        r, Jt, Js = self.residuals(skel, theta, root, s, anc)
        w = np.repeat(self.weights, 3)
        K = len(self.bone)
        zero = None if n_shape is None else np.zeros((3 * K, n_shape))
        return (
            r.reshape(-1) * w,
            Jt.reshape(3 * K, -1) * w[:, None],
            np.tile(np.eye(3), (K, 1)) * w[:, None],
            Js.reshape(3 * K, -1) * w[:, None],
            zero,
            None if zero is None else zero.copy(),
        )


class TrajectoryAnchors:
    """Bone-frame coordinates of the trajectories of the last fitted frame.

    :meth:`set` stores them from an accepted frame (ids (N,), parts (N,) with −1 for
    unassigned points, the pose); :meth:`observations` pairs the next frame's points
    with them by id.
    """

    def __init__(self):
        self.ids = np.zeros(0, np.int64)
        self.bone = np.zeros(0, int)
        self.q0 = np.zeros((0, 3))
        self.sigma = np.zeros(0)

    def clear(self) -> None:
        self.__init__()

    def set(self, skel: Skeleton, theta, root, s, xyz, sigma, ids, part) -> None:
        """Store the points of an accepted frame (those with ids and a part)."""
        if ids is None:
            self.clear()
            return
        use = np.asarray(part) >= 0
        ids = np.asarray(ids, np.int64)[use]
        order = np.argsort(ids, kind="stable")
        self.ids = ids[order]
        self.bone = np.asarray(part, int)[use][order]
        self.q0 = bone_local(skel, theta, root, s, np.asarray(xyz)[use][order], self.bone)
        self.sigma = np.asarray(sigma, float)[use][order]

    def observations(
        self, xyz, sigma, ids, slip_m: float, robust_scale: float, min_points: int = 1
    ) -> TrajectoryObs | None:
        """The trajectory observations of a frame's points ``xyz`` (N, 3), σ (N,) and
        ``ids`` (N,), or None when fewer than ``min_points`` continue a stored one."""
        if ids is None or not len(self.ids):
            return None
        ids = np.asarray(ids, np.int64)
        pos = np.clip(np.searchsorted(self.ids, ids), 0, len(self.ids) - 1)
        have = self.ids[pos] == ids
        if have.sum() < max(min_points, 1):
            return None
        k = pos[have]
        sig = np.sqrt(np.asarray(sigma, float)[have] ** 2 + self.sigma[k] ** 2 + slip_m**2)
        return TrajectoryObs(
            bone=self.bone[k],
            q0=self.q0[k],
            xyz=np.asarray(xyz)[have],
            sigma=sig,
            robust_scale=robust_scale,
        )
