"""Depth holds: the one direction a single view's occluding contours leave free.

With contours alone, a limb whose contour pairs all come from one camera is placed in
that image, but not along the camera's rays: its occluding contour is the same wherever
the limb swings towards or away from the camera.  Left free, it may drift in depth or
flip to its mirror image across the plane through the joint it hangs from (an arm swung
0.3 rad away from the camera and one swung 0.3 rad towards it draw almost the same
outline).  Hiding the part instead
(holding all its angles) also stops the motion the view does see: a leg seen by one
camera of walk_ortho3 was lost that way.

A depth hold is one observation per joint the part carries (its distal joint, e.g. the
wrist for the forearm): the joint's distance along the viewing ray of the one camera,
held at the previous frame's with σ ``sigma_m``,

    r_k = d_k · (x_k(θ, root, s) − x̂_k) / σ,

``d_k`` the unit ray from the camera centre to the held joint ``x̂_k``.  The two image
directions stay free for the contours.  Held at the *prediction* instead, the depth
keeps whatever velocity the last frames had, since nothing observes it: on the skin
look's walk (contours alone) both legs ran off in depth from frame 21 (MPJPE 82.8 mm).

Views a few tens of degrees apart (the line rig's three side cameras, 38° between the
outer ones) see nearly the same occluding contour of a limb, so they leave its depth
almost as free as one view: :func:`narrow_depth_holds` holds such a part's joints
along the mean of its views' rays.  With contours alone on the line rig, the sweater
walk 33.2 -> 26.3 mm, the skin walk 27.9 -> 25.6, the jumps 30.0 -> 25.0.

Frames: world Z up, metres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .camera import Camera
from .skeleton import Skeleton, joint_jacobians


@dataclass
class DepthHolds:
    """Joint depths held along one camera's rays (K holds).

    Attributes
    ----------
    joint : (K,) int — joints (index into ``Skeleton.joint_names``)
    direction : (K, 3) unit viewing rays, world
    target : (K, 3) the held joint positions, world metres
    sigma_m : (K,) a-priori σ along the ray, metres
    """

    joint: np.ndarray
    direction: np.ndarray
    target: np.ndarray
    sigma_m: np.ndarray

    def __len__(self) -> int:
        return len(self.joint)

    def block(self, skel: Skeleton, theta: np.ndarray, root: np.ndarray, s: np.ndarray):
        """Weighted residuals (K,) and Jacobians w.r.t. θ (K, n), root (K, 3), s (K, G)."""
        x, Jt, Js = joint_jacobians(skel, theta[None], root[None], s)
        d, w = self.direction, 1.0 / self.sigma_m
        r = np.einsum("kd,kd->k", x[0, self.joint] - self.target, d) * w
        J_theta = np.einsum("kd,kdn->kn", d, Jt[0, self.joint]) * w[:, None]
        J_s = np.einsum("kd,kdg->kg", d, Js[0, self.joint]) * w[:, None]
        return r, J_theta, d * w[:, None], J_s


def part_views(
    bone: np.ndarray, camera: np.ndarray, n_parts: int, n_cameras: int, min_pairs: int = 10
) -> np.ndarray:
    """(P, C) bool: the views with at least ``min_pairs`` contour pairs of each part
    (``bone``, ``camera``: (M,) int, body part and camera of each pair)."""
    per = np.bincount(bone * n_cameras + camera, minlength=n_parts * n_cameras)[
        : n_parts * n_cameras
    ]
    return per.reshape(n_parts, n_cameras) >= min_pairs


def single_view_parts(
    bone: np.ndarray, camera: np.ndarray, n_parts: int, n_cameras: int, min_pairs: int = 10
) -> np.ndarray:
    """The camera of every part whose contour pairs come from exactly one view.

    Parameters
    ----------
    bone, camera : (M,) int — body part and camera of each contour pair
    n_parts, n_cameras : int
    min_pairs : a view counts with at least this many pairs of the part

    Returns
    -------
    (P,) int — that camera, −1 for parts seen by no view or by several
    """
    seen = part_views(bone, camera, n_parts, n_cameras, min_pairs)
    return np.where(seen.sum(axis=1) == 1, np.argmax(seen, axis=1), -1)


def depth_holds(
    skel: Skeleton,
    theta: np.ndarray,
    root: np.ndarray,
    s: np.ndarray,
    view: np.ndarray,
    cameras: list[Camera],
    parts: np.ndarray,
    sigma_m: float,
) -> DepthHolds:
    """Depth holds at a pose for the joints carried by single-view parts.

    Parameters
    ----------
    theta : (n,) radians, root : (3,) metres, s : (G,) — the pose whose joints are held
        (the previous frame's)
    view : (P,) int — :func:`single_view_parts`
    cameras : list of Camera (C)
    parts : (P,) bool — the parts that may be held (e.g. the limbs not already hidden)
    sigma_m : σ of a hold along the ray, metres
    """
    use = (view >= 0) & parts
    joint = np.flatnonzero(use[skel.joint_bone])
    x = joint_jacobians(skel, theta[None], root[None], s)[0][0, joint]
    centres = np.array([c.center for c in cameras]).reshape(-1, 3)
    d = x - centres[view[skel.joint_bone[joint]]] if len(joint) else np.zeros((0, 3))
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
    return DepthHolds(joint, d, x, np.full(len(joint), float(sigma_m)))


def narrow_depth_holds(
    skel: Skeleton,
    theta: np.ndarray,
    root: np.ndarray,
    s: np.ndarray,
    seen: np.ndarray,
    cameras: list[Camera],
    parts: np.ndarray,
    sigma_m: float,
    max_spread_deg: float = 0.0,
) -> DepthHolds:
    """Depth holds for the joints of parts whose views look along nearly one direction.

    Views a few tens of degrees apart see almost the same occluding contour of a limb,
    so they leave its depth nearly as free as one view does.  A joint is held when
    the rays from its part's views (``seen``) to it are at most ``max_spread_deg``
    apart pairwise, along their mean direction; with 0 only single-view parts are held
    (:func:`depth_holds`).

    Parameters
    ----------
    theta : (n,) radians, root : (3,) metres, s : (G,) — the pose whose joints are held
    seen : (P, C) bool — :func:`part_views`
    cameras : list of Camera (C)
    parts : (P,) bool — the parts that may be held
    sigma_m : σ of a hold along the direction, metres
    max_spread_deg : largest angle between two of a joint's view rays, degrees
    """
    seen = np.asarray(seen, bool)
    use = seen.any(axis=1) & parts
    joint = np.flatnonzero(use[skel.joint_bone])
    if not len(joint):
        return DepthHolds(joint, np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0))
    x = joint_jacobians(skel, theta[None], root[None], s)[0][0, joint]
    centres = np.array([c.center for c in cameras]).reshape(-1, 3)
    rays = x[:, None] - centres[None]  # (K, C, 3)
    rays /= np.maximum(np.linalg.norm(rays, axis=2, keepdims=True), 1e-12)
    m = seen[skel.joint_bone[joint]]  # (K, C)
    cos = np.einsum("kad,kbd->kab", rays, rays)
    both = m[:, :, None] & m[:, None, :] & ~np.eye(m.shape[1], dtype=bool)
    cos = np.clip(np.where(both, cos, 1.0), -1.0, 1.0)
    spread = np.degrees(np.arccos(cos)).max(axis=(1, 2))
    keep = spread <= max_spread_deg
    d = np.einsum("kc,kcd->kd", m.astype(float), rays)[keep]
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
    return DepthHolds(joint[keep], d, x[keep], np.full(int(keep.sum()), float(sigma_m)))


def frame_depth_holds(
    skel: Skeleton, contours, hidden: np.ndarray, theta: np.ndarray, root: np.ndarray, s: np.ndarray
) -> DepthHolds | None:
    """The depth holds of one contours-alone frame.

    Parameters
    ----------
    contours : :class:`core.fit_contours.ContourFrame`, frozen (its pairs at the current
        pose); its ``cfg.depth_sigma_m`` (None: no holds) and ``cfg.depth_spread_deg``
        (the widest spread of views held, :func:`narrow_depth_holds`)
    hidden : (n,) bool — the hidden DOFs; their parts are held otherwise, not here
    theta : (n,) radians, root : (3,) metres, s : (G,) — the previous frame's pose

    Returns
    -------
    DepthHolds, or None (off, or no contour pairs)
    """
    sigma = contours.cfg.depth_sigma_m
    if sigma is None or contours.pairs is None or not len(contours.pairs):
        return None
    B = len(skel.bone_names)
    seen = part_views(contours.pairs.bone, contours.pairs.camera, B, len(contours.cameras))
    shown = np.ones(B, bool)
    shown[skel.dof_bones()[np.asarray(hidden)]] = False
    return narrow_depth_holds(
        skel, theta, root, s, seen, contours.cameras, shown, sigma, contours.cfg.depth_spread_deg
    )
