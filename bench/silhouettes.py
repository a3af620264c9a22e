"""Silhouette benchmark: ``python -m bench.silhouettes [--scene DIR] [--out DIR]``.

1. Studio scene (default ``sample_scenes/walk_line3``): every camera's background is
   estimated from the take itself (robust temporal median, no empty plate), the
   foreground of every frame is compared with the truth masks (IoU), and the occluding
   contours are compared with the truth masks' outlines (median distance, px).
   Side by side: OpenCV's MOG2 background subtractor run over the same frames.
2. Visibility index of every part in every camera (the second paper's criterion for
   using a camera) from our metaball body against a reference splatted from the true
   mesh (:mod:`bench.visibility`): mean absolute difference and the agreement of the
   ``VI >= 0.2`` decision.  The body is ``--fit FIT.json`` when given, else the truth pose
   (``core.truth_state``) carrying the *template* metaball shape — labelled as such
   (``python -m bench.visibility SCENE FIT.json …`` prints this section alone, for the
   template and any number of fitted states).
3. Contour tracking (paper 2) on the studio scene from the image foreground alone: the
   key-joint clicks give the first pose, the metaball shape is fitted to the first frame's
   silhouettes, then the EKF tracks from contours with per-part camera selection and,
   side by side, with all cameras fused: MPJPE per 5 frames against the truth.
4. Real video (``../shared/data/video/pose2sim_single``, 4 cameras, clutter, people in
   the background, shadows): masks and contours of every camera at quarter resolution,
   written as a PNG overlay (three frames per camera); no truth exists, so the figure is
   the picture plus timing.

``--selection-scenes A,B`` runs :mod:`bench.selection` instead: per-part selection vs all
cameras fused on self-occluding studio scenes, ``--track-frames`` frames each (50 for
the full clips).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial import cKDTree

from core.background import fit_background
from core.contours import draw_contours, occluding_contours
from core.scene import load_scene

REPO = Path(__file__).resolve().parents[1]
VIDEO = REPO.parent / "shared" / "data" / "video" / "pose2sim_single" / "videos"


def _iou(a, b):
    return float((a & b).sum() / max(1, (a | b).sum()))


def _contour_distance(pred_mask, true_mask):
    """Median distance (px) from predicted contour points to the true mask's contour."""
    cons = occluding_contours(pred_mask, spacing=1.0)
    true = occluding_contours(true_mask, spacing=0.5)
    if not cons or not true:
        return float("nan")
    d, _ = cKDTree(np.vstack([c.uv for c in true])).query(np.vstack([c.uv for c in cons]))
    return float(np.median(d))


def studio(scene_dir: Path) -> None:
    scene = load_scene(scene_dir)
    truth = scene.truth_masks()
    print(
        f"\n1. Studio scene {scene.name}: {len(scene.cameras)} cameras, {scene.n_frames} frames, "
        f"{scene.image_size[0]}x{scene.image_size[1]}"
    )
    print(
        f"{'camera':8s} {'ours IoU mean/min':>18s} {'contour px':>11s} {'ms/frame':>9s}   "
        f"{'MOG2 IoU mean/min':>18s} {'ms/frame':>9s}"
    )
    for c, cam in enumerate(scene.cameras):
        frames = np.array([scene.image(cam, i, color=True) for i in range(scene.n_frames)])
        t0 = time.perf_counter()
        model = fit_background(frames)
        masks = [model.foreground(f) for f in frames]
        ours_ms = 1e3 * (time.perf_counter() - t0) / len(frames)
        ious = [_iou(m, truth[c, i]) for i, m in enumerate(masks)]
        cdist = np.nanmedian([_contour_distance(m, truth[c, i]) for i, m in enumerate(masks)])
        # peer: OpenCV MOG2, two passes over the take (the first one learns)
        mog = cv2.createBackgroundSubtractorMOG2(history=len(frames), detectShadows=True)
        t0 = time.perf_counter()
        for f in frames:
            mog.apply(f)
        mog_masks = [mog.apply(f, learningRate=0) == 255 for f in frames]
        mog_ms = 1e3 * (time.perf_counter() - t0) / (2 * len(frames))
        mog_ious = [_iou(m, truth[c, i]) for i, m in enumerate(mog_masks)]
        print(
            f"{cam:8s} {np.mean(ious):8.3f} / {np.min(ious):.3f} {cdist:11.2f} {ours_ms:9.1f}   "
            f"{np.mean(mog_ious):8.3f} / {np.min(mog_ious):.3f} {mog_ms:9.1f}"
        )


def visibility(scene_dir: Path, fit: Path | None) -> None:
    from bench.visibility import HEADER, report
    from core.state import read_state
    from core.truth_state import truth_to_state

    scene = load_scene(scene_dir)
    if fit is not None:
        state, label = read_state(fit), fit.name
    else:
        state, _ = truth_to_state(scene.truth, scene.fps)
        label = "template, truth pose"
    frames = range(0, scene.n_frames, 5)
    print(
        f"\n2. Visibility index vs the true mesh ({len(frames)} frames x "
        f"{len(scene.cameras)} cameras; the template metaball shape at the truth pose "
        "unless --fit is given); our area ignoring occlusion: whole ellipsoids, or only "
        "the outer surface, which no other ellipsoid covers"
    )
    print(HEADER)
    report(label, state, scene, frames)


def contour_tracking(scene_dir: Path, n_frames: int) -> None:
    from core.contour_track import ContourTrackSettings, fit_shape_to_contours, track_contours
    from core.fit_init import initialise
    from core.landmarks import JOINTS, METRIC_JOINTS
    from core.model_render import camera_rays
    from core.skeleton import joint_positions

    scene = load_scene(scene_dir)
    cams = scene.calibration()
    nf = min(n_frames, scene.n_frames)
    t0 = time.perf_counter()
    contours = [[] for _ in range(nf)]
    for cam in scene.cameras:
        frames = np.array([scene.image(cam, i, color=True) for i in range(scene.n_frames)])
        model = fit_background(frames)
        for f in range(nf):
            contours[f].append(occluding_contours(model.foreground(frames[f]), spacing=2.0))
    t_seg = time.perf_counter() - t0
    init = initialise(scene.clicks(), cams, model="simplified")
    rays = [camera_rays(c) for c in cams]
    t0 = time.perf_counter()
    # the clicked joints are good to a few mm: hold the pose tightly while fitting shape
    tight = ContourTrackSettings(q_sigma_theta=0.01, q_sigma_root=0.002)
    balls, th0, rt0, rms = fit_shape_to_contours(
        init.skeleton,
        init.s,
        init.metaballs,
        init.theta,
        init.root_xyz,
        cams,
        contours[0],
        tight,
        rays=rays,
    )
    t_shape = time.perf_counter() - t0
    names = [str(n) for n in scene.truth["joint_names"]]
    idx = [JOINTS.index(j) for j in METRIC_JOINTS]
    tidx = [names.index(j) for j in METRIC_JOINTS]
    truth = scene.truth["joints_xyz"][:nf][:, tidx]
    j0 = joint_positions(init.skeleton, init.theta, init.root_xyz, init.s)[idx]
    e0 = 1e3 * np.linalg.norm(j0 - truth[0], axis=1).mean()
    print(
        f"\n3. Contour tracking on {scene.name}, {nf} frames, contours from our foreground "
        f"({t_seg:.0f} s); clicked pose MPJPE {e0:.1f} mm; shape fitted to frame 0 "
        f"silhouettes (RMS {rms:.2f} px, {t_shape:.1f} s)"
    )
    print(
        f"   {'cameras':22s} {'MPJPE mm per 5 frames':>40s} {'mean':>6s} {'not updated':>11s} "
        f"{'s/frame':>7s}"
    )
    for select, label in ((True, "per-part selection"), (False, "all fused")):
        t0 = time.perf_counter()
        out = track_contours(
            init.skeleton,
            init.s,
            balls,
            th0,
            rt0,
            cams,
            contours,
            ContourTrackSettings(select=select),
        )
        dt = (time.perf_counter() - t0) / nf
        th = np.array([t.theta for t in out])
        rt = np.array([t.root for t in out])
        err = 1e3 * np.linalg.norm(
            joint_positions(init.skeleton, th, rt, init.s)[:, idx] - truth, axis=2
        ).mean(axis=1)
        curve = " ".join(f"{e:5.0f}" for e in err[::5])
        print(
            f"   {label:22s} {curve:>40s} {err.mean():6.1f} "
            f"{sum(not t.updated for t in out):11d} {dt:7.2f}"
        )


def fuse(scene_dir: Path, fit: Path) -> None:
    """Points + contours: refine a point fit with contours, frame by frame."""
    from core.contour_track import ContourTrackSettings, refine_state_with_contours
    from core.evaluate import evaluate_state
    from core.state import read_state

    scene = load_scene(scene_dir)
    cams = scene.calibration()
    contours = [[] for _ in range(scene.n_frames)]
    for cam in scene.cameras:
        frames = np.array([scene.image(cam, i, color=True) for i in range(scene.n_frames)])
        model = fit_background(frames)
        for f in range(scene.n_frames):
            contours[f].append(occluding_contours(model.foreground(frames[f]), spacing=2.0))
    state = read_state(fit)
    t0 = time.perf_counter()
    cfg = ContourTrackSettings(sigma_px=3.0, huber_px=6.0, iterations=10)
    ref = refine_state_with_contours(state, cams, contours, cfg)
    dt = (time.perf_counter() - t0) / state.n_frames
    a = evaluate_state(state, scene.truth)
    b = evaluate_state(ref, scene.truth)
    print(
        f"\n3b. Points + contours ({fit}): MPJPE {a.mpjpe_mm:.1f} -> {b.mpjpe_mm:.1f} mm, "
        f"segment orientation {a.segment_orientation_rmse_deg:.1f} -> "
        f"{b.segment_orientation_rmse_deg:.1f} deg ({dt:.1f} s/frame)"
    )
    print(
        "   per joint mm: "
        + ", ".join(f"{k} {a.per_joint_mm[k]:.0f}->{b.per_joint_mm[k]:.0f}" for k in a.per_joint_mm)
    )


def real_video(out: Path, scale: float = 0.25) -> None:
    if not VIDEO.is_dir():
        print(f"\n4. Real video: skipped ({VIDEO} not found)")
        return
    print(f"\n4. Real video pose2sim_single at {scale:g}x: masks and contours per camera")
    rows = []
    for path in sorted(VIDEO.glob("cam*.mp4")):
        cap = cv2.VideoCapture(str(path))
        frames = []
        while True:
            ok, img = cap.read()
            if not ok:
                break
            small = cv2.resize(img, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
            frames.append(cv2.cvtColor(small, cv2.COLOR_BGR2RGB))
        cap.release()
        frames = np.array(frames)
        t0 = time.perf_counter()
        model = fit_background(frames)
        t_bg = time.perf_counter() - t0
        t0 = time.perf_counter()
        masks = [model.foreground(f, threshold=6.0) for f in frames]
        t_fg = 1e3 * (time.perf_counter() - t0) / len(frames)
        area = np.mean([m.mean() for m in masks])
        tiles = []
        for i in (0, len(frames) // 2, len(frames) - 1):
            tiles.append(draw_contours(frames[i], occluding_contours(masks[i])))
        rows.append(cv2.resize(np.hstack(tiles), (3 * 270, 480)))
        print(
            f"  {path.stem}: {frames.shape[0]} frames {frames.shape[2]}x{frames.shape[1]}, "
            f"background {t_bg:.1f} s, foreground {t_fg:.1f} ms/frame, "
            f"mean foreground {100 * area:.1f} % of the image"
        )
    out.mkdir(parents=True, exist_ok=True)
    png = out / "silhouettes_pose2sim.png"
    grid = (
        np.vstack([np.hstack(rows[:2]), np.hstack(rows[2:4])])
        if len(rows) == 4
        else np.vstack(rows)
    )
    cv2.imwrite(str(png), cv2.cvtColor(grid, cv2.COLOR_RGB2BGR))
    print(f"  wrote {png}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", type=Path, default=REPO / "sample_scenes" / "walk_line3")
    ap.add_argument("--out", type=Path, default=REPO / "out" / "bench")
    ap.add_argument("--fit", type=Path, default=None, help="fitted state of --scene")
    ap.add_argument("--skip-video", action="store_true", help="leave out the real video")
    ap.add_argument("--track-frames", type=int, default=25, help="frames of contour tracking")
    ap.add_argument(
        "--fuse", action="store_true", help="also fuse contours into a point fit (needs --fit)"
    )
    ap.add_argument(
        "--selection-scenes",
        default=None,
        help="only run bench.selection on these comma-separated scenes "
        "(e.g. dance_line3,dance_ortho3,pirouette_line3,pirouette_ortho3): "
        "per-part camera selection vs all cameras fused",
    )
    args = ap.parse_args(argv)
    if args.selection_scenes:
        from bench.selection import main as selection_main

        return selection_main(
            ["--scenes", args.selection_scenes, "--frames", str(args.track_frames)]
        )
    studio(args.scene)
    visibility(args.scene, args.fit)
    contour_tracking(args.scene, args.track_frames)
    if args.fuse and args.fit is not None:
        fuse(args.scene, args.fit)
    if not args.skip_video:
        real_video(args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
