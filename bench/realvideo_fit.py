"""Body fit on real video, checked in a held-out camera: ``python -m bench.realvideo_fit``.

Data: ``../shared/data/video/pose2sim_single`` (4 synchronised portrait cameras, 100
frames at 60 fps, a person with bare skin doing a balance/lunge movement in a cluttered
room; Qualisys calibration).  There is no joint truth, so the check is the silhouette
overlap in a camera the fit never saw.

Configurations (``--configs``): by default the body is fitted with **cam02, cam03,
cam04** — front, back-left and back-right of the person (azimuths about 12°, 135° and
206° around him; the largest gap between neighbours is 166°) — and **cam01**
(front-left, −38°) is held out.  With these three no two fitting cameras are closer
than 71°, too far apart for LSM on bare skin (no surface point survives at frame 0),
so the texture-only fit has no observations; ``cam01,cam02,cam04:cam03`` (cam01 and
cam02 are 50° apart) gives the texture-only fit its points, with cam03 held out.

1. **Initialisation** from ``bench/data/pose2sim_clicks.json``: 15 key joints clicked
   by eye at frame 0 (full-resolution pixels), forward-intersected from the fitting
   cameras' clicks only; posture and bone scales from :func:`core.fit_init.initialise`.
2. **Foreground** of every camera at ``--mask-scale`` (quarter resolution, 272 × 480
   px): robust temporal median (:func:`core.background.fit_background`) — the person
   holds the lunge for most of the take and burns into it — repaired with the
   calibration photo of the empty force plate (:func:`core.background.with_reference`,
   :func:`read_empty_scene`).  The person's mask is the foreground components touching
   a box around the clicked joints projected into that camera (the other people and
   the clutter are left out); occluding contours of the fitting cameras.
3. Three fits of the same frames, side by side:

   * **texture only** — LSM surface points (Wallis pre-filter, half resolution,
     :func:`core.surface.measure_surface` seeded by NCC along epipolar lines from
     points between the clicked joints, in the fitting camera closest in angle to
     another; tracked by :func:`core.tracking.track`; :mod:`bench.realvideo_texture`) fitted by
     :func:`core.fit.fit_sequence`; frames without enough points are marked diverged
     and hold the prediction;
   * **contours only** — metaball radii from frame 0's silhouettes
     (:func:`core.contour_track.fit_shape_to_contours`), then the EKF contour tracker
     (:func:`core.contour_track.track_contours`) with per-part camera selection by the
     visibility index (:data:`CONTOUR_CFG`); ``--compare-selection`` adds the
     motion-ranked selection and all cameras fused;
   * **texture + contours** — the contour EKF with each frame's point-fit pose as a
     direct measurement of ``[θ, root]`` before the contour update
     (:func:`core.fused_track.track_fused`: σ from the point fit's normal matrix,
     floored; gated; diverged frames contribute nothing);
   * **texture, refined** — every frame of the texture fit refined with its own
     contours (:func:`core.contour_track.refine_state_with_contours`, same selection);
     frames the texture fit marked diverged start from the contour track's pose.

4. **Check**: each fitted body rendered into the held-out camera
   (:func:`core.silhouette_check.body_masks`) against the person's mask there: IoU per
   frame (mean, median, 10th percentile, first and last frame) and the IoU after one
   image shift fitted over all frames (:func:`core.silhouette_check.shift_iou`: a
   calibration offset of the held-out camera moves every frame alike: the joints
   triangulated from the cam02–cam04 clicks project a median 44 px (full resolution),
   mostly up and left, from where they were clicked in cam01).  Overlays of a few
   frames (outlines over the held-out image) and the four cameras' masks go to
   ``--out/<config>/`` (:mod:`bench.realvideo_draw`).

Run: ``python -m bench.realvideo_fit [--frames 100] [--configs ...]`` (one
configuration of 100 frames takes about 5 minutes on 2 free cores; tracking is cached
in ``--out``).
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from bench.realvideo import scale_camera
from bench.realvideo_draw import draw_check, draw_masks
from bench.realvideo_inputs import (
    FPS,
    keep_in_region,
    load_clicks,
    person_region,
    read_empty_scene,
    read_video,
)
from bench.realvideo_texture import frame_points, reference_camera, texture_tracks
from core.background import fit_background, with_reference
from core.camera import Camera
from core.contour_track import ContourTrackSettings
from core.contours import occluding_contours
from core.errors import InputError
from core.formats import read_qca

REPO = Path(__file__).resolve().parents[1]
DATA = REPO.parent / "shared" / "data" / "video" / "pose2sim_single"
CLICKS = Path(__file__).resolve().parent / "data" / "pose2sim_clicks.json"
FIT_CAMS = ("cam02", "cam03", "cam04")
CHECK_CAM = "cam01"
#: Contour tracking settings (quarter-resolution pixels): per-part cameras chosen by the
#: visibility index (≥ 0.2) alone — adding the motion ranking lost the arms within 5
#: frames on this take (``--compare-selection`` prints it) — relinearised 8 times per
#: frame, contour ↔ rim pairs up to 20 px apart (fast arm swings at 60 fps).
CONTOUR_CFG = ContourTrackSettings(select=True, observability=False, iterations=8, max_dist_px=20.0)


# -- fits ---------------------------------------------------------------------------------
def fused_fit(
    state_tex, theta_con: np.ndarray, root_con: np.ndarray, cams: list[Camera], contours: list, cfg
):
    """Texture fit refined with contours; its diverged frames take the contour track's
    pose (the texture fit kept only a prediction there), then are refined likewise."""
    import copy

    from core.contour_track import refine_state_with_contours

    st = copy.deepcopy(state_tex)
    div = st.quality.diverged.copy()
    st.theta[div], st.root_xyz[div] = theta_con[div], root_con[div]
    st.quality.diverged[:] = False
    out = refine_state_with_contours(st, cams, contours, cfg)
    out.quality.diverged[:] = div  # the texture fit's verdict, for the report
    return out, div


def _stats(x: np.ndarray) -> str:
    x = x[np.isfinite(x)]
    if not len(x):
        return "      n/a"
    return f"{x.mean():6.3f} {np.median(x):6.3f} {np.percentile(x, 10):6.3f}"


# -- main ---------------------------------------------------------------------------------
def run_config(
    names: list[str], check: str, allc: dict, clicks: dict, video: dict, fg: dict, a, nf: int
) -> dict:
    """Initialise, fit three ways and check in the held-out camera; prints a table.

    ``video[name] = (grey (F, h, w) at a.scale, rgb (F, h', w', 3) at a.mask_scale)``,
    ``fg[name]`` the foreground masks (F, h', w') of every camera.
    """
    from core.contour_track import fit_shape_to_contours, track_contours
    from core.fit import SequenceSettings, fit_sequence
    from core.fit_init import initialise
    from core.fused_track import track_fused
    from core.landmarks import METRIC_JOINTS
    from core.model_render import camera_rays
    from core.motion_smoother import smooth_joints
    from core.silhouette_check import body_masks, mask_iou, shift_iou
    from core.skeleton import joint_positions

    tag = f"{''.join(n[-1] for n in names)}_{check}"
    out = a.out / tag
    print(f"\n=== fit with {', '.join(names)}; held out {check} ===")
    cams_full = [allc[n] for n in names]
    cams_t = [scale_camera(c, a.scale) for c in cams_full]
    cams_q = [scale_camera(c, a.mask_scale) for c in cams_full]
    cam_chk = scale_camera(allc[check], a.mask_scale)
    t0 = time.perf_counter()
    init = initialise(clicks, cams_full, model=a.model, gross_px=a.gross_px, path=str(a.clicks))
    print(
        f"clicks: {len(init.clicks.names)} joints, reprojection RMS median "
        f"{np.median(init.clicks.rms_px):.1f} px (full resolution); initial posture joint "
        f"RMSE {1000 * init.joint_rmse_m:.1f} mm ({time.perf_counter() - t0:.1f} s)"
    )
    for m in init.clicks.messages():
        print(f"  note: {m}")
    # the person's masks: foreground components near the clicked joints
    masks = {}
    for n in names + [check]:
        cam = cam_chk if n == check else cams_q[names.index(n)]
        masks[n] = keep_in_region(fg[n], person_region(cam, init.clicks.xyz))
    contours = [[occluding_contours(masks[n][f], spacing=2.0) for n in names] for f in range(nf)]
    n_con = np.array([sum(len(c) for per_cam in fc for c in per_cam) for fc in contours])
    h, w = masks[check].shape[1:]
    print(
        "person area "
        + ", ".join(f"{n} {100 * masks[n].mean():.1f} %" for n in masks)
        + f"; contour points per frame (fitting cameras) median {int(np.median(n_con))}"
    )
    person = masks[check]
    results = {}

    # texture only
    ref = reference_camera(cams_full)
    xyz, sxyz, info = texture_tracks(
        {n: video[n][0] for n in names}, cams_t, clicks, nf, a.scale, out / "tracks.npz", ref=ref
    )
    obs = frame_points(xyz, sxyz)
    npts = np.array([len(o.xyz) for o in obs])
    print(
        f"LSM (reference {names[ref]}): {info['seeds']} of {info['seed_candidates']} seeds, "
        f"{info['surface_points']} surface points at frame 0 ({info['surface_s']:.1f} s); "
        f"tracking {info['tracking_s'] / nf:.2f} s/frame; 3-D points per frame median "
        f"{int(np.median(npts))} (max {npts.max()}); frame-0 points through all frames "
        f"{info['frame0_through']}"
    )
    t0 = time.perf_counter()
    # one pass, as measured before the late shape (core.fit_scene.run_scene runs its
    # second pass; fit_sequence alone would only compute it)
    res = fit_sequence(
        obs,
        init,
        SequenceSettings(late_shape_points=None),
        fps=FPS,
        source_scene=str(a.data),
        metaball_model=a.model,
    )
    t_tex = (time.perf_counter() - t0) / nf
    st_tex = res.state
    div_tex = st_tex.quality.diverged
    results["texture only"] = (
        st_tex.s,
        st_tex.metaballs,
        st_tex.theta,
        st_tex.root_xyz,
        t_tex,
        f"{int(div_tex.sum())} diverged (pose held)",
    )

    # contours only: shape from frame 0's silhouettes, EKF with per-part camera selection
    rays_q = [camera_rays(c) for c in cams_q]
    t0 = time.perf_counter()
    sig_c = None
    if a.center_sigma is not None:
        from core.fit_contours import ContourSettings

        names = np.array(init.skeleton.bone_names)[init.metaballs.bone]
        sig_c = np.where(
            np.isin(names, ContourSettings().shape_center_parts), a.center_sigma, np.nan
        )
    balls_c, th0, rt0, rms0 = fit_shape_to_contours(
        init.skeleton,
        init.s,
        init.metaballs,
        init.theta,
        init.root_xyz,
        cams_q,
        contours[0],
        ContourTrackSettings(q_sigma_theta=0.05, q_sigma_root=0.01),
        rays=rays_q,
        center_prior_m=sig_c,
    )
    t_shape = time.perf_counter() - t0
    t0 = time.perf_counter()
    variants = {"contours only": CONTOUR_CFG}
    if a.compare_selection:
        variants["contours, motion-ranked"] = replace(CONTOUR_CFG, observability=True)
        variants["contours, all fused"] = replace(CONTOUR_CFG, select=False)
    for label, cfg in variants.items():
        t0 = time.perf_counter()
        tracks = track_contours(init.skeleton, init.s, balls_c, th0, rt0, cams_q, contours, cfg)
        spf = (time.perf_counter() - t0) / nf
        th, rt = np.array([t.theta for t in tracks]), np.array([t.root for t in tracks])
        n_upd = sum(t.updated for t in tracks)
        use = np.array([t.use for t in tracks])  # (F, P, C) cameras used per part
        results[label] = (
            init.s,
            balls_c,
            th,
            rt,
            spf,
            f"{nf - n_upd} not updated; {use.sum(axis=2).mean():.2f} cameras per part",
        )
        if label == "contours only":
            th_c, rt_c, t_con = th, rt, spf
            # the same track smoothed over the take (core.motion_smoother, as the
            # sequence fit's opt-in smooth_motion): frames the filter did not update
            # are not used
            held = ~np.array([t.updated for t in tracks], bool)
            th_sm, rt_sm, _ = smooth_joints(init.skeleton, init.s, th, rt, held)
            results["contours, smoothed"] = (init.s, balls_c, th_sm, rt_sm, spf, "")
            print(
                f"contour shape at frame 0: RMS {rms0:.2f} px ({t_shape:.1f} s); contour "
                f"EKF matches per frame median {int(np.median([t.n_matches for t in tracks]))}"
                f", residual RMS median {np.nanmedian([t.rms_px for t in tracks]):.2f} px"
            )

    # texture + contours: the point-fit poses as measurements in the contour EKF ...
    t0 = time.perf_counter()
    q_pts = np.hstack([st_tex.theta, st_tex.root_xyz])
    q_pts[div_tex | (res.n_points == 0)] = np.nan  # no points: e.g. the clicked frame's pose
    q_sig = np.hstack([st_tex.quality.theta_sigma, np.full((nf, 3), 0.01)])
    tr_f, n_used = track_fused(
        init.skeleton, init.s, balls_c, th0, rt0, cams_q, contours, q_pts, q_sig, CONTOUR_CFG
    )
    t_ekf = (time.perf_counter() - t0) / nf + t_tex
    results["texture + contours"] = (
        init.s,
        balls_c,
        np.array([t.theta for t in tr_f]),
        np.array([t.root for t in tr_f]),
        t_ekf,
        f"point-fit pose used in {int(np.sum(n_used > 0))} frames, "
        f"{np.mean(n_used[n_used > 0]) if n_used.any() else 0:.0f} of "
        f"{q_pts.shape[1]} components",
    )
    # ... and each point-fit frame refined with its contours (diverged: contour pose)
    t0 = time.perf_counter()
    cfg = replace(CONTOUR_CFG, iterations=10, sigma_px=1.5, huber_px=3.0)
    st_fu, _ = fused_fit(st_tex, th_c, rt_c, cams_q, contours, cfg)
    t_fu = (time.perf_counter() - t0) / nf + t_tex
    n_ref = int(np.sum(np.isfinite(st_fu.contour_rms_px)))
    results["texture, refined"] = (
        st_fu.s,
        st_fu.metaballs,
        st_fu.theta,
        st_fu.root_xyz,
        t_fu,
        f"{n_ref} of {nf} refined; {int(div_tex.sum())} from the contour track",
    )

    # check in the held-out camera
    rays_chk = camera_rays(cam_chk)
    t0 = time.perf_counter()
    ious, bodies, shifted = {}, {}, {}
    for label, (s_, balls, th, rt, _, _) in results.items():
        bodies[label] = body_masks(init.skeleton, s_, balls, th, rt, cam_chk, rays=rays_chk)
        ious[label] = mask_iou(bodies[label], person)
        shifted[label] = shift_iou(bodies[label], person, max_shift_px=16)
    t_chk = (time.perf_counter() - t0) / (nf * len(results))
    init_body = body_masks(
        init.skeleton,
        init.s,
        init.metaballs,
        init.theta[None],
        init.root_xyz[None],
        cam_chk,
        rays=rays_chk,
    )
    print(
        f"held-out {check} ({w}x{h} px), {nf} frames; the clicked pose at frame 0: IoU "
        f"{float(mask_iou(init_body[0], person[0])):.3f}"
    )
    print(
        f"{'fit':20s} {'IoU mean':>8s} {'median':>6s} {'p10':>6s}  {'frame 0':>7s} "
        f"{'last':>6s}  {'shifted mean':>12s} {'(du, dv) px':>11s}  {'jerk mm':>7s} "
        f"{'s/frame':>7s}  notes"
    )
    idx = [init.skeleton.joint_index(j) for j in METRIC_JOINTS]
    for label, (s_, _, th, rt, spf, flags) in results.items():
        i = ious[label]
        sh, si = shifted[label]
        xj = joint_positions(init.skeleton, th, rt, s_)[:, idx]
        acc = 1000 * np.median(np.linalg.norm(np.diff(xj, 2, axis=0), axis=2))
        print(
            f"{label:20s} {_stats(i)}  {i[0]:7.3f} {i[-1]:6.3f}  {np.nanmean(si):12.3f} "
            f"{str(tuple(int(x) for x in sh)):>11s}  {acc:7.1f} {spf:7.2f}  {flags}"
        )
    print(
        "(shifted: IoU after one image shift fitted over all frames, quarter-resolution px; "
        "jerk: median |second difference| of the 14 metric joints per frame, mm)"
    )
    steps = list(range(0, nf, max(1, nf // 10)))
    print("IoU per frame       " + " ".join(f"{f:5d}" for f in steps))
    for label in results:
        print(f"  {label:18s}" + " ".join(f"{ious[label][f]:5.2f}" for f in steps))
    for label in results:
        if label != "texture only":
            win = ious[label] - ious["texture only"]
            print(
                f"{label} vs texture only: better in {int(np.sum(win > 0))} of {nf} frames, "
                f"mean difference {np.nanmean(win):+.3f}"
            )
    print(
        f"speed: texture fit {t_tex:.2f} s/frame ({int(np.median(npts))} points/frame; "
        f"LSM tracking {info['tracking_s'] / nf:.2f} s/frame at {cams_t[0].size[0]}x"
        f"{cams_t[0].size[1]}); contour EKF {t_con:.2f} s/frame, with the point-fit poses "
        f"{t_ekf - t_tex:.2f} s/frame, refinement {t_fu - t_tex:.2f} s/frame "
        f"({int(np.median(n_con))} contour points, 3 cameras at {w}x{h}); check render "
        f"{1000 * t_chk:.0f} ms/frame"
    )

    picks = [f for f in (int(x) for x in a.overlay_frames.split(",")) if 0 <= f < nf]
    colours = {
        "texture only": (60, 120, 255),
        "contours only": (255, 160, 0),
        "contours, smoothed": (0, 160, 0),
        "texture + contours": (255, 0, 0),
        "texture, refined": (200, 0, 200),
        "contours, motion-ranked": (0, 200, 200),
        "contours, all fused": (255, 255, 0),
    }
    for f in picks:
        draw_check(
            video[check][1][f],
            person[f],
            {f"{k} IoU {ious[k][f]:.2f}": (bodies[k][f], colours[k]) for k in results},
            out / f"check_{check}_f{f:03d}.png",
        )
    draw_masks(
        {n: video[n][1] for n in sorted(masks)},
        {n: masks[n] for n in sorted(masks)},
        picks,
        out / "masks_4cams.png",
    )
    np.savez_compressed(
        out / "iou.npz", **{k.replace(" ", "_").replace("+", "and"): v for k, v in ious.items()}
    )
    print(f"wrote {len(picks)} overlays check_{check}_f*.png and masks_4cams.png to {out}")
    return ious


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--clicks", type=Path, default=CLICKS)
    ap.add_argument("--frames", type=int, default=100, help="frames to fit")
    ap.add_argument(
        "--bg-frames", type=int, default=100, help="frames the background models are estimated from"
    )
    ap.add_argument(
        "--configs",
        default=f"{','.join(FIT_CAMS)}:{CHECK_CAM}",
        help="';'-separated FIT,CAMS:CHECK configurations, e.g. "
        "'cam02,cam03,cam04:cam01;cam01,cam02,cam04:cam03'",
    )
    ap.add_argument("--scale", type=float, default=0.5, help="LSM tracking resolution")
    ap.add_argument(
        "--mask-scale", type=float, default=0.25, help="resolution of masks, contours and the check"
    )
    ap.add_argument("--model", choices=("simplified", "complete"), default="simplified")
    ap.add_argument(
        "--gross-px",
        type=float,
        default=20.0,
        help="click consistency threshold, full-resolution pixels",
    )
    ap.add_argument(
        "--no-empty",
        action="store_true",
        help="do not repair the backgrounds with the empty-scene photos",
    )
    ap.add_argument("--out", type=Path, default=REPO / "out" / "realvideo_fit")
    ap.add_argument(
        "--compare-selection",
        action="store_true",
        help="also track contours with motion-ranked camera selection and with all cameras fused",
    )
    ap.add_argument("--overlay-frames", default="0,30,60,99")
    ap.add_argument(
        "--center-sigma",
        type=float,
        default=None,
        help="free the trunk's, head's and legs' metaball centres in the shape "
        "from frame 0's silhouettes, with this σ, metres (default: held)",
    )
    a = ap.parse_args(argv)
    t_all = time.perf_counter()
    calib = a.data / "calibration" / "Calib.qca.txt"
    if not calib.is_file():
        raise InputError(f"{calib}: not found (the pose2sim_single data set is needed)")
    allc = {c.name: c for c in read_qca(calib)}
    configs = []
    for spec in a.configs.split(";"):
        fit_s, _, check = spec.partition(":")
        names = fit_s.split(",")
        if (
            not check
            or check in names
            or len(set(names)) != len(names)
            or any(n not in allc for n in names + [check])
        ):
            raise InputError(
                f"{calib}: --configs '{spec}' must name distinct fitting cameras "
                f"and one held-out camera among {sorted(allc)}"
            )
        configs.append((names, check))
    nf = int(a.frames)
    if nf < 2:
        raise InputError("--frames must be at least 2")
    a.out.mkdir(parents=True, exist_ok=True)
    clicks = load_clicks(a.clicks, list(allc))
    used = sorted({n for names, check in configs for n in names + [check]})
    t0 = time.perf_counter()
    n_read = max(nf, a.bg_frames)
    video, fg = {}, {}
    for n in used:
        grey, rgb = read_video(
            a.data / "videos" / f"{n}.mp4", allc[n].size, n_read, a.scale, a.mask_scale
        )
        video[n] = (grey[:nf], rgb[:nf])
        model = fit_background(rgb)
        empty = read_empty_scene(a.data, n, allc[n].size, a.mask_scale)
        if empty is not None and not a.no_empty:
            model = with_reference(model, rgb, empty)
        fg[n] = np.stack([model.foreground(f, threshold=6.0) for f in rgb[:nf]])
    t_fg = time.perf_counter() - t0
    print(
        f"video: {n_read} frames x {len(used)} cameras decoded, background models "
        f"{'with' if not a.no_empty else 'without'} the empty-scene photos, foreground of "
        f"{nf} frames: {t_fg:.0f} s ({1000 * t_fg / (n_read * len(used)):.0f} ms per "
        f"camera-frame)"
    )
    for names, check in configs:
        run_config(names, check, allc, clicks, video, fg, a, nf)
    print(f"\ntotal {time.perf_counter() - t_all:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
