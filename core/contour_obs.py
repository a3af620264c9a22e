"""Silhouette contour observations for the weighted least-squares fit (SPEC.md stage 8).

For one frame: the metaball body at the current (predicted) pose is rendered into every
camera (:mod:`core.model_render`), its visible rim (:mod:`core.model_contours`) is paired
with the observed occluding contours (:mod:`core.contour_match`) for the parts that
selected that camera (:mod:`core.camera_selection`), and each pair gives one observation
equation: the signed image offset along the contour normal,

    r = n_img . (z - proj(x(θ, root))),       pixels,

whose Jacobian is ``-n_img^T (d proj / d x) [dx/dθ | I]`` (the second paper's
``L_p = H R^-1 L``, eq. 9): the rim point ``x`` is held fixed in its bone's frame during
the linearisation.  Only the normal component is used because a contour does not say
where along itself a point belongs.

Each observation's a-priori σ is ``sigma_px``; the fitter weights it against the other
observation types by ``p_i / p_j = σ_j² / σ_i²``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .camera import Camera, camera_project_jacobians
from .camera_selection import Selection, select_cameras
from .contour_match import match_contours
from .contours import Contour
from .metaballs import Metaballs, world_frames
from .model_contours import rim_points
from .model_render import PartRender, render_parts
from .skeleton import Skeleton, bone_frames, forward, point_jacobians


@dataclass
class ContourObservations:
    """Linearised contour observation equations of one frame.

    Attributes
    ----------
    residual : ndarray, shape (M,)
        Signed offsets along the image normal, pixels (observed minus model).
    J_theta : ndarray, shape (M, n)
        d residual / d θ, pixels per radian.
    J_root : ndarray, shape (M, 3)
        d residual / d root position, pixels per metre.
    ellipsoid : ndarray, shape (M,), int
        Metaball whose rim gave each observation.
    J_radii : ndarray, shape (M, 3)
        d residual / d (lx, ly, lz) of that metaball, pixels per metre (the rim point moves
        with the visible radii ``visible_scale · l`` at fixed unit-sphere coordinates).
    camera : ndarray, shape (M,), int
    part : ndarray, shape (M,), int
        Bone index (the body part) of the model point.
    sigma_px : float
        A-priori standard deviation of one observation, pixels.
    selection : Selection
        The cameras every part used (visibility ≥ 0.2, observability ranking).
    renders : list of PartRender
        The model's per-camera renderings (masks, visibility).
    """

    residual: np.ndarray
    J_theta: np.ndarray
    J_root: np.ndarray
    ellipsoid: np.ndarray
    J_radii: np.ndarray
    camera: np.ndarray
    part: np.ndarray
    sigma_px: float
    selection: Selection
    renders: list[PartRender]

    def __len__(self) -> int:
        return len(self.residual)

    @property
    def rms_px(self) -> float:
        return float(np.sqrt(np.mean(self.residual**2))) if len(self) else float("nan")


def body_ellipsoids(
    skel: Skeleton, theta: np.ndarray, root_xyz: np.ndarray, s: np.ndarray, balls: Metaballs
):
    """The visible ellipsoid of every metaball at one pose.

    Returns centres (M, 3), axes (M, 3, 3) (columns in world), radii (M, 3) scaled to the
    rendered ellipsoids (:attr:`core.metaballs.Metaballs.visible`), and the part (bone)
    of each (M,).
    """
    pose = forward(skel, theta[None], np.asarray(root_xyz)[None], s)
    Rw, cw = world_frames(skel, pose, balls, s)
    return cw[0], Rw[0], balls.visible, balls.bone.copy()


def contour_observations(
    skel: Skeleton,
    theta: np.ndarray,
    root_xyz: np.ndarray,
    s: np.ndarray,
    balls: Metaballs,
    cameras: list[Camera],
    contours: list[list[Contour]],
    theta_rate: np.ndarray | None = None,
    sigma_px: float = 1.0,
    max_dist_px: float = 12.0,
    min_visibility: float = 0.2,
    select: bool = True,
    rays: list[np.ndarray] | None = None,
) -> ContourObservations:
    """Contour observation equations of one frame.

    Parameters
    ----------
    skel, theta (n,), root_xyz (3,), s (G,), balls
        The body at the predicted pose.
    cameras : list of Camera (C)
    contours : list (C) of list of Contour
        Observed occluding contours per camera (from the foreground masks).
    theta_rate : ndarray (n,), optional
        Predicted change of θ to the next frame (EKF rate); ranks cameras by the image
        motion of each part's contour points.  Without it every visible camera is used.
    sigma_px : float
        A-priori σ of a contour observation.
    select : bool
        Per-part camera selection (False: all cameras fused, for comparison).
    rays : list (C) of ndarray (H, W, 3), optional
        Cached viewing rays per camera (:func:`core.model_render.camera_rays`).
    """
    theta = np.asarray(theta, float)
    centers, axes, radii, part = body_ellipsoids(skel, theta, root_xyz, s, balls)
    n_parts = len(skel.bone_names)
    pose = forward(skel, theta[None], np.asarray(root_xyz, float)[None], s)
    Rb, pb = bone_frames(skel, pose)
    anc = skel.ancestors()
    renders, rims = [], []
    for c, cam in enumerate(cameras):
        r = render_parts(
            cam, centers, axes, radii, part, n_parts, rays=None if rays is None else rays[c]
        )
        renders.append(r)
        rims.append(rim_points(cam, centers, axes, radii, part, render=r))
    vis = np.stack([r.visibility_index for r in renders], axis=1)  # (P, C)
    observ = None
    if select and theta_rate is not None:
        observ = np.zeros((n_parts, len(cameras)))
        for c, (cam, rim) in enumerate(zip(cameras, rims, strict=True)):
            if len(rim) == 0:
                continue
            _, J_th, _ = _rim_jacobians(skel, pose, Rb, pb, rim, s, anc)
            _, _, J_xyz = camera_project_jacobians(cam, rim.xyz)
            duv = np.einsum("mij,mjk,k->mi", J_xyz, J_th, np.asarray(theta_rate, float))
            sums = np.zeros((n_parts, 2))
            np.add.at(sums, rim.part, duv)
            observ[:, c] = np.linalg.norm(sums, axis=1)
    selection = (
        select_cameras(vis, observ, min_visibility=min_visibility)
        if select
        else select_cameras(np.where(np.isfinite(vis), 1.0, np.nan))
    )
    res, Jt, Jr, cam_idx, parts, ells, Jrad = [], [], [], [], [], [], []
    for c, (cam, rim) in enumerate(zip(cameras, rims, strict=True)):
        use_parts = np.flatnonzero(selection.use[:, c])
        if len(use_parts) == 0 or len(rim) == 0:
            continue
        m = match_contours(cam, contours[c], rim, max_dist_px=max_dist_px, parts=use_parts)
        if len(m) == 0:
            continue
        sub = rim.select(m.rim_index)
        _, J_th, _ = _rim_jacobians(skel, pose, Rb, pb, sub, s, anc)
        _, _, J_xyz = camera_project_jacobians(cam, sub.xyz)
        nJ = np.einsum("mi,mij->mj", m.contour_normal, J_xyz)  # (M, 3)
        res.append(m.normal_residual)
        Jt.append(-np.einsum("mj,mjk->mk", nJ, J_th))
        Jr.append(-nJ)
        cam_idx.append(np.full(len(m), c))
        parts.append(sub.part)
        e = sub.ellipsoid
        # unit-sphere coordinates of the rim points: x = c + axes (r ∘ p)
        p_unit = np.einsum("mji,mj->mi", axes[e], sub.xyz - centers[e]) / radii[e]
        Jrad.append(-np.einsum("mj,mjk->mk", nJ, axes[e]) * p_unit * balls.vscale[e])
        ells.append(e)
    n = skel.n_dof
    if not res:
        return ContourObservations(
            np.zeros(0),
            np.zeros((0, n)),
            np.zeros((0, 3)),
            np.zeros(0, int),
            np.zeros((0, 3)),
            np.zeros(0, int),
            np.zeros(0, int),
            sigma_px,
            selection,
            renders,
        )
    return ContourObservations(
        np.concatenate(res),
        np.vstack(Jt),
        np.vstack(Jr),
        np.concatenate(ells),
        np.vstack(Jrad),
        np.concatenate(cam_idx),
        np.concatenate(parts),
        sigma_px,
        selection,
        renders,
    )


def _rim_jacobians(skel, pose, Rb, pb, rim, s, anc):
    """Jacobians of rim points held fixed in their bones' frames: (M, 3, n)."""
    bone = rim.part
    q0 = np.einsum("mji,mj->mi", Rb[0, bone], rim.xyz - pb[0, bone])  # bone frame
    group = np.full(len(bone), -1)
    x, J_theta, J_s = point_jacobians(skel, pose, bone, q0, group, s, anc)
    return x[0], J_theta[0], J_s[0]


def contour_mask(contours: list[Contour], size: tuple[int, int]) -> np.ndarray:
    """The foreground enclosed by occluding contours, shape (H, W) bool.

    Outer contours are filled, holes cleared again (``size`` is ``(W, H)``).
    """
    import cv2

    w, h = size
    m = np.zeros((h, w), np.uint8)
    outer = [np.round(c.uv).astype(np.int32) for c in contours if not c.hole and len(c) >= 3]
    holes = [np.round(c.uv).astype(np.int32) for c in contours if c.hole and len(c) >= 3]
    if outer:
        cv2.fillPoly(m, outer, 1)
    if holes:
        cv2.fillPoly(m, holes, 0)
    return m.astype(bool)


@dataclass
class SilhouetteField:
    """Distance outside the observed foreground of one camera.

    Attributes
    ----------
    dist : ndarray, shape (H, W)
        Pixels from each background pixel to the nearest foreground pixel (0 inside).
    grad : ndarray, shape (H, W, 2)
        Its image gradient ``(d/du, d/dv)``, pixels per pixel.
    """

    dist: np.ndarray
    grad: np.ndarray
    _stack: np.ndarray | None = field(default=None, init=False, repr=False, compare=False)

    def sample(self, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Bilinear distance (M,) and gradient (M, 2) at ``uv`` (M, 2); NaN outside."""
        if self._stack is None:  # (H, W, 3): distance and gradient, built on first use
            self._stack = np.concatenate([self.dist[..., None], self.grad], axis=2)
        stack = self._stack
        h, w = self.dist.shape
        u, v = uv[:, 0], uv[:, 1]
        ok = np.isfinite(u) & np.isfinite(v) & (u >= 0) & (v >= 0) & (u <= w - 1) & (v <= h - 1)
        u0 = np.clip(np.floor(np.where(ok, u, 0)).astype(int), 0, w - 2)
        v0 = np.clip(np.floor(np.where(ok, v, 0)).astype(int), 0, h - 2)
        a = (np.where(ok, u, 0) - u0)[:, None]
        b = (np.where(ok, v, 0) - v0)[:, None]
        val = (
            (1 - a) * (1 - b) * stack[v0, u0]
            + a * (1 - b) * stack[v0, u0 + 1]
            + (1 - a) * b * stack[v0 + 1, u0]
            + a * b * stack[v0 + 1, u0 + 1]
        )
        val[~ok] = np.nan
        return val[:, 0], val[:, 1:]


def silhouette_field(contours: list[Contour], size: tuple[int, int]) -> SilhouetteField:
    """:class:`SilhouetteField` of the foreground enclosed by ``contours`` (``size`` (W, H))."""
    import cv2

    fg = contour_mask(contours, size)
    dist = cv2.distanceTransform((~fg).astype(np.uint8), cv2.DIST_L2, 5).astype(float)
    gv, gu = np.gradient(dist)
    return SilhouetteField(dist, np.stack([gu, gv], axis=-1))


#: Sample points of a metaball for the containment term, in units of its visible radii:
#: the centre and half-way to the surface along each principal axis.
_INNER = np.vstack([np.zeros(3), 0.5 * np.eye(3), -0.5 * np.eye(3)])


@dataclass
class ContainmentObservations:
    """The body must project inside the foreground of every camera.

    Attributes
    ----------
    residual : ndarray, shape (M,)
        Distance outside the foreground of each sample point's projection minus the
        tolerance, pixels (≥ 0 where it counts; 0 inside).
    J_theta : ndarray, shape (M, n); J_root : ndarray, shape (M, 3)
        Its derivatives, pixels per radian / per metre.
    part : ndarray, shape (M,), int; camera : ndarray, shape (M,), int
    outside : ndarray, shape (M,), bool
        The point projects further than ``tol_px`` outside the foreground.
    """

    residual: np.ndarray
    J_theta: np.ndarray
    J_root: np.ndarray
    part: np.ndarray
    camera: np.ndarray
    outside: np.ndarray

    def __len__(self) -> int:
        return len(self.residual)


def _no_containment(n: int) -> ContainmentObservations:
    return ContainmentObservations(
        np.zeros(0),
        np.zeros((0, n)),
        np.zeros((0, 3)),
        np.zeros(0, int),
        np.zeros(0, int),
        np.zeros(0, bool),
    )


def containment_observations(
    skel: Skeleton,
    theta: np.ndarray,
    root_xyz: np.ndarray,
    s: np.ndarray,
    balls: Metaballs,
    cameras: list[Camera],
    fields: list[SilhouetteField],
    tol_px: float = 2.0,
    keep_parts: np.ndarray | None = None,
) -> ContainmentObservations:
    """Silhouette containment: points inside every metaball must project into the foreground.

    Unlike a contour, this holds in every camera whatever occludes the part (a limb in
    front of the trunk still projects inside the silhouette), and its capture range is
    as wide as the distance field: a limb that left the silhouette is pulled back
    towards the nearest foreground.  Seven points per metaball (:data:`_INNER`), each
    a residual ``max(D(proj(x)) - tol_px, 0)`` with the distance field ``D`` of
    :func:`silhouette_field`; points projecting outside the image are left out.
    ``keep_parts`` (P,) bool, optional: only the metaballs of these body parts.
    """
    theta = np.asarray(theta, float)
    root_xyz = np.asarray(root_xyz, float)
    centers, axes, radii, part = body_ellipsoids(skel, theta, root_xyz, s, balls)
    if keep_parts is not None:
        keep = np.asarray(keep_parts, bool)[part]
        centers, axes, radii, part = centers[keep], axes[keep], radii[keep], part[keep]
    n = skel.n_dof
    if not len(part):
        return _no_containment(n)
    K = len(_INNER)
    xyz = (
        centers[:, None] + np.einsum("eij,ekj->eki", axes, _INNER[None] * radii[:, None])
    ).reshape(-1, 3)
    bone = np.repeat(part, K)
    pose = forward(skel, theta[None], root_xyz[None], s)
    Rb, pb = bone_frames(skel, pose)
    anc = skel.ancestors()
    q0 = np.einsum("mji,mj->mi", Rb[0, bone], xyz - pb[0, bone])
    _, J_th, _ = point_jacobians(skel, pose, bone, q0, np.full(len(bone), -1), s, anc, scales=False)
    J_th = J_th[0]
    res, Jt, Jr, parts, cams, outside = [], [], [], [], [], []
    for c, (cam, fld) in enumerate(zip(cameras, fields, strict=True)):
        uv, _, J_xyz = camera_project_jacobians(cam, xyz)
        d, g = fld.sample(uv)
        ok = np.isfinite(d)
        if not ok.any():
            continue
        gJ = np.einsum("mi,mij->mj", g[ok], J_xyz[ok])  # (m, 3)
        on = d[ok] > tol_px
        res.append(np.where(on, d[ok] - tol_px, 0.0))
        Jt.append(np.einsum("mj,mjk->mk", gJ, J_th[ok]) * on[:, None])
        Jr.append(gJ * on[:, None])
        parts.append(bone[ok])
        cams.append(np.full(int(ok.sum()), c))
        outside.append(on)
    if not res:
        return _no_containment(n)
    return ContainmentObservations(
        np.concatenate(res),
        np.vstack(Jt),
        np.vstack(Jr),
        np.concatenate(parts),
        np.concatenate(cams),
        np.concatenate(outside),
    )
