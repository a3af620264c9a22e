"""Texture and contours in one extended Kalman filter (paper 2; issue 7, item 5).

The contour tracker (:mod:`core.contour_track`) runs an EKF over ``q = [θ, root]``.
Here every frame's pose fitted to the LSM surface points (:func:`core.fit.fit_sequence`,
its σ from the normal matrix) enters that same filter as a *direct measurement* of
``q`` before the iterated contour update:

    z = q_points,   h(q) = q,   H = I,   V = diag(max(σ_points, σ_floor)²),

so the texture pulls the parts it saw and the silhouettes do the rest.  σ from the
normal matrix ignores model error and wrong segmentations, so it is floored
(``sigma_floor_theta``, ``sigma_floor_root``).  A component whose innovation exceeds
``gate`` standard deviations of ``σ_points² + P`` is left out for that frame (a point
fit that slid off, e.g. along a poorly observed depth direction), and so are
components without a finite value or σ, and whole frames the point fit marked
diverged.

Frames: world Z up, metres; angles in radians.
"""

from __future__ import annotations

import numpy as np

from .camera import Camera
from .contour_track import (
    ContourTrackSettings,
    FrameTrack,
    frame_fields,
    start_filter,
    update_with_contours,
)
from .contours import Contour
from .metaballs import Metaballs
from .model_render import camera_rays
from .progress import Progress
from .skeleton import Skeleton


def track_fused(
    skel: Skeleton,
    s: np.ndarray,
    balls: Metaballs,
    theta0: np.ndarray,
    root0: np.ndarray,
    cameras: list[Camera],
    contours: list[list[list[Contour]]],
    q_points: np.ndarray,
    q_sigma: np.ndarray,
    cfg: ContourTrackSettings | None = None,
    sigma_floor_theta: float = 0.1,
    sigma_floor_root: float = 0.03,
    gate: float = 3.0,
    progress: Progress | None = None,
    silhouettes: bool = False,
) -> tuple[list[FrameTrack], np.ndarray]:
    """Track a pose through F frames with point-fit poses and contours.

    Parameters
    ----------
    skel, s, balls
        The subject's body (shape fixed).
    theta0 : ndarray, shape (n,); root0 : ndarray, shape (3,)
        Pose of the first frame.
    cameras : list of Camera (C)
    contours : list (F) of list (C) of list of Contour
        Observed occluding contours per frame and camera.
    q_points : ndarray, shape (F, n + 3)
        Pose fitted to each frame's 3-D points, ``[θ, root]`` (a row of NaN: no fit).
    q_sigma : ndarray, shape (F, n + 3)
        Its standard deviations (NaN: not determined by the points).
    cfg : ContourTrackSettings
    silhouettes : bool
        Also use the silhouette regions (:func:`core.contour_track.frame_fields`): the
        containment term, the limb search and the per-frame divergence flag of
        :func:`core.contour_track.update_with_contours`, as
        :func:`core.contour_track.track_contours` does.  Off by default (contours only,
        the behaviour before these existed).

    Returns
    -------
    tracks : list of FrameTrack, one per frame
    n_used : ndarray, shape (F,), int
        Components of ``q_points`` used as measurements in each frame.
    """
    cfg = cfg or ContourTrackSettings()
    n = skel.n_dof
    m = n + 3
    q_points = np.asarray(q_points, float)
    q_sigma = np.asarray(q_sigma, float)
    if q_points.shape != (len(contours), m) or q_sigma.shape != q_points.shape:
        raise ValueError(
            f"q_points {q_points.shape} and q_sigma {q_sigma.shape} must both be "
            f"({len(contours)}, {m})"
        )
    floor = np.concatenate([np.full(n, sigma_floor_theta), np.full(3, sigma_floor_root)])
    rays = [camera_rays(c) for c in cameras]
    ekf = start_filter(skel, np.asarray(theta0, float), np.asarray(root0, float), cfg)
    out, n_used = [], np.zeros(len(contours), int)
    for f, frame_contours in enumerate(contours):
        if f:
            ekf.predict()
        sig = np.maximum(q_sigma[f], floor)
        ok = np.isfinite(q_points[f]) & np.isfinite(sig)
        if ok.any():
            innov = q_points[f] - ekf.q
            spread = np.sqrt(sig**2 + np.diag(ekf.P)[:m])
            ok &= np.abs(np.where(ok, innov, 0.0)) <= gate * spread
        k = np.flatnonzero(ok)
        if len(k):
            H = np.eye(m)[k]
            ekf.update(q_points[f, k], lambda q, k=k: q[k], H, sig[k] ** 2)
            n_used[f] = len(k)
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
                fields=frame_fields(cameras, frame_contours) if silhouettes else None,
            )
        )
        if progress is not None:
            progress.update(f + 1, len(contours), f"texture + contour tracking: frame {f + 1}")
    return out, n_used
