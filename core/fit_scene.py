"""Fit a scene folder: calibration if needed, observations, initialisation, sequence fit.

:func:`run_scene` is ``python -m core fit``'s engine and :func:`fit_scene` the Blender
add-on's entry point.  Observations come from the tracker (``SCENE/tracks.npz``, made
on first use) or, for development, from the truth (points on the true mesh with noise
and outliers, :mod:`core.truth_points`); the fit itself is
:func:`core.fit.fit_sequence`.

Cues (``cues``, issue 7 item 6): ``"texture"`` (the default) fits those 3-D points
alone; ``"contours"`` needs no tracker: every camera's foreground (robust temporal
median background) gives each frame's occluding contours
(:func:`core.fit_contours.scene_contours`), the metaball shape is fitted to the clicked
frame's silhouettes after the click initialisation
(:func:`core.contour_track.fit_shape_to_contours`), and every frame is fitted to its
contours; ``"both"`` adds the contours to the points in every pose solve (and shapes the
body from the silhouettes, as with contours alone, when the clicked frame has too few
points); with either, the head and neck use no contours (:data:`CONTOUR_SKIP_PARTS`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from .errors import InputError
from .fit import FramePoints, SequenceSettings, fit_sequence
from .fit_types import ShapeRecord
from .progress import Progress, prefixed
from .state import FitState


# -- observation sources ------------------------------------------------------------------
def observations_from_tracks(path, n_frames: int) -> list[FramePoints]:
    """Per-frame observations from a tracker's ``tracks.npz``.

    Reads ``xyz`` (F, P, 3) metres with NaN where a trajectory is not measured, and
    optionally ``sigma`` (F, P) or ``sigma_xyz`` (F, P, 3) metres (default 3 mm), and
    ``uv`` (F, P, C, 2) pixels, NaN where camera c did not measure the point (the
    points' ``views``, whose lines of sight the fit keeps free of body); the trajectory
    id is the index P.
    """
    from pathlib import Path

    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: cannot be read as .npz ({exc})") from exc
    if "xyz" not in data:
        raise InputError(f"{path}: is missing the array 'xyz' (F, P, 3)")
    xyz = np.asarray(data["xyz"], float)
    if xyz.ndim != 3 or xyz.shape[2] != 3 or xyz.shape[0] != n_frames:
        raise InputError(f"{path}: 'xyz' has shape {list(xyz.shape)}, expected ({n_frames}, P, 3)")
    sigma = np.asarray(data.get("sigma", np.full(xyz.shape[:2], 0.003)), float)
    if "sigma" not in data and "sigma_xyz" in data:  # per-axis σ (F, P, 3): their RMS
        sx = np.asarray(data["sigma_xyz"], float)
        if sx.shape == xyz.shape:
            sigma = np.sqrt(np.mean(sx**2, axis=2))
    if sigma.shape != xyz.shape[:2]:
        sigma = np.full(xyz.shape[:2], 0.003)
    ids = np.arange(xyz.shape[1])
    views = None  # which cameras measured each point: finite image points (F, P, C, 2)
    uv = data.get("uv")
    if uv is not None and uv.ndim == 4 and uv.shape[:2] == xyz.shape[:2] and uv.shape[3] == 2:
        views = np.all(np.isfinite(uv), axis=3)
    out = []
    for f in range(n_frames):
        ok = np.all(np.isfinite(xyz[f]), axis=1) & np.isfinite(sigma[f]) & (sigma[f] > 0)
        out.append(
            FramePoints(
                xyz=xyz[f, ok],
                sigma=sigma[f, ok],
                ids=ids[ok],
                views=None if views is None else views[f, ok],
            )
        )
    return out


@dataclass
class SceneFit:
    """Result of :func:`run_scene`: the state, the messages, timings (seconds)."""

    state: FitState
    messages: list
    timings: dict
    source: str
    n_points: np.ndarray
    shape: ShapeRecord | None = None  # the whole-body shape fit's record, when it ran
    cues: str = "texture"
    #: (F,) contour pairs and their inlier RMS (px) at the fitted pose (None: no contours)
    contour_matches: np.ndarray | None = None
    contour_rms_px: np.ndarray | None = None
    hidden: np.ndarray | None = None  # (F, n) bool: DOFs held for want of observations


def run_scene(
    scene,
    observations: str = "auto",
    model: str = "complete",
    settings: SequenceSettings | None = None,
    progress: Progress | None = None,
    n_points: int = 3000,
    seed: int = 0,
    frames: int | None = None,
    cues: str = "texture",
    tracks=None,
    contour_settings=None,
    flow="auto",
) -> SceneFit:
    """The whole pipeline on a loaded :class:`core.scene.Scene`.

    Parameters
    ----------
    observations : ``"tracks"`` (``SCENE/tracks.npz``, tracked first when the tracker
        is available and the file is missing), ``"truth"`` (truth-derived points, for
        development; needs ``truth.npz``) or ``"auto"`` (tracks when possible, else
        truth-derived with a message saying so)
    model : metaball model, ``"simplified"`` or ``"complete"``
    frames : fit only the first ``frames`` frames (default all)
    cues : ``"texture"`` (3-D points only), ``"contours"`` (silhouette contours only, no
        tracker, no points) or ``"both"``
    tracks : path of the tracker's output to use (default ``SCENE/tracks.npz``; tracked
        there first when missing)
    contour_settings : :class:`core.fit_contours.ContourSettings` (None: its defaults)
    flow : :class:`core.fit_flow.FlowSettings`, True (its defaults), False / None (off)
        or ``"auto"`` (on with ``cues="both"``) — single-camera texture flow on the
        fitted body (:mod:`core.fit_flow`) as a further observation type, by default in
        the frames with too few 3-D points only
    """
    from .fit_init import initialise

    if cues not in CUES:
        raise ValueError(f"unknown cues {cues!r} (expected one of {CUES})")

    timings, msgs = {}, []
    t0 = time.perf_counter()
    if not scene.calibration_path.is_file():
        if not scene.has_wand:
            raise InputError(
                f"{scene.calibration_path}: not found and the scene has no "
                "wand/ sequence to calibrate from"
            )
        from .calibrate import calibrate_scene
        from .calibration_io import write_calibration

        rep = calibrate_scene(scene, progress=progress)
        write_calibration(scene.calibration_path, rep.cameras, rep.metadata())
        msgs.append(f"calibrated from the wand: {scene.calibration_path}")
        timings["calibration"] = time.perf_counter() - t0
    cameras = scene.calibration()
    nf = scene.n_frames if frames is None else min(int(frames), scene.n_frames)
    t1 = time.perf_counter()
    source = "contours" if cues == "contours" else _choose_source(scene, observations)
    if source == "contours":
        from .fit import FramePoints

        obs = [FramePoints(np.zeros((0, 3)), np.zeros(0)) for _ in range(nf)]
    elif source == "tracks":
        from pathlib import Path

        tracks = scene.root / "tracks.npz" if tracks is None else Path(tracks)
        if not tracks.is_file():
            _run_tracker(scene, tracks, progress)
            timings["tracking"] = time.perf_counter() - t1
        obs = observations_from_tracks(tracks, scene.n_frames)[:nf]
    else:
        from .truth_points import truth_observations

        if observations == "auto":
            msgs.append("no tracker output: using truth-derived observations (development)")
        obs = truth_observations(
            scene.truth, cameras, n_points=n_points, seed=seed, frames=range(nf)
        )
        timings["observations"] = time.perf_counter() - t1
    cframes = None
    if cues != "texture":
        contour_settings = _skip_settings(contour_settings)
        t3 = time.perf_counter()
        cframes, cmsgs = _scene_contour_frames(scene, cameras, nf, cues, contour_settings, progress)
        msgs += cmsgs
        timings["contours"] = time.perf_counter() - t3
    t2 = time.perf_counter()
    init = initialise(
        scene.clicks(),
        cameras,
        model=model,
        path=str(scene.root / "clicks.json"),
        hip_lean=(settings or SequenceSettings()).hip_lean,
    )
    msgs += init.clicks.messages()
    if init.frame >= nf:
        raise InputError(
            f"{scene.root / 'clicks.json'}: clicked frame {init.frame} is "
            f"outside the {nf} fitted frames"
        )
    min_points = (settings or SequenceSettings()).min_points
    silhouette_shaped = False
    if cframes is not None and (cues == "contours" or len(obs[init.frame].xyz) < min_points):
        # no points to shape the body at the clicked frame: the silhouettes do
        init = _shape_from_silhouettes(init, cameras, cframes[init.frame], msgs, contour_settings)
        silhouette_shaped = True
        # the shape is the silhouettes': no further shape frames, however the fit is
        # called (core fit passes its own settings and had two until da6b412, the add-on
        # and the benchmarks one).  Without points a second shape frame leaves the shape
        # as it is and only changes how the motion starts; single runs, one frame / two:
        # contours alone with the second pass, the sweater walk 19.8 / 19.2, the skin
        # walk 17.0 / 20.2 mm; cues both (flow, one pass): the skin walk 16.9 / 20.9,
        # walk_ortho3 17.6 / 17.1 mm (limb segments 43.4 / 20.6 deg).
        settings = replace(settings or SequenceSettings(), shape_frames=1)
    settings = settings or SequenceSettings()
    anchors = None
    if flow == "auto":
        flow = cues == "both"
    if flow:
        anchors = _flow_anchors(scene, cameras, flow, cframes)
    kw = dict(
        fps=scene.fps,
        source_scene=str(scene.root),
        metaball_model=model,
        progress=progress,
        cameras=cameras,
        flow=anchors,
    )
    silhouette_pass = (  # the written shape is what such a second pass tracks with
        silhouette_shaped
        and anchors is None
        and settings.silhouette_second_pass
        and settings.shape == "fit"
    )
    multi = (  # a one-pass fit (no late shape: core fit --one-pass) keeps one pass here too
        silhouette_shaped
        and contour_settings.shape_fit_frames > 1
        and settings.late_shape_points is not None
    )
    if multi and (spread := _views_spread_deg(cameras, init.root_xyz)) < (
        contour_settings.shape_frames_min_spread_deg
    ):
        multi = False
        msgs.append(
            f"shape over several frames: not solved, the cameras see the body from "
            f"directions within {spread:.0f} deg of each other"
        )
    passes = dict(
        obs=obs,
        init=init,
        settings=settings,
        multi=multi,
        silhouette_pass=silhouette_pass,
        contour_settings=contour_settings,
    )
    res = _fit_passes(cframes, anchors, kw, timings, t2, **passes)
    if silhouette_shaped and anchors is not None and _choose_refined(settings, anchors.cfg):
        res = _refined_alternative(
            res, scene, cameras, cframes, anchors.cfg, kw, timings, passes, progress
        )
    timings["fit"] = time.perf_counter() - t2
    timings["total"] = time.perf_counter() - t0
    if res.shape is not None:
        timings["shape_fit"] = res.shape.seconds
    return SceneFit(
        state=res.state,
        messages=msgs + res.messages,
        timings=timings,
        source=source,
        n_points=res.n_points,
        shape=res.shape,
        cues=cues,
        contour_matches=None if cframes is None else res.contour_matches,
        contour_rms_px=None if cframes is None else res.contour_rms_px,
        hidden=res.hidden,
    )


def _fit_passes(
    cframes,
    anchors,
    kw,
    timings,
    t_start,
    *,
    obs,
    init,
    settings,
    multi,
    silhouette_pass,
    contour_settings,
):
    """The sequence fit and the pass after it that :func:`run_scene` chose: the shape
    over several frames, the second pass with the written shape, or the late shape."""
    res = fit_sequence(
        obs, init, settings, contours=cframes, defer_shape=multi or not silhouette_pass, **kw
    )
    if multi and (~res.state.quality.diverged).sum() > 1:
        return _frames_shape_pass(
            obs, init, settings, res, cframes, anchors, kw, timings, t_start, contour_settings
        )
    if silhouette_pass and res.shape is not None and res.shape.frame_ok.any():
        return _second_pass(
            obs,
            init,
            settings,
            res,
            cframes,
            anchors,
            kw,
            timings,
            time.perf_counter() - t_start,
        )
    if res.late_shape is not None:
        return _late_pass(obs, init, settings, res, cframes, anchors, kw, timings, t_start)
    return res


def _choose_refined(settings, flow) -> bool:
    """Whether a fit with the sequence settings ``settings`` and the flow settings
    ``flow`` is made again with refined corners (a take the silhouettes shaped)."""
    return bool(settings.flow_choice and not flow.refine_lsm)


def _refined_alternative(first, scene, cameras, cframes, cfg, kw, timings, passes, progress):
    """The take fitted again with LSM-refined flow corners; the fit whose body the
    foregrounds explain better is returned (:func:`core.fit_choice.choose`), with a
    message giving both totals."""
    from .fit_choice import choose

    t0 = time.perf_counter()
    anchors = _flow_anchors(scene, cameras, replace(cfg, refine_lsm=True), cframes)
    kw = {**kw, "flow": anchors, "progress": prefixed(progress, "refined corners: ")}
    alt_timings: dict = {}
    second = _fit_passes(_fresh(cframes, None), anchors, kw, alt_timings, t0, **passes)
    best, totals = choose([first.state, second.state], cameras, cframes)
    timings["refined_alternative"] = time.perf_counter() - t0
    kept = ("Lucas–Kanade's corners", "LSM-refined corners")[best]
    note = (
        "texture flow: the take fitted with Lucas–Kanade's corners and with LSM-refined "
        f"ones, their bodies disagreeing with the foregrounds at {totals[0]:,.0f} / "
        f"{totals[1]:,.0f} pixels over the take: the fit with {kept} kept"
    )
    res = (first, second)[best]
    return replace(res, messages=res.messages + [note])


def _second_pass(obs, init, settings, first, cframes, anchors, kw, timings, seconds):
    """The motion fitted again, tracked with the whole-body shape of the ``first`` pass.

    A take shaped from one frame's silhouettes tracks a shape that only that posture
    showed; the first pass's written shape follows the silhouettes (and any points) of
    frames spread over the take.  The second pass keeps it (``shape = "template"``:
    nothing to re-solve without points), on fresh contour frames and flow anchors; the
    result carries the first pass's shape record.
    """
    timings["first_pass"] = seconds
    res = fit_sequence(
        obs,
        replace(init, metaballs=first.state.metaballs),
        replace(settings, shape="template", late_shape_points=None),
        contours=_fresh(cframes, anchors),
        **kw,
    )
    note = (
        "second pass: the motion tracked with the first pass's whole-body shape "
        f"({int(first.state.quality.diverged.sum())} -> "
        f"{int(res.state.quality.diverged.sum())} diverged frames)"
    )
    shape_msgs = [m for m in first.messages if m.startswith("whole-body shape")]
    return replace(res, shape=first.shape, messages=shape_msgs + [note] + res.messages)


def _frames_shape_pass(obs, init, settings, first, cframes, anchors, kw, timings, t_start, cfg):
    """The motion fitted again with the radii of several of the ``first`` pass's frames.

    The clicked frame's silhouettes shaped the body (:func:`_shape_from_silhouettes`);
    the radii are re-solved over ``cfg.shape_fit_frames`` fitted frames, evenly spaced
    among those not diverged (:func:`core.contour_shape_frames.fit_shape_to_frames`),
    then the take is fitted again from the clicks with that shape.  The whole-body
    shape written to the state starts from the clicked frame's (``shape_start``).
    """
    from .contour_shape_frames import fit_shape_to_frames
    from .contour_track import ContourTrackSettings

    timings["first_pass"] = time.perf_counter() - t_start
    st = first.state
    ok = np.flatnonzero(~st.quality.diverged)
    pick = np.unique(ok[np.round(np.linspace(0, len(ok) - 1, cfg.shape_fit_frames)).astype(int)])
    sigma = np.repeat(_radius_sigma(init.skeleton, init.metaballs, cfg)[:, None], 3, axis=1)
    if cfg.shape_frames_along_sigma_m is not None:
        sigma[:, 2] = cfg.shape_frames_along_sigma_m
    balls, _, _, rms = fit_shape_to_frames(
        init.skeleton,
        init.s,
        init.metaballs,
        st.theta[pick],
        st.root_xyz[pick],
        kw["cameras"],
        [cframes[f].contours for f in pick],
        ContourTrackSettings(),
        radius_prior_m=sigma,
        pose_sigma_rad=cfg.shape_frames_pose_sigma_rad,
        root_sigma_m=cfg.shape_frames_root_sigma_m,
        rays=cframes[pick[0]].rays,
    )
    if not np.isfinite(rms):
        note = "shape over several frames: too few contour pairs, the clicked frame's kept"
        return replace(first, messages=first.messages + [note])
    moved = np.abs(balls.radii - init.metaballs.radii) * 1000
    most, axis = np.unravel_index(np.argmax(moved), moved.shape)
    note = (
        f"shape re-solved over frames {pick.tolist()}'s silhouettes (contour RMS "
        f"{rms:.2f} px before the last step; radii moved {np.median(moved):.0f} mm median, "
        f"{moved.max():.0f} mm at most, {init.skeleton.bone_names[init.metaballs.bone[most]]}"
        f"'s {'xyz'[axis]}): the motion fitted again with it"
    )
    kw = {**kw, "progress": prefixed(kw.get("progress"), "second pass (shape over frames): ")}
    res = fit_sequence(
        obs,
        replace(init, metaballs=balls),
        settings,
        contours=_fresh(cframes, anchors),
        defer_shape=True,
        shape_start=init.metaballs,
        **kw,
    )
    return replace(res, messages=[note] + res.messages)


def _views_spread_deg(cameras, point) -> float:
    """The largest angle between two cameras' lines of sight to ``point`` (3,), degrees."""
    d = np.array([np.asarray(point, float) - cam.center for cam in cameras])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return float(np.degrees(np.arccos(np.clip((d @ d.T).min(), -1.0, 1.0))))


def _fresh(cframes, anchors):
    """Contour frames without a fit's cached state, and the flow's anchors cleared."""
    from .fit_contours import ContourFrame

    if anchors is not None:
        anchors.clear()
    if cframes is None:
        return None
    return [
        None if cf is None else ContourFrame(cf.cameras, cf.contours, cf.cfg, rays=cf.rays)
        for cf in cframes
    ]


def _late_pass(obs, init, settings, first, cframes, anchors, kw, timings, t_start):
    """The motion fitted again, tracked with the ``first`` pass's late shape
    (:mod:`core.fit_late_shape`: the parts the shape frames hardly saw, shaped from the
    fitted take)."""
    timings["first_pass"] = time.perf_counter() - t_start
    late = first.late_shape
    kw = {**kw, "progress": prefixed(kw.get("progress"), "second pass (late shape): ")}
    res = fit_sequence(obs, init, settings, contours=_fresh(cframes, anchors), shape0=late, **kw)
    return replace(res, messages=[late.message()] + res.messages)


#: The observation types ``run_scene`` / ``python -m core fit --cues`` can fit.
CUES = ("texture", "contours", "both")

#: Body parts whose contours are not used with ``cues="both"`` or ``"contours"`` (unless
#: the contour settings name their own ``skip_parts``): the head's template metaballs do
#: not follow a real head's outline (hair, face, a neck that the template makes a
#: cylinder).  With points fitting the rest of the body its contour pairs only bent the
#: neck (walk_line3, real tracks: MPJPE 28.6 -> 25.8 mm, head 93 -> 25 mm); with contours
#: alone the head and neck then follow the trunk and the clicked posture (walk, line3,
#: with the silhouette limb search: skin 35.1 -> 29.0 mm, sweater 32.1 -> 30.4 mm).
CONTOUR_SKIP_PARTS = ("head", "neck")


def _skip_settings(cfg):
    """The contour settings of a fit with contours: ``cfg`` (default
    :class:`core.fit_contours.ContourSettings`) with :data:`CONTOUR_SKIP_PARTS` unless it
    names parts to skip itself."""
    from .fit_contours import ContourSettings

    cfg = cfg or ContourSettings()
    return cfg if cfg.skip_parts else replace(cfg, skip_parts=CONTOUR_SKIP_PARTS)


def _scene_contour_frames(scene, cameras, nf: int, cues: str, cfg, progress):
    """Per-frame :class:`core.fit_contours.ContourFrame` list (or None when no camera
    is usable with ``cues="both"``) and the messages; with ``cues="contours"`` and no
    usable camera, InputError."""
    from .fit_contours import contour_frames, scene_contours

    sc = scene_contours(scene, cameras, nf, cfg, progress=progress)
    msgs = list(sc.messages)
    if not sc.camera_ok.any():
        if cues == "contours":
            raise InputError(
                f"{scene.root / 'images'}: no camera gives a usable foreground "
                "(a plausible person mask in at least half of the frames), so "
                "--cues contours has no silhouettes to fit"
            )
        msgs.append("no camera gives a usable foreground: the contours are not used")
        return None, msgs
    missing = int((~sc.view_ok[:, sc.camera_ok]).sum())
    if missing:
        msgs.append(
            f"{missing} camera views of usable cameras gave no plausible foreground "
            "(no contours there)"
        )
    return contour_frames(cameras, sc.contours, cfg), msgs


def _flow_anchors(scene, cameras, flow, cframes):
    """The :class:`core.fit_flow.FlowAnchors` of a scene: its grey images, read on demand
    and kept for the last few frames only (the flow reads two neighbouring frames)."""
    from .fit_flow import FlowAnchors, FlowSettings

    cache: dict = {}

    def image(c, f):
        if (c, f) not in cache:
            if len(cache) >= 4 * len(cameras):
                del cache[next(iter(cache))]  # the oldest read
            cache[c, f] = scene.image(c, f)
        return cache[c, f]

    cfg = flow if isinstance(flow, FlowSettings) else FlowSettings()
    rays = None if not cframes else cframes[0].rays
    return FlowAnchors(cameras, image, cfg, rays=rays)


#: σ of a metaball radius about the template's in the silhouette shape fit, metres
SHAPE_RADIUS_SIGMA_M = 0.02


def _center_sigma(skel, balls, cfg) -> np.ndarray | None:
    """σ (M,) of each metaball centre in the silhouette shape fit (NaN: held), metres."""
    if cfg is None or cfg.shape_center_sigma_m is None:
        return None
    names = np.array(skel.bone_names)[balls.bone]
    free = np.isin(names, cfg.shape_center_parts) & ~np.isin(names, cfg.shape_held_parts)
    return np.where(free, cfg.shape_center_sigma_m, np.nan)


def _radius_sigma(skel, balls, cfg) -> np.ndarray:
    """σ (M,) of each metaball's radii about the template's in the silhouette shape fit:
    ``cfg.shape_held_sigma_m`` for the parts whose template shape is kept, metres."""
    sigma = np.full(len(balls), SHAPE_RADIUS_SIGMA_M)
    if cfg is not None and cfg.shape_held_parts:
        held = np.isin(np.array(skel.bone_names)[balls.bone], cfg.shape_held_parts)
        sigma[held] = cfg.shape_held_sigma_m
    return sigma


def _containment(cframe, cfg) -> dict:
    """The containment keywords of :func:`core.contour_shape.fit_shape_to_contours`."""
    if cfg is None or not cfg.shape_containment_px:
        return {}
    return {"fields": cframe.fields(), "sigma_contain_px": cfg.shape_containment_px}


def _shape_from_silhouettes(init, cameras, cframe, msgs, cfg=None):
    """The initialisation with its metaball radii, the centres of
    ``cfg.shape_center_parts`` (:class:`core.fit_contours.ContourSettings`) and a refined
    pose fitted to the clicked frame's silhouettes
    (:func:`core.contour_track.fit_shape_to_contours`; the clicked pose held tightly)."""
    from .contour_track import ContourTrackSettings, fit_shape_to_contours

    tight = ContourTrackSettings(q_sigma_theta=0.01, q_sigma_root=0.002)
    balls, th, rt, rms = fit_shape_to_contours(
        init.skeleton,
        init.s,
        init.metaballs,
        init.theta,
        init.root_xyz,
        cameras,
        cframe.contours,
        tight,
        radius_prior_m=_radius_sigma(init.skeleton, init.metaballs, cfg),
        rays=cframe.rays,
        center_prior_m=_center_sigma(init.skeleton, init.metaballs, cfg),
        **_containment(cframe, cfg),
    )
    if not np.isfinite(rms) or not (np.all(np.isfinite(th)) and np.all(np.isfinite(rt))):
        msgs.append(
            f"frame {init.frame}: too few silhouette contour pairs for the shape: "
            "the template shape is kept"
        )
        return init
    moved = np.linalg.norm(balls.center0 - init.metaballs.center0, axis=1) * 100
    shift = (
        f"; {int((moved > 0).sum())} metaball centres moved, {np.median(moved[moved > 0]):.1f}"
        f" cm median, {moved.max():.1f} cm at most"
        if moved.max() > 0
        else ""
    )
    held = cfg.shape_held_parts if cfg is not None else ()
    kept = f"; the template shape kept: {', '.join(held)}" if held else ""
    msgs.append(
        f"shape fitted to frame {init.frame}'s silhouettes (contour RMS {rms:.2f} px "
        f"before the last step{shift}{kept})"
    )
    return replace(init, metaballs=balls, theta=th, root_xyz=rt)


def fit_scene(scene, progress: Progress | None = None, **kwargs) -> FitState:
    """The fitted state of a scene (the Blender add-on's entry point); see
    :func:`run_scene` for the keyword arguments."""
    return run_scene(scene, progress=progress, **kwargs).state


def _tracker_available() -> bool:
    import importlib.util

    return (
        importlib.util.find_spec("core.tracking") is not None
        and importlib.util.find_spec("core.track_cli") is not None
    )


def _choose_source(scene, observations: str) -> str:
    if observations not in ("auto", "tracks", "truth"):
        raise ValueError(f"unknown observation source {observations!r}")
    if observations == "truth":
        if not scene.has_truth:
            raise InputError(
                f"{scene.root / 'truth.npz'}: truth-derived observations need the scene's truth"
            )
        return "truth"
    have = (scene.root / "tracks.npz").is_file() or _tracker_available()
    if observations == "tracks" or have:
        if not have:
            raise InputError(
                f"{scene.root / 'tracks.npz'}: not found and the tracker "
                "(core.tracking) is not available"
            )
        return "tracks"
    if not scene.has_truth:
        raise InputError(
            f"{scene.root}: has no tracks.npz, the tracker is not available "
            "and there is no truth.npz to derive observations from"
        )
    return "truth"


def _run_tracker(scene, out, progress) -> None:
    """Run ``python -m core track SCENE -o tracks.npz`` in-process.

    Bad input the tracker meets (clicks, calibration, images) propagates as its own
    :class:`~core.errors.InputError`, so the user sees one line naming the file.
    """
    from .blas_threads import single_blas_thread
    from .cli import build_parser

    args = build_parser().parse_args(["track", str(scene.root), "-o", str(out)])
    if getattr(args, "_missing", None):
        raise InputError(
            f"{scene.root / 'tracks.npz'}: not found and the tracker "
            "(core.tracking) is not available"
        )
    with single_blas_thread():  # as `python -m core track` runs it
        rc = int(args._run(args) or 0)
    if rc != 0 or not out.is_file():
        raise InputError(f"{scene.root}: tracking failed (exit status {rc})")
