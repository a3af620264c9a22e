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

from . import fit_passes
from .errors import InputError
from .fit import FramePoints, SequenceSettings
from .fit_silhouette_shape import shape_from_silhouettes
from .fit_types import ShapeRecord
from .progress import Progress
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
        init = shape_from_silhouettes(init, cameras, cframes[init.frame], msgs, contour_settings)
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
        anchors = fit_passes.flow_anchors(scene, cameras, flow, cframes)
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
    if multi and (spread := fit_passes.views_spread_deg(cameras, init.root_xyz)) < (
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
    res = fit_passes.run_passes(cframes, anchors, kw, timings, t2, **passes)
    if (
        silhouette_shaped
        and anchors is not None
        and fit_passes.choose_refined(settings, anchors.cfg)
    ):
        res = fit_passes.refined_alternative(
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
