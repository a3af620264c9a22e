"""Settings of pose tracking from occluding contours (:class:`ContourTrackSettings`).

The options of the contour tracker's iterated EKF update (:mod:`core.contour_track`,
which re-exports this class), of its divergence check and recovery, and of the shape
solve from one frame's silhouettes (:func:`core.contour_shape.fit_shape_to_contours`).
Units per field: image distances in pixels, angles in radians, lengths in metres, rates
per frame.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class ContourTrackSettings:
    """Parameters of contour tracking (units in brackets)."""

    sigma_px: float = 1.0  # a-priori σ of one contour observation [px]
    huber_px: float = 2.0  # Huber threshold on contour residuals [px]
    iterations: int = 4  # relinearisations of the update per frame
    select: bool = True  # per-part camera selection (False: all fused)
    observability: bool = True  # ... ranked by predicted motion (False: visibility only)
    max_dist_px: float = 12.0  # largest contour ↔ rim pairing distance [px]
    min_matches: int = 40  # fewer contour matches: frame not updated
    q_sigma_theta: float = 0.05  # initial σ of the clicked pose [rad]
    q_sigma_root: float = 0.01  # [m]
    rate_sigma_theta: float = 0.05  # initial σ of the rates [rad/frame]
    rate_sigma_root: float = 0.02  # [m/frame]
    accel_theta: float = 0.04  # process noise [rad/frame²]
    accel_root: float = 0.01  # [m/frame²]
    damping: float = 0.9  # rate decay per frame
    containment: bool = True  # the body must project inside every foreground
    sigma_in_px: float = 2.0  # σ of a containment observation [px]
    huber_in_px: float = 6.0  # its Huber threshold [px]
    tol_in_px: float = 2.0  # distance outside the foreground that is free [px]
    diverge_outside: float = 0.15  # diverged: more model points this far outside ...
    diverge_outside_px: float = 8.0  # ... the foreground [px], or
    diverge_unexplained: float = 0.2  # more observed contour points this far from ...
    diverge_unexplained_px: float = 8.0  # ... the model's silhouette [px]
    recover: bool = True  # re-solve a diverged frame from a widened prior
    recover_sigma_theta: float = 0.35  # prior σ of the suspect parts' angles then [rad]
    recover_dist_px: float = 30.0  # contour pairing distance then [px]
    search: bool = True  # limb search before the update (core.contour_search)
    search_sigma_theta: float = 0.15  # prior σ of a re-posed limb's angles [rad]
