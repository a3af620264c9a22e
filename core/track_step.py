"""The matching steps of one frame of :func:`core.tracking.track`, from frame i to i+1.

:func:`predict` -> :func:`temporal` -> :func:`spatial`; the measurement and what
follows it are in :mod:`core.track_measure`.  Each step works on all N points (the P
of :class:`core.track_state.TrackerState`) and C cameras at once; ``s`` is the
:class:`core.track_settings.TrackSettings`, ``stage`` the frame's counts (the ``log``
entry of :func:`core.tracking.track`).  The steps are described in :mod:`core.tracking`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .intersect import triangulate
from .lsm import ImageStack, match
from .ncc import search
from .track_anchor import reanchor
from .track_filter import predict_in_image
from .track_occlusion import occluded
from .track_settings import TrackSettings
from .track_state import Frame, TrackerState


@dataclass
class Prediction:
    """Where each point is expected at frame i+1 and which cameras search it.

    Attributes
    ----------
    xyz, cov : ndarray, shapes (N, 3) and (N, 3, 3)
        Predicted positions (metres) and their covariances (m²).
    uv, sigma_px : ndarray, shapes (N, C, 2) and (N, C)
        ``xyz`` projected, pixels, and the projected standard deviation, pixels.
    search_uv : ndarray, shape (N, C, 2)
        Centre of the temporal NCC search (``uv``, or the linear 2-D prediction).
    has_vel : ndarray, shape (N, C), bool
        The point's velocity is known (the small box is searched).
    pairs : ndarray, shape (N, C), bool
        (point, camera) pairs searched by the temporal match.
    n_searchable : ndarray, shape (N,), int
        Cameras that could search the point before the occlusion test.
    live : ndarray, shape (N,), bool
        Measured at frame i.
    occ : ndarray, shape (N, C), bool
        Cameras in which the point is occluded (:mod:`core.track_occlusion`).
    """

    xyz: np.ndarray
    cov: np.ndarray
    uv: np.ndarray
    sigma_px: np.ndarray
    search_uv: np.ndarray
    has_vel: np.ndarray
    pairs: np.ndarray
    n_searchable: np.ndarray
    live: np.ndarray
    occ: np.ndarray


@dataclass
class Matches:
    """Image matches at frame i+1.

    Attributes
    ----------
    uv_t : ndarray, shape (N, C, 2)
        Temporal matches (after the key templates), pixels, NaN where none.
    key_aff : ndarray, shape (N, C, 2, 2)
        Affine from the key template into frame i+1 where ``key_ok``.
    key_ok : ndarray, shape (N, C), bool
        The key match held (else the key is reset to the new measurement).
    rekey : ndarray, shape (N, C), bool
        The match needs a spatial confirmation (its key match failed, or it coasts).
    has_t : ndarray, shape (N, C), bool
        ``uv_t`` is finite (set by :func:`spatial`).
    based : ndarray, shape (N,), bool
        The point has a spatial template camera (set by :func:`spatial`).
    uv_acc, uv_tonly : ndarray, shape (N, C, 2)
        Accepted matches (temporal, or re-acquired by the spatial match), and the
        accepted temporal ones alone, pixels (set by :func:`spatial`).
    """

    uv_t: np.ndarray
    key_aff: np.ndarray
    key_ok: np.ndarray
    rekey: np.ndarray
    has_t: np.ndarray | None = None
    based: np.ndarray | None = None
    uv_acc: np.ndarray | None = None
    uv_tonly: np.ndarray | None = None


def predict(st: TrackerState, nxt: Frame, i: int, s: TrackSettings, stage: dict) -> Prediction:
    """Advance the point filters to frame i+1 and choose the (point, camera) pairs.

    A pair is searched where the point is not dead, the camera measured it within the
    last ``max_coast + 1`` frames, has an image at i+1, is not occluded
    (``occlusion_m``) and the prediction is finite.
    """
    n, c = len(st), len(st.cameras)
    st.kf.predict()
    xyz_p, cov_p = st.kf.x[:, :3].copy(), st.kf.P[:, :3, :3].copy()
    proj = np.full((n, c, 2), np.nan)
    sig_p = np.full((n, c), np.nan)
    for j, cam in enumerate(st.cameras):
        proj[:, j], sig_p[:, j] = predict_in_image(cam, xyz_p, cov_p)
    age = i + 1 - st.last_f
    pairs = ~st.dead[:, None] & (st.last_f >= 0) & (age <= s.max_coast + 1) & nxt.valid[None]
    pairs_pre = pairs.copy()
    occ = np.zeros((n, c), bool)
    if s.occlusion_m is not None:
        occ = occluded(
            st.cameras,
            np.where(st.dead[:, None], np.nan, xyz_p),
            margin_m=s.occlusion_m,
            dilate_all=s.occlusion_dilate,
        )
        pairs &= ~occ
        stage["occluded"] = int(occ.sum())
    if s.predict == "ekf":
        pred = proj
        # a filter knows its point's velocity once the rate σ fell well below its
        # start (0.03 m/frame): until then the first, wide box is searched
        rate_sd = np.sqrt(np.max(np.diagonal(st.kf.P[:, 3:, 3:], axis1=1, axis2=2), axis=1))
        has_vel = np.broadcast_to((rate_sd < 0.015)[:, None], (n, c))
    else:
        lin = st.last_uv + age[..., None] * (st.last_uv - st.prev_uv)
        has_vel = np.all(np.isfinite(lin), axis=2)
        pred = np.where(has_vel[..., None], lin, st.last_uv)
    pairs &= np.all(np.isfinite(pred), axis=2)
    n_searchable = (pairs_pre & np.all(np.isfinite(pred), axis=2)).sum(axis=1)
    return Prediction(
        xyz=xyz_p,
        cov=cov_p,
        uv=proj,
        sigma_px=sig_p,
        search_uv=pred,
        has_vel=has_vel,
        pairs=pairs,
        n_searchable=n_searchable,
        live=~st.dead & (st.coast == 0),
        occ=occ,
    )


def _templates(st: TrackerState, pi: np.ndarray, ci: np.ndarray, i: int):
    """Images of the template frames of K (point, camera) pairs ``(pi, ci)``.

    Returns the stack (frame i's, or the frames ``last_f`` names, camera-major), the
    (K,) index of each pair's template image in it, and (K,) bool: that image exists.
    """
    c = len(st.cameras)
    lf = st.last_f[pi, ci]
    fr = np.unique(lf)
    tvalid = np.array([st.ring[f].valid[k] for f, k in zip(lf, ci, strict=True)])
    if len(fr) == 1 and fr[0] == i:
        return st.ring[i].stack, ci, tvalid
    tstack = ImageStack(np.concatenate([st.ring[f].stack.images for f in fr]))
    return tstack, np.searchsorted(fr, lf) * c + ci, tvalid


def temporal(
    st: TrackerState, nxt: Frame, pr: Prediction, i: int, s: TrackSettings, stage: dict
) -> Matches:
    """NCC search then temporal LSM from each camera's last measurement into frame i+1.

    Every converged match is matched again from its key template (``anchor``,
    :func:`core.track_anchor.reanchor`); where that fails the match needs the spatial
    match's confirmation (``confirm_rekey``).
    """
    n, c = len(st), len(st.cameras)
    pi, ci = np.nonzero(pr.pairs)
    m = Matches(
        uv_t=np.full((n, c, 2), np.nan),
        key_aff=np.full((n, c, 2, 2), np.nan),
        key_ok=np.zeros((n, c), bool),
        rekey=np.zeros((n, c), bool),
    )
    if not len(pi):
        return m
    if s.predict == "ekf" and s.adaptive:
        rad = np.clip(np.ceil(3.0 * pr.sigma_px[pi, ci]) + 1, 3, s.max_radius).astype(int)
    else:
        rad = np.where(pr.has_vel[pi, ci], s.ncc_radius, s.first_radius)
    tstack, tidx, tvalid = _templates(st, pi, ci, i)
    uv_start = pr.search_uv[pi, ci].copy()
    ncc_ok = np.zeros(len(pi), bool)
    for r in np.unique(rad):
        k = np.flatnonzero(rad == r)
        nc = search(
            tstack,
            nxt.stack,
            st.last_uv[pi[k], ci[k]],
            pr.search_uv[pi[k], ci[k]],
            half=s.half,
            radius=int(r),
            template_index=tidx[k],
            search_index=ci[k],
            min_score=0.6,
        )
        uv_start[k[nc.ok]] = nc.uv[nc.ok]
        ncc_ok[k] = nc.ok
    rt = match(
        tstack,
        nxt.stack,
        st.last_uv[pi, ci],
        uv_start,
        half=s.half,
        template_index=tidx,
        search_index=ci,
        max_shift_px=3.0,
        weight_sigma=s.temporal_sigma,
        max_sigma_px=s.max_sigma_px,
    )
    ok_t = rt.ok & nxt.valid[ci] & tvalid
    m.uv_t[pi[ok_t], ci[ok_t]] = rt.uv[ok_t]
    if s.anchor and ok_t.any():
        k = np.flatnonzero(ok_t)
        uv_a, aff_a, ok_a = reanchor(
            st.keys,
            st.key_stacks(),
            nxt.stack,
            pi[k],
            ci[k],
            rt.uv[k],
            rt.affine[k],
            half=s.half,
            max_px=s.anchor_px,
            weight_sigma=s.temporal_sigma,
            max_sigma_px=s.max_sigma_px,
        )
        m.uv_t[pi[k], ci[k]] = uv_a
        m.key_aff[pi[k], ci[k]] = aff_a
        m.key_ok[pi[k], ci[k]] = ok_a
        if s.confirm_rekey:
            m.rekey[pi[k], ci[k]] = ~ok_a
        stage["anchored"] = int(ok_a.sum())
    stage.update(
        seen=len(pi),
        ncc_ok=int(ncc_ok.sum()),
        temporal_ok=int(ok_t.sum()),
        temporal_status=np.bincount(rt.status, minlength=8).tolist(),
        radius_mean=float(rad.mean()),
    )
    return m


def _reacquire_start(
    nxt: Frame, pr: Prediction, m: Matches, tcam, qi, qc, start_s, from_t, s: TrackSettings
) -> None:
    """Start the re-acquisitions at the predicted point at an NCC peak instead.

    Of the K spatial pairs ``(qi, qc)``, those without a temporal match whose start
    ``start_s`` (N, C, 2) px is the projected prediction are searched by NCC (template:
    the template camera ``tcam`` (N,)'s match) in a box of ``3 σ + 1``, at most
    ``reacquire_radius``; ``start_s`` is updated in place where the peak is found.
    """
    k = np.flatnonzero(~m.has_t[qi, qc] & ~from_t[qi])
    if not len(k):
        return
    r_k = np.clip(np.ceil(3.0 * pr.sigma_px[qi[k], qc[k]]) + 1, 3, s.reacquire_radius)
    r_k = np.where(np.isfinite(r_k), r_k, s.reacquire_radius).astype(int)
    for r in np.unique(r_k):
        kk = k[r_k == r]
        nc = search(
            nxt.stack,
            nxt.stack,
            m.uv_t[qi[kk], tcam[qi[kk]]],
            start_s[qi[kk], qc[kk]],
            half=s.half,
            radius=int(r),
            template_index=tcam[qi[kk]],
            search_index=qc[kk],
            min_score=0.7,
        )
        start_s[qi[kk[nc.ok]], qc[kk[nc.ok]]] = nc.uv[nc.ok]


def spatial(
    st: TrackerState, nxt: Frame, pr: Prediction, m: Matches, s: TrackSettings, stage: dict
) -> None:
    """Spatial LSM at frame i+1 from each point's template camera into the others.

    The template camera is the reference camera's temporal match, else the first
    camera's, preferring matches that need no confirmation.  Cameras without a temporal
    match start at the projection of the intersection of the temporal matches (two or
    more), or else of the predicted point: they are re-acquired.  Fills ``m.has_t``,
    ``m.based``, ``m.uv_acc`` and ``m.uv_tonly`` (see :class:`Matches`); updates
    ``st.aff_sp`` where the reference camera's spatial match converged.
    """
    n, c, ref = len(st), len(st.cameras), st.ref
    has_t = m.has_t = np.all(np.isfinite(m.uv_t), axis=2)
    if s.coast_confirm:  # a coasting point: its matches need confirmation
        m.rekey |= (~st.dead & (st.coast > 0))[:, None] & has_t
    sure = has_t & ~m.rekey
    tcam = np.where(
        sure[:, ref],
        ref,
        np.where(
            sure.any(axis=1),
            np.argmax(sure, axis=1),
            np.where(has_t[:, ref], ref, np.argmax(has_t, axis=1)),
        ),
    )
    based = m.based = has_t[np.arange(n), tcam] & ~st.dead
    it_ = triangulate(st.cameras, m.uv_t, sigma_px=0.3)
    from_t = it_.ok & (it_.rms < s.max_rms_px)
    xyz_s = np.where(from_t[:, None], it_.xyz, pr.xyz)
    proj_s = np.stack([cam.project(xyz_s) for cam in st.cameras], axis=1)
    start_s = np.where(has_t[..., None], m.uv_t, proj_s)
    # not re-acquired in cameras where the point is occluded (has_t implies ~occ)
    qi, qc = np.nonzero(
        based[:, None]
        & (np.arange(c)[None] != tcam[:, None])
        & np.all(np.isfinite(start_s), axis=2)
        & nxt.valid[None]
        & ~pr.occ
    )
    m.uv_acc = np.full((n, c, 2), np.nan)
    m.uv_acc[based, tcam[based]] = m.uv_t[based, tcam[based]]
    m.uv_tonly = m.uv_acc.copy()
    if not len(qi):
        return
    if s.reacquire_radius:
        _reacquire_start(nxt, pr, m, tcam, qi, qc, start_s, from_t, s)
    tc = tcam[qi]
    aff0 = np.where((tc == ref)[:, None, None], st.aff_sp[qi, qc], np.eye(2))
    rs = match(
        nxt.stack,
        nxt.stack,
        m.uv_t[qi, tc],
        start_s[qi, qc],
        half=s.half,
        affine=aff0,
        template_index=tc,
        search_index=qc,
        max_shift_px=3.0,
        max_sigma_px=s.spatial_sigma_px,
    )
    d = np.linalg.norm(rs.uv - m.uv_t[qi, qc], axis=1)
    # A temporal match is vetoed only by a spatial match that converged elsewhere;
    # a failed spatial match (occlusion edge, weak texture in that view) leaves
    # the check to the forward intersection.  Re-acquisitions need the spatial.
    ht = has_t[qi, qc]
    agree = np.where(ht, ~rs.ok | (d < s.agree_px), rs.ok)
    agree &= ~m.rekey[qi, qc] | (rs.ok & (d < s.agree_px))
    use_uv = np.where(ht[:, None], m.uv_t[qi, qc], rs.uv)
    m.uv_acc[qi[agree], qc[agree]] = use_uv[agree]
    kt = agree & ht
    m.uv_tonly[qi[kt], qc[kt]] = use_uv[kt]
    stage.update(
        spatial_ok=int(rs.ok.sum()), agree=int(agree.sum()), reacquired=int((agree & ~ht).sum())
    )
    upd = agree & (tc == ref) & rs.ok
    st.aff_sp[qi[upd], qc[upd]] = rs.affine[upd]
