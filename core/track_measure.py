"""The measuring steps of one frame of :func:`core.tracking.track`, into frame i+1.

:func:`intersect` -> :func:`depth_test` -> :func:`update_points` ->
:func:`carry_coasting` -> :func:`reacquire_dormant` ->
:meth:`core.track_state.TrackerState.record` -> :func:`regenerate`, after the matching
steps of :mod:`core.track_step`; same conventions (N points, C cameras, ``s`` the
settings, ``stage`` the frame's counts).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .intersect import triangulate
from .surface import concat, measure_surface
from .surface_pairs import grow_pairs
from .surface_seed import grow_from_jumps
from .track_filter import COV_FLOOR, neighbour_rates
from .track_reacquire import dormant_step, predict_unmeasured
from .track_settings import TrackSettings
from .track_smooth import depth_outliers
from .track_state import Frame, TrackerState
from .track_step import Matches, Prediction


@dataclass
class Measurement:
    """The points measured at frame i+1.

    Attributes
    ----------
    uv : ndarray, shape (N, C, 2)
        Image points of the accepted intersection, pixels (NaN where not measured).
    xyz, cov : ndarray, shapes (N, 3) and (N, 3, 3)
        Forward intersections, metres and m².
    chosen : ndarray, shape (N,), bool
        Measured.
    was_coasting : ndarray, shape (N,), bool
        The point coasted into this frame.
    n_gated : int
        Candidate intersections rejected by the gates.
    any_two, any_rms : ndarray, shape (N,), bool
        Some candidate set had two cameras; and intersected within ``max_rms_px``.
    depth_out : ndarray, shape (N,), bool
        Measured, then dropped by the depth test.
    """

    uv: np.ndarray
    xyz: np.ndarray
    cov: np.ndarray
    chosen: np.ndarray
    was_coasting: np.ndarray
    n_gated: int
    any_two: np.ndarray
    any_rms: np.ndarray
    depth_out: np.ndarray


def intersect(st: TrackerState, pr: Prediction, m: Matches, s: TrackSettings) -> Measurement:
    """Forward intersection of the candidate camera sets, gated against the prediction.

    Candidates in turn: the accepted matches, the accepted temporal ones, and (with
    ``fallback``) every temporal match that needs no confirmation; the first that has
    two or more cameras, reprojects within ``max_rms_px``, lies within ``gate``
    (Mahalanobis) of the prediction and, for a coasting point, within ``coast_m`` of
    it, is taken.
    """
    n, c = len(st), len(st.cameras)
    out = Measurement(
        uv=np.full((n, c, 2), np.nan),
        xyz=np.full((n, 3), np.nan),
        cov=np.full((n, 3, 3), np.nan),
        chosen=np.zeros(n, bool),
        was_coasting=~st.dead & (st.coast > 0),
        n_gated=0,
        any_two=np.zeros(n, bool),
        any_rms=np.zeros(n, bool),
        depth_out=np.zeros(n, bool),
    )
    uv_tsure = np.where(
        (m.based[:, None] & (~m.rekey | np.all(np.isfinite(m.uv_acc), axis=2)))[..., None],
        m.uv_t,
        np.nan,
    )
    for cand in (m.uv_acc, m.uv_tonly) + ((uv_tsure,) if s.fallback else ()):
        inter = triangulate(st.cameras, cand, sigma_px=0.3)
        m2 = st.kf.mahalanobis2(inter.xyz, inter.cov + COV_FLOOR)
        two = np.sum(np.isfinite(cand[..., 0]), 1) >= 2
        out.any_two |= two
        out.any_rms |= two & inter.ok & (inter.rms < s.max_rms_px)
        ok = ~out.chosen & ~st.dead & inter.ok & (inter.rms < s.max_rms_px) & two
        near = m2 < s.gate**2
        if s.coast_m is not None:  # a coasting point: near its prediction
            dist = np.linalg.norm(inter.xyz - pr.xyz, axis=1)
            near &= ~out.was_coasting | (np.nan_to_num(dist, nan=np.inf) < s.coast_m)
        out.n_gated += int((ok & ~near).sum())
        ok &= near
        out.uv[ok], out.xyz[ok], out.cov[ok] = cand[ok], inter.xyz[ok], inter.cov[ok]
        out.chosen |= ok
    return out


def depth_test(
    st: TrackerState, ms: Measurement, s: TrackSettings, stage: dict, diagnose: bool
) -> None:
    """Unmeasure (in ``ms``) the points whose depth departs from their neighbours'.

    A measured point farther than ``depth_dev_m`` in depth from the median of its 8
    nearest measured neighbours (:func:`core.track_smooth.depth_outliers`) is set to
    NaN and flagged in ``ms.depth_out`` (N,); with ``diagnose``,
    ``stage["depth_rejected"]`` (N, 3) keeps its position, metres.
    """
    if s.depth_dev_m is None:
        return
    out = ms.depth_out = ms.chosen & depth_outliers(
        np.where(ms.chosen[:, None], ms.xyz, np.nan), st.viewpoint, s.depth_dev_m
    )
    if diagnose:
        stage["depth_rejected"] = np.where(out[:, None], ms.xyz, np.nan)
    ms.uv[out], ms.xyz[out], ms.cov[out] = np.nan, np.nan, np.nan
    ms.chosen &= ~out
    stage["depth_outliers"] = int(out.sum())


def update_points(st: TrackerState, ms: Measurement, s: TrackSettings) -> None:
    """Update the filters of the measured points; count the others' unmeasured frames.

    A point unmeasured for more than ``max_coast`` frames is dead (dormant while
    ``max_dormant`` allows, then gone).
    """
    rows = np.flatnonzero(ms.chosen)
    st.kf.update(ms.xyz[rows], ms.cov[rows] + COV_FLOOR, rows)
    st.coast = np.where(ms.chosen, 0, st.coast + 1)
    st.dead |= st.coast > s.max_coast
    st.gone |= st.dead & (st.coast > s.max_coast + s.max_dormant)


def carry_coasting(
    st: TrackerState, pr: Prediction, ms: Measurement, s: TrackSettings, stage: dict
) -> np.ndarray:
    """Carry the coasting points by their measured neighbours' rigid motion.

    With ``coast_neighbours`` (:func:`core.track_reacquire.predict_unmeasured`) the
    carried position and rate replace the filter's: they start the next frame's
    search and bridge the gap afterwards.

    Returns
    -------
    ndarray, shape (N, 3)
        The predictions recorded at frame i+1, metres: the carried positions, and for
        a point measured again after coasting the prediction it was measured at (it
        closes the bridge of its gap); NaN elsewhere.
    """
    n = len(st)
    pred_d = np.full((n, 3), np.nan)
    back = ms.was_coasting & ms.chosen
    pred_d[back] = pr.xyz[back]
    coasting = ~st.dead & ~ms.chosen
    if s.coast_neighbours and coasting.any() and ms.chosen.any():
        pc = predict_unmeasured(
            coasting,
            st.xyz_hist,
            st.pred_hist,
            st.rate_hist[-1],
            ms.xyz,
            ms.chosen,
            radius_m=s.neighbour_radius_m,
        )
        r = np.flatnonzero(np.all(np.isfinite(pc), axis=1))
        last = st.xyz_hist[-1][r]
        before = np.where(np.isfinite(last), last, st.pred_hist[-1][r])
        st.kf.x[r, 3:] = np.where(np.isfinite(before), pc[r] - before, st.kf.x[r, 3:])
        st.kf.x[r, :3] = pc[r]
        pred_d[r] = pc[r]
        stage["coast_predicted"] = len(r)
    return pred_d


def reacquire_dormant(
    st: TrackerState,
    nxt: Frame,
    m: Matches,
    ms: Measurement,
    pred_d: np.ndarray,
    s: TrackSettings,
    stage: dict,
) -> np.ndarray:
    """Predict the dormant points and re-acquire them from their key templates.

    With ``max_dormant`` (:func:`core.track_reacquire.dormant_step`).  Re-acquired
    points are written into ``ms`` (and their key matches into ``m``) and revived.

    Returns
    -------
    ndarray, shape (N, 3)
        ``pred_d`` with the dormant points' predictions, metres.
    """
    rstats: dict = {}
    stage["reacquire_stats"] = rstats
    dorm = st.dead & ~st.gone
    if not (s.max_dormant and ms.chosen.any() and dorm.any()):
        return pred_d
    pred_dm, rd = dormant_step(
        dorm,
        st.xyz_hist,
        st.pred_hist,
        st.rate_hist[-1],
        ms.xyz,
        ms.chosen,
        st.kf,
        st.keys,
        st.key_stacks(),
        nxt.stack,
        nxt.valid,
        st.cameras,
        half=s.half,
        weight_sigma=s.temporal_sigma,
        max_sigma_px=s.max_sigma_px,
        max_rms_px=s.max_rms_px,
        max_dist_m=s.reacquire_m,
        min_views=s.reacquire_views,
        occlusion_m=s.occlusion_m if s.reacquire_checks else None,
        depth_dev_m=s.depth_dev_m if s.reacquire_checks else None,
        radius_m=s.neighbour_radius_m,
        stats=rstats,
    )
    if len(rd.rows):
        r = rd.rows
        ms.uv[r], ms.xyz[r], ms.cov[r] = rd.uv, rd.xyz, rd.cov
        m.key_ok[r] = np.all(np.isfinite(rd.uv), axis=2)
        m.key_aff[r] = rd.affine
        ms.chosen[r], st.dead[r], st.coast[r] = True, False, 0
    pred_d = np.where(dorm[:, None], pred_dm, pred_d)
    st.gone |= st.dead & ~np.all(np.isfinite(pred_d), axis=1)  # no prediction
    stage.update(
        dormant=int((st.dead & ~st.gone).sum()) + len(rd.rows), reacquired_dormant=len(rd.rows)
    )
    return pred_d


def regenerate(
    st: TrackerState,
    nxt: Frame,
    pr: Prediction,
    ms: Measurement,
    i: int,
    s: TrackSettings,
    stage: dict,
) -> None:
    """Every ``regen_every`` frames, seed new points where no live point is.

    The surface at frame i+1 is grown again (:func:`core.surface.measure_surface`)
    from about 20 of the measured points over the reference camera's grid cells that
    no live point (measured, or coasting at its prediction) covers, and with
    ``jump_seeds`` also from seeds found along the epipolar lines beyond the depth jumps
    that growth stops at (:func:`core.surface_seed.grow_from_jumps`), and with
    ``pair_seeds`` from the pairs of the other cameras where the reference camera does
    not see (:func:`core.surface_pairs.grow_pairs`); the K new points
    are added to ``st`` (:meth:`core.track_state.TrackerState.append`) with rates
    from their measured neighbours.
    """
    chosen, ref = ms.chosen, st.ref
    if not (s.regen_every and (i + 1) % s.regen_every == 0 and chosen.any() and nxt.valid.all()):
        return
    occ = np.concatenate([ms.uv[chosen, ref], pr.uv[~st.dead & ~chosen, ref]])
    seeds = ms.uv[chosen][:: max(1, int(chosen.sum()) // 20)]
    seeds = seeds[np.all(np.isfinite(seeds[:, ref]), axis=1)]
    if not len(seeds):
        return
    new = measure_surface(
        nxt.stack,
        st.cameras,
        seeds,
        ref=ref,
        step=s.step,
        half=s.half,
        occupied_uv=occ,
        max_sigma_px=s.spatial_sigma_px,
        max_depth_dev_m=s.depth_dev_m,
    )
    if s.jump_seeds:  # surface beyond the depth jumps the growth stops at (a limb)
        jump = grow_from_jumps(
            nxt.stack,
            st.cameras,
            ref,
            ms.xyz[chosen],
            np.concatenate([occ, new.uv[:, ref]]),
            step=s.step,
            half=s.half,
            max_sigma_px=s.spatial_sigma_px,
            max_depth_dev_m=s.depth_dev_m,
        )
        if jump is not None and len(jump):
            new = concat(new, jump)
            stage["jump_seeded"] = len(jump)
    if s.pair_seeds and len(st.cameras) > 2:  # surface the reference camera does not see
        pairs = grow_pairs(
            nxt.stack,
            st.cameras,
            ref,
            ms.xyz[chosen],
            _occupied(st, pr, ms, new),
            step=s.step,
            half=s.half,
            max_sigma_px=s.spatial_sigma_px,
            max_depth_dev_m=s.depth_dev_m,
        )
        if len(pairs):
            new = concat(new, pairs)
            stage["pair_seeded"] = len(pairs)
    if len(new):
        rate0, rsig = neighbour_rates(ms.xyz[chosen], st.kf.x[chosen, 3:], new.xyz)
        st.append(new, rate0, rsig, i + 1)
        stage["regenerated"] = len(new)


def _occupied(st: TrackerState, pr: Prediction, ms: Measurement, new) -> list[np.ndarray]:
    """Image points (M_c, 2) per camera that the surface already covers at frame i+1:
    the live points (measured, or coasting at their prediction) where measured in that
    camera or projected there unoccluded, and the points ``new`` adds."""
    live = ~st.dead
    xyz = np.where(ms.chosen[:, None], ms.xyz, pr.xyz)[live]
    out = []
    for j, cam in enumerate(st.cameras):
        uv = np.where(np.isfinite(ms.uv[live, j]), ms.uv[live, j], cam.project(xyz))
        uv = uv[np.isfinite(ms.uv[live, j, 0]) | ~pr.occ[live, j]]
        out.append(np.concatenate([uv, new.uv[:, j]]))
    return out
