"""Spatial + temporal LSM tracking of surface points, trajectory filters, regeneration.

Per frame i -> i+1 (D'Apuzzo et al. 1999, section 2.4), for all live points and
cameras at once (the steps of :mod:`core.track_step` and :mod:`core.track_measure`,
on the per-point state of :mod:`core.track_state`; the options are
:class:`core.track_settings.TrackSettings`):

1. :func:`~core.track_step.predict`: every point carries a constant-velocity Kalman
   filter in 3-D (:class:`PointFilter`); its prediction is projected into every
   camera, and the projected covariance sets the NCC search box (``predict="ekf"``,
   default).  The paper's 2-D linear prediction ``uv_i + (uv_i - uv_{i-1})`` with a
   fixed box is kept as ``predict="linear"``.  Cameras in which the prediction lies
   behind the other live points' predicted surface (``occlusion_m``,
   :mod:`core.track_occlusion`) are skipped for the point;
2. :func:`~core.track_step.temporal`: NCC search in the box (template: the camera's
   last measurement of the point), then temporal LSM from that frame (usually i) to
   frame i+1, started at the NCC peak, then matched again from the point's key
   template (``anchor``, :mod:`core.track_anchor`: the patch where it was first
   measured in that camera, with the composed temporal affines) so that
   frame-to-frame drift does not build up; where the key match fails, the temporal
   match needs the spatial match's confirmation (``confirm_rekey``) before it becomes
   the new key;
3. :func:`~core.track_step.spatial`: spatial LSM at frame i+1 from the reference camera
   into the others, started at the temporal results (or, where a camera lost the
   point, at the projection of the intersection of the temporal matches, or of the
   predicted point: that camera is re-acquired).  A camera's temporal match is
   accepted unless the spatial match converged more than ``agree_px`` away from it (a
   failed spatial match does not veto: the forward intersection checks the
   geometry); a camera without a temporal match is re-acquired where the spatial
   match exists;
4. :func:`~core.track_measure.intersect`: the point is measured when two or more cameras
   are accepted, the forward intersection reprojects within ``max_rms_px`` and lies
   within ``gate`` (Mahalanobis) of the prediction; failing that, the temporal
   matches alone are tried (``fallback``, which also overrides a spatial veto);
5. :func:`~core.track_measure.depth_test`: a point whose depth departs from its measured
   neighbours' median (``depth_dev_m``, :mod:`core.track_smooth`) is not measured;
6. :func:`~core.track_measure.carry_coasting`: an unmeasured point coasts for up to
   ``max_coast`` frames, carried by the rigid motion of its measured neighbours
   (``coast_neighbours``, :func:`core.track_reacquire.predict_unmeasured`), and is
   searched from its last templates; measured again (within ``coast_m`` of the
   prediction), it continues its trajectory and the gap is bridged from the
   predictions (:func:`bridge_gaps`, else :func:`fill_gaps`; ``Tracks.measured`` is
   False there).  ``log`` says which step lost each point (:mod:`core.track_diagnose`);
7. :func:`~core.track_measure.reacquire_dormant`: a lost point stays dormant for up to
   ``max_dormant`` frames (:mod:`core.track_reacquire`): predicted from the rigid
   motion of its measured neighbours and searched with its key templates; when found
   in two or more cameras near its prediction it resumes the same trajectory, and the
   gap is bridged from the predictions (:func:`bridge_gaps`, not ``measured``).

Beyond the paper, every ``regen_every`` frames (:func:`~core.track_measure.regenerate`)
the surface is grown again from the live points (:func:`core.surface.measure_surface`)
over grid cells that no live point covers: lost points are regenerated and newly
visible surface is seeded; with ``jump_seeds`` (the default; ``core track
--no-jump-seeds``) also surface that growth cannot reach across a depth jump — a limb
beside or behind the trunk — by a depth search along the epipolar lines
(:mod:`core.surface_seed`).

:func:`filter_trajectories` (:mod:`core.track_trajectories`) applies the paper's
filters afterwards; the point filters live in :mod:`core.track_filter`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .camera import Camera
from .surface import Surface
from .track_diagnose import loss_reasons
from .track_filter import PointFilter, predict_in_image
from .track_measure import (
    Measurement,
    carry_coasting,
    depth_test,
    intersect,
    reacquire_dormant,
    regenerate,
    update_points,
)
from .track_settings import TrackSettings
from .track_state import TrackerState, load_frame
from .track_step import Matches, Prediction, predict, spatial, temporal
from .track_trajectories import (
    FilterResult,
    bridge_gaps,
    derivative,
    fill_gaps,
    filter_trajectories,
)

__all__ = [
    "FilterResult",
    "PointFilter",
    "TrackSettings",
    "Tracks",
    "fill_gaps",
    "filter_trajectories",
    "predict_in_image",
    "track",
]


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
        a[1:-1] = (self.xyz[2:] - 2 * self.xyz[1:-1] + self.xyz[:-2]) * self.fps**2
        return a


def track(
    frames,
    cameras: list[Camera],
    surface: Surface,
    n_frames: int,
    fps: float,
    *,
    settings: TrackSettings | None = None,
    progress=None,
    log: list | None = None,
    **options,
) -> Tracks:
    """Track the surface points through ``n_frames`` frames.

    Parameters
    ----------
    frames : callable ``frames(i) -> list of C grey images``
        Images of frame i in camera order; a camera whose image is missing may give
        ``None`` (its points are then not matched there in that frame).
    cameras : list of Camera, length C
    surface : Surface
        Points measured at frame 0 (:func:`core.surface.measure_surface`).
    n_frames : int
        Frames to track, from frame 0.
    fps : float
        Frame rate, frames per second (of :class:`Tracks`).
    settings : TrackSettings, optional
        The options (default: the defaults).
    progress : core.progress.Progress, optional
    log : list, optional
        Receives one dict per frame step with the counts of (point, camera) pairs
        through each stage (``seen``, ``ncc_ok``, ``temporal_ok``, ``spatial_ok``,
        ``agree``) and of points (``live_before``, ``measured``, ``coasting``,
        ``gated``, ``regenerated``; ``lost_by_temporal``: points that stopped being
        measured in this step, by their number of temporal matches 0, 1, 2, 3+);
        ``reason`` (P,) int8: for each point measured at frame i and not at i+1 the
        step that lost it (:data:`core.track_diagnose.REASONS`), else -1; ``occ``
        (P, C) bool: the cameras the occlusion test skipped).
    **options
        Any attribute of :class:`TrackSettings` (``half``, ``predict``, ``max_coast``,
        ``regen_every``, ``step``, ...), replacing its value in ``settings``.

    Returns
    -------
    Tracks
    """
    s = TrackSettings.of(settings, **options)
    st = TrackerState.begin(surface, cameras, load_frame(frames(0), cameras, 0), s.accel_sigma)
    for i in range(n_frames - 1):
        nxt = load_frame(frames(i + 1), cameras, i + 1)
        st.add_frame(nxt, i + 1, s.max_coast, s.anchor)
        stage: dict = {
            "live_before": int((~st.dead & (st.coast == 0)).sum()),
            "coasting_before": int((~st.dead & (st.coast > 0)).sum()),
        }
        pr = predict(st, nxt, i, s, stage)
        m = temporal(st, nxt, pr, i, s, stage)
        spatial(st, nxt, pr, m, s, stage)
        ms = intersect(st, pr, m, s)
        depth_test(st, ms, s, stage, diagnose=log is not None)
        if log is not None:
            _diagnose(pr, m, ms, stage)
        update_points(st, ms, s)
        pred_d = carry_coasting(st, pr, ms, s, stage)
        pred_d = reacquire_dormant(st, nxt, m, ms, pred_d, s, stage)
        st.record(i + 1, ms.uv, ms.xyz, ms.cov, ms.chosen, m.key_ok, m.key_aff, pred_d)
        lost_now = ~ms.chosen & (st.coast == 1)
        stage.update(
            measured=int(ms.chosen.sum()),
            gated=ms.n_gated,
            coasting=int((~st.dead & ~ms.chosen).sum()),
            lost_by_temporal=np.bincount(
                np.minimum(m.has_t.sum(axis=1)[lost_now], 3), minlength=4
            ).tolist(),
        )
        regenerate(st, nxt, pr, ms, i, s, stage)
        if log is not None:
            log.append(stage)
        if progress is not None:
            progress.update(
                i + 1, n_frames - 1, f"tracking: frame {i + 1}, {int(ms.chosen.sum())} points"
            )
    xyz = np.stack(st.xyz_hist)
    filled = fill_gaps(xyz, np.stack(st.rate_hist), s.max_coast)
    bridged = bridge_gaps(xyz, np.stack(st.pred_hist))
    return Tracks(
        xyz=np.where(np.isfinite(bridged), bridged, filled),
        uv=np.stack(st.uv_hist),
        sigma_xyz=np.stack(st.sig_hist),
        start=st.start,
        fps=float(fps),
        measured=np.all(np.isfinite(xyz), axis=2),
    )


def _diagnose(pr: Prediction, m: Matches, ms: Measurement, stage: dict) -> None:
    """``stage["reason"]``: the step that lost each point (:func:`loss_reasons`), and
    ``stage["occ"]``."""
    unconf = m.rekey & m.has_t & ~np.all(np.isfinite(m.uv_acc), axis=2)
    stage["reason"] = loss_reasons(
        pr.live & ~ms.chosen,
        pr.n_searchable,
        pr.pairs.sum(axis=1),
        m.has_t.sum(axis=1),
        unconf.sum(axis=1),
        ms.any_rms,
        ms.any_two,
        ms.depth_out,
    )
    stage["occ"] = pr.occ.copy()
