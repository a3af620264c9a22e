"""Per-part camera selection against all cameras fused, on self-occluding studio scenes.

``python -m bench.selection [--scenes dance_line3,dance_ortho3,pirouette_line3,pirouette_ortho3]
[--frames N] [--fps F] [--tracker ekf|fit] [--cues contours|both] [--click-draw N]
[--rows 2,4]``

The second paper's claim (issue 7): tracking each body part only from the cameras that see
it (visibility index ≥ 0.2) and observe its motion survives self-occlusion better than
fusing every camera.  For each scene: the occluding contours of every frame come from our
own foreground (:func:`core.background.fit_background`, a robust temporal median — no
truth masks), the key-joint clicks give the first pose, the metaball shape is fitted to
the first frame's silhouettes (:func:`core.contour_track.fit_shape_to_contours`), then the
contour EKF (:func:`core.contour_track.track_contours`) runs three times (:data:`METHODS`)
— with the paper's per-part camera selection (visibility, then the cameras ranked by the
part's predicted motion), with the visibility test alone, and with all cameras fused —
and one row each is printed side by side: MPJPE
(all frames, diverged ones included), limb segment orientation RMSE
(:func:`core.evaluate.evaluate`), frames the tracker marked diverged, frames whose MPJPE
exceeds ``--lost-mm`` (an independent check against the truth), s/frame (CPU time), and
the agreement of the cameras each part used with the truth's visibility (which cameras
see ≥ 20 % of the part in the true mesh, :func:`truth_visibility`, every 5th frame):
``hid.used`` — fraction of the part-views used that the truth says are hidden;
``seen.unused`` — fraction of the truth's visible part-views left out.

``--tracker fit`` runs the sequence fit (:func:`core.fit_scene.run_scene`, ``cues=
"contours"``: the weighted least squares of each frame with contour observations, the
silhouette limb search, the constant-velocity prediction) instead of the EKF, with the
same three camera choices (:class:`core.fit_contours.ContourSettings` ``select`` and
``rank_motion``, without ``wide_view_deg``) and two more rows (:data:`FIT_ROWS`): the
paper's selection plus a view across a part's kept views where those all look from one
side, and that with the views the selection leaves out paired too at twice the σ (the
fit's default); its own shape comes from the first frame's silhouettes.  ``--rows``
picks rows by number.  With
``--cues both`` the fit also takes the scene's tracked texture points (``core track``,
run first where ``tracks.npz`` is missing), as ``core fit --cues both`` does.
``--click-draw N`` moves every click by N(0, 0.5 px) per axis with seed N, as
``bench.fit_spread``'s run N does (0: the scene's clicks).

Scenes: the dance scenes are :data:`bench.fit.STUDIO_SCENES` (rendered and cached by
:func:`bench.fit.render_studio_scene`); the pirouette scenes (``pirouette.bvh``, CMU
"Daz-friendly" joint names, from BVH frame 120 — the clip's busiest 2 s: the hips turn
about 700 degrees) are rendered here, once, from a copy of the clip whose joints are
renamed to the CMU names the studio's character expects (:data:`DAZ_TO_CMU`), and cached
under ``out/bench_fit/<name>``.
"""

from __future__ import annotations

import argparse
import os
import re
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_SCENES = ("dance_line3", "dance_ortho3", "pirouette_line3", "pirouette_ortho3")

#: Daz-friendly CMU joint -> the CMU (MotionBuilder) name the studio character uses.
DAZ_TO_CMU = {
    "hip": "Hips",
    "abdomen": "LowerBack",
    "chest": "Spine",
    "neck": "Neck",
    "head": "Head",
}
for _s, _S in (("l", "Left"), ("r", "Right")):
    DAZ_TO_CMU.update(
        {
            f"{_s}Collar": f"{_S}Shoulder",
            f"{_s}Shldr": f"{_S}Arm",
            f"{_s}ForeArm": f"{_S}ForeArm",
            f"{_s}Hand": f"{_S}Hand",
            f"{_s}Mid1": f"{_S}FingerBase",
            f"{_s}Mid2": f"{_S}HandIndex1",
            f"{_s}Thigh": f"{_S}UpLeg",
            f"{_s}Shin": f"{_S}Leg",
            f"{_s}Foot": f"{_S}Foot",
        }
    )

#: Pirouette scenes: name -> (rig, first BVH frame).
PIROUETTE_SCENES = {"pirouette_line3": ("line3", 120), "pirouette_ortho3": ("orthogonal3", 120)}


def renamed_bvh(src: Path, dst: Path) -> Path:
    """Copy of the BVH ``src`` with Daz-friendly joint names replaced (:data:`DAZ_TO_CMU`)."""
    text = src.read_text()
    out = re.sub(
        r"^(\s*(?:ROOT|JOINT)\s+)(\S+)",
        lambda m: m.group(1) + DAZ_TO_CMU.get(m.group(2), m.group(2)),
        text,
        flags=re.M,
    )
    dst.parent.mkdir(parents=True, exist_ok=True)
    dst.write_text(out)
    return dst


def scene_dir(name: str, fps: float | None = None) -> Path:
    """The cached scene folder of ``name``, rendered first when missing.

    ``fps`` other than the studio's 25 renders the same clip, BVH start and stretch of
    motion (2 s) at that frame rate — more frames, less motion between them — cached
    as ``<name>_<fps>fps``.  (The same stretch matters: the background is the robust
    temporal median of the take, and over a shorter one a dancer turning in place
    stays in it.)
    """
    from bench.fit import (
        FPS,
        FRAMES,
        MOCAP,
        RENDERS,
        SIZE,
        STUDIO_SCENES,
        render_cached,
        render_studio_scene,
    )

    fps = FPS if fps is None else float(fps)
    if name not in PIROUETTE_SCENES and fps == FPS:
        return render_studio_scene(name)[0]
    out = RENDERS / (name if fps == FPS else f"{name}_{fps:g}fps")
    if (out / "scene.toml").is_file() and (out / "truth.npz").is_file():
        return out
    if name in PIROUETTE_SCENES:
        rig, start = PIROUETTE_SCENES[name]
        bvh = renamed_bvh(MOCAP / "pirouette.bvh", RENDERS / "pirouette_cmu.bvh")
    else:
        clip, rig, start = STUDIO_SCENES[name]
        bvh = MOCAP / clip
    return render_cached(
        out.name,
        out,
        [
            "--bvh",
            str(bvh),
            "--rig",
            rig,
            "--start",
            str(start),
            "--frames",
            str(round(FRAMES * fps / FPS)),
            "--fps",
            f"{fps:g}",
            "--size",
            SIZE,
            "--wand-positions",
            "0",
        ],
    )[0]


def scene_contours(scene, n_frames: int, spacing: float = 2.0):
    """Occluding contours (F, C) from our own foreground of every camera."""
    from core.background import fit_background
    from core.contours import occluding_contours

    contours = [[] for _ in range(n_frames)]
    for cam in scene.cameras:
        frames = np.array([scene.image(cam, i, color=True) for i in range(scene.n_frames)])
        model = fit_background(frames)
        for f in range(n_frames):
            contours[f].append(occluding_contours(model.foreground(frames[f]), spacing=spacing))
    return contours


def truth_visibility(scene, frames) -> np.ndarray:
    """Visibility index of every part in every camera from the true mesh, (F', P, C).

    Parts are labelled by the model's own boundaries at the truth pose (template shape,
    :func:`bench.visibility.model_vertex_parts`); NaN where the part covers fewer than
    :data:`bench.visibility.MIN_AREA_PX` pixels.
    """
    from bench.visibility import (
        MIN_AREA_PX,
        body_render,
        mesh_visibility,
        model_vertex_parts,
    )
    from core.truth_state import truth_to_state

    state, _ = truth_to_state(scene.truth, scene.fps)
    cams = scene.calibration()
    P = len(state.skeleton.bone_names)
    out = np.full((len(frames), P, len(cams)), np.nan)
    for i, f in enumerate(frames):
        centers, axes, radii, bone = body_render(state, f)
        vpart = model_vertex_parts(scene.truth["vertices"][f], centers, axes, radii, bone)
        for c, cam in enumerate(cams):
            ref, full = mesh_visibility(
                cam, scene.truth["vertices"][f], scene.truth["faces"], vpart, P
            )
            out[i, :, c] = np.where(full >= MIN_AREA_PX, ref, np.nan)
    return out


def camera_agreement(use: np.ndarray, ref: np.ndarray) -> tuple[float, float]:
    """How the cameras used per part (F', P, C bool) agree with the truth's visibility.

    Returns the fraction of used part-views the truth says are hidden (VI < 0.2) and
    the fraction of the truth's visible part-views (VI ≥ 0.2) left unused.
    """
    scored = np.isfinite(ref)
    seen = scored & (np.nan_to_num(ref) >= 0.2)
    used = use & scored
    hidden_used = float((used & ~seen).sum() / max(1, used.sum()))
    seen_unused = float((seen & ~use).sum() / max(1, seen.sum()))
    return hidden_used, seen_unused


def _joints_like_truth(skel, theta, root, s, names):
    """Fitted joints (F, J, 3) in the order of the truth's ``names``."""
    from core.skeleton import joint_positions

    xyz = joint_positions(skel, theta, root, s)
    order = [skel.joint_names.index(n) for n in names]
    return xyz[:, order]


def _fit_rows(
    scene, nf: int, lost_mm: float, vis_frames, ref_vi, cues: str = "contours", which=None
):
    """The sequence fit (``cues``: contours alone, or ``"both"`` with the tracked points),
    once per camera choice of :data:`FIT_ROWS` (``which``: their indices; None: all)."""
    from core.evaluate import evaluate_state
    from core.fit_contours import ContourSettings
    from core.fit_scene import run_scene as fit_run

    truth = {
        k: (v[:nf] if getattr(v, "ndim", 0) and v.shape[0] == scene.n_frames else v)
        for k, v in scene.truth.items()
    }
    cams = [c.name for c in scene.calibration()]
    rows = []
    for k, (label, fields) in enumerate(FIT_ROWS):
        if which is not None and k not in which:
            continue
        t0 = time.process_time()
        res = fit_run(
            scene,
            observations="tracks",
            cues=cues,
            frames=nf,
            contour_settings=ContourSettings(**fields),
        )
        dt = (time.process_time() - t0) / nf
        st = res.state
        ev = evaluate_state(st, truth)
        parts = st.skeleton.bone_names
        use = np.array(
            [
                [[c in st.quality.cameras[f].get(p, ()) for c in cams] for p in parts]
                for f in vis_frames
            ]
        )
        hidden_used, seen_unused = camera_agreement(use, ref_vi)
        diverged = np.asarray(st.quality.diverged, bool)
        curve = np.where(diverged, np.nan, ev.curves["mpjpe_mm"])
        rows.append(
            {
                "scene": scene.root.name,
                "method": label,
                "mpjpe_mm": ev.mpjpe_mm,
                "seg_rmse_deg": ev.segment_orientation_rmse_deg,
                "diverged": int(diverged.sum()),
                "lost": int((curve > lost_mm).sum()),
                "s_per_frame": dt,
                "curve": curve,
                "diverged_mask": diverged,
                "hidden_used": hidden_used,
                "seen_unused": seen_unused,
            }
        )
    return rows


def run_scene(
    name: str,
    n_frames: int,
    lost_mm: float = 100.0,
    settings: dict | None = None,
    fps: float | None = None,
    tracker: str = "ekf",
    cues: str = "contours",
    click_draw: int = 0,
    rows=None,
):
    """Track one scene with selection and fused; returns a list of result dicts.

    ``fps``: the scene's frame rate (see :func:`scene_dir`); None for the studio's 25.
    ``tracker``: ``"ekf"`` (the contour EKF) or ``"fit"`` (the sequence fit with
    contours alone; its MPJPE leaves out the frames it marked diverged).  ``cues``: with
    the fit, ``"contours"`` alone or ``"both"`` (the tracked points too).
    ``click_draw``: the clicks moved as ``bench.fit_spread``'s run of that number.
    ``rows``: with the fit, the indices of :data:`FIT_ROWS` to run (None: all).
    """
    from core.contour_track import ContourTrackSettings, fit_shape_to_contours, track_contours
    from core.evaluate import evaluate, truth_joints
    from core.fit_init import initialise
    from core.model_render import camera_rays
    from core.scene import load_scene

    scene = load_scene(scene_dir(name, fps))
    if click_draw:
        from bench.fit_spread import perturbed_clicks

        moved = perturbed_clicks(scene.clicks(), 0.5, click_draw)  # fit_spread's default
        scene.clicks = lambda: moved
    cams = scene.calibration()
    nf = min(n_frames, scene.n_frames)
    if tracker == "fit":
        vis_frames = list(range(0, nf, 5))
        ref_vi = truth_visibility(scene, vis_frames)
        what = "contours alone" if cues == "contours" else "tracked points and contours"
        print(
            f"\n{name}: {len(cams)} cameras, {nf} frames; the sequence fit with {what}", flush=True
        )
        return _fit_rows(scene, nf, lost_mm, vis_frames, ref_vi, cues, rows)
    t0 = time.process_time()
    contours = scene_contours(scene, nf)
    t_seg = time.process_time() - t0
    init = initialise(scene.clicks(), cams, model="simplified")
    rays = [camera_rays(c) for c in cams]
    tight = ContourTrackSettings(q_sigma_theta=0.01, q_sigma_root=0.002)
    t0 = time.process_time()
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
    t_shape = time.process_time() - t0
    txyz, names = truth_joints(scene.truth)
    txyz = txyz[:nf]
    height = float(scene.truth["height_m"])
    vis_frames = list(range(0, nf, 5))
    t0 = time.process_time()
    ref_vi = truth_visibility(scene, vis_frames)
    t_vis = time.process_time() - t0
    print(
        f"\n{name}: {len(cams)} cameras, {nf} frames; contours {t_seg:.0f} s CPU; shape "
        f"fitted to frame 0 (RMS {rms:.2f} px, {t_shape:.0f} s CPU); truth visibility of "
        f"{len(vis_frames)} frames {t_vis:.0f} s CPU",
        flush=True,
    )
    rows = []
    for select, ranked, label in METHODS:
        cfg = ContourTrackSettings(select=select, observability=ranked, **(settings or {}))
        t0 = time.process_time()
        out = track_contours(init.skeleton, init.s, balls, th0, rt0, cams, contours, cfg)
        dt = (time.process_time() - t0) / nf
        th = np.array([t.theta for t in out])
        rt = np.array([t.root for t in out])
        fxyz = _joints_like_truth(init.skeleton, th, rt, init.s, names)
        ev = evaluate(fxyz, txyz, names, height)
        diverged = np.array([getattr(t, "diverged", not t.updated) for t in out])
        lost = ev.curves["mpjpe_mm"] > lost_mm
        use = np.array([out[f].use for f in vis_frames])
        hidden_used, seen_unused = camera_agreement(use, ref_vi)
        rows.append(
            {
                "scene": scene.root.name,
                "method": label,
                "mpjpe_mm": ev.mpjpe_mm,
                "seg_rmse_deg": ev.segment_orientation_rmse_deg,
                "diverged": int(diverged.sum()),
                "lost": int(lost.sum()),
                "s_per_frame": dt,
                "curve": ev.curves["mpjpe_mm"],
                "track": out,
                "diverged_mask": diverged,
                "hidden_used": hidden_used,
                "seen_unused": seen_unused,
                "searched": sum(len(t.searched) for t in out) / nf,
            }
        )
    return rows


#: Compared camera choices, as (select, rank by predicted motion, label): the paper's
#: selection (visibility ≥ 0.2, cameras ranked by the part's predicted contour motion),
#: the visibility test alone, and every camera fused.
METHODS = (
    (True, True, "per-part selection"),
    (True, False, "selection, VI only"),
    (False, False, "all fused"),
)
#: ``--tracker fit``'s rows, as (label, :class:`core.fit_contours.ContourSettings`
#: fields): the three above, the paper's selection plus a view across where a part's
#: kept views all look from one side (``wide_view_deg``), and that with the views the
#: selection leaves out paired too at twice the σ (``unselected_sigma_scale``).
FIT_ROWS = (
    ("per-part selection", {"wide_view_deg": None, "unselected_sigma_scale": None}),
    ("selection, VI only", {"rank_motion": False, "wide_view_deg": None,
                            "unselected_sigma_scale": None}),
    ("all fused", {"select": False, "unselected_sigma_scale": None}),
    ("selection + wide view", {"wide_view_deg": 60.0, "unselected_sigma_scale": None}),
    ("+ left out at 2 sigma", {"wide_view_deg": 60.0, "unselected_sigma_scale": 2.0}),
)  # fmt: skip


def print_rows(rows, lost_mm: float) -> None:
    print(
        f"{'scene':24s} {'cameras':20s} {'MPJPE mm':>9s} {'seg RMSE deg':>12s} "
        f"{'diverged':>8s} {f'>{lost_mm:g} mm':>8s} {'s/frame':>7s} {'hid.used':>8s} "
        f"{'seen.unused':>11s}   MPJPE per 5 frames"
    )
    for r in rows:
        curve = " ".join(f"{e:4.0f}" for e in r["curve"][::5])
        print(
            f"{r['scene']:24s} {r['method']:20s} {r['mpjpe_mm']:9.1f} {r['seg_rmse_deg']:12.1f} "
            f"{r['diverged']:8d} {r['lost']:8d} {r['s_per_frame']:7.2f} "
            f"{r['hidden_used']:8.2f} {r['seen_unused']:11.2f}   {curve}",
            flush=True,
        )


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--scenes",
        default=",".join(DEFAULT_SCENES),
        help="comma-separated scene names (bench.fit.STUDIO_SCENES or pirouette_*)",
    )
    ap.add_argument("--frames", type=int, default=50, help="frames per scene")
    ap.add_argument(
        "--lost-mm",
        type=float,
        default=100.0,
        help="a frame with MPJPE above this counts as lost (truth check)",
    )
    ap.add_argument(
        "--fps",
        type=float,
        default=None,
        help="render the scenes' 2 s at this frame rate (default: the studio's 25); "
        "--frames counts frames at this rate",
    )
    ap.add_argument(
        "--tracker",
        choices=("ekf", "fit"),
        default="ekf",
        help="the contour EKF (default) or the sequence fit (contours alone, or see --cues)",
    )
    ap.add_argument(
        "--cues",
        choices=("contours", "both"),
        default="contours",
        help="with --tracker fit: contours alone (default) or the tracked points too",
    )
    ap.add_argument(
        "--click-draw",
        type=int,
        default=0,
        help="move every click by N(0, 0.5 px) with this seed, as bench.fit_spread's run "
        "of that number (0: the scene's clicks)",
    )
    ap.add_argument(
        "--rows",
        default=None,
        help="with --tracker fit: comma-separated indices of the rows to run, 0-4 in the "
        "order printed (default all)",
    )
    args = ap.parse_args(argv)
    if args.cues != "contours" and args.tracker != "fit":
        ap.error("--cues both needs --tracker fit")
    which = None
    if args.rows is not None:
        try:
            which = {int(k) for k in args.rows.split(",")}
        except ValueError:
            ap.error(f"--rows {args.rows!r}: give comma-separated row numbers, e.g. 2,4")
        if args.tracker != "fit" or not which <= set(range(len(FIT_ROWS))):
            ap.error(f"--rows needs --tracker fit and numbers 0-{len(FIT_ROWS) - 1}")
    rows = []
    for name in args.scenes.split(","):
        rows += run_scene(
            name.strip(),
            args.frames,
            args.lost_mm,
            fps=args.fps,
            tracker=args.tracker,
            cues=args.cues,
            click_draw=args.click_draw,
            rows=which,
        )
        n = len(METHODS) if args.tracker == "ekf" else len(which or FIT_ROWS)
        print_rows(rows[-n:], args.lost_mm)
    load = " ".join(f"{x:.2f}" for x in os.getloadavg())
    print(f"\nAll scenes (load average {load}):")
    print_rows(rows, args.lost_mm)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
