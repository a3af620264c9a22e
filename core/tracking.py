"""Spatial + temporal LSM tracking of surface points, trajectory filters, regeneration.

Per frame i -> i+1 (D'Apuzzo et al. 1999, section 2.4), for all live points and
cameras at once:

1. prediction: every point carries a constant-velocity Kalman filter in 3-D
   (:class:`PointFilter`); its prediction is projected into every camera, and the
   projected covariance sets the NCC search box (``predict="ekf"``, default).  The
   paper's 2-D linear prediction ``uv_i + (uv_i - uv_{i-1})`` with a fixed box is
   kept as ``predict="linear"``;
   Cameras in which the prediction lies behind the other live points' predicted
   surface (``occlusion_m``, :mod:`core.track_occlusion`) are skipped for the point;
2. NCC search in the box (template: the camera's last measurement of the point);
3. temporal LSM from that frame (usually i) to frame i+1, started at the NCC peak,
   then matched again from the point's key template (``anchor``,
   :mod:`core.track_anchor`: the patch where it was first measured in that camera,
   with the composed temporal affines) so that frame-to-frame drift does not build up;
   where the key match fails, the temporal match needs the spatial match's
   confirmation (``confirm_rekey``) before it becomes the new key;
4. spatial LSM at frame i+1 from the reference camera into the others, started at
   the temporal results (or, where a camera lost the point, at the projection of the
   intersection of the temporal matches, or of the predicted point: that camera is
   re-acquired);
5. a camera's temporal match is accepted unless the spatial match converged more than
   ``agree_px`` away from it (a failed spatial match does not veto: the forward
   intersection checks the geometry); a camera without a temporal match is
   re-acquired where the spatial match exists.  The point is measured when two or
   more cameras are accepted, the forward intersection reprojects within
   ``max_rms_px`` and lies within ``gate`` (Mahalanobis) of the prediction; failing
   that, the temporal matches alone are tried (``fallback``, which also overrides a
   spatial veto).  A point whose depth departs from its measured neighbours'
   median (``depth_dev_m``, :mod:`core.track_smooth`) is not measured, unless
   leaving out one of three or more cameras makes it pass (``depth_retry``).  An
   unmeasured point coasts for up to ``max_coast`` frames, carried by the rigid
   motion of its measured neighbours (``coast_neighbours``,
   :func:`core.track_reacquire.predict_unmeasured`), and is searched from its last
   templates; measured again (within ``coast_m`` of the prediction), it continues
   its trajectory and the gap is bridged from the predictions (:func:`bridge_gaps`,
   else :func:`fill_gaps`; ``Tracks.measured`` is False there).  ``log`` says which
   step lost each point (:mod:`core.track_diagnose`).
6. a lost point stays dormant for up to ``max_dormant`` frames
   (:mod:`core.track_reacquire`): predicted from the rigid motion of its measured
   neighbours and searched with its key templates; when found in two or more cameras
   near its prediction it resumes the same trajectory, and the gap is bridged from
   the predictions (:func:`bridge_gaps`, not ``measured``).

Beyond the paper, every ``regen_every`` frames the surface is grown again from the
live points (:func:`core.surface.measure_surface`) over grid cells that no live point
covers: lost points are regenerated and newly visible surface is seeded.

:func:`filter_trajectories` (:mod:`core.track_trajectories`) applies the paper's
filters afterwards; the point filters live in :mod:`core.track_filter`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .camera import Camera
from .intersect import triangulate
from .lsm import ImageStack, match
from .ncc import search
from .surface import Surface, measure_surface
from .track_anchor import KeyTemplates, reanchor
from .track_diagnose import loss_reasons
from .track_filter import COV_FLOOR, PointFilter, neighbour_rates, predict_in_image
from .track_occlusion import occluded
from .track_reacquire import dormant_step, predict_unmeasured
from .track_smooth import depth_outliers, drop_one_camera
from .track_trajectories import (
    FilterResult,
    bridge_gaps,
    derivative,
    fill_gaps,
    filter_trajectories,
)

__all__ = ["FilterResult", "PointFilter", "Tracks", "fill_gaps", "filter_trajectories",
           "predict_in_image", "track"]


@dataclass
class Tracks:
    """Trajectories of P points over F frames in C cameras (NaN where not tracked).

    Attributes
    ----------
    xyz : ndarray, shape (F, P, 3)
        World positions, metres.
    uv : ndarray, shape (F, P, C, 2)
        Image positions, pixels.
    sigma_xyz : ndarray, shape (F, P, 3)
        Standard deviations of ``xyz`` from the forward intersection, metres.
    start : ndarray, shape (P,), int
        Frame where each trajectory starts (0 for the surface measured at frame 0,
        later for regenerated / new points).
    fps : float
    measured : ndarray, shape (F, P) bool, optional
        The position was measured (forward intersection) in that frame; False where a
        gap was bridged (:func:`bridge_gaps` after a re-acquisition, :func:`fill_gaps`
        after coasting) or the point is not tracked.
    """

    xyz: np.ndarray
    uv: np.ndarray
    sigma_xyz: np.ndarray
    start: np.ndarray
    fps: float
    measured: np.ndarray | None = None

    @property
    def alive(self) -> np.ndarray:
        """(F, P) bool: the point has a 3-D position at that frame."""
        return np.all(np.isfinite(self.xyz), axis=2)

    def velocity(self) -> np.ndarray:
        """(F, P, 3) m/s by central differences (one-sided at the ends), NaN where unknown."""
        return derivative(self.xyz, self.fps)

    def acceleration(self) -> np.ndarray:
        """(F, P, 3) m/s² (second differences), NaN where unknown."""
        a = np.full_like(self.xyz, np.nan)
        a[1:-1] = (self.xyz[2:] - 2 * self.xyz[1:-1] + self.xyz[:-2]) * self.fps ** 2
        return a


def track(frames, cameras: list[Camera], surface: Surface, n_frames: int, fps: float, *,
          half: int = 6, predict: str = "ekf", ncc_radius: int = 5, first_radius: int = 14,
          adaptive: bool = True, max_radius: int = 16, agree_px: float = 0.5,
          max_rms_px: float = 1.0, accel_sigma: float = 0.025, gate: float = 5.0,
          max_coast: int = 1, temporal_sigma: float | None = 4.0,
          max_sigma_px: float = 0.12, spatial_sigma_px: float = 0.15,
          fallback: bool = True, regen_every: int = 3,
          anchor: bool = True, anchor_px: float = 1.0, confirm_rekey: bool = True,
          occlusion_m: float | None = 0.05, reacquire_radius: int = 0,
          depth_dev_m: float | None = 0.01, depth_retry: bool = False,
          occlusion_confirm: bool = False, reacquire_checks: bool = True,
          occlusion_dilate: bool = True, coast_neighbours: bool = True,
          coast_m: float | None = 0.006, neighbour_radius_m: float = 0.06,
          coast_fallback: bool = False, coast_confirm: bool = True,
          max_dormant: int = 0,
          reacquire_m: float = 0.01, reacquire_views: int = 2,
          step: int = 2, progress=None,
          log: list | None = None) -> Tracks:
    """Track the surface points through ``n_frames`` frames.

    Parameters
    ----------
    frames : callable ``frames(i) -> list of C grey images``
        Images of frame i in camera order; a camera whose image is missing may give
        ``None`` (its points are then not matched there in that frame).
    cameras : list of Camera, length C
    surface : Surface
        Points measured at frame 0 (:func:`core.surface.measure_surface`).
    predict : {"ekf", "linear"}
        Start of the temporal search: the per-point 3-D Kalman prediction projected
        into each camera, or the paper's 2-D linear prediction (same image motion as
        in the last step, no motion where unknown).
    ncc_radius, first_radius : int
        NCC search box half widths with a velocity estimate and without one, pixels
        (``predict="linear"`` or ``adaptive=False``).
    adaptive : bool
        With ``predict="ekf"``: box half width ``3 σ + 1`` of the projected prediction
        covariance, within ``[3, max_radius]`` px, instead of the fixed radii.
    accel_sigma : float
        Process noise of the point filters, m / frame².
    gate : float
        Largest Mahalanobis distance between a measured point and its prediction.
    max_coast : int
        Frames a point may go unmeasured (occluded, no match, a failed check) before
        it is dropped (or goes dormant); meanwhile it is carried by its neighbours'
        motion (``coast_neighbours``) and searched from its last templates at that
        prediction, and the gaps so bridged are filled afterwards
        (:attr:`Tracks.measured` is False there).  Before the neighbour prediction
        and the ``coast_m`` gate (and the key templates, ``confirm_rekey``, the
        occlusion and depth tests), 3 frames raised the 95th percentile of the 3-D
        error over 50 frames to ~90 mm.  With them, on walk_line3 (50 frames,
        ``bench.tracking --no-compare --track-kw '{"max_coast": N}'``, 2,048 frame-0
        points): N = 0 / 2 / 3 -> measured in every frame 25.1 / 25.0 / 23.1 %, kept
        to the last frame with flagged gaps of <= 5 frames 25.1 / 29.4 / 29.0 %, 95th
        percentile of the measured positions 9.56 / 10.30 / 10.05 mm (bridged
        point-frames: 95th 17.9 / 16.9 mm) with ``coast_m=0.01`` and no
        ``coast_confirm``.  With both as now (default 1): N = 1 / 2 -> 25.8 / 23.8 %,
        27.0 / 26.7 %, 9.69 / 9.79 mm (bridged 13.7 / 15.4 mm); live at the last frame
        96.3 % (100.3 % with N = 0: coasting points hold their grid cells against
        regeneration).
    temporal_sigma : float or None
        Gaussian weighting σ of the temporal LSM patches, pixels (None: uniform).
    max_sigma_px : float
        Largest σ of an accepted temporal match, pixels.  With the other defaults on
        walk_line3 (50 frames), 0.15: measured in every frame 25.6 -> 26.6 %, 95th
        percentile 9.67 -> 9.79 mm.
    spatial_sigma_px : float
        Largest σ of an accepted spatial match (and of the regenerated surface points),
        pixels.
    fallback : bool
        Where the accepted cameras fail the intersection or the gate, try the
        temporal matches alone (also those a spatial match vetoed).
    regen_every : int
        Regenerate / seed new points every this many frames (0: never).  3 (with
        ``depth_dev_m``, which drops points every frame): the live count at the last
        of 50 frames on walk_line3 stays at 101 % of the first (82 % with 5).
    anchor : bool
        Match every temporal match again from the point's key template
        (:mod:`core.track_anchor`): removes the drift of frame-to-frame matching.
        On walk_line3 (50 frames) frame-0 points measured in every frame 32.3 ->
        35.8 %, error median 3.82 -> 3.59 mm, 95th percentile 35.9 -> 36.9 mm; about
        20 % more CPU time.
    anchor_px : float
        Largest distance between the key match and the temporal match, pixels; beyond
        it (or where the key match fails) the key is reset to the new measurement.
    confirm_rekey : bool
        A temporal match whose key match failed (its key would be reset to it) is
        accepted only where a spatial match from another camera converged within
        ``agree_px`` of it (the appearance changed: occlusion, or a slip onto other
        texture), and it is not used by the fallback.  Without it, a point that a
        leg or arm passed in front of took the occluder's texture as its new key and
        followed it.  walk_line3, 50 frames (``bench.tracking``, all else as before):
        95th percentile of the 3-D error 18.3 -> 13.1 mm, median 2.95 -> 2.74 mm,
        frame-0 points measured in every frame 33.5 -> 29.0 %.
    occlusion_m : float, optional
        Cameras in which a point's prediction lies more than this behind the surface
        of the other live points' predictions (:func:`core.track_occlusion.occluded`)
        are not matched for it in that frame (None: no test).  walk_line3 as above,
        0.05 alone: 95th 18.3 -> 13.0 mm, measured in every frame 33.5 -> 28.3 %; with
        ``confirm_rekey``: 11.4 mm, 26.6 %.
    reacquire_radius : int
        Where fewer than two cameras have a temporal match, the spatial matches into
        the others start at the predicted point: search them first by NCC (template:
        the spatial template camera's match) in a box of ``3 σ + 1`` of the prediction,
        at most this half width, pixels.  0 (default): LSM from the prediction.  On
        walk_line3 (50 frames, other defaults) 8: frame-0 points measured in every
        frame 25.6 -> 26.4 %, 95th percentile 9.67 -> 9.71 mm, median 2.34 -> 2.43 mm.
    depth_dev_m : float, optional
        A point whose intersection lies farther than this in depth from the median of
        its 8 nearest measured neighbours in the same frame
        (:func:`core.track_smooth.depth_outliers`) is not measured there; regenerated
        surfaces are filtered the same way (None: no test).  walk_line3 with the two
        options above and the frame-0 surface filtered alike (2,006 of 2,124
        points): 0.01 -> 95th 9.0 mm, median 2.26 mm, measured in every frame
        25.4 %, live at the last frame 82 % (101 % with ``regen_every=3``: 95th
        9.7 mm, 25.6 %); 0.015 -> 10.3 mm, 28.0 %, 94 %.
    max_dormant : int
        Frames a lost point is kept dormant (after ``max_coast``) and searched again
        (:mod:`core.track_reacquire`): predicted from the rigid motion of its
        neighbours that moved with it, re-acquired from its key templates in
        ``reacquire_views`` or more cameras within ``reacquire_m`` of that prediction;
        the trajectory resumes with the same index and the gap is bridged from the
        predictions (:func:`bridge_gaps`, :attr:`Tracks.measured` False there).
        0 (default): never.  On walk_line3 (50 frames, with ``anchor``) 10 frames
        raised the frame-0 points through every frame from 35.8 to 37.3 % but the 95th
        percentile of the error from 36.9 to 39.4 mm (bridged point-frames: median
        13 mm); with ``reacquire_views=3, reacquire_m=0.006``: 36.4 %, 38.5 mm,
        bridged median 5.6 mm.  Without the rate test on the neighbours, wrong
        re-acquisitions on the crossing legs raised the 95th percentile to 100 mm.
        With the current defaults (``bench.tracking --no-compare --max-dormant 10``):
        measured in every frame 25.6 -> 26.9 %, through every frame with bridged gaps
        29.3 %, 95th percentile of the measured positions 9.67 -> 10.98 mm (bridged
        point-frames: median 5.5 mm, 95th 17.5 mm).
    reacquire_m : float
        Largest distance between a re-acquired point and its prediction, metres.
    reacquire_views : int
        Cameras in which a dormant point must be found again.
    depth_retry : bool
        A depth outlier (``depth_dev_m``) measured in three or more cameras is
        intersected again without each camera in turn, and kept where one subset passes
        the depth test and the gate (:func:`core.track_smooth.drop_one_camera`): a
        per-camera instead of a per-point rejection.  walk_line3 with ``max_coast=2``
        (50 frames): measured in every frame 25.0 -> 25.5 %, 95th percentile 10.30 ->
        10.13 mm; 15 frames without coasting: 32.8 -> 33.4 %, 9.20 -> 9.43 mm.
    occlusion_confirm : bool
        Cameras flagged by the occlusion test are matched all the same, but their
        temporal matches are accepted only where a spatial match confirms them (as
        ``confirm_rekey``) and they are not re-acquired there.  walk_line3, 15
        frames, ``max_coast=2``: this and ``depth_retry`` together raised the points
        measured in every frame from 34.6 to 35.9 % and the 95th percentile from 9.20
        to 9.90 mm (of the bridged point-frames from 21.7 to 109 mm).
    occlusion_dilate : bool
        Passed to :func:`core.track_occlusion.occluded` as ``dilate_all``.
    reacquire_checks : bool
        Dormant points are not searched in cameras where their prediction is occluded
        by the measured cloud (``occlusion_m``) and are not re-acquired as depth
        outliers (``depth_dev_m``; :func:`core.track_reacquire.dormant_step`).
    coast_neighbours : bool
        A coasting point (``max_coast``) is carried by the rigid motion of its measured
        neighbours (:func:`core.track_reacquire.predict_unmeasured`) instead of its own
        constant-velocity prediction: that starts the next frame's search, and bridges
        the gap when it is measured again (:func:`bridge_gaps`; else :func:`fill_gaps`).
    neighbour_radius_m : float
        Radius of the neighbours whose rigid motion carries coasting and dormant
        points, metres.
    coast_fallback : bool
        Where the neighbours give a coasting or dormant point no prediction, its own
        constant-velocity prediction stands in (it keeps a position to be predicted
        and searched from in the next frames) instead of the point being dropped.
    coast_confirm : bool
        The temporal matches of a coasting point are accepted only where a spatial
        match confirms them (as ``confirm_rekey``).
    coast_m : float, optional
        A coasting point is measured again only within this distance of its
        prediction, metres (None: the Mahalanobis ``gate`` alone).
    log : list, optional
        Receives one dict per frame step with the counts of (point, camera) pairs
        through each stage (``seen``, ``ncc_ok``, ``temporal_ok``, ``spatial_ok``,
        ``agree``) and of points (``live_before``, ``measured``, ``coasting``,
        ``gated``, ``regenerated``; ``lost_by_temporal``: points that stopped being
        measured in this step, by their number of temporal matches 0, 1, 2, 3+);
        ``reason`` (P,) int8: for each point measured at frame i and not at i+1 the
        step that lost it (:data:`core.track_diagnose.REASONS`), else -1; ``occ``
        (P, C) bool: the cameras the occlusion test skipped).

    Returns
    -------
    Tracks
    """
    if predict not in ("ekf", "linear"):
        raise ValueError(f"predict must be 'ekf' or 'linear', got {predict!r}")
    c = len(cameras)
    viewpoint = np.mean([cam.center for cam in cameras], axis=0)
    ref = surface.ref
    p0 = len(surface)
    uv_hist = [surface.uv.copy()]                    # measured, per frame (P, C, 2)
    xyz_hist = [surface.xyz.copy()]
    sig_hist = [np.sqrt(np.abs(np.diagonal(surface.cov, axis1=1, axis2=2)))]
    rate_hist = [np.zeros((p0, 3))]                  # filtered rates, m/frame
    start = np.zeros(p0, int)
    aff_sp = surface.affine.copy()                   # spatial affine ref -> camera
    kf = PointFilter.start(surface.xyz, surface.cov + COV_FLOOR, accel_sigma=accel_sigma)
    seen0 = np.all(np.isfinite(surface.uv), axis=2)
    last_f = np.where(seen0, 0, -1)                  # (P, C) last measured frame
    last_uv = surface.uv.copy()                      # (P, C, 2) there
    prev_uv = np.full_like(last_uv, np.nan)          # and in the frame before, if measured
    coast = np.zeros(p0, int)
    dead = np.zeros(p0, bool)                        # not tracked (lost or dormant)
    gone = np.zeros(p0, bool)                        # dropped for good
    pred_hist = [np.full((p0, 3), np.nan)]           # dormant points' predictions
    keys = KeyTemplates.start(surface.uv, 0)
    ring = {0: _stack(frames(0), cameras, 0)}
    for i in range(n_frames - 1):
        nxt = _stack(frames(i + 1), cameras, i + 1)
        ring[i + 1] = nxt
        needed = keys.frames() if anchor else set()
        for f in [f for f in ring if f < i - max_coast]:
            if f not in needed:
                del ring[f]
            elif f == i - max_coast - 1:                # drop the cached upsampled mosaic
                ring[f] = _Frame(ImageStack(ring[f].stack.images), ring[f].valid)
        n = len(kf)
        stage: dict = {"live_before": int((~dead & (coast == 0)).sum()),
                       "coasting_before": int((~dead & (coast > 0)).sum())}
        kf.predict()
        xyz_p, cov_p = kf.x[:, :3].copy(), kf.P[:, :3, :3].copy()
        proj = np.full((n, c, 2), np.nan)
        sig_p = np.full((n, c), np.nan)
        for j, cam in enumerate(cameras):
            proj[:, j], sig_p[:, j] = predict_in_image(cam, xyz_p, cov_p)
        age = i + 1 - last_f
        pairs = ~dead[:, None] & (last_f >= 0) & (age <= max_coast + 1) & nxt.valid[None]
        live = ~dead & (coast == 0)                  # measured at frame i
        pairs_pre = pairs.copy()
        occ = np.zeros((n, c), bool)
        if occlusion_m is not None:
            occ = occluded(cameras, np.where(dead[:, None], np.nan, xyz_p),
                           margin_m=occlusion_m, dilate_all=occlusion_dilate)
            if not occlusion_confirm:
                pairs &= ~occ
            stage["occluded"] = int(occ.sum())
        # --- temporal: NCC then LSM from each camera's last measurement into i+1 ---
        if predict == "ekf":
            pred = proj
            # a filter knows its point's velocity once the rate σ fell well below its
            # start (0.03 m/frame): until then the first, wide box is searched
            rate_sd = np.sqrt(np.max(np.diagonal(kf.P[:, 3:, 3:], axis1=1, axis2=2), axis=1))
            has_vel = np.broadcast_to((rate_sd < 0.015)[:, None], (n, c))
        else:
            lin = last_uv + age[..., None] * (last_uv - prev_uv)
            has_vel = np.all(np.isfinite(lin), axis=2)
            pred = np.where(has_vel[..., None], lin, last_uv)
        pairs &= np.all(np.isfinite(pred), axis=2)
        n_searchable = (pairs_pre & np.all(np.isfinite(pred), axis=2)).sum(axis=1)
        pi, ci = np.nonzero(pairs)
        uv_t = np.full((n, c, 2), np.nan)
        key_aff = np.full((n, c, 2, 2), np.nan)      # key -> i+1 where re-anchored
        key_ok = np.zeros((n, c), bool)
        rekey = np.zeros((n, c), bool)               # key match failed: appearance changed
        if len(pi):
            if predict == "ekf" and adaptive:
                rad = np.clip(np.ceil(3.0 * sig_p[pi, ci]) + 1, 3, max_radius).astype(int)
            else:
                rad = np.where(has_vel[pi, ci], ncc_radius, first_radius)
            lf = last_f[pi, ci]
            fr = np.unique(lf)
            tvalid = np.array([ring[f].valid[k] for f, k in zip(lf, ci, strict=True)])
            if len(fr) == 1 and fr[0] == i:
                tstack, tidx = ring[i].stack, ci
            else:
                tstack = ImageStack(np.concatenate([ring[f].stack.images for f in fr]))
                tidx = np.searchsorted(fr, lf) * c + ci
            st = pred[pi, ci].copy()
            ncc_ok = np.zeros(len(pi), bool)
            for r in np.unique(rad):
                k = np.flatnonzero(rad == r)
                nc = search(tstack, nxt.stack, last_uv[pi[k], ci[k]], pred[pi[k], ci[k]],
                            half=half, radius=int(r), template_index=tidx[k],
                            search_index=ci[k], min_score=0.6)
                st[k[nc.ok]] = nc.uv[nc.ok]
                ncc_ok[k] = nc.ok
            rt = match(tstack, nxt.stack, last_uv[pi, ci], st, half=half,
                       template_index=tidx, search_index=ci, max_shift_px=3.0,
                       weight_sigma=temporal_sigma, max_sigma_px=max_sigma_px)
            ok_t = rt.ok & nxt.valid[ci] & tvalid
            uv_t[pi[ok_t], ci[ok_t]] = rt.uv[ok_t]
            if anchor and ok_t.any():
                k = np.flatnonzero(ok_t)
                uv_a, aff_a, ok_a = reanchor(
                    keys, {f: ring[f].stack for f in keys.frames()}, nxt.stack, pi[k],
                    ci[k], rt.uv[k], rt.affine[k], half=half, max_px=anchor_px,
                    weight_sigma=temporal_sigma, max_sigma_px=max_sigma_px)
                uv_t[pi[k], ci[k]] = uv_a
                key_aff[pi[k], ci[k]] = aff_a
                key_ok[pi[k], ci[k]] = ok_a
                if confirm_rekey:
                    rekey[pi[k], ci[k]] = ~ok_a
                stage["anchored"] = int(ok_a.sum())
            stage.update(seen=len(pi), ncc_ok=int(ncc_ok.sum()), temporal_ok=int(ok_t.sum()),
                         temporal_status=np.bincount(rt.status, minlength=8).tolist(),
                         radius_mean=float(rad.mean()))
        # --- spatial LSM at i+1 from the reference camera (or the first temporal one) ---
        has_t = np.all(np.isfinite(uv_t), axis=2)
        if occlusion_confirm:            # matched, but accepted only where confirmed
            rekey |= occ & has_t
        if coast_confirm:                # a coasting point: its matches need confirmation
            rekey |= (~dead & (coast > 0))[:, None] & has_t
        # the spatial template: the reference camera's temporal match, else the first
        # camera's, preferring matches whose key held
        sure = has_t & ~rekey
        tcam = np.where(sure[:, ref], ref, np.where(sure.any(axis=1), np.argmax(sure, axis=1),
                        np.where(has_t[:, ref], ref, np.argmax(has_t, axis=1))))
        based = has_t[np.arange(n), tcam] & ~dead
        # Cameras without a temporal match start at the intersection of the temporal
        # matches (two or more) projected, or else at the predicted point projected.
        it_ = triangulate(cameras, uv_t, sigma_px=0.3)
        from_t = it_.ok & (it_.rms < max_rms_px)
        xyz_s = np.where(from_t[:, None], it_.xyz, xyz_p)
        proj_s = np.stack([cam.project(xyz_s) for cam in cameras], axis=1)
        start_s = np.where(has_t[..., None], uv_t, proj_s)
        qi, qc = np.nonzero(based[:, None] & (np.arange(c)[None] != tcam[:, None])
                            & np.all(np.isfinite(start_s), axis=2) & nxt.valid[None]
                            & ~(occ & ~has_t))
        uv_acc = np.full((n, c, 2), np.nan)
        uv_acc[based, tcam[based]] = uv_t[based, tcam[based]]
        uv_tonly = uv_acc.copy()
        if len(qi) and reacquire_radius:
            # re-acquisitions started at the predicted point: NCC in a box around it
            k = np.flatnonzero(~has_t[qi, qc] & ~from_t[qi])
            if len(k):
                r_k = np.clip(np.ceil(3.0 * sig_p[qi[k], qc[k]]) + 1, 3, reacquire_radius)
                r_k = np.where(np.isfinite(r_k), r_k, reacquire_radius).astype(int)
                for r in np.unique(r_k):
                    kk = k[r_k == r]
                    nc = search(nxt.stack, nxt.stack, uv_t[qi[kk], tcam[qi[kk]]],
                                start_s[qi[kk], qc[kk]], half=half, radius=int(r),
                                template_index=tcam[qi[kk]], search_index=qc[kk],
                                min_score=0.7)
                    start_s[qi[kk[nc.ok]], qc[kk[nc.ok]]] = nc.uv[nc.ok]
        if len(qi):
            tc = tcam[qi]
            aff0 = np.where((tc == ref)[:, None, None], aff_sp[qi, qc], np.eye(2))
            rs = match(nxt.stack, nxt.stack, uv_t[qi, tc], start_s[qi, qc], half=half,
                       affine=aff0, template_index=tc, search_index=qc, max_shift_px=3.0,
                       max_sigma_px=spatial_sigma_px)
            d = np.linalg.norm(rs.uv - uv_t[qi, qc], axis=1)
            # A temporal match is vetoed only by a spatial match that converged elsewhere;
            # a failed spatial match (occlusion edge, weak texture in that view) leaves
            # the check to the forward intersection.  Re-acquisitions need the spatial.
            ht = has_t[qi, qc]
            agree = np.where(ht, ~rs.ok | (d < agree_px), rs.ok)
            agree &= ~rekey[qi, qc] | (rs.ok & (d < agree_px))
            use_uv = np.where(ht[:, None], uv_t[qi, qc], rs.uv)
            uv_acc[qi[agree], qc[agree]] = use_uv[agree]
            kt = agree & ht
            uv_tonly[qi[kt], qc[kt]] = use_uv[kt]
            stage.update(spatial_ok=int(rs.ok.sum()), agree=int(agree.sum()),
                         reacquired=int((agree & ~ht).sum()))
            upd = agree & (tc == ref) & rs.ok
            aff_sp[qi[upd], qc[upd]] = rs.affine[upd]
        # --- forward intersection, gated against the prediction ---
        uv_new = np.full((n, c, 2), np.nan)
        xyz_new = np.full((n, 3), np.nan)
        cov_new = np.full((n, 3, 3), np.nan)
        chosen = np.zeros(n, bool)
        n_gated = 0
        was_coasting = ~dead & (coast > 0)           # coasting into this frame
        uv_tsure = np.where((based[:, None] & (~rekey | np.all(np.isfinite(uv_acc), axis=2)))
                            [..., None], uv_t, np.nan)
        cands = (uv_acc, uv_tonly) + ((uv_tsure,) if fallback else ())
        any_two = np.zeros(n, bool)
        any_rms = np.zeros(n, bool)
        for cand in cands:
            inter = triangulate(cameras, cand, sigma_px=0.3)
            m2 = kf.mahalanobis2(inter.xyz, inter.cov + COV_FLOOR)
            two = np.sum(np.isfinite(cand[..., 0]), 1) >= 2
            any_two |= two
            any_rms |= two & inter.ok & (inter.rms < max_rms_px)
            ok = (~chosen & ~dead & inter.ok & (inter.rms < max_rms_px) & two)
            near = m2 < gate ** 2
            if coast_m is not None:                  # a coasting point: near its prediction
                dist = np.linalg.norm(inter.xyz - xyz_p, axis=1)
                near &= ~was_coasting | (np.nan_to_num(dist, nan=np.inf) < coast_m)
            n_gated += int((ok & ~near).sum())
            ok &= near
            uv_new[ok], xyz_new[ok], cov_new[ok] = cand[ok], inter.xyz[ok], inter.cov[ok]
            chosen |= ok
        out = np.zeros(n, bool)
        if depth_dev_m is not None:
            out = chosen & depth_outliers(np.where(chosen[:, None], xyz_new, np.nan),
                                          viewpoint, depth_dev_m)
            if log is not None:
                stage["depth_rejected"] = np.where(out[:, None], xyz_new, np.nan)
            uv_out = uv_new[out]
            uv_new[out], xyz_new[out], cov_new[out] = np.nan, np.nan, np.nan
            chosen &= ~out
            if depth_retry and out.any():
                r = np.flatnonzero(out)
                uv_r, xyz_r, cov_r, ok_r = drop_one_camera(
                    cameras, uv_out, viewpoint, xyz_new[chosen], depth_dev_m,
                    max_rms_px=max_rms_px)
                z = np.full((n, 3), np.nan)
                zc = np.full((n, 3, 3), np.nan)
                z[r], zc[r] = xyz_r, cov_r
                ok_r &= kf.mahalanobis2(z, zc + COV_FLOOR)[r] < gate ** 2
                r = r[ok_r]
                uv_new[r], xyz_new[r], cov_new[r] = uv_r[ok_r], xyz_r[ok_r], cov_r[ok_r]
                chosen[r], out[r] = True, False
                stage["depth_retried"] = len(r)
            stage["depth_outliers"] = int(out.sum())
        if log is not None:
            unconf = rekey & has_t & ~np.all(np.isfinite(uv_acc), axis=2)
            stage["reason"] = loss_reasons(
                live & ~chosen, n_searchable, pairs.sum(axis=1), has_t.sum(axis=1),
                unconf.sum(axis=1), any_rms, any_two, out)
            stage["occ"] = occ.copy()
        rows = np.flatnonzero(chosen)
        kf.update(xyz_new[rows], cov_new[rows] + COV_FLOOR, rows)
        coast = np.where(chosen, 0, coast + 1)
        dead |= coast > max_coast
        gone |= dead & (coast > max_coast + max_dormant)
        pred_d = np.full((n, 3), np.nan)
        back = was_coasting & chosen                 # the prediction it was measured at
        pred_d[back] = xyz_p[back]                   # (closes the bridge of its gap)
        rstats: dict = {}
        stage["reacquire_stats"] = rstats
        coasting = ~dead & ~chosen
        if coast_neighbours and coasting.any() and chosen.any():
            # coasting points: carried by their neighbours' rigid motion (also the
            # start of next frame's search, and the bridge of the gap afterwards)
            pc = predict_unmeasured(coasting, xyz_hist, pred_hist, rate_hist[-1], xyz_new,
                                    chosen, radius_m=neighbour_radius_m)
            r = np.flatnonzero(np.all(np.isfinite(pc), axis=1))
            before = np.where(np.isfinite(xyz_hist[-1][r]), xyz_hist[-1][r], pred_hist[-1][r])
            kf.x[r, 3:] = np.where(np.isfinite(before), pc[r] - before, kf.x[r, 3:])
            kf.x[r, :3] = pc[r]
            pred_d[r] = pc[r]
            stage["coast_predicted"] = len(r)
            if coast_fallback:                       # else the filter's own prediction
                pred_d[coasting & ~np.all(np.isfinite(pc), axis=1)] = kf.x[
                    coasting & ~np.all(np.isfinite(pc), axis=1), :3]
        if max_dormant and chosen.any() and (dead & ~gone).any():
            dorm = dead & ~gone
            pred_dm, rd = dormant_step(
                dorm, xyz_hist, pred_hist, rate_hist[-1], xyz_new, chosen, kf, keys,
                {f: ring[f].stack for f in keys.frames()}, nxt.stack, nxt.valid, cameras,
                half=half, weight_sigma=temporal_sigma, max_sigma_px=max_sigma_px,
                max_rms_px=max_rms_px, max_dist_m=reacquire_m, min_views=reacquire_views,
                occlusion_m=occlusion_m if reacquire_checks else None,
                depth_dev_m=depth_dev_m if reacquire_checks else None,
                radius_m=neighbour_radius_m,
                fallback=kf.x[:, :3] if coast_fallback else None, stats=rstats)
            if len(rd.rows):
                r = rd.rows
                uv_new[r], xyz_new[r], cov_new[r] = rd.uv, rd.xyz, rd.cov
                key_ok[r] = np.all(np.isfinite(rd.uv), axis=2)
                key_aff[r] = rd.affine
                chosen[r], dead[r], coast[r] = True, False, 0
            pred_d = np.where(dorm[:, None], pred_dm, pred_d)
            gone |= dead & ~np.all(np.isfinite(pred_d), axis=1)     # no prediction
            stage.update(dormant=int((dead & ~gone).sum()) + len(rd.rows),
                         reacquired_dormant=len(rd.rows))
        keys.f[gone] = -1                            # their key frames may be released
        got = np.all(np.isfinite(uv_new), axis=2)
        keys.affine[got & key_ok] = key_aff[got & key_ok]
        gp, gc = np.nonzero(got & ~key_ok)
        keys.reset(gp, gc, uv_new[gp, gc], i + 1)
        prev_uv = np.where((got & (last_f == i))[..., None], last_uv,
                           np.where(got[..., None], np.nan, prev_uv))
        last_uv = np.where(got[..., None], uv_new, last_uv)
        last_f = np.where(got, i + 1, last_f)
        lost_now = ~chosen & (coast == 1)
        n_t = has_t.sum(axis=1)
        stage.update(measured=int(chosen.sum()), gated=n_gated,
                     coasting=int((~dead & ~chosen).sum()),
                     lost_by_temporal=np.bincount(np.minimum(n_t[lost_now], 3),
                                                  minlength=4).tolist())
        uv_hist.append(uv_new)
        xyz_hist.append(xyz_new)
        sig_hist.append(np.sqrt(np.abs(np.diagonal(cov_new, axis1=1, axis2=2))))
        rate_hist.append(np.where(chosen[:, None], kf.x[:, 3:], np.nan))
        pred_hist.append(pred_d)
        # --- regenerate lost points and seed newly visible surface ---
        if regen_every and (i + 1) % regen_every == 0 and chosen.any() and nxt.valid.all():
            occ = np.concatenate([uv_new[chosen, ref], proj[~dead & ~chosen, ref]])
            seeds = uv_new[chosen][:: max(1, int(chosen.sum()) // 20)]
            seeds = seeds[np.all(np.isfinite(seeds[:, ref]), axis=1)]
            new = (measure_surface(nxt.stack, cameras, seeds, ref=ref, step=step, half=half,
                                   occupied_uv=occ, max_sigma_px=spatial_sigma_px,
                                   max_depth_dev_m=depth_dev_m)
                   if len(seeds) else None)
            if new is not None and len(new):
                k = len(new)
                uv_hist = [_pad(u, k) for u in uv_hist]
                xyz_hist = [_pad(x, k) for x in xyz_hist]
                sig_hist = [_pad(s, k) for s in sig_hist]
                rate_hist = [_pad(s, k) for s in rate_hist]
                pred_hist = [_pad(s, k) for s in pred_hist]
                uv_hist[-1][-k:] = new.uv
                xyz_hist[-1][-k:] = new.xyz
                sig_hist[-1][-k:] = np.sqrt(np.abs(np.diagonal(new.cov, axis1=1, axis2=2)))
                rate0, rsig = neighbour_rates(xyz_new[chosen], kf.x[chosen, 3:], new.xyz)
                rate_hist[-1][-k:] = rate0
                kf.append(PointFilter.start(new.xyz, new.cov + COV_FLOOR, rate0, rsig))
                start = np.concatenate([start, np.full(k, i + 1)])
                aff_sp = np.concatenate([aff_sp, new.affine])
                keys.append(KeyTemplates.start(new.uv, i + 1))
                seen_n = np.all(np.isfinite(new.uv), axis=2)
                last_f = np.concatenate([last_f, np.where(seen_n, i + 1, -1)])
                last_uv = np.concatenate([last_uv, new.uv])
                prev_uv = np.concatenate([prev_uv, np.full_like(new.uv, np.nan)])
                coast = np.concatenate([coast, np.zeros(k, int)])
                dead = np.concatenate([dead, np.zeros(k, bool)])
                gone = np.concatenate([gone, np.zeros(k, bool)])
                stage["regenerated"] = k
        if log is not None:
            log.append(stage)
        if progress is not None:
            progress.update(i + 1, n_frames - 1,
                            f"tracking: frame {i + 1}, {int(chosen.sum())} points")
    xyz = np.stack(xyz_hist)
    measured = np.all(np.isfinite(xyz), axis=2)
    filled = fill_gaps(xyz, np.stack(rate_hist), max_coast)
    bridged = bridge_gaps(xyz, np.stack(pred_hist))
    filled = np.where(np.isfinite(bridged), bridged, filled)
    return Tracks(xyz=filled, uv=np.stack(uv_hist), sigma_xyz=np.stack(sig_hist),
                  start=start, fps=float(fps), measured=measured)


def _pad(a: np.ndarray, k: int) -> np.ndarray:
    return np.concatenate([a, np.full((k,) + a.shape[1:], np.nan)])


@dataclass
class _Frame:
    stack: ImageStack
    valid: np.ndarray     # (C,) bool: the camera has an image in this frame


def _stack(images, cameras: list[Camera], i: int) -> _Frame:
    valid = np.array([im is not None for im in images])
    if len(images) != len(cameras):
        raise ValueError(f"frame {i}: {len(images)} images for {len(cameras)} cameras")
    if not valid.any():
        raise ValueError(f"frame {i}: no camera has an image")
    shape = next(im for im in images if im is not None).shape
    ims = [im if im is not None else np.zeros(shape, np.uint8) for im in images]
    return _Frame(ImageStack(ims), valid)
