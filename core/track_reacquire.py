"""Re-acquisition of lost points: neighbour-motion prediction and key-template matching.

A point lost by the tracker (occluded, turned away, a failed match) is kept *dormant*
with its key templates (:class:`core.track_anchor.KeyTemplates`).  In every frame its
position is predicted from the motion of its neighbours: the rigid motion (least
squares, Kabsch / Horn) of the nearest points measured both in the last frame and in
the current one, among those whose rate in the last frame was close to the point's own
— the points that moved with it, on the same body part — carries the point's last
position (measured, or predicted) one frame on (:func:`neighbour_motion`,
:func:`dormant_step`).  Where that prediction projects into two or more cameras, the
key templates are searched there (NCC, then LSM from the key with its last affine) and
the point is re-acquired when the forward intersection of the matches is
consistent and lies close to the prediction (:func:`reacquire`).  The trajectory
resumes with the same index; the frames in between are bridged from the predictions
(:func:`core.track_trajectories.bridge_gaps`).

Shapes: Q queried points, M neighbour candidates, C cameras; world metres, pixels.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .camera import Camera
from .intersect import triangulate
from .lsm import ImageStack, match
from .nan_median import nanmedian
from .ncc import search
from .track_anchor import KeyTemplates
from .track_filter import COV_FLOOR, PointFilter, neighbour_rates
from .track_occlusion import occluded
from .track_smooth import depth_deviation


def rigid_fit(src: np.ndarray, dst: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weighted least-squares rigid motions ``dst ≈ R @ src + t``, batched.

    Parameters
    ----------
    src, dst : ndarray, shape (Q, K, 3)
        Corresponding points (world metres); rows with weight 0 are ignored.
    w : ndarray, shape (Q, K)
        Weights (0 or positive); each batch needs three or more non-collinear points.

    Returns
    -------
    R : ndarray, shape (Q, 3, 3)
        Rotations (det +1).
    t : ndarray, shape (Q, 3)
        Translations, metres.
    """
    ws = np.maximum(w.sum(axis=1, keepdims=True), 1e-12)
    src = np.where(w[..., None] > 0, src, 0.0)
    dst = np.where(w[..., None] > 0, dst, 0.0)
    cs = np.einsum("qk,qkd->qd", w, src) / ws
    cd = np.einsum("qk,qkd->qd", w, dst) / ws
    H = np.einsum("qk,qki,qkj->qij", w, src - cs[:, None], dst - cd[:, None])
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(Vt.transpose(0, 2, 1) @ U.transpose(0, 2, 1)))
    D = np.broadcast_to(np.eye(3), H.shape).copy()
    D[:, 2, 2] = np.where(d == 0, 1.0, d)
    R = Vt.transpose(0, 2, 1) @ D @ U.transpose(0, 2, 1)
    return R, cd - np.einsum("qij,qj->qi", R, cs)


def neighbour_motion(
    xyz_then: np.ndarray,
    xyz_now: np.ndarray,
    query: np.ndarray,
    *,
    rate_then: np.ndarray | None = None,
    query_rate: np.ndarray | None = None,
    max_rate_dev: float = 0.015,
    k: int = 10,
    radius_m: float = 0.06,
    min_neighbours: int = 5,
    inlier_m: float = 0.003,
    min_spread: float = 0.3,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Predict points from the rigid motion of their nearest neighbours.

    Parameters
    ----------
    xyz_then, xyz_now : ndarray, shape (M, 3)
        Neighbour candidates at the query's frame and now, metres (rows with NaN are
        not used).
    query : ndarray, shape (Q, 3)
        Points at the earlier frame, metres.
    rate_then : ndarray, shape (M, 3), optional
        The candidates' rates at the earlier frame, metres per frame.
    query_rate : ndarray, shape (Q, 3), optional
        The queries' rates there: only neighbours whose rate differs by less than
        ``max_rate_dev`` (m/frame) are used — points that moved with the query, on the
        same body part (legs and arms pass close to each other).
    k, radius_m, min_neighbours
        Up to ``k`` neighbours within ``radius_m`` are fitted; fewer than
        ``min_neighbours`` give no prediction.
    inlier_m : float
        Neighbours farther than ``max(3 × median, inlier_m)`` metres from the rigid fit
        (wrong matches, another body part) are dropped and the motion fitted again.
    min_spread : float
        Where the neighbours' second principal standard deviation is below this times
        the distance from their centroid to the query (nearly collinear neighbours),
        only their mean translation is applied.

    Returns
    -------
    xyz : ndarray, shape (Q, 3)
        Predicted positions now, metres, NaN where not ``ok``.
    rms : ndarray, shape (Q,)
        RMS residual of the kept neighbours' rigid fit, metres (how rigid the patch
        moved).
    ok : ndarray, shape (Q,), bool
    """
    q = len(query)
    xyz = np.full((q, 3), np.nan)
    rms = np.full(q, np.nan)
    ok = np.zeros(q, bool)
    good = np.all(np.isfinite(xyz_then), axis=1) & np.all(np.isfinite(xyz_now), axis=1)
    use_rate = rate_then is not None and query_rate is not None
    if use_rate:
        good &= np.all(np.isfinite(rate_then), axis=1)
    if good.sum() < min_neighbours or q == 0:
        return xyz, rms, ok
    a, b = xyz_then[good], xyz_now[good]
    kk = min(3 * k if use_rate else k, len(a))
    qf = np.all(np.isfinite(query), axis=1)
    d, idx = cKDTree(a).query(
        np.where(qf[:, None], query, 1e9), k=kk, distance_upper_bound=radius_m
    )
    d, idx = d.reshape(q, kk), idx.reshape(q, kk)
    w = np.isfinite(d)
    idx = np.minimum(idx, len(a) - 1)
    if use_rate:
        dev = np.linalg.norm(rate_then[good][idx] - query_rate[:, None], axis=2)
        w &= ~(dev > max_rate_dev)  # a NaN query rate keeps them all
        # the k nearest of the neighbours that moved with the query
        order = np.argsort(~w, axis=1, kind="stable")[:, :k]
        idx, w = np.take_along_axis(idx, order, 1), np.take_along_axis(w, order, 1)
    w = w.astype(float)
    ok = w.sum(axis=1) >= min_neighbours
    if not ok.any():
        return xyz, rms, ok
    src, dst, w = a[idx[ok]], b[idx[ok]], w[ok]
    # Start from the neighbours whose displacement is near the median displacement
    # (a rigid fit through gross outliers can be anything), then fit, drop neighbours
    # far off the fit, and fit again.
    disp = np.where(w[..., None] > 0, dst - src, np.nan)
    dev = np.linalg.norm(disp - nanmedian(disp, axis=1)[:, None], axis=2)
    w = w * (
        np.nan_to_num(dev, nan=np.inf)
        <= np.maximum(3.0 * nanmedian(dev, axis=1), 3 * inlier_m)[:, None]
    )
    for _ in range(2):
        R, t = rigid_fit(src, dst, w)
        res = np.linalg.norm(np.einsum("qij,qkj->qki", R, src) + t[:, None] - dst, axis=2)
        med = nanmedian(np.where(w > 0, res, np.nan), axis=1)
        w = w * (res <= np.maximum(3.0 * med, inlier_m)[:, None])
    R, t = rigid_fit(src, dst, w)
    res = np.einsum("qij,qkj->qki", R, src) + t[:, None] - dst
    good = w.sum(axis=1) >= min_neighbours
    # Nearly collinear neighbours (an occlusion edge) leave the rotation about their
    # line undetermined: where their second principal spread is small against the
    # lever arm to the query, only their mean translation is applied.
    ws = np.maximum(w.sum(axis=1), 1e-12)
    cs = np.einsum("qk,qkd->qd", w, src) / ws[:, None]
    cd = np.einsum("qk,qkd->qd", w, dst) / ws[:, None]
    sc = np.einsum("qk,qki,qkj->qij", w, src - cs[:, None], src - cs[:, None]) / ws[:, None, None]
    spread = np.sqrt(np.maximum(np.linalg.eigvalsh(sc)[:, 1], 0.0))
    lever = np.linalg.norm(query[ok] - cs, axis=1)
    rigid = spread >= min_spread * lever
    moved = np.where(rigid[:, None], np.einsum("qij,qj->qi", R, query[ok]) + t, query[ok] + cd - cs)
    xyz[ok] = np.where(good[:, None], moved, np.nan)
    rms[ok] = np.sqrt(np.sum(w * np.sum(res**2, axis=2), axis=1) / np.maximum(w.sum(axis=1), 1))
    ok[ok] = good
    return xyz, rms, ok


@dataclass
class Reacquired:
    """Outcome of :func:`reacquire` for Q dormant points.

    Attributes
    ----------
    ok : ndarray, shape (Q,), bool
        Re-acquired.
    uv : ndarray, shape (Q, C, 2)
        Matches in the new frame, pixels (NaN where a camera did not match).
    affine : ndarray, shape (Q, C, 2, 2)
        Affines from the key patches to the new frame.
    xyz : ndarray, shape (Q, 3)
        Forward intersection, metres.
    cov : ndarray, shape (Q, 3, 3)
        Its covariance, m².
    """

    ok: np.ndarray
    uv: np.ndarray
    affine: np.ndarray
    xyz: np.ndarray
    cov: np.ndarray


def reacquire(
    keys: KeyTemplates,
    stacks: dict,
    search_stack: ImageStack,
    valid: np.ndarray,
    cameras: list[Camera],
    points: np.ndarray,
    xyz_pred: np.ndarray,
    *,
    half: int = 6,
    radius: int = 4,
    min_score: float = 0.7,
    weight_sigma: float | None = 4.0,
    max_sigma_px: float = 0.2,
    max_rms_px: float = 1.0,
    max_dist_m: float = 0.01,
    min_views: int = 2,
    skip: np.ndarray | None = None,
    stats: dict | None = None,
) -> Reacquired:
    """Search dormant points at their predicted positions with their key templates.

    Parameters
    ----------
    keys : KeyTemplates
    stacks : dict int -> ImageStack
        Images of the key frames in use, camera order.
    search_stack : ImageStack
        Images of the new frame, camera order.
    valid : ndarray, shape (C,), bool
        Cameras with an image in the new frame.
    points : ndarray, shape (Q,), int
        Rows of the dormant points in ``keys``.
    xyz_pred : ndarray, shape (Q, 3)
        Predicted positions, metres.
    radius : int
        NCC search half width around the projected prediction, pixels.
    max_dist_m : float
        Largest distance between the re-acquired point and its prediction, metres.
    min_views : int
        Cameras in which the point must be matched (two or more).
    skip : ndarray, shape (Q, C), bool, optional
        Cameras not searched for a point (e.g. where it is predicted occluded).
    stats : dict, optional
        Receives counts: (point, camera) pairs ``searched``, ``ncc_ok``, ``lsm_ok``,
        ``skipped`` (by ``skip``); points with two or more views ``two_views``, within
        the reprojection limit ``rms_ok``, near the prediction ``near``.
    """
    q, c = len(points), len(cameras)
    uv = np.full((q, c, 2), np.nan)
    aff = np.full((q, c, 2, 2), np.nan)
    proj = np.stack([cam.project(xyz_pred) for cam in cameras], axis=1)  # (Q, C, 2)
    kf = keys.f[points]
    w, h = search_stack.shape[2], search_stack.shape[1]
    m = half + radius + 2
    inside = (
        (proj[..., 0] >= m)
        & (proj[..., 0] <= w - 1 - m)
        & (proj[..., 1] >= m)
        & (proj[..., 1] <= h - 1 - m)
    )
    search_pc = (kf >= 0) & inside & valid[None] & np.all(np.isfinite(proj), axis=2)
    if skip is not None:
        if stats is not None:
            stats["skipped"] = stats.get("skipped", 0) + int((search_pc & skip).sum())
        search_pc &= ~skip
    qi, ci = np.nonzero(search_pc)
    if len(qi):
        fr = np.unique(kf[qi, ci])
        tstack = (
            stacks[int(fr[0])]
            if len(fr) == 1
            else ImageStack(np.concatenate([stacks[int(f)].images for f in fr]))
        )
        tidx = np.searchsorted(fr, kf[qi, ci]) * c + ci
        kuv = keys.uv[points[qi], ci]
        nc = search(
            tstack,
            search_stack,
            kuv,
            proj[qi, ci],
            half=half,
            radius=radius,
            template_index=tidx,
            search_index=ci,
            min_score=min_score,
        )
        r = match(
            tstack,
            search_stack,
            kuv,
            nc.uv,
            half=half,
            affine=keys.affine[points[qi], ci],
            template_index=tidx,
            search_index=ci,
            max_shift_px=2.0,
            weight_sigma=weight_sigma,
            max_sigma_px=max_sigma_px,
        )
        good = nc.ok & r.ok
        if stats is not None:
            for k_, v_ in (
                ("searched", len(qi)),
                ("ncc_ok", int(nc.ok.sum())),
                ("lsm_ok", int(good.sum())),
            ):
                stats[k_] = stats.get(k_, 0) + v_
        uv[qi[good], ci[good]] = r.uv[good]
        aff[qi[good], ci[good]] = r.affine[good]
    inter = triangulate(cameras, uv, sigma_px=0.3)
    n_views = np.sum(np.isfinite(uv[..., 0]), axis=1)
    dist = np.linalg.norm(inter.xyz - xyz_pred, axis=1)
    ok = (
        inter.ok
        & (n_views >= max(min_views, 2))
        & (inter.rms < max_rms_px)
        & (np.nan_to_num(dist, nan=np.inf) < max_dist_m)
    )
    if stats is not None:
        two = inter.ok & (n_views >= max(min_views, 2))
        for k_, v_ in (
            ("two_views", two),
            ("rms_ok", two & (inter.rms < max_rms_px)),
            ("near", ok),
        ):
            stats[k_] = stats.get(k_, 0) + int(v_.sum())
    return Reacquired(ok=ok, uv=uv, affine=aff, xyz=inter.xyz, cov=inter.cov)


def predict_unmeasured(
    query: np.ndarray,
    xyz_hist: list,
    pred_hist: list,
    rate_last: np.ndarray,
    xyz_new: np.ndarray,
    chosen: np.ndarray,
    *,
    max_rigid_rms: float = 0.005,
    radius_m: float = 0.06,
) -> np.ndarray:
    """Carry unmeasured points one frame on by the rigid motion of their neighbours.

    Each queried point's position in the last frame (measured, else predicted:
    ``pred_hist[-1]``) is moved by the rigid motion of the neighbours measured in both
    frames whose rate there was close to the point's own (measured, or that of its
    predictions; :func:`neighbour_motion`).

    Parameters
    ----------
    query : ndarray, shape (P,), bool
        Points to predict.
    xyz_hist, pred_hist : list of ndarray, shape (P, 3)
        Measured and predicted positions of every frame so far, metres.
    rate_last : ndarray, shape (P, 3)
        Filtered rates of the points measured in the last frame, m/frame (NaN else).
    xyz_new : ndarray, shape (P, 3)
        Positions measured in the new frame, metres; ``chosen`` (P,) bool marks them.
    max_rigid_rms : float
        Predictions whose neighbours moved less rigidly than this (RMS, metres) are
        not trusted.
    radius_m : float
        Neighbours are searched within this distance, metres.

    Returns
    -------
    ndarray, shape (P, 3)
        Predicted positions in the new frame, metres (NaN where not queried or no
        prediction).
    """
    n = len(query)
    pred = np.full((n, 3), np.nan)
    d = np.flatnonzero(query)
    if len(d) == 0:
        return pred
    last = np.where(np.isfinite(xyz_hist[-1]), xyz_hist[-1], pred_hist[-1])
    rate = rate_last.copy()
    if len(pred_hist) > 1:  # predicted points: their predicted rate
        before = np.where(np.isfinite(xyz_hist[-2]), xyz_hist[-2], pred_hist[-2])
        rate = np.where(np.isfinite(rate), rate, pred_hist[-1] - before)
    xyz_p, rms, ok = neighbour_motion(
        last[chosen],
        xyz_new[chosen],
        last[d],
        rate_then=rate_last[chosen],
        query_rate=rate[d],
        radius_m=radius_m,
    )
    ok &= rms < max_rigid_rms
    pred[d[ok]] = xyz_p[ok]
    return pred


@dataclass
class DormantStep:
    """Dormant points re-acquired by :func:`dormant_step` (K of them, C cameras).

    Attributes
    ----------
    rows : ndarray, shape (K,), int
        Their rows among all points.
    uv : ndarray, shape (K, C, 2)
        Matches in the new frame, pixels (NaN where a camera did not match).
    affine : ndarray, shape (K, C, 2, 2)
        Affines from the key patches to the new frame.
    xyz : ndarray, shape (K, 3)
        Forward intersections, metres.
    cov : ndarray, shape (K, 3, 3)
        Their covariances, m².
    """

    rows: np.ndarray
    uv: np.ndarray
    affine: np.ndarray
    xyz: np.ndarray
    cov: np.ndarray


def dormant_step(
    dormant: np.ndarray,
    xyz_hist: list,
    pred_hist: list,
    rate_last: np.ndarray,
    xyz_new: np.ndarray,
    chosen: np.ndarray,
    kf: PointFilter,
    keys: KeyTemplates,
    stacks: dict,
    search_stack: ImageStack,
    valid: np.ndarray,
    cameras: list[Camera],
    *,
    half: int = 6,
    weight_sigma: float | None = 4.0,
    max_sigma_px: float = 0.2,
    max_rms_px: float = 1.0,
    max_dist_m: float = 0.01,
    min_views: int = 2,
    max_rigid_rms: float = 0.005,
    occlusion_m: float | None = None,
    depth_dev_m: float | None = None,
    radius_m: float = 0.06,
    stats: dict | None = None,
) -> tuple[np.ndarray, DormantStep]:
    """Predict the dormant points one frame on and try to re-acquire them.

    The prediction carries each point's position in the last frame (measured, or
    predicted: ``pred_hist[-1]``) by the rigid motion of the neighbours measured in
    both frames whose rate there was close to the point's own (measured, or that of
    its predictions; :func:`neighbour_motion`).  Points found again
    (:func:`reacquire`) get their filters in ``kf`` restarted there.

    Parameters
    ----------
    dormant : ndarray, shape (P,), bool
    xyz_hist, pred_hist : list of ndarray, shape (P, 3)
        Measured and predicted (dormant) positions of every frame so far, metres.
    rate_last : ndarray, shape (P, 3)
        Filtered rates of the points measured in the last frame, m/frame (NaN else).
    xyz_new : ndarray, shape (P, 3)
        Positions measured in the new frame, metres; ``chosen`` (P,) bool marks them.
    kf : PointFilter
    keys : KeyTemplates
    stacks : dict int -> ImageStack
        Images of the key frames in use; ``search_stack`` those of the new frame, with
        ``valid`` (C,) bool where a camera has an image.
    max_rigid_rms : float
        Predictions whose neighbours moved less rigidly than this (RMS, metres) are
        not trusted.
    occlusion_m : float, optional
        Cameras in which the prediction lies more than this behind the cloud of the
        points measured in the new frame (:func:`core.track_occlusion.occluded`) are
        not searched: an occluder's texture there is what a wrong re-acquisition
        locks on to.
    depth_dev_m : float, optional
        A re-acquired point farther than this in depth from the median of its 8
        nearest points measured in the new frame
        (:func:`core.track_smooth.depth_deviation`) is not taken.
    radius_m : float
        Neighbour radius of the prediction (:func:`predict_unmeasured`), metres.
    stats : dict, optional
        Receives the counts of :func:`reacquire` and ``depth_rejected``.

    Returns
    -------
    pred : ndarray, shape (P, 3)
        Predicted positions of the dormant points in the new frame, metres (NaN where
        no prediction: such points cannot come back).
    DormantStep
    """
    pred = predict_unmeasured(
        dormant,
        xyz_hist,
        pred_hist,
        rate_last,
        xyz_new,
        chosen,
        max_rigid_rms=max_rigid_rms,
        radius_m=radius_m,
    )
    rows = np.flatnonzero(dormant & np.all(np.isfinite(pred), axis=1))
    c = len(cameras)
    empty = DormantStep(
        np.zeros(0, int),
        np.zeros((0, c, 2)),
        np.zeros((0, c, 2, 2)),
        np.zeros((0, 3)),
        np.zeros((0, 3, 3)),
    )
    if len(rows) == 0:
        return pred, empty
    skip = None
    if occlusion_m is not None:
        cloud = np.concatenate([xyz_new[chosen], pred[rows]])
        skip = occluded(cameras, cloud, margin_m=occlusion_m)[int(chosen.sum()) :]
    ra = reacquire(
        keys,
        stacks,
        search_stack,
        valid,
        cameras,
        rows,
        pred[rows],
        half=half,
        weight_sigma=weight_sigma,
        max_sigma_px=max_sigma_px,
        max_rms_px=max_rms_px,
        max_dist_m=max_dist_m,
        min_views=min_views,
        skip=skip,
        stats=stats,
    )
    if depth_dev_m is not None and chosen.sum() > 8:
        dev = depth_deviation(
            ra.xyz, np.mean([cam.center for cam in cameras], axis=0), xyz_new[chosen]
        )
        deep = ra.ok & ~(np.abs(np.nan_to_num(dev, nan=np.inf)) <= depth_dev_m)
        if stats is not None:
            stats["depth_rejected"] = stats.get("depth_rejected", 0) + int(deep.sum())
        ra.ok &= ~deep
    r = rows[ra.ok]
    if len(r) == 0:
        return pred, empty
    rate0, rsig = neighbour_rates(xyz_new[chosen], kf.x[chosen, 3:], ra.xyz[ra.ok])
    restart = PointFilter.start(ra.xyz[ra.ok], ra.cov[ra.ok] + COV_FLOOR, rate0, rsig)
    kf.x[r], kf.P[r] = restart.x, restart.P
    return pred, DormantStep(r, ra.uv[ra.ok], ra.affine[ra.ok], ra.xyz[ra.ok], ra.cov[ra.ok])
