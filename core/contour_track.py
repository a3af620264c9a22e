"""Pose tracking from occluding contours inside an extended Kalman filter (paper 2).

Kakadiaris & Metaxas track each body part from the occluding contours of the cameras that
see it and observe its motion, with an extended Kalman filter over the pose.  Here:

* state ``x = [q, q_dot]`` with ``q = [θ (n), root_xyz (3)]`` — the skeleton's joint
  angles and root position — and a damped constant-velocity model (:mod:`core.ekf`);
* per frame, after the prediction, an **iterated EKF update** with the contour
  observations of :func:`core.contour_obs.contour_observations` (residual along the
  image normal, σ = ``sigma_px``; Huber-reweighted so that a segmentation error pulls
  no harder than a few pixels), relinearised ``iterations`` times because the rim and
  the correspondences move with the pose.  Solved in information form,
  ``(P⁻¹ + Hᵀ W H) δ = ...``, since there are many more contour points than parameters;
* per-part camera selection from the predicted rates (visibility ≥ 0.2, observability
  ranking), recorded per frame in the quality;
* joint limits as a projection after each update (:meth:`core.ekf.EKF._apply_limits`);
* a frame with too few contour matches is not updated: the prediction is kept and the
  frame is marked diverged, so the filter coasts through occlusions and recovers.

The contours can come from image foreground masks (:mod:`core.background`) or any other
segmentation.  The shape (scales ``s`` and metaball radii) is held fixed; it can be
solved beforehand from one frame's silhouettes (:func:`core.contour_shape.fit_shape_to_contours`).
The settings are :class:`core.contour_track_settings.ContourTrackSettings`; both are
re-exported here.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.linalg

from .camera import Camera
from .contour_obs import containment_observations, contour_observations, silhouette_field
from .contour_shape import fit_shape_to_contours  # noqa: F401  (re-exported)
from .contour_track_settings import ContourTrackSettings
from .contours import Contour
from .ekf import EKF
from .metaballs import Metaballs
from .model_render import camera_rays
from .progress import Progress
from .skeleton import Skeleton


@dataclass
class FrameTrack:
    """Outcome of one frame.

    Attributes
    ----------
    theta : (n,) radians; root : (3,) metres; q_sigma : (n + 3,) posterior σ
    rms_px : contour residual RMS after the update (NaN when not updated)
    n_matches : contour observations used
    updated : False when the frame kept the prediction (too few matches)
    use : (P, C) bool — cameras used per part
    diverged : the model lost the body in this frame (:func:`divergence`): more than
        ``diverge_outside`` of its points project outside the foreground, or more than
        ``diverge_unexplained`` of the observed contour is far from its silhouette
    outside_frac, unexplained_frac : those two fractions (NaN: not measured)
    recovered : the frame was diverged after the usual update and a re-solve from a
        widened prior (:func:`update_with_contours`) was kept
    searched : limbs re-posed by the search before the update (:mod:`core.contour_search`)
    """

    theta: np.ndarray
    root: np.ndarray
    q_sigma: np.ndarray
    rms_px: float
    n_matches: int
    updated: bool
    use: np.ndarray
    diverged: bool = False
    outside_frac: float = float("nan")
    unexplained_frac: float = float("nan")
    recovered: bool = False
    searched: list = field(default_factory=list)


def _limits(skel: Skeleton) -> tuple[np.ndarray, np.ndarray]:
    lo = np.concatenate([skel.dof_lo, np.full(3, -np.inf)])
    hi = np.concatenate([skel.dof_hi, np.full(3, np.inf)])
    return lo, hi


def start_filter(
    skel: Skeleton, theta0: np.ndarray, root0: np.ndarray, cfg: ContourTrackSettings
) -> EKF:
    """An EKF at the clicked pose (n + 3 parameters, zero rates)."""
    n = skel.n_dof
    q0 = np.concatenate([theta0, root0])
    per = lambda a, b: np.concatenate([np.full(n, a), np.full(3, b)])  # noqa: E731
    lo, hi = _limits(skel)
    return EKF.start(
        q0,
        per(cfg.q_sigma_theta, cfg.q_sigma_root),
        per(cfg.rate_sigma_theta, cfg.rate_sigma_root),
        per(cfg.accel_theta, cfg.accel_root),
        damping=cfg.damping,
        lower=lo,
        upper=hi,
    )


def bone_dofs(skel: Skeleton) -> list[np.ndarray]:
    """The DOFs that rotate each bone relative to its parent bone, list (B) of int arrays."""
    out = []
    for b in range(len(skel.bone_names)):
        pb = skel.bone_parent[b]
        stop = skel.bone_dof[pb] if pb >= 0 else -1
        k, dofs = skel.bone_dof[b], []
        while k >= 0 and k != stop:
            dofs.append(k)
            k = skel.dof_parent[k]
        out.append(np.array(dofs[::-1], int))
    return out


def _solve(
    x_pred, P_pred, skel, s, balls, cameras, contours, cfg, rays, fields, max_dist_px, iterations
):
    """Iterated information-form update from the prior (x_pred, P_pred).

    Returns (x, P, obs) — P None and x the prior when too few contour matches.
    """
    n = skel.n_dof
    m = n + 3
    N = x_pred.size
    P_inv = scipy.linalg.cho_solve(scipy.linalg.cho_factor(P_pred + 1e-12 * np.eye(N)), np.eye(N))
    rate = x_pred[m : m + n]
    x_i = x_pred.copy()
    obs = info = None
    for _ in range(max(1, iterations)):
        theta, root = x_i[:n], x_i[n:m]
        obs = contour_observations(
            skel,
            theta,
            root,
            s,
            balls,
            cameras,
            contours,
            theta_rate=rate if cfg.select and cfg.observability else None,
            sigma_px=cfg.sigma_px,
            max_dist_px=max_dist_px,
            select=cfg.select,
            rays=rays,
        )
        if len(obs) < cfg.min_matches:
            return x_pred, None, obs
        J = np.zeros((len(obs), N))
        J[:, :n], J[:, n:m] = obs.J_theta, obs.J_root
        r = obs.residual
        w = _huber(r, cfg.huber_px) / cfg.sigma_px**2
        if fields is not None and cfg.containment:
            co = containment_observations(
                skel, theta, root, s, balls, cameras, fields, tol_px=cfg.tol_in_px
            )
            Jc = np.zeros((len(co), N))
            Jc[:, :n], Jc[:, n:m] = co.J_theta, co.J_root
            J = np.vstack([J, Jc])
            r = np.concatenate([r, co.residual])
            w = np.concatenate([w, _huber(co.residual, cfg.huber_in_px) / cfg.sigma_in_px**2])
        # linearised about x_i: r(x) ≈ r_i + J (x − x_i); minimise
        # |x − x_pred|²_{P⁻¹} + |r_i + J (x − x_i)|²_W
        JW = J.T * w
        info = P_inv + JW @ J
        rhs = P_inv @ (x_pred - x_i) - JW @ r
        delta = scipy.linalg.cho_solve(scipy.linalg.cho_factor(info), rhs)
        x_i = x_i + delta
        if np.max(np.abs(delta[:m])) < 1e-5:
            break
    P = scipy.linalg.cho_solve(scipy.linalg.cho_factor(info), np.eye(N))
    return x_i, 0.5 * (P + P.T), obs


def _huber(r: np.ndarray, k: float) -> np.ndarray:
    a = np.abs(r)
    return np.where(a <= k, 1.0, k / np.maximum(a, 1e-12))


def divergence(
    skel: Skeleton,
    theta: np.ndarray,
    root: np.ndarray,
    s: np.ndarray,
    balls: Metaballs,
    cameras: list[Camera],
    contours: list[list[Contour]],
    fields: list,
    renders: list,
    cfg: ContourTrackSettings,
) -> tuple[float, float, np.ndarray]:
    """How far the model at a pose has lost the observed silhouettes.

    Returns
    -------
    outside_frac : float
        Fraction of the model's inner points (:func:`core.contour_obs.containment_observations`,
        every camera) projecting more than ``cfg.diverge_outside_px`` outside the
        foreground — a part where there is no body.
    unexplained_frac : float
        Fraction of the observed contour points further than ``cfg.diverge_unexplained_px``
        from the model's rendered silhouette (``renders``, :class:`PartRender` per
        camera) — body the model does not explain.
    part_outside : ndarray, shape (B,)
        Per part, the largest fraction of its points outside in any camera.
    """
    import cv2

    co = containment_observations(
        skel, theta, root, s, balls, cameras, fields, tol_px=cfg.diverge_outside_px
    )
    B = len(skel.bone_names)
    part_out = np.zeros(B)
    if len(co):
        for c in range(len(cameras)):
            k = co.camera == c
            cnt = np.bincount(co.part[k], minlength=B)[:B]
            bad = np.bincount(co.part[k], weights=co.outside[k], minlength=B)[:B]
            part_out = np.maximum(part_out, np.where(cnt > 0, bad / np.maximum(cnt, 1), 0.0))
    outside = float(co.outside.mean()) if len(co) else float("nan")
    far = total = 0
    for cons, rnd in zip(contours, renders, strict=True):
        if not cons:
            continue
        uv = np.vstack([c.uv for c in cons])
        d = cv2.distanceTransform((~rnd.mask).astype(np.uint8), cv2.DIST_L2, 5)
        h, w = d.shape
        iu = np.clip(np.round(uv[:, 0]).astype(int), 0, w - 1)
        iv = np.clip(np.round(uv[:, 1]).astype(int), 0, h - 1)
        far += int((d[iv, iu] > cfg.diverge_unexplained_px).sum())
        total += len(uv)
    unexplained = far / total if total else float("nan")
    return outside, unexplained, part_out


def _is_diverged(outside: float, unexplained: float, cfg: ContourTrackSettings) -> bool:
    return bool(outside > cfg.diverge_outside or unexplained > cfg.diverge_unexplained)


def update_with_contours(
    ekf: EKF,
    skel: Skeleton,
    s: np.ndarray,
    balls: Metaballs,
    cameras: list[Camera],
    contours: list[list[Contour]],
    cfg: ContourTrackSettings,
    rays=None,
    fields=None,
) -> FrameTrack:
    """Iterated EKF update of ``ekf`` (in place) with one frame's contours.

    ``fields`` (list (C) of :class:`core.contour_obs.SilhouetteField`, optional) adds the
    silhouette containment term (``cfg.containment``) and lets the frame be checked for
    divergence (:func:`divergence`).  A diverged frame is re-solved once
    (``cfg.recover``) from the prediction with the angles of the suspect parts (those
    with points outside the foreground, or every part when none is) widened to
    ``cfg.recover_sigma_theta`` and their rates zeroed, pairing contours up to
    ``cfg.recover_dist_px``.  The re-solve is kept when it explains the silhouettes
    better.  A frame still diverged after that is marked ``diverged`` and its covariance
    is left widened, so that the next frames can pull the parts back.  Before the
    update, with ``fields`` and ``cfg.search``, :func:`core.contour_search.search_limbs`
    re-poses limbs the prediction left behind (recorded in ``searched``).
    """
    n = skel.n_dof
    m = n + 3
    moved: list = []
    if fields is not None and cfg.search:
        from .contour_search import LIMBS, search_limbs

        found = search_limbs(
            skel, ekf.x[:n], ekf.x[n:m], s, balls, cameras, contours, fields, rays=rays
        )
        for name in found.moved:
            idx = np.array([skel.dof_index(d) for d in LIMBS[name][1]])
            if name == "trunk":
                ekf.x[n:m] = found.root
                ekf.P[n:m, n:m] += np.eye(3) * (2 * cfg.q_sigma_root) ** 2
            ekf.x[idx] = found.theta[idx]
            ekf.x[m + idx] = 0.0
            ekf.P[idx, :] = 0.0
            ekf.P[:, idx] = 0.0
            ekf.P[m + idx, :] = 0.0
            ekf.P[:, m + idx] = 0.0
            ekf.P[idx, idx] = cfg.search_sigma_theta**2
            ekf.P[m + idx, m + idx] = cfg.rate_sigma_theta**2
        moved = found.moved
    x_pred, P_pred = ekf.x.copy(), ekf.P.copy()
    x, P, obs = _solve(
        x_pred,
        P_pred,
        skel,
        s,
        balls,
        cameras,
        contours,
        cfg,
        rays,
        fields,
        cfg.max_dist_px,
        cfg.iterations,
    )
    if P is None:
        ekf.x, ekf.P = x_pred, P_pred
        return FrameTrack(
            x_pred[:n].copy(),
            x_pred[n:m].copy(),
            np.sqrt(np.diag(P_pred)[:m]),
            float("nan"),
            len(obs),
            False,
            obs.selection.use,
            diverged=True,
        )
    ekf.x, ekf.P = x, P
    ekf._apply_limits()
    out_f = unexp = float("nan")
    diverged = recovered = False
    if fields is not None:
        out_f, unexp, part_out = divergence(
            skel, ekf.x[:n], ekf.x[n:m], s, balls, cameras, contours, fields, obs.renders, cfg
        )
        diverged = _is_diverged(out_f, unexp, cfg)
        if diverged and cfg.recover:
            suspects = np.flatnonzero(part_out > 0.3)
            dofs = bone_dofs(skel)
            idx = np.concatenate([dofs[b] for b in suspects]) if len(suspects) else np.arange(n)
            P2 = P_pred.copy()
            x2 = x_pred.copy()
            P2[idx, idx] += cfg.recover_sigma_theta**2
            x2[m + idx] = 0.0
            P2[m + idx, m + idx] += cfg.rate_sigma_theta**2
            xr, Pr, obs_r = _solve(
                x2,
                P2,
                skel,
                s,
                balls,
                cameras,
                contours,
                cfg,
                rays,
                fields,
                cfg.recover_dist_px,
                2 * cfg.iterations,
            )
            if Pr is not None:
                # tighten the pairing again from the recovered pose
                xr, Pr2, obs_r2 = _solve(
                    xr,
                    Pr,
                    skel,
                    s,
                    balls,
                    cameras,
                    contours,
                    cfg,
                    rays,
                    fields,
                    cfg.max_dist_px,
                    cfg.iterations,
                )
                if Pr2 is not None:
                    Pr, obs_r = Pr2, obs_r2
                lo, hi = _limits(skel)
                xr[:m] = np.clip(xr[:m], lo, hi)
                o2, u2, _ = divergence(
                    skel, xr[:n], xr[n:m], s, balls, cameras, contours, fields, obs_r.renders, cfg
                )
                if o2 + u2 < out_f + unexp:
                    ekf.x, ekf.P, obs = xr, Pr, obs_r
                    out_f, unexp = o2, u2
                    recovered = True
                    diverged = _is_diverged(out_f, unexp, cfg)
        if diverged:
            ekf.P[:m, :m] += np.diag(
                np.concatenate([np.full(n, cfg.q_sigma_theta), np.full(3, cfg.q_sigma_root)]) ** 2
            )
    rms = float(np.sqrt(np.mean(obs.residual**2)))
    return FrameTrack(
        ekf.x[:n].copy(),
        ekf.x[n:m].copy(),
        np.sqrt(np.diag(ekf.P)[:m]),
        rms,
        len(obs),
        True,
        obs.selection.use,
        diverged=diverged,
        outside_frac=out_f,
        unexplained_frac=unexp,
        recovered=recovered,
        searched=moved,
    )


def frame_fields(cameras: list[Camera], contours: list[list[Contour]]) -> list:
    """:func:`core.contour_obs.silhouette_field` of every camera of one frame, list (C)."""
    return [silhouette_field(cons, cam.size) for cons, cam in zip(contours, cameras, strict=True)]


def track_contours(
    skel: Skeleton,
    s: np.ndarray,
    balls: Metaballs,
    theta0: np.ndarray,
    root0: np.ndarray,
    cameras: list[Camera],
    contours: list[list[list[Contour]]],
    cfg: ContourTrackSettings | None = None,
    progress: Progress | None = None,
) -> list[FrameTrack]:
    """Track a pose through F frames of contours.

    Parameters
    ----------
    skel, s, balls
        The subject's body (shape fixed).
    theta0 : (n,), root0 : (3,)
        Pose of the first frame (e.g. from the key-joint clicks).
    cameras : list of Camera (C)
    contours : list (F) of list (C) of list of Contour
        Observed occluding contours per frame and camera.

    Returns
    -------
    list of FrameTrack, one per frame
    """
    cfg = cfg or ContourTrackSettings()
    rays = [camera_rays(c) for c in cameras]
    ekf = start_filter(skel, np.asarray(theta0, float), np.asarray(root0, float), cfg)
    out = []
    for f, frame_contours in enumerate(contours):
        if f:
            ekf.predict()
        out.append(
            update_with_contours(
                ekf,
                skel,
                s,
                balls,
                cameras,
                frame_contours,
                cfg,
                rays=rays,
                fields=frame_fields(cameras, frame_contours),
            )
        )
        if progress is not None:
            progress.update(f + 1, len(contours), f"contour tracking: frame {f + 1}")
    return out


def refine_state_with_contours(
    state,
    cameras: list[Camera],
    contours: list[list[list[Contour]]],
    cfg: ContourTrackSettings | None = None,
    sigma_floor_theta: float = 0.02,
    sigma_hidden: float = 0.3,
    sigma_root: float = 0.005,
    progress: Progress | None = None,
):
    """Fuse contour observations into a fitted state, frame by frame.

    Each frame's pose from the point fit is the prior of an iterated information-form
    update with that frame's contours (:func:`update_with_contours`): DOFs the points
    determined (small σ in ``state.quality.theta_sigma``, floored at
    ``sigma_floor_theta``) barely move; DOFs of parts the points did not see (σ NaN or
    large — e.g. a part held at its previous angles) take their pose from the
    silhouettes, with σ ``sigma_hidden``.  Frames marked diverged are left alone.

    Returns
    -------
    FitState
        A copy with refined ``theta``/``root_xyz``; the quality records the contour RMS
        (pixels, in ``contour_rms_px``) and the cameras each part used.
    """
    import copy

    # corrections of hidden parts can be large (0.1–0.2 rad): relinearise more often
    cfg = cfg or ContourTrackSettings(iterations=10)
    skel = state.skeleton
    n = skel.n_dof
    out = copy.deepcopy(state)
    rays = [camera_rays(c) for c in cameras]
    q = out.quality
    rms_px = np.full(state.n_frames, np.nan)
    for f in range(min(state.n_frames, len(contours))):
        if q.diverged[f]:
            continue
        sig = np.asarray(q.theta_sigma[f], float).copy()
        sig = np.where(np.isfinite(sig), np.maximum(sig, sigma_floor_theta), sigma_hidden)
        ekf = start_filter(skel, out.theta[f], out.root_xyz[f], cfg)
        ekf.P[:n, :n] = np.diag(sig**2)
        ekf.P[n : n + 3, n : n + 3] = np.eye(3) * sigma_root**2
        r = update_with_contours(
            ekf, skel, out.s, out.metaballs, cameras, contours[f], cfg, rays=rays
        )
        if r.updated:
            out.theta[f], out.root_xyz[f] = r.theta, r.root
            rms_px[f] = r.rms_px
            q.cameras[f] = {
                skel.bone_names[p]: [cameras[c].name for c in np.flatnonzero(r.use[p])]
                for p in range(len(skel.bone_names))
            }
        if progress is not None:
            progress.update(f + 1, state.n_frames, f"contour refinement: frame {f + 1}")
    out.contour_rms_px = rms_px
    return out
