"""``python -m core fit SCENE -o fit.json``: the whole pipeline, written as a fitted state.

Runs what the scene needs: calibration from ``wand/`` when ``calibration.toml`` is
missing, tracking when ``tracks.npz`` is missing and the tracker is available, the
initialisation from ``clicks.json`` and the fit (:func:`core.fit_scene.run_scene`).
``--observations truth`` fits truth-derived surface points instead of tracks (a
development stand-in, see :mod:`core.truth_points`; the output says so).
``--cues`` chooses the observation types of every frame's weighted least squares:
``texture`` (the default: the 3-D surface points of the tracker, or the truth-derived
ones), ``contours`` (the silhouettes' occluding contours from every camera's
foreground, σ in pixels; no tracker; the metaball shape is fitted to the clicked
frame's silhouettes) or ``both``; with contours the cameras each part used are written
per frame in the state's quality (SPEC: ``quality.cameras``).
``--shape`` chooses the body shape written: ``written`` (default) fits the whole-body
metaball shape after the motion, at the fitted poses, from the deflated template
(:func:`core.metaball_surface.deflate`) — with contours to the points and silhouettes of frames
spread over the take, else to the points of the frames nearest the clicked one — for
the state only (the motion is the same as with ``template``); ``template`` keeps the
per-part shape of the shape frames, that the motion was tracked with;
``tracked`` fits it right after the shape frames and tracks with it (``--fit-shape`` is
the same; see :mod:`core.fit`); the shape fit's result is printed as a note.  Prints the
per-frame quality summary, the messages (dropped clicks, diverged frames) and the
timings; diverged frames are flagged in the file, never written as garbage.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scene", type=Path, help="scene folder")
    parser.add_argument(
        "-o", "--output", type=Path, default=None, help="fitted-state file (default SCENE/fit.json)"
    )
    parser.add_argument(
        "--observations",
        choices=("auto", "tracks", "truth"),
        default="auto",
        help="3-D observations: tracks.npz, truth-derived points (development),"
        " or auto (tracks when available)",
    )
    parser.add_argument(
        "--model", choices=("simplified", "complete"), default="complete", help="metaball model"
    )
    parser.add_argument("--frames", type=int, default=None, help="fit only the first N frames")
    parser.add_argument(
        "--points", type=int, default=3000, help="candidate truth-derived points per frame"
    )
    parser.add_argument("--predictor", choices=("ekf", "constant_velocity"), default="ekf")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--cues",
        choices=("texture", "contours", "both"),
        default="texture",
        help="observations of the fit: texture (3-D surface points, the "
        "default), contours (silhouette contours from each camera's "
        "foreground: no tracker, shape fitted to the clicked frame's "
        "silhouettes) or both",
    )
    parser.add_argument(
        "--tracks",
        type=Path,
        default=None,
        metavar="NPZ",
        help="tracker output to fit (default SCENE/tracks.npz, tracked first when missing)",
    )
    parser.add_argument(
        "--contour-sigma",
        type=float,
        default=None,
        metavar="PX",
        help="a-priori sigma of one contour observation, pixels (default 3)",
    )
    parser.add_argument(
        "--no-flow",
        dest="flow",
        action="store_false",
        help="with --cues both: no single-camera texture flow in the "
        "frames that have too few 3-D points (on by default)",
    )
    parser.add_argument(
        "--shape",
        choices=("template", "written", "tracked"),
        default="written",
        help="body shape: 'written' (default) fits the whole-body metaball "
        "shape after the motion (to the silhouettes too, with "
        "contours), for the state only; 'template' keeps the per-part "
        "shape of the shape frames; 'tracked' fits it after the shape "
        "frames and tracks with it",
    )
    parser.add_argument("--fit-shape", action="store_true", help="the same as --shape tracked")
    parser.add_argument(
        "--feet-from-points",
        action="store_true",
        help="turn each foot about its shin at the clicked frame to the heading of the "
        "points under it (off by default: on the default scene it fixes the right "
        "foot's 17 degrees but the fit as a whole loses; see core/foot_heading.py)",
    )
    parser.add_argument(
        "--smooth",
        action="store_true",
        help="smooth the whole fitted motion over the take (each joint's path by a Kalman "
        "smoother whose smoothness its likelihood chooses, then the angles solved to it; "
        "the hidden limbs' angles are smoothed anyway; off by default: it spreads a sudden "
        "kick; see core/motion_smoother.py)",
    )
    parser.add_argument(
        "--one-pass",
        action="store_true",
        help="no second pass with the late shape (bones the shape frames hardly saw, "
        "shaped over the fitted take), nor with the shape over --shape-frames: about half "
        "the fit time where a bone qualifies, but the default scene's walk 12.3 against "
        "14.0 mm (median of 4 click draws; see core/fit_late_shape.py)",
    )
    parser.add_argument(
        "--shape-frames",
        type=int,
        default=None,
        metavar="N",
        help="where the silhouettes alone shape the body (no texture points at the clicked "
        "frame) and two cameras see it from at least 60 degrees apart: its radii are "
        "solved again over N fitted frames' silhouettes and the motion fitted again with "
        "them (default 5; 0: off, one pass, about half the fit time; the orthogonal "
        "pirouette 23.35 against 28.5 mm with it, median of 4 click draws; see "
        "core/contour_shape_frames.py)",
    )
    parser.add_argument(
        "--one-flow",
        action="store_true",
        help="fit a take the silhouettes shape once, with Lucas-Kanade's texture-flow "
        "corners; by default it is fitted a second time with corners refined by least "
        "squares matching and the fit the foregrounds explain better is kept (twice the "
        "fit time; the orthogonal dance 25.05 against 26.25 mm and the pirouette 22.8 "
        "against 23.35 with it, median of 4 click draws; see core/fit_choice.py)",
    )
    parser.add_argument(
        "--prediction-start-only",
        action="store_true",
        help="fit a frame without texture points (contours alone) from the prediction "
        "only, not also from the previous frame's pose and its extrapolation: about half "
        "the fit time on a rig without points, but a fast limb may be lost (the "
        "orthogonal dance: 36 against 96 mm; see SequenceSettings.contour_starts)",
    )


def run(args: argparse.Namespace) -> int:
    from .errors import InputError, check_output
    from .fit import SequenceSettings
    from .fit_scene import run_scene
    from .progress import Progress
    from .scene import load_scene
    from .state import write_state

    choice = "tracked" if args.fit_shape else args.shape
    shape, track = ("template", False) if choice == "template" else ("fit", choice == "tracked")

    if args.frames is not None and args.frames < 1:
        raise InputError("--frames must be at least 1")
    if args.contour_sigma is not None and not args.contour_sigma > 0:
        raise InputError("--contour-sigma must be a positive number of pixels")
    if args.shape_frames is not None and (args.shape_frames < 0 or args.shape_frames == 1):
        raise InputError("--shape-frames must be 0 (off) or at least 2")
    scene = load_scene(args.scene, check_images=False)
    if args.tracks is not None and not args.tracks.is_file():
        raise InputError(f"{args.tracks}: --tracks file not found")
    csettings = None
    if args.contour_sigma is not None or args.shape_frames is not None:
        from .fit_contours import ContourSettings

        csettings = ContourSettings()
        if args.contour_sigma is not None:
            csettings.sigma_px = args.contour_sigma
        if args.shape_frames is not None:
            csettings.shape_fit_frames = args.shape_frames
    out = check_output(
        args.output if args.output is not None else scene.root / "fit.json", "the fitted state"
    )
    res = run_scene(
        scene,
        observations=args.observations,
        model=args.model,
        settings=SequenceSettings(
            predictor=args.predictor,
            shape=shape,
            shape_fit_track=track,
            foot_heading=args.feet_from_points,
            smooth_motion=args.smooth,
            contour_starts=not args.prediction_start_only,
            flow_choice=not args.one_flow,
            late_shape_points=None if args.one_pass else SequenceSettings.late_shape_points,
        ),
        progress=Progress(),
        n_points=args.points,
        seed=args.seed,
        frames=args.frames,
        cues=args.cues,
        contour_settings=csettings,
        tracks=args.tracks,
        flow="auto" if args.flow else False,
    )
    st = res.state
    if st.n_frames < scene.n_frames:  # pad unfitted frames: hold the last pose, flagged
        st = _pad(st, scene.n_frames)
    write_state(out, st)
    q = st.quality
    label = {
        "truth": "truth-derived observations (development stand-in)",
        "contours": "silhouette contours alone",
    }.get(res.source, "tracks")
    if res.source != "contours" and args.cues == "both":
        label += " and silhouette contours"
    print(f"fitted {res.state.n_frames} of {scene.n_frames} frames from {label}")
    for m in res.messages:
        print(f"  note: {m}")
    rm = q.rmse_m[np.isfinite(q.rmse_m)]
    print(
        f"points per frame: median {int(np.median(res.n_points))}; surface RMS median "
        f"{1000 * np.median(rm) if len(rm) else float('nan'):.2f} mm; diverged frames "
        f"{int(q.diverged.sum())}"
    )
    if res.contour_matches is not None:
        cr = res.contour_rms_px[np.isfinite(res.contour_rms_px)]
        print(
            f"contour pairs per frame: median {int(np.median(res.contour_matches))}; "
            f"contour RMS median {np.median(cr) if len(cr) else float('nan'):.2f} px"
        )
    tm = res.timings
    print(
        "seconds: "
        + ", ".join(f"{k} {v:.1f}" for k, v in tm.items())
        + f"; fit {tm['fit'] / res.state.n_frames:.2f} s/frame"
    )
    print(f"wrote {out}")
    return 0


def _pad(state, n_frames: int):
    from .state import FitState, Quality

    k = state.n_frames
    extra = n_frames - k
    q = state.quality
    rep = lambda a: np.concatenate([a, np.repeat(a[-1:], extra, axis=0)])  # noqa: E731
    qq = Quality(
        rmse_m=np.concatenate([q.rmse_m, np.full(extra, np.nan)]),
        theta_sigma=np.concatenate(
            [q.theta_sigma, np.full((extra, q.theta_sigma.shape[1]), np.nan)]
        ),
        converged=np.concatenate([q.converged, np.zeros(extra, bool)]),
        diverged=np.concatenate([q.diverged, np.ones(extra, bool)]),
        cameras=list(q.cameras) + [{} for _ in range(extra)],
        unobserved=None
        if q.unobserved is None
        else np.concatenate([q.unobserved, np.ones((extra, q.unobserved.shape[1]), bool)]),
    )
    return FitState(
        skeleton=state.skeleton,
        s=state.s,
        metaballs=state.metaballs,
        root_xyz=rep(state.root_xyz),
        theta=rep(state.theta),
        quality=qq,
        fps=state.fps,
        source_scene=state.source_scene,
        metaball_model=state.metaball_model,
    )
