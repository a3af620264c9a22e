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
segmentation.  The shape (scales ``s`` and metaball radii) is held fixed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from .camera import Camera
from .contour_obs import contour_observations
from .contours import Contour
from .ekf import EKF
from .metaballs import Metaballs
from .model_render import camera_rays
from .progress import Progress
from .skeleton import Skeleton


@dataclass
class ContourTrackSettings:
    """Parameters of contour tracking (units in brackets)."""

    sigma_px: float = 1.0            # a-priori σ of one contour observation [px]
    huber_px: float = 2.0            # Huber threshold on contour residuals [px]
    iterations: int = 4              # relinearisations of the update per frame
    select: bool = True              # per-part camera selection (False: all fused)
    observability: bool = True       # ... ranked by predicted motion (False: visibility only)
    max_dist_px: float = 12.0        # largest contour ↔ rim pairing distance [px]
    min_matches: int = 40            # fewer contour matches: frame not updated
    q_sigma_theta: float = 0.05      # initial σ of the clicked pose [rad]
    q_sigma_root: float = 0.01       # [m]
    rate_sigma_theta: float = 0.05   # initial σ of the rates [rad/frame]
    rate_sigma_root: float = 0.02    # [m/frame]
    accel_theta: float = 0.04        # process noise [rad/frame²]
    accel_root: float = 0.01         # [m/frame²]
    damping: float = 0.9             # rate decay per frame


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
    """

    theta: np.ndarray
    root: np.ndarray
    q_sigma: np.ndarray
    rms_px: float
    n_matches: int
    updated: bool
    use: np.ndarray


def _limits(skel: Skeleton) -> tuple[np.ndarray, np.ndarray]:
    lo = np.concatenate([skel.dof_lo, np.full(3, -np.inf)])
    hi = np.concatenate([skel.dof_hi, np.full(3, np.inf)])
    return lo, hi


def start_filter(skel: Skeleton, theta0: np.ndarray, root0: np.ndarray,
                 cfg: ContourTrackSettings) -> EKF:
    """An EKF at the clicked pose (n + 3 parameters, zero rates)."""
    n = skel.n_dof
    q0 = np.concatenate([theta0, root0])
    per = lambda a, b: np.concatenate([np.full(n, a), np.full(3, b)])  # noqa: E731
    lo, hi = _limits(skel)
    return EKF.start(q0, per(cfg.q_sigma_theta, cfg.q_sigma_root),
                     per(cfg.rate_sigma_theta, cfg.rate_sigma_root),
                     per(cfg.accel_theta, cfg.accel_root), damping=cfg.damping,
                     lower=lo, upper=hi)


def update_with_contours(ekf: EKF, skel: Skeleton, s: np.ndarray, balls: Metaballs,
                         cameras: list[Camera], contours: list[list[Contour]],
                         cfg: ContourTrackSettings, rays=None) -> FrameTrack:
    """Iterated EKF update of ``ekf`` (in place) with one frame's contours."""
    n = skel.n_dof
    m = n + 3
    x_pred, P_pred = ekf.x.copy(), ekf.P.copy()
    N = x_pred.size
    P_inv = scipy.linalg.cho_solve(scipy.linalg.cho_factor(P_pred + 1e-12 * np.eye(N)),
                                   np.eye(N))
    rate = x_pred[m:m + n]
    x_i = x_pred.copy()
    obs = None
    info = None
    for _ in range(max(1, cfg.iterations)):
        theta, root = x_i[:n], x_i[n:m]
        obs = contour_observations(skel, theta, root, s, balls, cameras, contours,
                                   theta_rate=rate if cfg.select and cfg.observability
                                   else None,
                                   sigma_px=cfg.sigma_px, max_dist_px=cfg.max_dist_px,
                                   select=cfg.select, rays=rays)
        if len(obs) < cfg.min_matches:
            ekf.x, ekf.P = x_pred, P_pred
            return FrameTrack(x_pred[:n].copy(), x_pred[n:m].copy(),
                              np.sqrt(np.diag(P_pred)[:m]), float("nan"), len(obs), False,
                              obs.selection.use)
        J = np.zeros((len(obs), N))
        J[:, :n], J[:, n:m] = obs.J_theta, obs.J_root
        r = obs.residual
        a = np.abs(r)
        w = np.where(a <= cfg.huber_px, 1.0, cfg.huber_px / np.maximum(a, 1e-12))
        w = w / cfg.sigma_px**2
        # linearised about x_i: r(x) ≈ r_i + J (x − x_i); minimise
        # |x − x_pred|²_{P⁻¹} + |r_i + J (x − x_i)|²_W
        JW = J.T * w
        info = P_inv + JW @ J
        rhs = P_inv @ (x_pred - x_i) - JW @ r
        delta = scipy.linalg.cho_solve(scipy.linalg.cho_factor(info), rhs)
        x_i = x_i + delta
        if np.max(np.abs(delta[:m])) < 1e-5:
            break
    ekf.x = x_i
    ekf.P = scipy.linalg.cho_solve(scipy.linalg.cho_factor(info), np.eye(N))
    ekf.P = 0.5 * (ekf.P + ekf.P.T)
    ekf._apply_limits()
    rms = float(np.sqrt(np.mean(obs.residual**2)))
    return FrameTrack(ekf.x[:n].copy(), ekf.x[n:m].copy(), np.sqrt(np.diag(ekf.P)[:m]), rms,
                      len(obs), True, obs.selection.use)


def track_contours(skel: Skeleton, s: np.ndarray, balls: Metaballs, theta0: np.ndarray,
                   root0: np.ndarray, cameras: list[Camera],
                   contours: list[list[list[Contour]]],
                   cfg: ContourTrackSettings | None = None,
                   progress: Progress | None = None) -> list[FrameTrack]:
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
        out.append(update_with_contours(ekf, skel, s, balls, cameras, frame_contours, cfg,
                                        rays=rays))
        if progress is not None:
            progress.update(f + 1, len(contours), f"contour tracking: frame {f + 1}")
    return out


def fit_shape_to_contours(skel: Skeleton, s: np.ndarray, balls: Metaballs, theta: np.ndarray,
                          root: np.ndarray, cameras: list[Camera], contours: list[list[Contour]],
                          cfg: ContourTrackSettings | None = None, radius_prior_m: float = 0.02,
                          iterations: int = 6, rays=None
                          ) -> tuple[Metaballs, np.ndarray, np.ndarray, float]:
    """Metaball radii (and a pose refinement) from one frame's silhouettes.

    Minimises the Huber-weighted contour residuals (σ = ``cfg.sigma_px``) plus priors:
    the pose about ``theta``/``root`` with σ ``cfg.q_sigma_theta``/``cfg.q_sigma_root``
    (e.g. the clicked pose) and every radius about its starting value with
    σ ``radius_prior_m`` — radii along a camera's line of sight are seen by the other
    cameras only, and the prior keeps unobserved ones where they are.

    Returns
    -------
    balls : Metaballs with the fitted radii
    theta : (n,), root : (3,) refined pose
    rms_px : contour residual RMS at the end
    """
    cfg = cfg or ContourTrackSettings()
    n, E = skel.n_dof, len(balls)
    theta0 = np.asarray(theta, float).copy()
    root0 = np.asarray(root, float).copy()
    r0 = balls.radii.copy()
    th, rt, radii = theta0.copy(), root0.copy(), r0.copy()
    w_pose = np.concatenate([np.full(n, cfg.q_sigma_theta), np.full(3, cfg.q_sigma_root)]) ** -2
    w_rad = np.full(3 * E, radius_prior_m**-2)
    rms = float("nan")
    for _ in range(iterations):
        cur = balls.copy(radii=radii)
        obs = contour_observations(skel, th, rt, s, cur, cameras, contours,
                                   sigma_px=cfg.sigma_px, max_dist_px=cfg.max_dist_px,
                                   select=cfg.select, rays=rays)
        if len(obs) < cfg.min_matches:
            break
        M = len(obs)
        J = np.zeros((M, n + 3 + 3 * E))
        J[:, :n], J[:, n:n + 3] = obs.J_theta, obs.J_root
        cols = n + 3 + 3 * obs.ellipsoid[:, None] + np.arange(3)[None]
        np.put_along_axis(J, cols, obs.J_radii, axis=1)
        r = obs.residual
        a = np.abs(r)
        w = np.where(a <= cfg.huber_px, 1.0, cfg.huber_px / np.maximum(a, 1e-12))
        w = w / cfg.sigma_px**2
        prior_w = np.concatenate([w_pose, w_rad])
        x = np.concatenate([th, rt, radii.ravel()])
        x0 = np.concatenate([theta0, root0, r0.ravel()])
        A = (J.T * w) @ J + np.diag(prior_w)
        g = (J.T * w) @ r + prior_w * (x - x0)
        delta = -scipy.linalg.cho_solve(scipy.linalg.cho_factor(A), g)
        th, rt = th + delta[:n], rt + delta[n:n + 3]
        radii = np.maximum(radii + delta[n + 3:].reshape(E, 3), 0.01)
        rms = float(np.sqrt(np.mean(r**2)))
        if np.max(np.abs(delta)) < 1e-5:
            break
    return balls.copy(radii=radii), th, rt, rms


def refine_state_with_contours(state, cameras: list[Camera],
                               contours: list[list[list[Contour]]],
                               cfg: ContourTrackSettings | None = None,
                               sigma_floor_theta: float = 0.02, sigma_hidden: float = 0.3,
                               sigma_root: float = 0.005, progress: Progress | None = None):
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
        ekf.P[n:n + 3, n:n + 3] = np.eye(3) * sigma_root**2
        r = update_with_contours(ekf, skel, out.s, out.metaballs, cameras, contours[f], cfg,
                                 rays=rays)
        if r.updated:
            out.theta[f], out.root_xyz[f] = r.theta, r.root
            rms_px[f] = r.rms_px
            q.cameras[f] = {skel.bone_names[p]: [cameras[c].name for c in np.flatnonzero(
                r.use[p])] for p in range(len(skel.bone_names))}
        if progress is not None:
            progress.update(f + 1, state.n_frames, f"contour refinement: frame {f + 1}")
    out.contour_rms_px = rms_px
    return out
