"""Contour ↔ rim pairs of one frame, and their residuals with analytic Jacobians.

:func:`match_frame` renders the body at a pose into every camera, keeps the rim points
on the outline of the model's whole silhouette (:func:`outer_rim`), selects the
cameras of each part (visibility, observability ranking) and pairs the image
contours with the rim (:class:`ContourPairs`, each rim point held in its metaball's
unit-sphere frame).  :func:`contour_block` evaluates the frozen pairs at a state: the
residual ``r_i = n_i · (z_i − proj_c(x_i(θ, root, s, radii, centres)))`` and its exact
Jacobians.  Used by :class:`core.fit_contours.ContourFrame` (which re-exports
these names), which weights the rows.

Frames: world Z up, metres; image pixels as in :mod:`core.camera`; angles radians.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .camera import Camera, camera_project_jacobians
from .camera_selection import Selection, add_wide_views, select_cameras
from .contour_match import match_contours
from .contour_settings import ContourSettings
from .contours import Contour
from .metaballs import Metaballs, world_frames
from .model_contours import rim_points
from .model_render import render_parts
from .skeleton import Skeleton, bone_frames, forward, point_jacobians


@dataclass
class ContourPairs:
    """Frozen contour ↔ rim correspondences of one frame (M pairs).

    Attributes
    ----------
    camera : (M,) int camera index
    ellipsoid : (M,) int metaball of the rim point
    bone : (M,) int its bone (the body part)
    p_unit : (M, 3) the rim point in its metaball's unit-sphere frame
    z : (M, 2) image contour points, pixels
    normal : (M, 2) their outward unit image normals
    sigma_scale : (M,) factor on each pair's σ (1 for the views the part's camera
        selection chose; :attr:`ContourSettings.unselected_sigma_scale` for the others)
    """

    camera: np.ndarray
    ellipsoid: np.ndarray
    bone: np.ndarray
    p_unit: np.ndarray
    z: np.ndarray
    normal: np.ndarray
    sigma_scale: np.ndarray

    def __len__(self) -> int:
        return len(self.camera)


def _empty_pairs() -> ContourPairs:
    return ContourPairs(
        np.zeros(0, int),
        np.zeros(0, int),
        np.zeros(0, int),
        np.zeros((0, 3)),
        np.zeros((0, 2)),
        np.zeros((0, 2)),
        np.zeros(0),
    )


def match_frame(
    skel: Skeleton,
    balls: Metaballs,
    theta: np.ndarray,
    root: np.ndarray,
    s: np.ndarray,
    cameras: list[Camera],
    contours: list[list[Contour]],
    cfg: ContourSettings,
    theta_rate: np.ndarray | None = None,
    rays: list[np.ndarray] | None = None,
) -> tuple[ContourPairs, Selection]:
    """Pair one frame's image contours with the model's visible rim at a pose.

    Each part pairs in the cameras its selection chose (:func:`select_cameras`, plus
    :func:`add_wide_views`) and, with ``cfg.unselected_sigma_scale``, also in the others
    that see any of it, those pairs' σ times the scale (``ContourPairs.sigma_scale``).

    Parameters
    ----------
    skel, balls, theta (n,), root (3,), s (G,)
        The body and its pose (radians, metres).
    cameras : list (C) of Camera
    contours : list (C) of list of Contour
    theta_rate : (n,) predicted change of θ per frame, optional; ranks each part's
        cameras by the image motion of its rim (observability); without it every
        camera where the part is visible is used
    rays : list (C) of (H, W, 3) cached viewing rays (:func:`core.model_render.camera_rays`)

    Returns
    -------
    (ContourPairs, Selection) — the pairs and the cameras each part used.
    """
    pose = forward(skel, np.asarray(theta, float)[None], np.asarray(root, float)[None], s)
    Rw, cw = world_frames(skel, pose, balls, s)
    centers, axes, radii = cw[0], Rw[0], balls.visible
    n_parts = len(skel.bone_names)
    renders, rims = [], []
    for c, cam in enumerate(cameras):
        r = render_parts(
            cam, centers, axes, radii, balls.bone, n_parts, rays=None if rays is None else rays[c]
        )
        renders.append(r)
        rim = rim_points(cam, centers, axes, radii, balls.bone, n_per=cfg.rim_samples, render=r)
        if cfg.outer_px > 0:
            rim = rim.select(outer_rim(cam, rim, r.part_id >= 0, cfg.outer_px))
        rims.append(rim)
    vis = np.stack([r.visibility_index for r in renders], axis=1)  # (P, C)
    observ = None
    if cfg.select and cfg.rank_motion and theta_rate is not None:
        observ = np.zeros((n_parts, len(cameras)))
        anc = skel.ancestors()
        for c, (cam, rim) in enumerate(zip(cameras, rims, strict=True)):
            if len(rim) == 0:
                continue
            _, J_th, _ = _rim_point_jacobian(skel, pose, rim.part, rim.xyz, s, anc)
            _, _, J_xyz = camera_project_jacobians(cam, rim.xyz)
            duv = np.einsum("mij,mjk,k->mi", J_xyz, J_th, np.asarray(theta_rate, float))
            sums = np.zeros((n_parts, 2))
            np.add.at(sums, rim.part, duv)
            observ[:, c] = np.linalg.norm(sums, axis=1)
    if cfg.select:
        sel = select_cameras(vis, observ, min_visibility=cfg.min_visibility)
    else:
        sel = select_cameras(np.where(np.isfinite(vis), 1.0, np.nan))
    sel.use[:, [not contours[c] for c in range(len(cameras))]] = False  # nothing to pair
    if cfg.select and cfg.wide_view_deg is not None:
        part_xyz = np.full((n_parts, 3), np.nan)
        for p in np.unique(balls.bone):
            part_xyz[p] = centers[balls.bone == p].mean(axis=0)
        outline = None
        if cfg.wide_view_outline > 0:
            outline = np.stack([np.bincount(r.part, minlength=n_parts) for r in rims], axis=1)
        add_wide_views(
            sel,
            np.array([cam.center for cam in cameras]),
            part_xyz,
            cfg.depth_spread_deg,
            cfg.wide_view_deg,
            cfg.min_visibility,
            pairable=np.array([bool(c) for c in contours]),
            outline=outline,
            min_outline=cfg.wide_view_outline,
        )
    if cfg.skip_parts:
        sel.use[[skel.bone_index(b) for b in cfg.skip_parts]] = False
    pair = sel.use.copy()
    soft = cfg.select and cfg.unselected_sigma_scale is not None
    if soft:  # the views left out too, less trusted
        pair |= np.isfinite(vis)
        pair[:, [not contours[c] for c in range(len(cameras))]] = False
        if cfg.skip_parts:
            pair[[skel.bone_index(b) for b in cfg.skip_parts]] = False
    out = []
    for c, (cam, rim) in enumerate(zip(cameras, rims, strict=True)):
        use_parts = np.flatnonzero(pair[:, c])
        if len(use_parts) == 0 or len(rim) == 0 or not contours[c]:
            continue
        m = match_contours(cam, contours[c], rim, max_dist_px=cfg.max_dist_px, parts=use_parts)
        if len(m) == 0:
            continue
        e = rim.ellipsoid[m.rim_index]
        x = rim.xyz[m.rim_index]
        p_unit = np.einsum("mji,mj->mi", axes[e], x - centers[e]) / radii[e]
        bone = balls.bone[e]
        scale = np.where(sel.use[bone, c], 1.0, cfg.unselected_sigma_scale if soft else 1.0)
        out.append(
            ContourPairs(np.full(len(m), c), e, bone, p_unit, m.contour_uv, m.contour_normal, scale)
        )
    if not out:
        return _empty_pairs(), sel
    return ContourPairs(
        *(
            np.concatenate([getattr(p, k) for p in out])
            for k in ("camera", "ellipsoid", "bone", "p_unit", "z", "normal", "sigma_scale")
        )
    ), sel


def outer_rim(camera: Camera, rim, mask: np.ndarray, offset_px: float = 3.0) -> np.ndarray:
    """Which rim points lie on the outline of the model's whole silhouette, shape (M,) bool.

    An image contour is the outline of the person's foreground, so only model rim points
    with background just outside them can correspond to it: a limb's rim in front of the
    trunk (an internal occluding contour) is inside the silhouette and has no image
    contour to pair with.  The test samples ``mask`` (H, W) (the model's rendering) at
    ``offset_px`` along the projected outward surface normal.
    """
    if len(rim) == 0:
        return np.zeros(0, bool)
    step = 0.01  # metres along the 3-D normal, to get its image direction
    d = camera.project(rim.xyz + step * rim.normal) - rim.uv
    nd = np.linalg.norm(d, axis=1, keepdims=True)
    d = np.where(nd > 1e-9, d / np.maximum(nd, 1e-9), 0.0)
    p = np.round(rim.uv + offset_px * d).astype(int)
    h, w = mask.shape
    inside = (p[:, 0] >= 0) & (p[:, 0] < w) & (p[:, 1] >= 0) & (p[:, 1] < h)
    covered = np.zeros(len(p), bool)
    covered[inside] = mask[p[inside, 1], p[inside, 0]]
    return ~covered


def _rim_point_jacobian(skel, pose, bone, xyz, s, anc, scales=False):
    """World positions (M, 3) and d x / d θ (M, 3, n) of points fixed in their bones;
    with ``scales`` also d x / d s (M, 3, G) through the DOF offsets above each point
    (its own offset held unscaled), else None."""
    Rb, pb = bone_frames(skel, pose)
    q0 = np.einsum("mji,mj->mi", Rb[0, bone], xyz - pb[0, bone])
    x, J_theta, J_s = point_jacobians(
        skel, pose, bone, q0, np.full(len(bone), -1), s, anc, scales=scales
    )
    return x[0], J_theta[0], None if J_s is None else J_s[0]


def contour_block(
    skel: Skeleton,
    balls: Metaballs,
    theta: np.ndarray,
    root: np.ndarray,
    s: np.ndarray,
    cameras: list[Camera],
    pairs: ContourPairs,
    anc: np.ndarray | None = None,
    shape: bool = True,
):
    """Residuals and analytic Jacobians of frozen contour pairs at a state.

    Parameters
    ----------
    skel, balls : the body (``balls.radii`` (M, 3) and ``balls.center0`` (M, 3) are the
        current shape unknowns)
    theta : (n,) radians; root : (3,) metres; s : (G,) bone scales
    cameras : list (C) of Camera
    pairs : ContourPairs (K pairs)
    shape : also return the Jacobians w.r.t. s, the radii and the centres

    Returns
    -------
    r : (K,) ``n · (z − proj(x))``, pixels (unweighted)
    J_theta : (K, n) px/rad; J_root : (K, 3) px/m; J_s : (K, G) px;
    J_radii : (K, 3M) px/m; J_centers : (K, 3M) px/m (the last three None when not shape)
    """
    n, G, M = skel.n_dof, skel.n_groups, len(balls.radii)
    K = len(pairs)
    r = np.zeros(K)
    J_t, J_r = np.zeros((K, n)), np.zeros((K, 3))
    J_s = np.zeros((K, G)) if shape else None
    J_rad = np.zeros((K, 3 * M)) if shape else None
    J_c = np.zeros((K, 3 * M)) if shape else None
    if K == 0:
        return r, J_t, J_r, J_s, J_rad, J_c
    anc = skel.ancestors() if anc is None else anc
    pose = forward(skel, np.asarray(theta, float)[None], np.asarray(root, float)[None], s)
    Rw, cw = world_frames(skel, pose, balls, s)
    Rb, _ = bone_frames(skel, pose)
    e, bone = pairs.ellipsoid, pairs.bone
    local = balls.visible[e] * pairs.p_unit  # (K, 3) in the metaball's axes
    xyz = cw[0, e] + (Rw[0, e] @ local[:, :, None])[:, :, 0]
    _, J_th, Js0 = _rim_point_jacobian(skel, pose, bone, xyz, s, anc, scales=shape)
    nJ = np.zeros((K, 3))  # n^T d proj / d x
    for c, cam in enumerate(cameras):
        k = np.flatnonzero(pairs.camera == c)
        if not len(k):
            continue
        uv, _, J_xyz = camera_project_jacobians(cam, xyz[k])
        r[k] = np.sum(pairs.normal[k] * (pairs.z[k] - uv), axis=1)
        nJ[k] = (pairs.normal[k][:, None, :] @ J_xyz)[:, 0]
    J_t[:] = -(nJ[:, None, :] @ J_th)[:, 0]
    J_r[:] = -nJ
    if shape:
        # bone scales: the DOF offsets above the point (point_jacobians' J_s of a point
        # with no group: its own offset does not enter) and the metaball's own centre
        # c0 · s_g in its bone's frame
        g = balls.group[e]
        own = np.einsum("kij,kj->ki", Rb[0, bone], balls.center0[e])
        Js = Js0.copy()
        has = np.flatnonzero(g >= 0)
        Js[has, :, g[has]] += own[has]
        J_s[:] = -np.einsum("kj,kjg->kg", nJ, Js)
        cols = 3 * e[:, None] + np.arange(3)[None]
        # radii: d x / d l_e = R_e diag(visible_scale p)
        d_rad = -np.einsum("kj,kji->ki", nJ, Rw[0, e]) * balls.vscale[e] * pairs.p_unit
        np.put_along_axis(J_rad, cols, d_rad, axis=1)
        scale = np.where(g >= 0, np.asarray(s, float)[np.maximum(g, 0)], 1.0)
        d_cen = -np.einsum("kj,kji->ki", nJ, Rb[0, bone]) * scale[:, None]
        np.put_along_axis(J_c, cols, d_cen, axis=1)
    return r, J_t, J_r, J_s, J_rad, J_c
