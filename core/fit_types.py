"""The sequence fit's inputs, settings and results (:func:`core.fit.fit_sequence`).

:class:`FramePoints` — one frame's 3-D surface observations; :class:`SequenceSettings`
— the fit's settings; :class:`ShapeRecord` — the whole-body shape fit's record;
:class:`SequenceResult` — the fitted state with per-frame diagnostics;
:func:`frame_observations` — a frame's points as the per-frame fit's observations.
World frame: Z up, metres; angles in radians.  All are re-exported by :mod:`core.fit`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .fitting import FitSettings, Observations
from .shape_fit import ShapeSettings
from .state import FitState


@dataclass
class FramePoints:
    """One frame's 3-D observations.

    Attributes
    ----------
    xyz : (N, 3) world points, metres
    sigma : (N,) a-priori σ of each point, metres
    ids : (N,) int trajectory ids, or None
    views : (N, C) bool — which of the scene's C cameras measured each point, or None
        (their lines of sight are free of body, :mod:`core.free_space`)
    """

    xyz: np.ndarray
    sigma: np.ndarray
    ids: np.ndarray | None = None
    views: np.ndarray | None = None

    def __post_init__(self):
        self.xyz = np.asarray(self.xyz, float).reshape(-1, 3)
        self.sigma = np.broadcast_to(np.asarray(self.sigma, float), (len(self.xyz),)).copy()
        good = np.all(np.isfinite(self.xyz), axis=1) & np.isfinite(self.sigma)
        good &= self.sigma > 0
        if not good.all():
            self.xyz, self.sigma = self.xyz[good], self.sigma[good]
            if self.ids is not None:
                self.ids = np.asarray(self.ids)[good]
            if self.views is not None:
                self.views = np.asarray(self.views, bool)[good]


@dataclass
class SequenceSettings:
    """Settings of :func:`fit_sequence` (lengths in metres, angles in radians)."""

    shape_frames: int = 2
    #: sweeps of the shape frames' solve, each from the last one's shape and anchored
    #: to it.  2 on make demo's walk, runs 0-3: 12.9 / 16.1 / 12.7 / 15.1 -> 9.9 / 13.9 /
    #: 15.6 / 15.0 mm (median 14.0 -> 14.4): left at 1 (docs/design.md, "The late shape")
    shape_sweeps: int = 1
    predictor: str = "ekf"  # or "constant_velocity"
    damping: float = 0.8  # rate decay per frame of the prediction
    sigma_pred: float = 0.15  # floor of the prior σ on each predicted angle
    sigma_pred_max: float = 0.6
    accel_sigma: float = 0.05  # EKF process noise, rad (or m) per frame²
    #: a frame without points (contours alone) is also fitted from the previous
    #: frame's pose and from its undamped extrapolation; such a fit replaces the one
    #: from the prediction where its body disagrees with the foreground at a share
    #: ``contour_start_margin`` fewer pixels (:meth:`core.fit_frame.FrameFitter.
    #: fit_frame`): the damped prediction lags a fast limb, and on dance_ortho3 took
    #: the crossing legs for each other (docs/design.md, "Three starts for a frame
    #: fitted from contours alone"; a margin of 0.05 lost that dance again)
    contour_starts: bool = True
    #: a take the silhouettes shaped (no 3-D points at the clicked frame) and that
    #: follows the texture flow is fitted twice, with Lucas–Kanade's corners and with
    #: corners refined by least squares matching (``FlowSettings.refine_lsm``); the fit
    #: whose body disagrees with the foregrounds at fewer pixels over the take is kept
    #: (:mod:`core.fit_choice`).  Twice the fit time there.  ``bench.fit_spread``, four
    #: click draws, median MPJPE: dance_ortho3 26.25 -> 25.05 mm, pirouette_ortho3
    #: 23.35 -> 22.8, walk_ortho3 11.15 -> 10.35, jumps_ortho3 10.7 (the first fit kept);
    #: no draw loses a limb, which the refined fit alone does in two of the dance's
    #: (docs/design.md, "Two fits of a take, the foregrounds choose")
    flow_choice: bool = True
    contour_start_margin: float = 0.0
    #: the hips' rest offsets keep their forward part from the clicked pelvis
    #: (:func:`core.fit_init.initialise`): jumps_line3 draws 0-3 14.5 -> 13.4 mm median,
    #: make demo's walk 12.3 -> 14.4, dance_ortho3 run 0 24.2 -> 108.5 (docs/design.md,
    #: "The hips in front of the pelvis")
    hip_lean: bool = False
    shape_scales: bool = False  # bone scales refitted to the points (else: the clicks')
    shape_centers: bool = True  # metaball centres free in the shape solve
    shape_sigma_radius: float = 0.02  # shape priors towards the template, metres
    shape_sigma_center: float = 0.01
    min_part_points: int = 8  # a part with fewer points is hidden: ...
    sigma_hidden: float = 0.05  # ... its DOFs follow the prior with this σ (rad), ...
    sigma_hidden_anchor: float = 0.15  # ... and drift back to the clicked posture; ...
    hold_hidden: bool = True  # ... held at the previous frame's angles (else following
    #                           the damped prediction); fed back to the filter only
    sigma_hidden_meas: float = 0.3  # ... as a measurement of this σ (rad): its σ grows
    #: afterwards, angles whose every part is hidden are interpolated across the gap
    #: between two observed frames (:mod:`core.fit_bridge`)
    bridge_hidden: bool = True
    #: before that, a limb's unobserved angles predicted from the opposite thigh's swing
    #: where that thigh explains ≥ ``couple_r2`` of an angle's variance over the frames
    #: the limb was observed (:mod:`core.fit_coupling`); what it leaves is bridged
    couple_hidden: bool = True
    couple_r2: float = 0.5
    #: ... and only over stretches where the thigh's swing stays within the range it
    #: spans on those frames, widened by this share of it each side (None: no limit) —
    #: the line is not extrapolated (an arm seen in one half of its swing)
    couple_reach: float | None = 0.25
    #: then an arm whose parts are hidden takes the other arm's angles, mirrored, where
    #: the legs move mirrored (a jump, a squat) over the stretch: their mirror image
    #: explains ≥ ``mirror_r2`` of their sagittal variance (:mod:`core.fit_mirror`)
    mirror_hidden: bool = True
    mirror_r2: float = 0.8
    #: a seen forearm or hand below a mirrored upper arm keeps the place its points gave
    #: it (:mod:`core.fit_reattach`): jumps_line3 run 0 15.14 → 14.72 mm
    mirror_keep_seen: bool = True
    #: last, the unobserved angles nothing replaced (a stretch running to the first or
    #: last frame) take their running median over this many frames: no observation
    #: decides them and they flicker (:mod:`core.fit_smooth`; 1: off)
    smooth_held_frames: int = 7
    #: in a walk (the thighs swing against each other), a hidden arm that nothing above
    #: placed swings with the opposite thigh, ``gait_arm_ratio`` degrees per degree,
    #: from the literature's arm and hip excursions (:mod:`core.fit_gait`)
    gait_arms: bool = True
    gait_arm_ratio: float = 0.7
    #: last, after the shapes, a hidden arm whose forearm or hand lies
    #: inside the trunk (the trunk's field above ``clear_level`` at one of their metaball
    #: centres; 0.5 is its surface) is moved out by the least change of its unobserved
    #: angles, and with ``clear_silhouettes`` (and contours) one whose metaballs project
    #: outside a camera's foreground is moved into it (:mod:`core.fit_clearance`)
    clear_trunk: bool = True
    clear_level: float = 0.3
    clear_silhouettes: bool = True
    #: at the end, the motion smoothed over the take where it is seen too: each joint's
    #: path by a Kalman smoother whose smoothness that path's likelihood chooses, then
    #: the angles solved to it (:func:`core.motion_smoother.smooth_joints`).  Over 4
    #: click sets (``bench.fit_spread``'s), MPJPE / acceleration error medians: make
    #: demo's walk 13.51 / 4.06 → 13.34 mm / 2.90 mm per frame², jumps_line3 14.86 /
    #: 5.36 → 14.67 / 3.49, walk_ortho3 13.14 / 5.73 → 12.93 / 3.36 (every fit gains);
    #: dance_line3 run 0 199.9 → 200.1 mm, dance_ortho3 137.3 → 136.4 (docs/design.md,
    #: "The jitter").  Off: a kick that is a step — a thigh turned 0.7 rad between two
    #: frames, ``tests/core/test_fit_recovery.py`` — is spread over its neighbours (the
    #: ankle 93 mm off at the kick instead of < 40 mm); one smoothness for every angle
    #: did worse (130 mm there, and less gain elsewhere)
    smooth_motion: bool = False
    #: without ``smooth_motion``, the same smoother's values for the angles no
    #: observation decided only (:func:`core.fit_bridge.unobserved`: the coupled,
    #: mirrored, bridged, swung and held ones, whose jitter is most of the fit's — the
    #: walk's hidden right wrist 13.4 mm/frame² against 0.8–4.2 for the seen joints);
    #: a seen limb's kick is left as it was.  Over the same 4 click sets, MPJPE /
    #: acceleration error medians: make demo's walk 13.51 / 4.06 → 13.40 / 3.62,
    #: jumps_line3 14.86 / 5.36 → 14.82 / 4.56, walk_ortho3 13.14 / 5.73 → 13.12 / 5.68;
    #: dance_line3 run 0 199.9 → 199.6 mm (docs/design.md, "The jitter")
    smooth_unobserved: bool = True
    #: σ (rad) of the difference between neighbouring spine links' changes from the
    #: clicked posture (:mod:`core.fit_chain`); None: no such prior (0.1 narrows the
    #: walk's spread over click sets but loses the dance)
    sigma_trunk_chain: float | None = None
    sigma_click: float = 0.003  # σ of a forward-intersected click, metres
    #: turn each foot about its shin at the clicked frame to the heading of the points
    #: round it (:mod:`core.foot_heading`; the clicks alone leave the template's turn).
    #: make demo's walk over 4 click sets: right shin 17.0 / 35.9 / 9.8 / 12.6 → 2.7 /
    #: 4.9 / 3.9 / 4.9°, but the left 2.0 / 9.7 / 13.3 / 11.9 → 8.3 / 5.2 / 10.7 / 10.9°
    #: and MPJPE median 12.7 → 13.5 mm (the ankles 8 / 9 → 8 / 12 mm): off
    foot_heading: bool = False
    segment_max_dist: float = 0.04
    segment_margin: float = 0.015  # ambiguous points between non-adjacent parts dropped
    #: label the points with the initial shape's radii (the clicked posture's body, as
    #: the paper segments) at the fitted centres, not with the per-part shape solve's,
    #: which can grow a part over its neighbour and hand it the neighbour's points.
    #: make demo's walk over 4 click sets: MPJPE median 16.5 → 14.7 mm (13.7 with the
    #: silhouette search's veto slack, :func:`core.fit_search.keeps_points`), the head
    #: 4–16 → 4–10 mm; jumps_line3 15.0 → 15.3, walk_ortho3 14.2 → 14.2; dance_line3's
    #: median 135.1 → 108.7 mm (141.6 with the slack; 44 → 64 → 89 of 200 frames
    #: diverged) — the dance reshuffles its draws with any change (design.md)
    segment_initial_radii: bool = True
    min_points: int = 40
    max_rmse_m: float = 0.025
    min_inliers: float = 0.5
    inlier_m: float = 0.02
    resegment: bool = True
    #: tracked trajectories as rigid-motion observations (:mod:`core.fit_trajectory`):
    #: a point tracked since the previous fitted frame stays fixed in its part's frame,
    #: σ its two positions' and ``traj_slip_m`` (skin and cloth) in quadrature, Cauchy
    #: knee ``traj_robust`` σ
    trajectories: bool = True
    traj_slip_m: float = 0.004
    traj_robust: float = 3.0
    search: bool = True  # annealed retry with the limb search (core.fit_search)
    search_tau: float = 0.05  # truncation of the search's point distances, metres
    search_min_gain: float = 100.0  # explain-cost decrease that moves a limb
    #: the annealed retry also starts from the prediction moved across the floor with
    #: the points since the last fitted frame (core.fit_search.recentred_starts): a body
    #: lost for some frames is found again where the person went meanwhile
    recentre: bool = True
    #: the search and the frame's explain cost also count body in a point's line of sight
    #: to the cameras that measured it (core.free_space; needs the points' views and the
    #: cameras)
    free_space: bool = True
    #: contours alone: limbs re-placed where they explain the foreground best, then the
    #: frame refitted; a failed frame refitted with the root re-centred on the foreground
    #: (core.silhouette_search)
    silhouette_search: bool = True
    #: with contours, in frames with points too: after the point-based fit (and its limb
    #: search), the silhouette limb search, its refit kept on the same terms, a limb's
    #: move vetoed where the frame's points would be explained worse
    #: (core.fit_search.keeps_points): a limb the tracker lost (a dance kick).
    #: dance_line3 (cues both) 264.2 mm over 21 accepted frames, 29 diverged -> 76.0 mm
    #: over 36, 14 diverged; make demo 11.6 -> 11.7, jumps_line3 14.0 -> 14.7 mm
    silhouette_search_points: bool = True
    #: with contours, in frames with points: the limb search's refit (core.fit_search)
    #: is kept only where its body disagrees with the foreground at no more than
    #: (1 + this) times the pixels the plain fit's does; None: not checked.  make demo's
    #: walk, clicks moved (draw 1): a burst of points off the body at frame 9 took the
    #: right leg 41 cm off (7,312 -> 11,732 px), 25.4 -> 16.1 mm; the moves kept in two
    #: draws logged change the outline by 0.83-1.13 times (0.1 refused the jumps' 1.13:
    #: 15.9 -> 16.6 mm); seven of eight draws bit for bit the same
    #: (docs/design.md, "Points that lure a limb off the outline")
    search_outline_margin: float | None = 0.25
    #: in frames with points, the silhouette search's arm grids take the upper arm's
    #: twist as in frames without (core.silhouette_search.SILHOUETTE_LIMBS); False
    #: leaves the twist to the fit there.  Measured, kept on: walk_line3 medians 14.0 ->
    #: 13.1 mm, jumps_line3 15.6 -> 16.3 (docs/design.md, "The hidden arm's twist ...")
    silhouette_points_twist: bool = True
    #: contours alone: the silhouette search also tries a knee or elbow folded beyond
    #: 120° at a few absolute flexions (core.silhouette_search.UNFOLD_DEG), not only
    #: within ±60° of the fit: a shin or forearm folded onto its parent hides inside the
    #: parent's outline, costs nothing there, and the offsets cannot unfold it
    #: (docs/design.md, "A folded limb the silhouette search could not unfold")
    contour_unfold: bool = True
    #: contours alone: a search that folds a knee or elbow (beyond 120°) is weighed, after
    #: the refit, against the search without that fold.  Measured, off: dance_ortho3 run
    #: 3's fold is kept either way, run 2 went 25.1 -> 42.5 mm (docs/design.md, "A fold
    #: the silhouette search makes")
    contour_no_fold: bool = False
    #: contours alone: after the silhouette search's refit is kept, the limbs it moved
    #: are put back where the start had them, on the rest of the body as refitted, and
    #: the frame refitted once more; kept when it disagrees with the foreground at fewer
    #: pixels (a limb moved to make up for a root or trunk that was off).  Measured, off:
    #: dance_ortho3 run 3 38.8 -> 25.6 mm, runs 0 and 2 24.2 -> 39.2 and 25.1 -> 30.8
    contour_restore: bool = False
    #: contours alone: a frame whose body overlaps the foreground less (mean IoU over the
    #: cameras with one) is diverged.  Walk, skin look, a 29 mm fit: 0.81-0.90; the dance
    #: (orthogonal3) lost by 600 mm and more: below 0.45, down to 0 with the body 25 m away
    min_silhouette_iou: float = 0.5
    retry_unexplained: float = 0.2  # share of points > inlier_m from the body: retry
    max_unexplained: float = 0.3  # ... above this share the frame is marked diverged
    #: (segmentation reach m, robust knee in σ) per stage of an annealed fit
    anneal: tuple = ((0.12, 12.0), (0.07, 6.0), (0.04, 3.0), (0.04, 3.0))
    max_nfev: int = 20
    max_nfev_shape: int = 40
    #: "template": the per-part shape solve of the shape frames only (the shape the
    #: motion is tracked with); "fit" (default): then the whole-body shape fit
    #: (:func:`core.shape_fit.fit_shape`) — the blended surface that is rendered,
    #: measured and built in Blender.  make demo's walk, surface against the true mesh:
    #: per-part 29.0 mm, whole-body 13.7 mm (jumps_line3 31.3 -> 14.1, walk_ortho3 with
    #: contours alone 44.5 -> 17.0 mm); the motion is the same bit for bit
    shape: str = "fit"
    #: with shape = "fit": its frames — the first ones (shape frames at least) when the
    #: tracking uses it, else the fitted frames nearest the clicked frame (without
    #: silhouettes; see ``shape_fit_silhouette_frames``)
    shape_fit_frames: int = 3
    #: with shape = "fit" after the motion and silhouette contours: this many fitted
    #: frames spread evenly over the take instead, their silhouettes fitted with their
    #: points (:func:`core.shape_fit.fit_shape` ``contours``).  make demo's walk, the
    #: written surface against the true mesh (frames 0/12/24/36/48): the 3 frames
    #: nearest the clicked one without silhouettes 28.8 mm; with them 21.5 mm; 5 / 8 /
    #: 12 frames spread 14.6 / 15.2 / 17.9 mm (12: not converged in 10 rounds)
    shape_fit_silhouette_frames: int = 5
    #: a take whose clicked frame the silhouettes shaped (contours alone there) and that
    #: follows no texture flow: fit the motion a second time, tracked with the
    #: whole-body shape the first pass wrote (:func:`core.fit_scene.run_scene`; shape =
    #: "fit" only).  Contours alone, MPJPE first -> second pass: the sweater walk 26.3 ->
    #: 19.8 (22.0 -> 19.2 with a second shape frame), the skin walk 26.9 -> 23.1 (29.5 ->
    #: 20.2), jumps_line3 25.0 -> 20.7, walk_ortho3 33.1 -> 19.8 mm.  With the texture
    #: flow (cues both, no points) it helped once and hurt twice: walk_ortho3 17.6 ->
    #: 15.2 (17.1 -> 22.1 with a second shape frame), the skin walk 16.9 -> 19.0 mm
    silhouette_second_pass: bool = True
    #: the late shape (:mod:`core.fit_late_shape`): bones with fewer than
    #: ``late_shape_missed`` points in the shape frames and at least
    #: ``late_shape_points`` over every ``late_shape_step``-th fitted frame are
    #: re-shaped there at the fitted poses, and :func:`core.fit_scene.run_scene` fits
    #: the motion a second time with that shape (None: off).  make demo's walk, runs
    #: 0-3 of bench.fit_spread: 12.9 / 16.1 / 12.7 / 15.1 -> 11.1 / 13.5 / 12.4 / 12.2
    #: mm; jumps_line3 has no such bone (one pass, unchanged)
    late_shape_points: int | None = 100
    late_shape_missed: int = 30
    #: ... unless the fit leaves more than this share of the points unexplained in its
    #: median frame (its poses may be wrong; dance_line3, lost: 0.19, the walk 0.066)
    late_shape_max_unexplained: float = 0.1
    late_shape_step: int = 5
    #: with shape = "fit": track with the fitted shape (True: fitted right after the
    #: shape frames), or track with the per-part shape and fit the whole-body shape
    #: after the motion, at the fitted poses, for the state only (False)
    shape_fit_track: bool = False
    #: with shape = "fit": start the whole-body shape fit (and its prior) from the
    #: deflated template (:func:`core.metaball_surface.deflate`), whose blended surface follows
    #: the ellipsoids the contours render instead of swelling where metaballs overlap
    shape_fit_deflate: bool = True
    shape_fit: ShapeSettings | None = None  # its settings (None: its defaults)
    fit: FitSettings = field(
        default_factory=lambda: FitSettings(members="neighbours", irls_rounds=2, robust="cauchy")
    )


@dataclass
class ShapeRecord:
    """What the whole-body shape fit (``SequenceSettings.shape = "fit"``) did.

    Attributes
    ----------
    frames : (K,) int frames whose points and held poses were fitted
    frame_ok : (K,) bool — False for a frame the shape fit left out (too few points)
    rms_m : (K,) RMS distance of each frame's inlier points to the fitted surface,
        metres (NaN where left out)
    converged : bool — :attr:`core.shape_fit.ShapeFit.converged`
    message : str — :attr:`core.shape_fit.ShapeFit.message`
    seconds : float — wall time of the shape fit
    """

    frames: np.ndarray
    frame_ok: np.ndarray
    rms_m: np.ndarray
    converged: bool
    message: str
    seconds: float


@dataclass
class SequenceResult:
    """Output of :func:`fit_sequence`: the fitted state and per-frame diagnostics
    (``shape``: the whole-body shape fit's record, None unless it ran)."""

    state: FitState
    n_points: np.ndarray  # (F,) points assigned to a part
    inlier_share: np.ndarray  # (F,)
    unexplained: np.ndarray  # (F,) share of the points > inlier_m from the body
    retried: np.ndarray  # (F,) bool: a refit after the limb search was kept
    messages: list
    seconds: float
    shape: ShapeRecord | None = None
    #: (F,) contour pairs and their inlier RMS (pixels) at the fitted pose; 0 / NaN
    #: without contours
    contour_matches: np.ndarray | None = None
    contour_rms_px: np.ndarray | None = None
    #: (F, n) bool: the DOFs of parts too little observed at the fitted pose (held)
    hidden: np.ndarray | None = None
    #: :class:`core.fit_late_shape.LateShape` for a second pass, or None
    late_shape: object | None = None


def point_sigma(sigma_m: np.ndarray, model_m: float) -> np.ndarray:
    """A-priori σ (N,) of a point's distance to the model surface: the point's own σ and
    the metaball model's misfit to a real body, added in quadrature (metres)."""
    return np.sqrt(np.asarray(sigma_m, float) ** 2 + model_m**2)


def frame_observations(
    pts: FramePoints,
    part: np.ndarray,
    q_pred,
    sig_pred,
    n: int,
    joints=None,
    model_m: float = 0.004,
) -> Observations:
    """The points of one frame assigned to a part (``part`` (N,) bone index, −1: left
    out) as :class:`core.fitting.Observations`, with the prior on the angles
    (``q_pred`` (≥ n,) radians or None, σ ``sig_pred`` (n,)) and optional joint
    observations ``joints`` = (indices, xyz (K, 3) metres, σ metres)."""
    use = part >= 0
    o = Observations(
        xyz=pts.xyz[use],
        part=part[use],
        sigma=point_sigma(pts.sigma[use], model_m),
        theta_pred=None if q_pred is None else q_pred[:n],
        sigma_pred=sig_pred,
    )
    if joints is not None:
        o.joint_idx, o.joint_xyz, o.sigma_joint = joints
    return o
