"""Fitting across frames and the scene-level pipeline (SPEC stage 8, issue 5 items 6–7).

:func:`fit_sequence` works on plain arrays: per frame a set of 3-D observations
(:class:`FramePoints`: ``xyz`` (N, 3) world metres, ``sigma`` (N,) metres, optional
trajectory ``ids``) from any source — the tracker's ``tracks.npz``, or, for
development, truth-derived points (:mod:`core.truth_points`).  Starting from the
clicked frame's initial posture (:mod:`core.fit_init`):

1. **shape** — at the clicked frame the pose is the clicks' (bone scales ``s`` from the
   clicks are kept); the metaball radii and centres are solved to that frame's points
   with the pose held, the points re-segmented with the new shape and solved again;
   the next ``shape_frames − 1`` frames are pose-fitted and join the shape solve; the
   shape is fixed afterwards and every shape frame's pose refitted (the clicked frame
   with the clicks as joint observations, σ ``sigma_click``).  With
   ``settings.shape = "fit"`` (the default; ``"template"`` is the above alone) the
   *whole-body* shape is fitted as well (:func:`core.shape_fit.fit_shape`: metaball
   radii and centres, the anti-bulge term with the scene's ``cameras``), from the
   template deflated so that its blended surface follows the ellipsoids the contours
   render (``shape_fit_deflate``, :func:`core.metaballs.deflate`).  With
   ``shape_fit_track = False`` (its default) the tracking keeps the per-part shape and the
   whole-body shape is fitted after the motion, at the fitted poses, and only written to
   the state (:func:`core.fit_whole_shape.written_shape`: with silhouette contours, at
   ``shape_fit_silhouette_frames`` frames spread over the take, to their points and
   silhouettes; else at the ``shape_fit_frames`` frames nearest the clicked one, to
   their points); with ``shape_fit_track`` it is fitted right after at least
   ``shape_fit_frames`` shape frames, replaces the shape, and those frames' poses are
   refitted once more.  Its convergence,
   message and per-frame flags are recorded (:class:`ShapeRecord`);
2. **motion** — every other frame is *predicted* (the extended Kalman filter of
   :mod:`core.ekf` over ``[θ, root]``, or constant velocity), its points are
   *segmented* to body parts at the predicted pose (:mod:`core.segment`: points far
   from every part or ambiguous between non-adjacent parts are left out), the pose is
   refined by weighted least squares (attractor distances with Cauchy re-weighting)
   with a prior on the angles — the prediction, its σ capped for stiff DOFs
   (:data:`core.skeleton.STIFF_SIGMA`), fused with a prior towards the clicked
   posture for DOFs a person hardly moves (:data:`core.skeleton.ANCHOR_SIGMA`); a part
   with fewer than ``min_part_points`` points near it is *hidden*: its DOFs are held
   at the previous frame's angles (``hold_hidden``, the default; else they follow the
   filter's damped prediction), drift back to the clicked posture, and reach the
   filter only as a weak measurement (σ ``sigma_hidden_meas``), so that their
   reported σ grows while they are hidden.
   The points are segmented again at the refined pose and the pose refined once more.
   Tracked trajectories (points with ``ids``) that continue from the previous fitted
   frame are also *rigid-motion* observations (``trajectories``,
   :mod:`core.fit_trajectory`): each stays fixed in its part's frame, which observes a
   part's twist and slide that the surface distances do not;
3. **recovery** (:mod:`core.fit_search`) — the robust *explain cost* (truncated
   distances of all points to the whole body, no segmentation) judges poses.  After
   an accepted fit, the limb grid search tries to place each limb where it explains
   more points (a limb lost while hidden, or one faster than the prediction); if a
   limb moves, the frame is refitted from there and the lower-cost fit kept.  A fit
   that fails, or leaves more than ``retry_unexplained`` of the points far from the
   body, is retried *annealed* (wide segmentation and a soft robust knee first,
   narrowing; limb search after the first stage) from the better of the prediction
   and the previous frame (zero velocity);
4. **quality** (:mod:`core.fit_assess`) — per frame the RMS point-to-surface distance of
   the inlier points (metres), σ of every joint angle (normal matrix; hidden parts: the
   filter's), converged and diverged flags.  A frame with fewer than ``min_points``
   assigned points, a non-finite solution, an RMS above ``max_rmse_m``, too few inliers
   or more than ``max_unexplained`` of its points far from the body is *diverged*: its
   pose is the prediction (finite), flagged, and not fed to the filter;
5. **bridging** (``bridge_hidden``, :mod:`core.fit_bridge`) — once every frame is
   fitted, an angle whose every part was hidden is interpolated across each stretch
   between two observed frames, instead of staying held at the first of them;
   before that, a limb whose observed frames show it moving with the opposite thigh
   (gait) follows that thigh across the stretch (``couple_hidden``,
   :mod:`core.fit_coupling`), and a hidden arm takes the other arm's angles, mirrored,
   where the legs move mirrored (a jump; ``mirror_hidden``, :mod:`core.fit_mirror`).

**Free space** (``free_space``, :mod:`core.free_space`; the points' ``views`` and the
cameras): the limb search and the explain cost that picks among a frame's fits also
count the body found in a point's lines of sight to the cameras that measured it, and
a limb is also searched for the points it buries or hides.  The shape solves keep every
metaball within bounds of the template (``FitSettings.radius_ratio``, ``center_shift``).

**Contours** (``contours``, one :class:`core.fit_contours.ContourFrame` per frame, issue 7
item 6): the frame's silhouette contours join every pose solve as one more observation
type (σ in pixels, Huber-weighted, re-paired with the model's rim at every re-weighting
round, per-part camera selection with the predicted rates); the pairs of a part that
has at least ``min_part_points`` points get σ × ``textured_scale`` (default 1; the
metaball outline is not the body's, a larger factor lets the contours mainly place what
the points miss); a part with fewer than ``min_part_matches`` contour pairs *and* too
few points is hidden (with points and ``unhide`` False: too few points alone).  A frame with fewer
than ``min_points`` points (always, with contours alone) is fitted from its contours,
judged by them (at least ``min_matches`` pairs, inlier RMS ≤ ``max_rms_px``, the body's
projection overlapping the foreground at a mean IoU ≥ ``min_silhouette_iou``; a frame that
fails is refitted once more with the root re-centred on the foreground,
:func:`core.silhouette_search.recentre_root`, from the fit and then from the
prediction); instead of
the point-based limb search it has the silhouette one (``silhouette_search``,
:func:`core.silhouette_search.search_limbs_silhouette`: a limb moved to where it best
explains the foreground that the rest of the body leaves unexplained — an arm that
swung out from in front of the trunk beyond the contour pairing's reach — and the frame
refitted from there, kept when the body's projection then disagrees with the foreground
at fewer pixels — in frames with points too, after their own search
(``silhouette_search_points``), where a limb moves only if the frame's points are
explained no worse: a limb faster than the tracker, whose points it lost); the joints of
a part whose contour pairs all come from one camera, or from cameras whose rays to it
are at most ``ContourSettings.depth_spread_deg`` apart,
are held along those rays at the previous frame's depth (σ
``ContourSettings.depth_sigma_m``, :mod:`core.fit_depth`: such views leave that
direction free); the cameras each part used are recorded in the quality.

Frames before the clicked frame are processed backwards from it the same way.
:func:`core.fit_scene.fit_scene` runs what a scene needs (calibration from the wand when
``calibration.toml`` is missing, the initialisation from ``clicks.json``, the
observations, the fit) and returns a :class:`core.state.FitState`.
"""

from __future__ import annotations

import time

import numpy as np

from .fit_assess import assess_frame
from .fit_bridge import unobserved
from .fit_contours import containment_parts
from .fit_coupling import fill_unobserved
from .fit_depth import frame_depth_holds
from .fit_init import Initialisation
from .fit_predict import PosePredictor
from .fit_search import explain_cost, keeps_points, recentred_starts, search_limbs
from .fit_trajectory import TrajectoryAnchors
from .fit_types import FramePoints, SequenceResult, SequenceSettings, frame_observations
from .fit_whole_shape import has_outline, whole_body_shape, written_shape
from .fitting import FitSettings, fit
from .free_space import FrameProbes
from .metaballs import deflate
from .progress import Progress
from .segment import carry_labels, no_labels, segment_points
from .silhouette_search import (
    recentre_root,
    search_limbs_silhouette,
    silhouette_disagreement,
)
from .skeleton import anchor_sigma, joint_positions, stiff_sigma
from .state import FitState, Quality


def fit_sequence(
    frames: list[FramePoints],
    init: Initialisation,
    settings: SequenceSettings | None = None,
    fps: float = 25.0,
    source_scene: str = "",
    metaball_model: str = "simplified",
    progress: Progress | None = None,
    cameras: list | None = None,
    contours: list | None = None,
    flow=None,
) -> SequenceResult:
    """Fit shape and motion to the observations of every frame.

    Parameters
    ----------
    frames : F per-frame observations (any may be empty)
    init : the initial body and posture of frame ``init.frame``
    settings : SequenceSettings
    cameras : list of :class:`core.camera.Camera` or None — the scene's cameras, for
        the anti-bulge term of the whole-body shape fit (``settings.shape = "fit"``;
        without them only its data points, symmetry, smoothness and prior act)
    contours : list (F) of :class:`core.fit_contours.ContourFrame` (or None per frame),
        optional — silhouette contours as a further observation type; frames may then
        have no points at all (contours alone)
    flow : :class:`core.fit_flow.FlowAnchors` or None — image corners of every camera
        lifted onto each fitted frame and followed into the next as a further
        observation type (single-camera texture motion)

    Returns
    -------
    SequenceResult (its ``state`` holds finite numbers for every frame).
    """
    t_start = time.perf_counter()
    cfg = settings or SequenceSettings()
    nf = len(frames)
    if nf == 0:
        raise ValueError("no frames to fit")
    if cfg.shape not in ("template", "fit"):
        raise ValueError(f"unknown shape option {cfg.shape!r}")
    if contours is not None and len(contours) < nf:
        raise ValueError(f"{len(contours)} contour frames for {nf} frames")
    skel, balls = init.skeleton, init.metaballs.copy()
    template = init.metaballs.copy()  # the shape solves' bounds (FitSettings.radius_ratio)
    n = skel.n_dof
    f0 = min(max(init.frame, 0), nf - 1)
    s, radii = init.s.copy(), balls.radii.copy()
    theta = np.zeros((nf, n))
    root = np.zeros((nf, 3))
    q_sig = np.full((nf, n), np.nan)
    rmse = np.full(nf, np.nan)
    conv = np.zeros(nf, bool)
    div = np.zeros(nf, bool)
    n_pts = np.zeros(nf, int)
    inl = np.zeros(nf)
    unexpl = np.full(nf, np.nan)
    retried = np.zeros(nf, bool)
    hid = np.zeros((nf, n), bool)
    c_n = np.zeros(nf, int)
    c_rms = np.full(nf, np.nan)
    cams_used: list[dict] = [{} for _ in range(nf)]
    msgs: list[str] = []
    ci = init.clicks
    click_obs = (np.array([skel.joint_index(j) for j in ci.names]), ci.xyz, cfg.sigma_click)
    pose_cfg = FitSettings(**{**cfg.fit.__dict__, "max_nfev": cfg.max_nfev})
    labels = no_labels()
    stiff = stiff_sigma(skel)
    anchor = anchor_sigma(skel)

    dof_bone = skel.dof_bones()
    anchors = TrajectoryAnchors()  # the trajectories of the last fitted frame

    def cframe(f):
        return None if contours is None else contours[f]

    frame_probes = FrameProbes(frames, cameras, cfg.free_space)

    def hidden_dofs(xyz, q, max_dist, cf=None):
        """(n,) bool: DOFs of parts with fewer than ``min_part_points`` points within
        ``max_dist`` of them at pose q (counted without the ambiguity margin: a limb
        beside the trunk is seen even where its points are not used) and, with contours
        ``cf``, fewer than its ``min_part_matches`` contour pairs there."""
        if len(xyz):
            part, _ = segment_points(xyz, skel, balls, q[:n], q[n:], s, radii, max_dist, 0.0)
            cnt = np.bincount(part[part >= 0], minlength=len(skel.bone_names))
        else:
            cnt = np.zeros(len(skel.bone_names), int)
        hidden = cnt[dof_bone] < cfg.min_part_points
        if cf is not None:
            # parts that the points observe: their contour pairs weigh less (σ × scale)
            cf.part_scale = np.where(cnt >= cfg.min_part_points, cf.cfg.textured_scale, 1.0)
            cf.containment_parts = containment_parts(
                cnt, len(xyz) >= cfg.min_points, cfg.min_part_points, cf.cfg
            )
            cf.freeze(skel, balls.copy(radii=radii), q[:n], q[n:], s)
            if len(xyz) < cfg.min_points or cf.cfg.unhide:
                # beside points, one view's contours do not un-hide a part (its depth)
                views = cf.cfg.unhide_views if len(xyz) >= cfg.min_points else 1
                hidden &= (
                    cf.part_counts(len(skel.bone_names), views)[dof_bone] < cf.cfg.min_part_matches
                )
        return hidden

    def prior(hidden, th_pred, sig_pred, th_hold):
        """Target and σ of the prior on the angles: the prediction, σ capped for stiff
        DOFs; the DOFs of parts with too few points (hidden) follow the (damped)
        prediction, or are held at ``th_hold`` (the previous frame, when given), with σ
        ``sigma_hidden``; fused with a prior towards the initial posture (anchored DOFs,
        and hidden parts, which drift back to the clicked posture instead of
        wandering)."""
        sig = np.minimum(sig_pred, stiff)
        target = th_pred if th_hold is None else np.where(hidden, th_hold, th_pred)
        sig = np.where(hidden, np.minimum(sig, cfg.sigma_hidden), sig)
        sig_a = np.where(hidden, np.minimum(anchor, cfg.sigma_hidden_anchor), anchor)
        w1, w2 = 1.0 / sig**2, 1.0 / sig_a**2
        return (w1 * target + w2 * init.theta) / (w1 + w2), 1.0 / np.sqrt(w1 + w2)

    def search_start(f, cands):
        """Of the candidate poses (k, n+3), the one whose body explains frame f's points
        best (:func:`core.fit_search.explain_cost`)."""
        cands = np.atleast_2d(cands)
        if len(cands) == 1 or not len(frames[f].xyz):
            return cands[0].copy()
        cost = explain_cost(
            frames[f].xyz,
            skel,
            balls,
            s,
            radii,
            cands[:, :n],
            cands[:, n:],
            cfg.search_tau,
            probes=frame_probes(f),
        )
        return cands[int(np.argmin(cost))].copy()

    def one_frame(f, q_pred, sig_pred, joints=None, q_hold=None, anneal=False):
        """Pose-only fit of frame f from ``q_pred`` (n+3,), which is also the prior's
        target; returns ``(q, FitResult, ok, part or message, labels)``.

        Plain: segment, fit, segment again, fit (``cfg.segment_max_dist`` and the
        robust scale of ``cfg.fit``).  ``anneal``: the stages of ``cfg.anneal`` —
        wide segmentation and a soft robust knee first, narrowing — and, after the
        first stage has brought the trunk near its points, every limb placed by
        :func:`core.fit_search.search_limbs` (its new angles become the prior's
        target)."""
        pts = frames[f]
        cf = cframe(f)
        lab = labels
        stages = (
            cfg.anneal
            if anneal
            else ((cfg.segment_max_dist, cfg.fit.robust_scale),) * (2 if cfg.resegment else 1)
        )
        if cf is not None and len(pts.xyz) < cfg.min_points:  # contours alone: no
            stages = stages[:1]  # segmentation to redo (they re-pair every round)
        q, target_q = q_pred.copy(), q_pred.copy()
        r = part = None
        traj = (
            anchors.observations(pts.xyz, pts.sigma, pts.ids, cfg.traj_slip_m, cfg.traj_robust)
            if cfg.trajectories
            else None
        )
        for k, (max_dist, knee) in enumerate(stages):
            if anneal and k == 1 and cfg.search:
                q[:n] = search_limbs(
                    pts.xyz,
                    skel,
                    balls,
                    s,
                    radii,
                    q[:n],
                    q[n:],
                    tau=cfg.search_tau,
                    probes=frame_probes(f),
                ).theta
                target_q = q.copy()
            if len(pts.xyz):
                part, _ = segment_points(
                    pts.xyz, skel, balls, q[:n], q[n:], s, radii, max_dist, cfg.segment_margin
                )
                part, lab = carry_labels(part, pts.ids, lab)
            else:
                part = np.zeros(0, int)
            if (part >= 0).sum() < cfg.min_points and cf is None:
                if r is None:
                    return (
                        None,
                        None,
                        False,
                        f"frame {f}: only {(part >= 0).sum()} usable points",
                        lab,
                    )
                break
            hidden = hidden_dofs(pts.xyz, q, max_dist, cf)
            target, sig = prior(
                hidden, target_q[:n], sig_pred, None if q_hold is None else q_hold[:n]
            )
            o = frame_observations(pts, part, target, sig, n, joints)
            o.contours = cf
            if cf is not None and len(pts.xyz) < cfg.min_points:
                q_ref = target_q if q_hold is None else q_hold  # the previous frame
                o.depth = frame_depth_holds(skel, cf, hidden, q_ref[:n], q_ref[n:], s)
            o.trajectory = traj
            if flow is not None and (
                len(pts.xyz) < cfg.min_points or not flow.cfg.without_points_only
            ):
                o.flow = flow.observations(f)
            stage_cfg = (
                pose_cfg
                if knee == pose_cfg.robust_scale
                else FitSettings(**{**pose_cfg.__dict__, "robust_scale": knee})
            )
            if cf is not None and stage_cfg.irls_rounds < cf.cfg.rounds:
                stage_cfg = FitSettings(**{**stage_cfg.__dict__, "irls_rounds": cf.cfg.rounds})
            r = fit(skel, balls, o, q[:n], q[n:], s, radii, solve="pose", settings=stage_cfg)
            q = np.concatenate([r.theta, r.root_xyz])
        return q, r, True, part, lab

    def assess(f, res):
        """Quality of a fitted frame, without side effects: ``(ok, reasons, stats)``."""
        return assess_frame(
            res, skel, balls, radii, s, frames[f].xyz, cframe(f), lambda: frame_probes(f), cfg
        )

    def record(f, res, ok, why, stats):
        """Write the quality of frame f (and the message of a diverged one); commit the
        segmentation labels of an accepted fit."""
        nonlocal labels
        if stats is not None:
            n_pts[f], inl[f], rmse[f], q_sig[f] = (
                stats["n"],
                stats["inl"],
                stats["rmse"],
                stats["sig"],
            )
            unexpl[f] = stats["unexplained"]
            if stats["contour"] is not None:
                c_n[f], c_rms[f] = stats["contour"]["n"], stats["contour"]["rms_px"]
        if ok:
            conv[f] = stats["conv"]
            labels = res[4]
            if cframe(f) is not None:
                cams_used[f] = cframe(f).cameras_used(skel)
        else:
            msgs.append(
                f"frame {f}: {why}: marked diverged"
                if stats is not None
                else f"{why}: marked diverged"
            )

    def recentre_retry(f, res, ok, why, st, q_pred, sig_pred, joints, q_hold):
        """Contours alone, a frame that failed: the root moved to centre the body on
        the foreground (:func:`core.silhouette_search.recentre_root`, from the fit or
        the prediction) and the frame refitted from there; the first refit accepted
        wins.  Returns ``(res, ok, why, stats)``."""
        cf = cframe(f)
        body = balls.copy(radii=radii)
        starts = [q_pred]
        if res[0] is not None and np.all(np.isfinite(res[0])):
            starts.insert(0, res[0])
        for q0 in starts:
            q1 = q0.copy()
            q1[n:] = recentre_root(skel, body, q0[:n], q0[n:], s, cf.cameras, cf.grids())
            res2 = one_frame(f, q1, sig_pred, joints, q_hold)
            ok2, why2, st2 = assess(f, res2)
            if ok2:
                retried[f] = True
                return res2, ok2, why2, st2
        return res, ok, why, st

    def silhouette_retry(f, res, st, sig_pred, joints, q_hold):
        """Every limb placed where it best explains the frame's foreground
        (:func:`search_limbs_silhouette`; with points, a move vetoed by ``keeps_points``)
        and the frame refitted from there, the moved DOFs' hold and prior following the
        search; the refit is kept when it is accepted and the body's projection disagrees
        with the foreground at fewer pixels.  Returns ``(res, ok, why, stats)``."""
        cf = cframe(f)
        q = res[0]
        body = balls.copy(radii=radii)
        xyz = frames[f].xyz
        veto = (
            keeps_points(xyz, skel, balls, s, radii, q[n:], cfg.search_tau, frame_probes(f))
            if len(xyz) >= cfg.min_points
            else None
        )
        sr = search_limbs_silhouette(
            skel, body, s, q[:n], q[n:], cf.cameras, cf.masks(), allowed=veto
        )
        if not sr.moved:
            return res, True, "", st
        q1 = q.copy()
        q1[:n] = sr.theta
        hold = None
        if q_hold is not None:
            hold = q_hold.copy()
            moved = sr.theta != q[:n]
            hold[:n][moved] = sr.theta[moved]
        res2 = one_frame(f, q1, sig_pred, joints, hold)
        ok2, why2, st2 = assess(f, res2)
        if ok2 and (
            silhouette_disagreement(skel, body, res2[0][:n], res2[0][n:], s, cf.cameras, cf.grids())
            < silhouette_disagreement(skel, body, q[:n], q[n:], s, cf.cameras, cf.grids())
        ):
            retried[f] = True
            return res2, ok2, why2, st2
        return res, True, "", st

    def fit_frame(f, q_pred, sig_pred, alternatives=(), joints=None, q_hold=None):
        """Fit frame f: the plain fit from the prediction, then

        * when it is accepted, the limb search (:func:`core.fit_search.search_limbs`)
          from its pose: a limb that a better place explains more points at is moved
          there and the frame refitted from it (a limb lost while hidden, or one that
          moved faster than the prediction);
        * when it fails or leaves more than ``cfg.retry_unexplained`` of the points far
          from the body, an annealed fit (:func:`one_frame` ``anneal``) from the best
          of the prediction and the alternatives;

        the accepted fit of lowest explain cost wins.  Returns ``(ok, q)`` with q the
        fitted pose, or the prediction when no fit is accepted."""
        res = one_frame(f, q_pred, sig_pred, joints, q_hold)
        ok, why, st = assess(f, res)
        search = cfg.search and len(frames[f].xyz) >= cfg.min_points  # needs points
        if search and ok and st["unexplained"] <= cfg.retry_unexplained:
            sr = search_limbs(
                frames[f].xyz,
                skel,
                balls,
                s,
                radii,
                res[0][:n],
                res[0][n:],
                tau=cfg.search_tau,
                min_gain=cfg.search_min_gain,
                probes=frame_probes(f),
            )
            if sr.moved:
                q1 = res[0].copy()
                q1[:n] = sr.theta
                res2 = one_frame(f, q1, sig_pred, joints, q_hold)
                ok2, why2, st2 = assess(f, res2)
                if ok2 and st2["cost"] < st["cost"]:
                    res, ok, why, st = res2, ok2, why2, st2
                    retried[f] = True
        elif search:
            # also the prediction moved onto the points: after frames that failed, the
            # person may have walked on while the prediction stayed behind
            cands = np.stack([q_pred, *alternatives])
            if cfg.recentre and last_fitted >= 0:
                cands = np.concatenate(
                    [
                        cands,
                        recentred_starts(
                            frames[f].xyz, q_pred, frames[last_fitted].xyz, root[last_fitted], up
                        ),
                    ]
                )
            q0 = search_start(f, cands)
            res2 = one_frame(f, q0, sig_pred, joints, q_hold, anneal=True)
            ok2, why2, st2 = assess(f, res2)
            if ok2 and (not ok or st2["cost"] < st["cost"]):
                res, ok, why, st = res2, ok2, why2, st2
                retried[f] = True
        if (
            search
            and ok
            and cfg.silhouette_search
            and cfg.silhouette_search_points
            and has_outline(cframe(f))
        ):
            res, ok, why, st = silhouette_retry(f, res, st, sig_pred, joints, q_hold)
        elif not search and cfg.silhouette_search and cframe(f) is not None:
            if not ok:
                res, ok, why, st = recentre_retry(
                    f, res, ok, why, st, q_pred, sig_pred, joints, q_hold
                )
            if ok:
                res, ok, why, st = silhouette_retry(f, res, st, sig_pred, joints, q_hold)
        record(f, res, ok, why, st)
        if ok:
            hid[f] = hidden_dofs(frames[f].xyz, res[0], cfg.segment_max_dist, cframe(f))
        return ok, (res[0] if ok else q_pred)

    last_fitted = -1  # the last frame stored as fitted with points (recentred_starts)
    up = np.subtract(
        *joint_positions(skel, init.theta, init.root_xyz, init.s)[
            [skel.joint_index("neck"), skel.joint_index("pelvis")]
        ]
    )  # the body upright

    def store(f, q, ok):
        nonlocal last_fitted
        theta[f], root[f] = q[:n], q[n:]
        div[f] = not ok
        if ok and len(frames[f].xyz) >= cfg.min_points:
            last_fitted = f

    def keep_trajectories(f):
        """Keep frame f's trajectories in their parts' frames (none after a diverged
        frame) for the next frame's rigid-motion observations."""
        pts = frames[f]
        if flow is not None:
            near = [g for g in (f - 1, f + 1) if 0 <= g < nf]
            if div[f] or (
                flow.cfg.without_points_only
                and all(len(frames[g].xyz) >= cfg.min_points for g in near)
            ):
                flow.clear()  # (no neighbour will use the flow)
            else:
                cf = cframe(f)
                flow.set(
                    skel,
                    balls.copy(radii=radii),
                    theta[f],
                    root[f],
                    s,
                    f,
                    None if cf is None else cf.masks(),
                )
        if not cfg.trajectories or div[f] or pts.ids is None:
            anchors.clear()
            return
        part = carry_labels(np.full(len(pts.xyz), -1), pts.ids, labels)[0]
        anchors.set(skel, theta[f], root[f], s, pts.xyz, pts.sigma, pts.ids, part)

    # 1) shape: at the clicked frame the clicks fix the pose; later shape frames are
    #    pose-fitted with the current shape, then the shape is re-solved over all of
    #    them with their poses held (shape-only solves avoid the shape/pose trade-off)
    shape_cfg = FitSettings(
        **{
            **cfg.fit.__dict__,
            "max_nfev": cfg.max_nfev_shape,
            "fit_scales": cfg.shape_scales,
            "free_centers": cfg.shape_centers,
            "sigma_radius": cfg.shape_sigma_radius,
            "sigma_center": cfg.shape_sigma_center,
        }
    )
    shape_first = cfg.shape == "fit" and cfg.shape_fit_track
    n_shape = max(cfg.shape_frames, 1, cfg.shape_fit_frames if shape_first else 1)
    shape_range = list(range(f0, min(nf, f0 + n_shape)))
    store(f0, np.concatenate([init.theta, init.root_xyz]), True)
    shaped = []
    for k, f in enumerate(shape_range):
        if k:
            ok, q = fit_frame(
                f, np.concatenate([theta[f - 1], root[f - 1]]), np.full(n, cfg.sigma_pred_max)
            )
            store(f, q, ok)
            if not ok:
                continue
        for rnd in range(2):  # segment, solve the shape, segment again with it
            obs_s, keep = [], []
            for g in (shaped + [f]) if rnd == 0 else shaped:
                part, _d = segment_points(
                    frames[g].xyz,
                    skel,
                    balls,
                    theta[g],
                    root[g],
                    s,
                    radii,
                    cfg.segment_max_dist,
                    cfg.segment_margin,
                )
                if (part >= 0).sum() >= cfg.min_points:
                    obs_s.append(frame_observations(frames[g], part, None, cfg.sigma_pred, n))
                    keep.append(g)
            if not obs_s:
                break
            rs = fit(
                skel,
                balls,
                obs_s,
                theta[keep],
                root[keep],
                s,
                radii,
                solve="shape",
                settings=shape_cfg,
                shape_ref=template,
            )
            s, radii = rs[0].s.copy(), rs[0].radii.copy()
            balls.center0 = rs[0].centers.copy()
            shaped = keep
        if progress is not None:
            progress.update(k + 1, nf + len(shape_range), f"shape: frame {f}")
    if not shaped:
        msgs.append(
            "no usable points in the shape frames: the template shape is kept"
            if contours is None
            else "no usable points in the shape frames: the "
            "initial shape (e.g. fitted to the silhouettes) is kept"
        )

    def refit_shape_frames():
        for f in shape_range:  # the poses with the final shape
            if div[f]:
                continue
            ok, q = fit_frame(
                f,
                np.concatenate([theta[f], root[f]]),
                np.full(n, cfg.sigma_pred_max),
                joints=click_obs if f == f0 else None,
            )
            if ok:
                store(f, q, True)
            elif f != f0:
                store(f, np.concatenate([theta[f], root[f]]), False)

    refit_shape_frames()
    shape_rec = None
    fitted_balls = None
    start = init.metaballs  # the whole-body shape fit's start and prior
    if cfg.shape == "fit" and cfg.shape_fit_deflate:
        start = deflate(skel, init.metaballs, s)
    if shape_first:
        fitted_balls, _, shape_rec = whole_body_shape(
            skel,
            start,
            s,
            theta,
            root,
            frames,
            [f for f in shape_range if not div[f]],
            cameras,
            cfg.shape_fit,
            msgs,
        )
        balls, radii = fitted_balls, fitted_balls.radii.copy()
        refit_shape_frames()
    # 2) motion forwards and backwards from the clicked frame ----------------------
    done = len(shape_range)
    for direction, order in ((1, range(shape_range[-1] + 1, nf)), (-1, range(f0 - 1, -1, -1))):
        seq = shape_range if direction == 1 else [f0]
        pred = PosePredictor(np.concatenate([theta[seq[0]], root[seq[0]]]), cfg, n)
        for f in seq[1:]:
            q = np.concatenate([theta[f], root[f]])
            pred.predict()
            if not div[f]:
                pred.accept(q, None)
            else:
                pred.skip()
        if len(order):
            keep_trajectories(order[0] - direction)
        for f in order:
            q_pred, sig_pred = pred.predict()
            q_prev = np.concatenate([theta[f - direction], root[f - direction]])
            if cframe(f) is not None:  # predicted rates rank the cameras (observability)
                cframe(f).theta_rate = q_pred[:n] - q_prev[:n]
            ok, q = fit_frame(
                f, q_pred, sig_pred, [q_prev], q_hold=q_prev if cfg.hold_hidden else None
            )
            if ok:
                sig = np.concatenate([q_sig[f], np.full(3, 0.005)])
                sig = np.where(np.isfinite(sig), sig, 0.05)
                sig[:n][hid[f]] = cfg.sigma_hidden_meas  # a hidden part's angles: weak
                q_sig[f] = np.where(hid[f], pred.accept(q, sig), q_sig[f])
                store(f, q, True)
            else:
                pred.skip()
                store(f, q_pred, False)
            keep_trajectories(f)
            done += 1
            if progress is not None:
                progress.update(done, nf + len(shape_range), f"frame {f}")
    unobs = unobserved(hid, skel.dof_parent)
    theta[:], fill_msgs = fill_unobserved(
        skel,
        theta,
        root,
        s,
        unobs,
        div,
        cfg.couple_hidden,
        cfg.bridge_hidden,
        cfg.couple_r2,
        hid,
        (f0,),
        cfg.mirror_hidden,
        cfg.mirror_r2,
    )
    msgs += fill_msgs
    if cfg.shape == "fit" and not shape_first:  # at the fitted poses, for the state only
        fitted_balls, shape_rec = written_shape(
            skel,
            start,
            s,
            theta,
            root,
            frames,
            contours,
            ~div & conv,
            n_pts,
            unobs,
            f0,
            cfg,
            cameras,
            msgs,
            progress,
        )
    balls_out = balls.copy(radii=radii) if fitted_balls is None else fitted_balls.copy()
    q = Quality(
        rmse_m=rmse,
        theta_sigma=q_sig,
        converged=conv & ~div,
        diverged=div,
        cameras=cams_used,
        unobserved=unobs,
    )
    state = FitState(
        skeleton=skel,
        s=s,
        metaballs=balls_out,
        root_xyz=root,
        theta=theta,
        quality=q,
        fps=fps,
        source_scene=source_scene,
        metaball_model=metaball_model,
    )
    if retried.any():
        msgs.append(f"{int(retried.sum())} frames refitted after the limb search")
    return SequenceResult(
        state=state,
        n_points=n_pts,
        inlier_share=inl,
        unexplained=unexpl,
        retried=retried,
        messages=msgs,
        seconds=time.perf_counter() - t_start,
        shape=shape_rec,
        contour_matches=c_n,
        contour_rms_px=c_rms,
        hidden=hid,
    )
