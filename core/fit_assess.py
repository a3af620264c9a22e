"""Judging one fitted frame of the sequence fit: accepted, or diverged and why.

:func:`assess_frame` scores a frame's pose solve without side effects.  A frame with
texture points is judged by them: the signed distance of every assigned point to its
part's surface (:func:`surface_residuals`; inliers within ``inlier_m``), the RMS of the
inliers, their share, and the share of all the frame's points far from the whole body
(:func:`core.fit_search.explain_distance`).  Its *explain cost* — the truncated squared
distances of all points plus, with free space, the body found in the points' lines of
sight — is what the sequence fit compares alternative fits of a frame by.  A frame
with too few points and contours is judged by the contours alone: enough contour
pairs, their RMS in pixels, and the body's projection overlapping the foreground.
"""

from __future__ import annotations

import numpy as np

from .attractor import attractor, gather, member_table
from .fit_search import explain_cost, explain_distance
from .fit_types import SequenceSettings
from .metaballs import Metaballs, world_frames
from .silhouette_search import silhouette_iou
from .skeleton import Skeleton, forward


def surface_residuals(
    skel: Skeleton,
    balls: Metaballs,
    theta,
    root,
    s,
    radii,
    xyz: np.ndarray,
    part: np.ndarray,
    members: str = "part",
) -> np.ndarray:
    """Signed distance (N,) metres of each point to its part's surface (positive inside;
    membership as in :func:`core.attractor.member_table`)."""
    pose = forward(skel, np.asarray(theta)[None], np.asarray(root)[None], s)
    Rw, cw = world_frames(skel, pose, balls, s)
    idx, ok = gather(*member_table(skel, balls, members), part)
    return attractor(xyz, idx, ok, Rw[0], cw[0], radii).dist


def assess_frame(
    res: tuple,
    skel: Skeleton,
    balls: Metaballs,
    radii: np.ndarray,
    s: np.ndarray,
    xyz: np.ndarray,
    cf,
    probes,
    cfg: SequenceSettings,
) -> tuple[bool, str, dict | None]:
    """Quality of one fitted frame: ``(ok, reasons, stats)``.

    Parameters
    ----------
    res : ``(q, FitResult, solved, part or message, labels)`` of the frame's pose solve;
        q (n + 3,) the angles (radians) and the root (metres), part (N,) the points'
        bone indices (−1 unassigned)
    balls : the body's metaballs; radii : (M, 3) their current radii, metres
    s : (G,) bone scales
    xyz : (N, 3) the frame's points, world metres
    cf : the frame's :class:`core.fit_contours.ContourFrame`, or None
    probes : callable returning the frame's free-space probes
        (:class:`core.free_space.FrameProbes` of the frame) or None; called only when
        the frame is judged by its points
    cfg : the sequence fit's settings (thresholds)

    Returns
    -------
    ok : bool, the frame is accepted
    reasons : why not, e.g. ``"surface RMS 31.2 mm"`` ("" when ok)
    stats : dict or None (a failed solve) — ``n`` points used, ``inl`` inlier share,
        ``rmse`` metres, ``sig`` (n,) angle σ, ``conv``, ``unexplained`` share,
        ``cost`` (explain cost, m²; with contours alone the contour cost), ``contour``
        (the contour statistics or None)
    """
    if not res[2]:
        return False, str(res[3]), None
    q, r, _, part, _ = res
    n = skel.n_dof
    use = part >= 0
    cst = None if cf is None else cf.stats(skel, balls.copy(radii=radii), q[:n], q[n:], s)
    if use.sum() < cfg.min_points and cst is not None:  # judged by its contours alone
        stats = {
            "n": 0,
            "inl": cst["inl"],
            "rmse": np.nan,
            "sig": r.theta_sigma,
            "conv": bool(r.converged),
            "unexplained": 1.0 - cst["inl"],
            "cost": cst["cost"],
            "contour": cst,
        }
        bad = []
        if not np.all(np.isfinite(q)):
            bad.append("non-finite solution")
        if cst["n"] < cf.cfg.min_matches:
            bad.append(f"only {cst['n']} contour pairs")
        elif cst["rms_px"] > cf.cfg.max_rms_px:
            bad.append(f"contour RMS {cst['rms_px']:.1f} px")
        iou = silhouette_iou(skel, balls.copy(radii=radii), q[:n], q[n:], s, cf.cameras, cf.grids())
        if np.isfinite(iou).any() and np.nanmean(iou) < cfg.min_silhouette_iou:
            bad.append(f"silhouette IoU {np.nanmean(iou):.2f}")
        return not bad, ", ".join(bad), stats
    d = surface_residuals(skel, balls, q[:n], q[n:], s, radii, xyz[use], part[use], cfg.fit.members)
    inlier = np.abs(d) < cfg.inlier_m
    share = float(inlier.mean()) if len(d) else 0.0
    rm = float(np.sqrt(np.mean(d[inlier] ** 2))) if inlier.any() else np.inf
    d_all = explain_distance(xyz, skel, balls, s, radii, q[:n], q[n:])
    cost = float(np.sum(np.minimum(np.abs(d_all), cfg.search_tau) ** 2))
    pr = probes()
    if pr is not None:  # body in the points' lines of sight, in the same units (m²)
        cost += float(
            explain_cost(
                np.zeros((0, 3)),
                skel,
                balls,
                s,
                radii,
                q[None, :n],
                q[None, n:],
                cfg.search_tau,
                sigma=1.0,
                probes=pr,
            )[0]
        )
    stats = {
        "n": int(use.sum()),
        "inl": share,
        "rmse": rm,
        "sig": r.theta_sigma,
        "conv": bool(r.converged),
        "unexplained": float(np.mean(np.abs(d_all) > cfg.inlier_m)),
        "cost": cost,
        "contour": cst,
    }
    bad = []
    if not np.all(np.isfinite(q)):
        bad.append("non-finite solution")
    if rm > cfg.max_rmse_m:
        bad.append(f"surface RMS {rm * 1000:.1f} mm")
    if share < cfg.min_inliers:
        bad.append(f"only {100 * share:.0f} % inlier points")
    if stats["unexplained"] > cfg.max_unexplained:
        bad.append(f"{100 * stats['unexplained']:.0f} % of the points far from the body")
    return not bad, ", ".join(bad), stats
