"""Metaball radii from several fitted frames' silhouettes, each frame's pose free.

One frame's three outlines leave much of a body's shape free: a radius along one
camera's line of sight is seen by the other two only, and a posture that folds a limb
in front of the trunk hides its outline in that view.  A fitted take shows the same
body in many postures.  :func:`fit_shape_to_frames` solves the metaball radii shared by
K such frames, each frame's pose refined about its fitted pose, to the occluding
contours of every frame in every camera (:func:`core.contour_obs.contour_observations`,
Huber-weighted, σ in pixels): one Gauss–Newton solve of the observations of
:func:`core.contour_shape.fit_shape_to_contours`, over K poses and one shape.  The
metaball centres are held (free, on the studio's jumps they trade against the poses:
docs/design.md, stop 66).

Frames: world Z up, metres; radii metres; angles radians; image pixels as in
:mod:`core.camera`.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg

from .camera import Camera
from .contour_obs import contour_observations
from .contour_shape import contour_rows
from .contour_track_settings import ContourTrackSettings
from .contours import Contour
from .metaballs import Metaballs
from .skeleton import Skeleton


def fit_shape_to_frames(
    skel: Skeleton,
    s: np.ndarray,
    balls: Metaballs,
    thetas: np.ndarray,
    roots: np.ndarray,
    cameras: list[Camera],
    contours: list[list[list[Contour]]],
    cfg: ContourTrackSettings | None = None,
    radius_prior_m: float | np.ndarray = 0.02,
    pose_sigma_rad: float = 0.1,
    root_sigma_m: float = 0.02,
    iterations: int = 6,
    rays=None,
) -> tuple[Metaballs, np.ndarray, np.ndarray, float]:
    """Metaball radii shared by K frames, and the K poses, from their silhouettes.

    Minimises the Huber-weighted contour residuals (σ = ``cfg.sigma_px``) of every frame
    plus priors: each frame's joint angles about ``thetas[k]`` with σ ``pose_sigma_rad``
    and its root about ``roots[k]`` with σ ``root_sigma_m`` (the fitted poses: free
    enough for the outline of a new shape to move them), and every radius about its
    starting value with σ ``radius_prior_m`` (metres: one σ, (E,) per metaball or (E, 3)
    per radius), which keeps the radii no frame observes where they are.

    Parameters
    ----------
    thetas : (K, n) joint angles, rad; roots : (K, 3) root positions, m
    contours : per frame, per camera, the foreground's occluding contours
    rays : per camera precomputed pixel rays (:func:`core.contour_obs.contour_observations`)

    Returns
    -------
    balls : Metaballs with the fitted radii (centres as given)
    thetas : (K, n), roots : (K, 3) refined poses
    rms_px : the contour residual RMS over every frame at the last step's start (NaN
        when no frame had ``cfg.min_matches`` pairs: nothing was solved)
    """
    cfg = cfg or ContourTrackSettings()
    th = np.array(thetas, float)
    rt = np.array(roots, float)
    K, n = th.shape
    E, p = len(balls), n + 3
    th0, rt0, r0 = th.copy(), rt.copy(), balls.radii.copy()
    radii = r0.copy()
    R = slice(K * p, K * p + 3 * E)  # the radii's columns, after the K poses'
    sig_pose = np.tile(np.r_[np.full(n, pose_sigma_rad), np.full(3, root_sigma_m)], K)
    sig_r = np.asarray(radius_prior_m, float)
    sig_r = np.broadcast_to(sig_r[:, None] if sig_r.ndim == 1 else sig_r, (E, 3)).ravel()
    prior_w = np.concatenate([sig_pose, sig_r]) ** -2
    rms = float("nan")
    for _ in range(iterations):
        cur = balls.copy(radii=radii)
        A = np.zeros((K * p + 3 * E,) * 2)
        g = np.zeros(K * p + 3 * E)
        sq, m = 0.0, 0
        for k in range(K):
            obs = contour_observations(
                skel,
                th[k],
                rt[k],
                s,
                cur,
                cameras,
                contours[k],
                sigma_px=cfg.sigma_px,
                max_dist_px=cfg.max_dist_px,
                select=cfg.select,
                rays=rays,
            )
            if len(obs) < cfg.min_matches:
                continue  # a frame without enough pairs keeps its pose
            Jp, Jr, r, w = contour_rows(obs, E, cfg)
            P = slice(k * p, (k + 1) * p)
            A[P, P] += (Jp.T * w) @ Jp
            A[P, R] += (Jp.T * w) @ Jr
            A[R, R] += (Jr.T * w) @ Jr
            g[P] += (Jp.T * w) @ r
            g[R] += (Jr.T * w) @ r
            sq, m = sq + float(r @ r), m + len(r)
        if m == 0:
            break
        A[R, : R.start] = A[: R.start, R].T
        x = np.concatenate([np.hstack([th, rt]).ravel(), radii.ravel()])
        x0 = np.concatenate([np.hstack([th0, rt0]).ravel(), r0.ravel()])
        A[np.diag_indices_from(A)] += prior_w
        g += prior_w * (x - x0)
        delta = -scipy.linalg.cho_solve(scipy.linalg.cho_factor(A), g)
        poses = delta[: R.start].reshape(K, p)
        th, rt = th + poses[:, :n], rt + poses[:, n:]
        radii = np.maximum(radii + delta[R].reshape(E, 3), 0.01)
        rms = float(np.sqrt(sq / m))
        if np.max(np.abs(delta)) < 1e-5:
            break
    return balls.copy(radii=radii), th, rt, rms
