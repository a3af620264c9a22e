"""Metaball shape (and a pose refinement) from one frame's silhouettes.

:func:`fit_shape_to_contours` solves the metaball radii, optionally their centres in
their bones' frames, and the pose of one frame to that frame's occluding contours in
every camera (:func:`core.contour_obs.contour_observations`, Huber-weighted, σ in
pixels), with priors about the start: the clicked pose and the template shape.  It is
a Gauss–Newton solve of the same contour observations as the tracker
(:mod:`core.contour_track`, which re-exports it), with the shape free.

Frames: world Z up, metres; radii and centres metres (centres in their bones' frames);
angles radians; image pixels as in :mod:`core.camera`.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg

from .camera import Camera
from .contour_obs import contour_observations
from .contour_track_settings import ContourTrackSettings
from .contours import Contour
from .metaballs import Metaballs
from .skeleton import Skeleton, bone_frames, forward


def fit_shape_to_contours(
    skel: Skeleton,
    s: np.ndarray,
    balls: Metaballs,
    theta: np.ndarray,
    root: np.ndarray,
    cameras: list[Camera],
    contours: list[list[Contour]],
    cfg: ContourTrackSettings | None = None,
    radius_prior_m: float | np.ndarray = 0.02,
    iterations: int = 6,
    rays=None,
    center_prior_m=None,
    center_axes: tuple = (0, 1, 2),
    fields: list | None = None,
    sigma_contain_px: float = 2.0,
    contain_tol_px: float = 3.0,
) -> tuple[Metaballs, np.ndarray, np.ndarray, float]:
    """Metaball radii (and centres, and a pose refinement) from one frame's silhouettes.

    Minimises the Huber-weighted contour residuals (σ = ``cfg.sigma_px``) plus priors:
    the pose about ``theta``/``root`` with σ ``cfg.q_sigma_theta``/``cfg.q_sigma_root``
    (e.g. the clicked pose) and every radius about its starting value with
    σ ``radius_prior_m`` (metres, one σ or (E,) per metaball) — radii along a camera's
    line of sight are seen by the other cameras only, and the prior keeps unobserved
    ones where they are.

    With ``center_prior_m`` (metres, one σ or (E,) per metaball; NaN or 0: held) the
    metaball centres (``Metaballs.center0``, in their bones' frames) are free too, about
    their starting values with that σ, along ``center_axes`` of the bone frame (z runs
    along the bone; ``(0, 1)`` keeps each metaball's place along its bone, which hardly
    changes the outline of a chain of them — measured worse on the studio's feet, whose
    template metaballs are misplaced along the foot too).  The template puts
    them on the bone axis, where this body's flesh is not (the head and the chest lie in
    front of the neck and spine joints); held on the axis, the silhouettes push the
    whole body forward in every later frame.  A centre moves its rendered ellipsoid's
    rim rigidly, so its Jacobian is the root translation's through the bone's rotation
    and scale.  It needs a pose held by the clicks (tight ``q_sigma_*``): a free pose
    trades the centres against the joints.

    With ``fields`` (per camera a :class:`core.contour_obs.SilhouetteField` or None) every
    metaball's rendered surface is also held inside the foregrounds
    (:func:`core.shape_containment.shape_containment`: points at 0.9 of its semi-axes,
    ``contain_tol_px`` tolerated, σ ``sigma_contain_px``), in its radii and centres: a
    rim that stands out further than the contour pairing reaches pays for it.

    Returns
    -------
    balls : Metaballs with the fitted radii (and centres)
    theta : (n,), root : (3,) refined pose
    rms_px : contour residual RMS at the end
    """
    cfg = cfg or ContourTrackSettings()
    n, E = skel.n_dof, len(balls)
    theta0 = np.asarray(theta, float).copy()
    root0 = np.asarray(root, float).copy()
    r0, c0 = balls.radii.copy(), balls.center0.copy()
    th, rt, radii, cen = theta0.copy(), root0.copy(), r0.copy(), c0.copy()
    sig_c = np.broadcast_to(
        np.nan if center_prior_m is None else np.asarray(center_prior_m, float), (E,)
    )
    free = np.flatnonzero(np.isfinite(sig_c) & (sig_c > 0))  # metaballs with free centres
    ax = np.asarray(center_axes, int)
    k = len(ax)
    nc = k * len(free)
    slot = np.full(E, -1)
    slot[free] = np.arange(len(free))
    w_pose = np.concatenate([np.full(n, cfg.q_sigma_theta), np.full(3, cfg.q_sigma_root)]) ** -2
    sig_r = np.broadcast_to(np.asarray(radius_prior_m, float), (E,))
    w_shape = np.concatenate([np.repeat(sig_r, 3) ** -2, np.repeat(sig_c[free], k) ** -2])
    scale = np.where(balls.group >= 0, np.asarray(s, float)[np.maximum(balls.group, 0)], 1.0)
    rms = float("nan")
    for _ in range(iterations):
        cur = balls.with_parts(cen, radii)
        obs = contour_observations(
            skel,
            th,
            rt,
            s,
            cur,
            cameras,
            contours,
            sigma_px=cfg.sigma_px,
            max_dist_px=cfg.max_dist_px,
            select=cfg.select,
            rays=rays,
        )
        if len(obs) < cfg.min_matches:
            break
        J_pose, J_radii, r, w = contour_rows(obs, E, cfg)
        J = np.hstack([J_pose, J_radii, np.zeros((len(obs), nc))])
        e = obs.ellipsoid
        if nc and (on := slot[e] >= 0).any():
            Rb, _ = bone_frames(skel, forward(skel, th[None], rt[None], s))
            eo = e[on]
            Jc = np.einsum("mj,mjk->mk", obs.J_root[on], Rb[0, balls.bone[eo]]) * scale[eo, None]
            J[
                np.flatnonzero(on)[:, None],
                n + 3 + 3 * E + k * slot[eo][:, None] + np.arange(k)[None],
            ] = Jc[:, ax]
        if fields is not None:
            Jo, ro = _containment_rows(skel, th, rt, s, cur, cameras, fields, contain_tol_px)
            Jo = _with_centres(Jo, ro, free, slot, ax, scale, skel, th, rt, s, cur)
            J = np.vstack([J, np.hstack([np.zeros((len(ro), n + 3)), Jo])])
            r = np.concatenate([r, ro.residual])
            w = np.concatenate([w, np.full(len(ro), sigma_contain_px**-2)])
        prior_w = np.concatenate([w_pose, w_shape])
        x = np.concatenate([th, rt, radii.ravel(), cen[np.ix_(free, ax)].ravel()])
        x0 = np.concatenate([theta0, root0, r0.ravel(), c0[np.ix_(free, ax)].ravel()])
        A = (J.T * w) @ J + np.diag(prior_w)
        g = (J.T * w) @ r + prior_w * (x - x0)
        delta = -scipy.linalg.cho_solve(scipy.linalg.cho_factor(A), g)
        th, rt = th + delta[:n], rt + delta[n : n + 3]
        radii = np.maximum(radii + delta[n + 3 : n + 3 + 3 * E].reshape(E, 3), 0.01)
        cen[np.ix_(free, ax)] += delta[n + 3 + 3 * E :].reshape(-1, k)
        rms = float(np.sqrt(np.mean(obs.residual**2)))
        if np.max(np.abs(delta)) < 1e-5:
            break
    return balls.copy().with_parts(cen, radii), th, rt, rms


def contour_rows(obs, n_balls: int, cfg) -> tuple:
    """The contour observations' Jacobian blocks and Huber weights.

    Parameters
    ----------
    obs : :class:`core.contour_obs.ContourObservations` of one frame (M pairs)
    n_balls : E, the number of metaballs
    cfg : settings with ``sigma_px`` and ``huber_px`` (pixels)

    Returns
    -------
    J_pose : (M, n + 3) — by the joint angles (rad) and the root translation (m), px
    J_radii : (M, 3E) — by every metaball's three radii (m), px
    r : (M,) residuals, px
    w : (M,) weights, 1/px² (Huber-reweighted 1/σ²)
    """
    J_radii = np.zeros((len(obs), 3 * n_balls))
    cols = 3 * obs.ellipsoid[:, None] + np.arange(3)[None]
    np.put_along_axis(J_radii, cols, obs.J_radii, axis=1)
    r = obs.residual
    a = np.abs(r)
    w = np.where(a <= cfg.huber_px, 1.0, cfg.huber_px / np.maximum(a, 1e-12))
    return np.hstack([obs.J_theta, obs.J_root]), J_radii, r, w / cfg.sigma_px**2


def _containment_rows(skel, th, rt, s, balls, cameras, fields, tol_px):
    """The containment's Jacobian in the radii (M, 3E), and its observations."""
    from .shape_containment import shape_containment

    co = shape_containment(skel, th, rt, s, balls, cameras, fields, tol_px=tol_px)
    E = len(balls)
    J = np.zeros((len(co), 3 * E))
    if len(co):
        d = co.axis_grad * co.unit * balls.vscale[co.ball]  # by the field radii
        np.put_along_axis(J, 3 * co.ball[:, None] + np.arange(3)[None], d, axis=1)
    return J, co


def _with_centres(J, co, free, slot, ax, scale, skel, th, rt, s, balls):
    """``J`` (M, 3E) with the columns of the free centres appended (M, 3E + k·len(free))."""
    k = len(ax)
    Jc = np.zeros((len(co), k * len(free)))
    on = np.flatnonzero(slot[co.ball] >= 0) if len(co) else np.zeros(0, int)
    if len(on):
        Rb, _ = bone_frames(skel, forward(skel, th[None], rt[None], s))
        e = co.ball[on]
        g = np.einsum("mj,mjk->mk", co.grad[on], Rb[0, balls.bone[e]]) * scale[e, None]
        Jc[on[:, None], k * slot[e][:, None] + np.arange(k)[None]] = g[:, ax]
    return np.hstack([J, Jc])
