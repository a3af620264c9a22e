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
   render (``shape_fit_deflate``, :func:`core.metaball_surface.deflate`).  With
   ``shape_fit_track = False`` (its default) the tracking keeps the per-part shape and the
   whole-body shape is fitted after the motion, at the fitted poses, and only written to
   the state (:func:`core.fit_whole_shape.written_shape`: with silhouette contours, at
   ``shape_fit_silhouette_frames`` frames spread over the take, to their points and
   silhouettes; else at the ``shape_fit_frames`` frames nearest the clicked one, to
   their points); with ``shape_fit_track`` it is fitted right after at least
   ``shape_fit_frames`` shape frames, replaces the shape, and those frames' poses are
   refitted once more.  Its convergence,
   message and per-frame flags are recorded (:class:`ShapeRecord`).  Bones the shape
   frames hardly saw are shaped *late*, over the fitted take
   (:mod:`core.fit_late_shape`, ``late_shape_points``), and returned for a second pass
   that starts from that shape (``shape0``; :func:`core.fit_scene.run_scene` runs it);
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
   where the legs move mirrored (a jump; ``mirror_hidden``, :mod:`core.fit_mirror`);
   last, in a walk, a hidden arm that neither placed swings with the opposite thigh
   (``gait_swing_arms``, :mod:`core.fit_gait`);
6. **smoothing** (:mod:`core.motion_smoother`) — a fixed-interval Kalman smoother
   (forward and backward) over the whole take, one smoothness for every angle and the
   root that the take's own likelihood chooses, after the written shape (fitted at the
   poses the observations gave); diverged frames are left as they are.  By default
   (``smooth_unobserved``) only the angles no observation decided (step 5's filled and
   held ones) take their smoothed values; ``smooth_motion`` smooths the whole motion
   instead, each joint's path with its own smoothness and then the angles solved to it
   (:func:`core.motion_smoother.smooth_joints`; off by default: it spreads a kick);
7. **clearance** (``clear_trunk``, :mod:`core.fit_clearance`) — last, after the shapes
   (which it does not feed): a hidden arm that step 5's rules put inside the trunk, or
   (``clear_silhouettes``, with contours) where a camera's foreground shows no body, is
   moved out of the trunk and into the foregrounds by the least change of its
   unobserved angles, and the unobserved angles are smoothed again.

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

Frames before the clicked frame are processed backwards from it the same way.  The fit
of one frame (steps 2–4: segmentation, prior, hidden parts, recovery, quality; with
contours the silhouette retries) is :class:`core.fit_frame.FrameFitter`, which also
holds the current shape and the per-frame results.
:func:`core.fit_scene.fit_scene` runs what a scene needs (calibration from the wand when
``calibration.toml`` is missing, the initialisation from ``clicks.json``, the
observations, the fit) and returns a :class:`core.state.FitState`.
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from .fit_bridge import unobserved
from .fit_clearance import clear_trunk
from .fit_coupling import fill_unobserved
from .fit_frame import FrameFitter
from .fit_init import Initialisation
from .fit_late_shape import LateShape, late_shape, shape_settings
from .fit_predict import PosePredictor
from .fit_types import FramePoints, SequenceResult, SequenceSettings, frame_observations
from .fit_whole_shape import whole_body_shape, written_shape
from .fitting import fit
from .foot_heading import feet_from_points
from .metaball_surface import deflate
from .motion_smoother import smooth_angles, smooth_joints
from .progress import Progress
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
    shape0: LateShape | None = None,
    defer_shape: bool = False,
    shape_start=None,
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
    shape0 : :class:`core.fit_late_shape.LateShape` or None — a first pass's late shape
        to track with (its radii and centres replace the template's before the shape
        frames' solve, which starts from them); with it no late shape is computed
    defer_shape : bool — the caller fits the motion again when a late shape qualifies
        (:func:`core.fit_scene.run_scene`): the whole-body shape written to the state
        is then not fitted here (the second pass writes its own; on make demo's walk
        it took 15–21 s of a first pass of ~150–160 s).  The state then carries the
        shape the motion was tracked with.
    shape_start : Metaballs or None — the start and prior of the whole-body shape written
        to the state (None: ``init.metaballs``, the shape the motion is tracked with).
        The shape over several frames (:func:`core.fit_passes.frames_shape_pass`) tracks
        with its own radii and writes the body from the clicked frame's: written from
        its own, walk_ortho3's and jumps_ortho3's visibility index went 0.048 -> 0.052
        and 0.038 -> 0.054 (run 0), from the clicked frame's 0.047 and 0.040.

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
    f0 = min(max(init.frame, 0), nf - 1)
    feet = []
    if cfg.foot_heading and len(frames[f0].xyz):
        theta0, feet = feet_from_points(
            init.skeleton, init.theta, init.root_xyz, init.s, frames[f0].xyz, init.clicks.names
        )
        init = replace(init, theta=theta0)
    fx = FrameFitter(frames, init, cfg, contours, flow, cameras)  # per frame: fit, results
    if shape0 is not None:  # the late shape of a first pass (core.fit_late_shape)
        fx.radii, fx.balls.center0 = shape0.radii.copy(), shape0.centers.copy()
    fx.msgs += [f"clicked frame {f0}: " + h.message() for h in feet]
    skel = init.skeleton
    template = init.metaballs.copy()  # the shape solves' bounds (FitSettings.radius_ratio)
    n = skel.n_dof
    ci = init.clicks
    click_obs = (np.array([skel.joint_index(j) for j in ci.names]), ci.xyz, cfg.sigma_click)

    # 1) shape: at the clicked frame the clicks fix the pose; later shape frames are
    #    pose-fitted with the current shape, then the shape is re-solved over all of
    #    them with their poses held (shape-only solves avoid the shape/pose trade-off)
    shape_cfg = shape_settings(cfg)
    shape_first = cfg.shape == "fit" and cfg.shape_fit_track
    n_shape = max(cfg.shape_frames, 1, cfg.shape_fit_frames if shape_first else 1)
    shape_range = list(range(f0, min(nf, f0 + n_shape)))
    fx.store(f0, np.concatenate([init.theta, init.root_xyz]), True)
    for _sweep in range(max(cfg.shape_sweeps, 1)):  # each sweep starts from the last's shape
        shaped = []
        for k, f in enumerate(shape_range):
            if k:
                ok, q = fx.fit_frame(
                    f,
                    np.concatenate([fx.theta[f - 1], fx.root[f - 1]]),
                    np.full(n, cfg.sigma_pred_max),
                )
                fx.store(f, q, ok)
                if not ok:
                    continue
            for rnd in range(2):  # segment, solve the shape, segment again with it
                obs_s, keep = [], []
                for g in (shaped + [f]) if rnd == 0 else shaped:
                    part = fx.stored_labels(g)
                    if (part >= 0).sum() >= cfg.min_points:
                        obs_s.append(frame_observations(frames[g], part, None, cfg.sigma_pred, n))
                        keep.append(g)
                if not obs_s:
                    break
                rs = fit(
                    skel,
                    fx.balls,
                    obs_s,
                    fx.theta[keep],
                    fx.root[keep],
                    fx.s,
                    fx.radii,
                    solve="shape",
                    settings=shape_cfg,
                    shape_ref=template,
                )
                fx.s, fx.radii = rs[0].s.copy(), rs[0].radii.copy()
                fx.balls.center0 = rs[0].centers.copy()
                shaped = keep
            if progress is not None:
                progress.update(k + 1, nf + len(shape_range), f"shape: frame {f}")
    if not shaped:
        fx.msgs.append(
            "no usable points in the shape frames: the template shape is kept"
            if contours is None
            else "no usable points in the shape frames: the "
            "initial shape (e.g. fitted to the silhouettes) is kept"
        )

    def refit_shape_frames():
        for f in shape_range:  # the poses with the final shape
            if fx.div[f]:
                continue
            ok, q = fx.fit_frame(
                f,
                np.concatenate([fx.theta[f], fx.root[f]]),
                np.full(n, cfg.sigma_pred_max),
                joints=click_obs if f == f0 else None,
            )
            if ok:
                fx.store(f, q, True)
            elif f != f0:
                fx.store(f, np.concatenate([fx.theta[f], fx.root[f]]), False)

    refit_shape_frames()
    shape_rec = None
    fitted_balls = None
    base = init.metaballs if shape_start is None else shape_start
    start = base  # the whole-body shape fit's start and prior
    if cfg.shape == "fit" and cfg.shape_fit_deflate:
        start = deflate(skel, base, fx.s)
    if shape_first:
        fitted_balls, _, shape_rec = whole_body_shape(
            skel,
            start,
            fx.s,
            fx.theta,
            fx.root,
            frames,
            [f for f in shape_range if not fx.div[f]],
            cameras,
            cfg.shape_fit,
            fx.msgs,
        )
        fx.balls, fx.radii = fitted_balls, fitted_balls.radii.copy()
        refit_shape_frames()
    if fx.flow is not None and fx.flow.cfg.reference and not fx.div[f0]:
        cf = fx.cframe(f0)
        fx.flow.set_reference(
            skel,
            fx.balls.copy(radii=fx.radii),
            fx.theta[f0],
            fx.root[f0],
            fx.s,
            f0,
            None if cf is None else cf.masks(),
        )
    # 2) motion forwards and backwards from the clicked frame ----------------------
    done = len(shape_range)
    for direction, order in ((1, range(shape_range[-1] + 1, nf)), (-1, range(f0 - 1, -1, -1))):
        seq = shape_range if direction == 1 else [f0]
        pred = PosePredictor(np.concatenate([fx.theta[seq[0]], fx.root[seq[0]]]), cfg, n)
        for f in seq[1:]:
            q = np.concatenate([fx.theta[f], fx.root[f]])
            pred.predict()
            if not fx.div[f]:
                pred.accept(q, None)
            else:
                pred.skip()
        if len(order):
            fx.keep_trajectories(order[0] - direction)
        for f in order:
            q_pred, sig_pred = pred.predict()
            q_prev = np.concatenate([fx.theta[f - direction], fx.root[f - direction]])
            if fx.cframe(f) is not None:  # predicted rates rank the cameras (observability)
                fx.cframe(f).theta_rate = q_pred[:n] - q_prev[:n]
            more = contour_starts(fx, f, direction, q_prev) if cfg.contour_starts else ()
            ok, q = fx.fit_frame(
                f,
                q_pred,
                sig_pred,
                [q_prev],
                q_hold=q_prev if cfg.hold_hidden else None,
                contour_starts=more,
            )
            if ok:
                sig = np.concatenate([fx.q_sig[f], np.full(3, 0.005)])
                sig = np.where(np.isfinite(sig), sig, 0.05)
                sig[:n][fx.hid[f]] = cfg.sigma_hidden_meas  # a hidden part's angles: weak
                fx.q_sig[f] = np.where(fx.hid[f], pred.accept(q, sig), fx.q_sig[f])
                fx.store(f, q, True)
            else:
                pred.skip()
                fx.store(f, q_pred, False)
            fx.keep_trajectories(f)
            done += 1
            if progress is not None:
                progress.update(done, nf + len(shape_range), f"frame {f}")
    unobs = unobserved(fx.hid, skel.dof_parent)
    fx.theta[:], fill_msgs = fill_unobserved(
        skel,
        fx.theta,
        fx.root,
        fx.s,
        unobs,
        fx.div,
        cfg.couple_hidden,
        cfg.bridge_hidden,
        cfg.couple_r2,
        fx.hid,
        (f0,),
        cfg.mirror_hidden,
        cfg.mirror_r2,
        cfg.mirror_keep_seen,
        cfg.smooth_held_frames,
        cfg.gait_arms,
        cfg.gait_arm_ratio,
        reach=cfg.couple_reach,
    )
    fx.msgs += fill_msgs
    written = cfg.shape == "fit" and not shape_first  # the shape written to the state
    # fitted at the poses the observations gave, before any smoothing below
    posed = (fx.theta.copy(), fx.root.copy()) if written else None
    if cfg.smooth_motion:
        fx.theta[:], fx.root[:], sm = smooth_joints(skel, fx.s, fx.theta, fx.root, fx.div)
        fx.msgs.append(
            f"motion smoothed over the take (the joints' positions, then the angles; "
            f"{int((sm.far.any(axis=1) & ~fx.div).sum())} frames with a joint more than "
            f"3 σ off its smoothed path down-weighted)"
        )
    elif cfg.smooth_unobserved and unobs.any() and _smooth_unobserved(fx, unobs):
        fx.msgs.append(
            f"unobserved angles smoothed over the take in "
            f"{int((unobs & ~fx.div[:, None]).any(axis=1).sum())} frames"
        )
    late = None
    if shape0 is None and cfg.late_shape_points is not None:
        late = late_shape(
            fx,
            shape_range,
            template,
            cfg.late_shape_step,
            cfg.late_shape_points,
            cfg.late_shape_missed,
            cfg.late_shape_max_unexplained,
        )
    if written and defer_shape and late is not None:
        fx.msgs.append("whole-body shape: left to the second pass (late shape)")
    elif written:
        fitted_balls, shape_rec = written_shape(
            skel,
            start,
            fx.s,
            *posed,
            frames,
            contours,
            ~fx.div & fx.conv,
            fx.n_pts,
            unobs,
            f0,
            cfg,
            cameras,
            fx.msgs,
            progress,
        )
    balls_out = fx.balls.copy(radii=fx.radii) if fitted_balls is None else fitted_balls.copy()
    if cfg.clear_trunk:  # last: a hidden arm the rules put inside the trunk, or outside
        # a foreground, moved (after the shapes, which it does not feed), smoothed again
        th_c, clr = clear_trunk(
            skel,
            balls_out,
            fx.s,
            fx.theta,
            fx.root,
            unobs,
            fx.div,
            cfg.clear_level,
            views=_views(contours, nf) if cfg.clear_silhouettes else None,
            ref_frames=(f0,),
        )
        if clr.frames:
            fx.theta[:] = th_c
            if cfg.smooth_unobserved and not cfg.smooth_motion:
                _smooth_unobserved(fx, unobs)
            fx.msgs.append(
                f"hidden arm moved out of the trunk or into the foregrounds in "
                f"{len(clr.frames)} frames (trunk field at its forearm or hand up to "
                f"{max(clr.before):.2f}, now {max(clr.after):.2f}; outside a foreground up "
                f"to {max(clr.px_before):.1f} px beyond the tolerance, now "
                f"{max(clr.px_after):.1f})"
            )
    q = Quality(
        rmse_m=fx.rmse,
        theta_sigma=fx.q_sig,
        converged=fx.conv & ~fx.div,
        diverged=fx.div,
        cameras=fx.cams_used,
        unobserved=unobs,
    )
    state = FitState(
        skeleton=skel,
        s=fx.s,
        metaballs=balls_out,
        root_xyz=fx.root,
        theta=fx.theta,
        quality=q,
        fps=fps,
        source_scene=source_scene,
        metaball_model=metaball_model,
    )
    if fx.retried.any():
        fx.msgs.append(f"{int(fx.retried.sum())} frames refitted after the limb search")
    return SequenceResult(
        state=state,
        n_points=fx.n_pts,
        inlier_share=fx.inl,
        unexplained=fx.unexpl,
        retried=fx.retried,
        messages=fx.msgs,
        seconds=time.perf_counter() - t_start,
        shape=shape_rec,
        contour_matches=fx.c_n,
        contour_rms_px=fx.c_rms,
        hidden=fx.hid,
        late_shape=late,
    )


def _smooth_unobserved(fx: FrameFitter, unobs: np.ndarray) -> bool:
    """The angles no observation decided (the filled and held ones) take their values
    smoothed over the take (:func:`core.motion_smoother.smooth_angles`), in place;
    False when too few frames were fitted to choose a smoothness."""
    skel = fx.skel
    th_s, _, sm = smooth_angles(fx.theta, fx.root, fx.div, lo=skel.dof_lo, hi=skel.dof_hi)
    if not np.isfinite(sm.ratio).any():
        return False
    fx.theta[:] = np.where(unobs, th_s, fx.theta)
    return True


def _views(contours: list | None, nf: int) -> list | None:
    """Per frame the cameras with a foreground and their silhouette fields, ``(cameras,
    fields)`` or None (:func:`core.fit_clearance.clear_trunk`'s ``views``)."""
    if contours is None:
        return None
    out = []
    for f in range(nf):
        cf = contours[f]
        fl = [] if cf is None else cf.fields()
        use = [c for c, x in enumerate(fl) if x is not None]
        out.append(([cf.cameras[c] for c in use], [fl[c] for c in use]) if use else None)
    return out


def contour_starts(fx: FrameFitter, f: int, direction: int, q_prev: np.ndarray) -> list:
    """More starts (n + 3,) for frame f's fit from contours alone: the previous
    frame's pose ``q_prev`` (``f − direction``) and, where the frame before it was
    fitted too, their undamped constant-velocity extrapolation."""
    starts = [q_prev]
    g, h = f - direction, f - 2 * direction
    if 0 <= h < fx.nf and not fx.div[g] and not fx.div[h]:
        starts.append(2 * q_prev - np.concatenate([fx.theta[h], fx.root[h]]))
    return starts
