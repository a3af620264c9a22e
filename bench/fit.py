"""Benchmark of ``core fit`` + ``core evaluate`` on studio scenes.

``python -m bench.fit [SCENE ...] [--frames N] [--observations truth|tracks] [--cues C]
[--tracks NPZ] [--real texture|contours|both|none] [--renders DIR] [--compare-flow]``

Without SCENE arguments it runs the default sample scene (``sample_scenes/walk_line3``)
and the studio scenes of :data:`DEFAULT_SET` (walk, dance and jumps clips of
``../shared/data/mocap`` through the ``line3`` and ``orthogonal3`` rigs, 25 fps,
512x384, 50 frames, true ``calibration.toml``, no wand sequence).  A SCENE argument
is either a scene folder or one of the :data:`STUDIO_SCENES` names.  Studio scenes are
cached under ``out/bench_fit/<name>``; a missing one is rendered first by
``python -m sample_scenes.studio`` in a subprocess, one at a time.

For each scene: runs ``python -m core fit`` (timed end to end) and ``python -m core
evaluate --json``, which also reports the fitted metaball surface against the true mesh
(``surface_mm``: mean distance of the true surface, sampled by area, to the fitted
``Σ f = 0.5``, :func:`core.evaluate.surface_distance_mm`), and prints one table row
with per-joint MPJPE and per-segment orientation RMSE lines under it.  With
``--observations truth`` the fit uses truth-derived surface points — a development
stand-in for the tracker, labelled as such in the table, never the pipeline's result.

With truth-derived observations, the default scene's row is followed by a row of the
same scene through the **real pipeline** (``--real``, default ``both``): the tracker's
``tracks.npz`` (``python -m core track``, cached by :mod:`bench.looks` under
``out/bench_fit/looks``, tracked first when missing: minutes) fitted with those cues
(``python -m core fit --observations tracks --tracks ... --cues ...``) — the product,
printed beside the stand-in.  ``--observations tracks --cues C`` fits every listed scene
from its tracks instead.  ``--compare-flow`` (with ``--cues both``) prints under each
row the same fit without the single-camera texture flow (:mod:`core.fit_flow`).

``python -m bench.fit --fit-shape [SCENE] [--frames N]`` instead compares, on one scene
(default ``walk_line3``) with truth-derived observations, the template shape with the
whole-body fitted shape (``SequenceSettings(shape="fit")``, :mod:`core.shape_fit`)
side by side, in-process (:func:`core.fit_scene.run_scene`, :func:`core.evaluate.evaluate_state`):
MPJPE, segment orientation RMSE and the metaball surface (the fitted shape both tracked
with and only written to the state, ``shape_fit_track``) against the true mesh
(:func:`bench.shape.surface_distances`, both directions, and mesh -> ball over the
vertices two cameras see, :func:`bench.shape.seen_vertices`).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
import tomllib
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DEFAULT = ROOT / "sample_scenes" / "walk_line3"
MOCAP = ROOT.parent / "shared" / "data" / "mocap"
RENDERS = ROOT / "out" / "bench_fit"

#: Studio scenes: name -> (BVH file in ``../shared/data/mocap``, rig, first BVH frame).
#: 50 frames at 25 fps are 2 s (240 frames of the 120 fps clips).  ``01_01`` from
#: frame 150: standing, crouch (BVH ~190-200), a forward jump (hips 0.4 m up at ~250),
#: landing (~285) and standing again.  ``05_06`` from 260: upright at the start (head
#: 0.40 m above the hips), arms swinging and turning.  The ``dance_bend_*`` scenes
#: start at 120, the clip's busiest 2 s, already bent over (head below the hips from
#: BVH ~125 to ~215): not in the default set.
STUDIO_SCENES: dict[str, tuple[str, str, int]] = {
    "walk_ortho3": ("02_01.bvh", "orthogonal3", 0),
    "dance_line3": ("05_06.bvh", "line3", 260),
    "dance_ortho3": ("05_06.bvh", "orthogonal3", 260),
    "jumps_line3": ("01_01.bvh", "line3", 150),
    "jumps_ortho3": ("01_01.bvh", "orthogonal3", 150),
    "dance_bend_line3": ("05_06.bvh", "line3", 120),
    "dance_bend_ortho3": ("05_06.bvh", "orthogonal3", 120),
}
#: The scenes run without SCENE arguments (after ``sample_scenes/walk_line3``).
DEFAULT_SET = ("walk_ortho3", "dance_line3", "dance_ortho3", "jumps_line3", "jumps_ortho3")
FRAMES, FPS, SIZE = 50, 25.0, "512x384"


def render_cached(name: str, out: Path, studio_args: list[str]) -> tuple[Path, float | None]:
    """Return the scene folder ``out``, rendering it first when missing.

    Runs ``python -m sample_scenes.studio --out OUT *studio_args`` in a subprocess (one
    Blender per render); a folder holding ``scene.toml`` and ``truth.npz`` counts as
    cached.

    Returns
    -------
    (Path, float or None)
        The scene folder and the render wall time in seconds (None when cached).

    Raises
    ------
    RuntimeError
        The studio failed; the message ends with its last line of stderr.
    """
    if (out / "scene.toml").is_file() and (out / "truth.npz").is_file():
        return out, None
    cmd = [sys.executable, "-m", "sample_scenes.studio", "--out", str(out), *studio_args]
    print(f"rendering {name}: python {' '.join(cmd[1:])}", flush=True)
    t0 = time.perf_counter()
    p = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
    wall = time.perf_counter() - t0
    if p.returncode != 0 or not (out / "truth.npz").is_file():
        raise RuntimeError(f"studio failed for {name}: {p.stderr.strip().splitlines()[-1:]}")
    print(f"rendered {name} in {wall:.0f} s", flush=True)
    return out, wall


def render_studio_scene(name: str, root: Path = RENDERS) -> tuple[Path, float | None]:
    """Return the cached studio scene ``root/name``, rendering it first when missing.

    Parameters
    ----------
    name : str
        A key of :data:`STUDIO_SCENES`.
    root : Path
        Cache folder; the scene is ``root / name``.

    Returns
    -------
    (Path, float or None)
        The scene folder and the render wall time in seconds (None when cached).
    """
    bvh, rig, start = STUDIO_SCENES[name]
    return render_cached(
        name,
        root / name,
        [
            "--bvh",
            str(MOCAP / bvh),
            "--rig",
            rig,
            "--start",
            str(start),
            "--frames",
            str(FRAMES),
            "--fps",
            str(FPS),
            "--size",
            SIZE,
            "--wand-positions",
            "0",
        ],
    )


#: Joint -> the DOF whose σ says whether the part that places the joint was observed.
_PLACING_DOF = {
    "l_elbow": "l_shoulder_x",
    "r_elbow": "r_shoulder_x",
    "l_wrist": "l_elbow_x",
    "r_wrist": "r_elbow_x",
    "l_knee": "l_hip_x",
    "r_knee": "r_hip_x",
    "l_ankle": "l_knee_x",
    "r_ankle": "r_knee_x",
}
#: σ (radians) above which that DOF counts as unobserved in a frame: a hidden part's
#: angles follow the damped prediction and their σ grows from frame to frame.
HIDDEN_SIGMA = 0.1


def hidden_split(state, truth: dict) -> dict:
    """MPJPE (mm) of the limb joints over the frames where their part was observed and
    where it was hidden (σ of its placing DOF > :data:`HIDDEN_SIGMA`), with the counts
    of joint-frames, and the per-joint hidden share; diverged frames left out."""
    from core.evaluate import truth_joints

    txyz, names = truth_joints(truth)
    fxyz = state.joints_xyz(names)
    ok = ~state.quality.diverged
    sig = state.quality.theta_sigma
    seen_e, hid_e, share = [], [], {}
    for j, dof in _PLACING_DOF.items():
        k = names.index(j)
        e = np.linalg.norm(fxyz[ok, k] - txyz[ok, k], axis=-1) * 1000.0
        h = ~(sig[ok, state.skeleton.dof_index(dof)] <= HIDDEN_SIGMA)
        seen_e.append(e[~h])
        hid_e.append(e[h])
        share[j] = float(h.mean()) if len(h) else 0.0
    seen, hid = np.concatenate(seen_e), np.concatenate(hid_e)
    return {
        "seen_mm": float(seen.mean()) if len(seen) else float("nan"),
        "n_seen": len(seen),
        "hidden_mm": float(hid.mean()) if len(hid) else float("nan"),
        "n_hidden": len(hid),
        "hidden_share": share,
    }


def run_one(
    scene: Path,
    frames: int | None,
    observations: str,
    model: str,
    cues: str = "texture",
    tracks: Path | None = None,
    shape: str = "written",
    flow: bool = True,
) -> dict:
    """Fit and evaluate one scene folder; return the figures (or ``{"error": ...}``).

    ``cues``, ``tracks`` (a tracker output other than ``SCENE/tracks.npz``) and ``shape``
    go to ``python -m core fit --cues --tracks --shape``; ``flow=False`` adds
    ``--no-flow``."""
    from core.scene import load_scene
    from core.state import read_state

    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "fit.json"
        cmd = [
            sys.executable,
            "-m",
            "core",
            "fit",
            str(scene),
            "-o",
            str(out),
            "--observations",
            observations,
            "--model",
            model,
            "--cues",
            cues,
            "--shape",
            shape,
        ]
        if tracks is not None:
            cmd += ["--tracks", str(tracks)]
        if not flow:
            cmd += ["--no-flow"]
        if frames:
            cmd += ["--frames", str(frames)]
        t0 = time.perf_counter()
        p = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
        wall = time.perf_counter() - t0
        if p.returncode != 0:
            return {"scene": scene.name, "error": p.stderr.strip().splitlines()[-1:]}
        ev = subprocess.run(
            [sys.executable, "-m", "core", "evaluate", str(scene), str(out), "--json"],
            capture_output=True,
            text=True,
            cwd=ROOT,
        )
        if ev.returncode != 0:
            return {"scene": scene.name, "error": ev.stderr.strip().splitlines()[-1:]}
        metrics = json.loads(ev.stdout.strip().splitlines()[-1])
        state = read_state(out)
        fit_line = [ln for ln in p.stdout.splitlines() if ln.startswith("seconds:")]
        pts_line = [ln for ln in p.stdout.splitlines() if ln.startswith("points per frame")]
    sc = load_scene(scene, check_images=False)
    ok = [f for f in range(state.n_frames) if not state.quality.diverged[f]]
    track_path = tracks if tracks is not None else scene / "tracks.npz"
    tracked = None
    if observations == "tracks" and track_path.exists() and "vertices" in sc.truth:
        from bench.tracking import tracked_point_errors

        with np.load(track_path) as z:
            tracked = tracked_point_errors(
                {k: z[k] for k in z.files}, sc.truth["vertices"], sc.truth["faces"]
            )
    surf = metrics.get("surface_mm")  # core.evaluate.surface_distance_mm
    return {
        "hidden": hidden_split(state, sc.truth),
        "scene": scene.name,
        "size": sc.image_size,
        "frames": len(ok),
        "n_frames": state.n_frames,
        "rig": sc.meta.get("source", {}).get("rig", "?"),
        "metrics": metrics,
        "surface_mm": surf,
        "wall_s": wall,
        "s_per_frame": wall / max(state.n_frames, 1),
        "fit_line": fit_line[0] if fit_line else "",
        "pts": pts_line[0] if pts_line else "",
        "tracked": tracked,
    }


def shape_comparison(
    scene_dir: Path,
    frames: int | None,
    model: str = "complete",
    n_points: int = 3000,
    seed: int = 0,
    eval_frames: int = 3,
) -> list[dict]:
    """Template shape vs the whole-body fitted shape on one scene, truth-derived points.

    Parameters
    ----------
    scene_dir : scene folder with ``truth.npz``
    frames : fit the first ``frames`` frames (None: all)
    eval_frames : fitted frames (evenly spread, not diverged) whose surface is measured

    Returns
    -------
    list of three dicts (``"template"``; ``"fit"``: tracked with the fitted shape;
    ``"fit-output"``: tracked with the per-part shape, the fitted one written): ``eval``
    (:class:`core.evaluate.Evaluation` over the fitted frames), ``ball_mesh_mm`` /
    ``mesh_ball_mm`` / ``seen_mesh_ball_mm`` mean surface distances (mm), ``seconds`` of
    the fit, ``record`` (the :class:`core.fit_types.ShapeRecord` or None) and ``diverged`` frames.
    """
    from bench.shape import seen_vertices, surface_distances
    from core.evaluate import evaluate_state
    from core.fit import SequenceSettings
    from core.fit_cli import _pad
    from core.fit_scene import run_scene
    from core.scene import load_scene

    scene = load_scene(scene_dir, check_images=False)
    cams = scene.calibration()
    verts, faces = scene.truth["vertices"], np.asarray(scene.truth["faces"], int)
    out = []
    for shape, track in (("template", True), ("fit", True), ("fit", False)):
        t0 = time.perf_counter()
        res = run_scene(
            scene,
            observations="truth",
            model=model,
            n_points=n_points,
            seed=seed,
            frames=frames,
            settings=SequenceSettings(shape=shape, shape_fit_track=track),
        )
        sec = time.perf_counter() - t0
        st = res.state
        ok = np.flatnonzero(~st.quality.diverged)
        pick = ok[np.unique(np.linspace(0, len(ok) - 1, eval_frames).round().astype(int))]
        bm, mb, seen_mb = [], [], []
        for f in pick:
            d = surface_distances(
                st.skeleton, st.theta[f], st.root_xyz[f], st.s, st.metaballs, verts[f], faces
            )
            bm.append(d["ball_to_mesh"])
            mb.append(d["mesh_to_ball"])
            seen_mb.append(d["mesh_to_ball"][seen_vertices(verts[f], faces, cams)[d["vertex_idx"]]])
        full = _pad(st, scene.n_frames) if st.n_frames < scene.n_frames else st
        out.append(
            {
                "shape": shape if track else "fit-output",
                "eval": evaluate_state(full, scene.truth),
                "ball_mesh_mm": 1e3 * float(np.mean(np.concatenate(bm))),
                "mesh_ball_mm": 1e3 * float(np.mean(np.concatenate(mb))),
                "seen_mesh_ball_mm": 1e3 * float(np.mean(np.concatenate(seen_mb))),
                "eval_frames": pick.tolist(),
                "seconds": sec,
                "n_frames": st.n_frames,
                "diverged": int(st.quality.diverged.sum()),
                "record": res.shape,
            }
        )
    return out


def print_shape_comparison(rows: list[dict], scene: Path) -> None:
    """Print :func:`shape_comparison` as a side-by-side table."""
    r0 = rows[0]
    print(
        f"{scene.name}: template vs whole-body fitted shape, TRUTH-DERIVED OBSERVATIONS "
        f"(points sampled on the true mesh, 1.5 mm noise, 5 % outliers), {r0['n_frames']} "
        f"frames; surface on frames {[r['eval_frames'] for r in rows]}"
    )
    print(f"{'':26s}" + "".join(f"{r['shape']:>12s}" for r in rows))
    lines = [
        ("MPJPE mm", lambda r: r["eval"].mpjpe_mm),
        ("max joint err % height", lambda r: r["eval"].max_joint_error_pct_height),
        ("frames <= 1 % height %", lambda r: 100 * r["eval"].frames_within_1pct),
        ("segment orient. RMSE deg", lambda r: r["eval"].segment_orientation_rmse_deg),
    ]
    for seg in r0["eval"].per_segment_rmse_deg:
        lines.append((f"  {seg} deg", lambda r, k=seg: r["eval"].per_segment_rmse_deg[k]))
    lines += [
        ("ball -> mesh mm", lambda r: r["ball_mesh_mm"]),
        ("mesh -> ball mm", lambda r: r["mesh_ball_mm"]),
        ("seen mesh -> ball mm", lambda r: r["seen_mesh_ball_mm"]),
        ("diverged frames", lambda r: r["diverged"]),
        ("fit seconds", lambda r: r["seconds"]),
    ]
    for name, get in lines:
        print(f"{name:26s}" + "".join(f"{get(r):12.2f}" for r in rows))
    for rec in (r["record"] for r in rows[1:]):
        print(
            f"shape fit: frames {rec.frames.tolist()}, frame_ok {rec.frame_ok.tolist()}, "
            f"RMS mm {np.round(1e3 * rec.rms_m, 2).tolist()}, {rec.seconds:.1f} s, "
            f"converged {rec.converged}: {rec.message}",
            flush=True,
        )


def _resolve(arg: str, renders: Path) -> tuple[Path, float | None]:
    if arg in STUDIO_SCENES:
        return render_studio_scene(arg, renders)
    return Path(arg), None


def _render_note(scene: Path, wall: float | None) -> str:
    try:
        meta = tomllib.loads((scene / "scene.toml").read_text())
    except (OSError, tomllib.TOMLDecodeError):
        return ""
    spi = meta.get("seconds_per_image")
    src = meta.get("source", {})
    note = f"{src.get('bvh', '?')} from BVH frame {src.get('bvh_start_frame', '?')}"
    if spi is not None:
        note += f", {spi:.2f} s/image"
    if wall is not None:
        note += f", rendered now in {wall:.0f} s"
    return note


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.fit", description=__doc__.splitlines()[0])
    ap.add_argument(
        "scenes",
        nargs="*",
        help=f"scene folders or studio scene names {list(STUDIO_SCENES)} "
        f"(default: walk_line3 and {', '.join(DEFAULT_SET)})",
    )
    ap.add_argument("--frames", type=int, default=None)
    ap.add_argument("--observations", default="truth", choices=("truth", "tracks", "auto"))
    ap.add_argument("--model", default="complete", choices=("simplified", "complete"))
    ap.add_argument("--renders", type=Path, default=RENDERS, help="studio scene cache folder")
    ap.add_argument(
        "--cues",
        default="texture",
        choices=("texture", "contours", "both"),
        help="observation types of the fit (python -m core fit --cues)",
    )
    ap.add_argument(
        "--tracks",
        type=Path,
        default=None,
        help="tracker output for --observations tracks (default SCENE/tracks.npz; "
        "for walk_line3 the bench.looks cache)",
    )
    ap.add_argument(
        "--real",
        default="both",
        choices=("texture", "contours", "both", "none"),
        help="with truth-derived observations: also fit walk_line3 through the "
        "real pipeline (its tracker's tracks) with these cues, printed under "
        "the truth-derived row (default both; none: skip)",
    )
    ap.add_argument(
        "--shape",
        default="written",
        choices=("template", "written", "tracked"),
        help="body shape of the fits (python -m core fit --shape)",
    )
    ap.add_argument(
        "--fit-shape",
        action="store_true",
        help="compare the template with the whole-body fitted shape on one scene "
        "(default walk_line3), truth-derived observations, in-process",
    )
    ap.add_argument(
        "--compare-flow",
        action="store_true",
        help="with --cues both: each scene also without the single-camera "
        "texture flow (core fit --no-flow), the row printed under it",
    )
    args = ap.parse_args(argv)
    if args.fit_shape:
        scene, _ = _resolve(args.scenes[0], args.renders) if args.scenes else (DEFAULT, None)
        print_shape_comparison(shape_comparison(scene, args.frames, args.model), scene)
        return 0
    names = args.scenes or [str(DEFAULT), *DEFAULT_SET]
    scenes = [_resolve(a, args.renders) for a in names]  # renders first, sequentially
    label = (
        "TRUTH-DERIVED OBSERVATIONS (points sampled on the true mesh, 1.5 mm noise, "
        "5 % outliers) — not the image pipeline's result"
        if args.observations == "truth"
        else f"observations: {args.observations}"
    )
    print(f"{label}; body shape: {args.shape}")
    hdr = (
        f"{'scene':<14}{'rig':<12}{'frames':>7}{'MPJPE mm':>10}{'max %h':>8}{'<=1% fr':>9}"
        f"{'seg deg':>9}{'surf mm':>9}{'s/frame':>9}  fit timing / points / source"
    )
    print(hdr, flush=True)
    for scene, render_wall in scenes:
        tracks = args.tracks
        if args.observations == "tracks" and tracks is None and _is_default(scene):
            tracks = default_tracks()
        r = run_one(
            scene, args.frames, args.observations, args.model, args.cues, tracks, args.shape
        )
        print_row(r, scene, render_wall)
        if args.compare_flow and args.cues == "both":
            print_row(
                run_one(
                    scene,
                    args.frames,
                    args.observations,
                    args.model,
                    args.cues,
                    tracks,
                    args.shape,
                    flow=False,
                ),
                scene,
                None,
                name="  no flow",
            )
        if args.observations == "truth" and args.real != "none" and _is_default(scene):
            print(
                f"  the same scene through the REAL pipeline (tracks of python -m core "
                f"track, {default_tracks().relative_to(ROOT)}; cues {args.real}):",
                flush=True,
            )
            print_row(
                run_one(
                    scene,
                    args.frames,
                    "tracks",
                    args.model,
                    args.real,
                    default_tracks(),
                    args.shape,
                ),
                scene,
                None,
                name="  real " + args.real,
            )
    return 0


def _is_default(scene: Path) -> bool:
    return Path(scene).resolve() == DEFAULT.resolve()


def default_tracks() -> Path:
    """The real tracker's output for the default scene, cached by :mod:`bench.looks`
    (``python -m core track`` run first when missing, a few minutes)."""
    from bench.looks import tracks_of

    return tracks_of(DEFAULT, DEFAULT.name)[0]


def print_row(r: dict, scene: Path, render_wall: float | None, name: str | None = None) -> None:
    """One table row of :func:`run_one`'s figures and its per-joint / per-segment lines."""
    if "error" in r:
        print(f"{name or r['scene']:<14} failed: {r['error']}", flush=True)
        return
    m = r["metrics"]
    print(
        f"{name or r['scene']:<14}{r['rig']:<12}{r['frames']:>4}/{r['n_frames']:<2}"
        f"{m['mpjpe_mm']:>10.1f}"
        f"{m['max_joint_error_pct_height']:>8.2f}"
        f"{100 * m['frames_within_1pct_height']:>8.0f}%"
        f"{m['segment_orientation_rmse_deg']:>9.1f}{r['surface_mm'] or float('nan'):>9.1f}"
        f"{r['s_per_frame']:>9.2f}  {r['size'][0]}x{r['size'][1]}; {r['fit_line']}; "
        f"{r['pts']}; {_render_note(scene, render_wall)}"
    )
    print("    per joint mm: " + ", ".join(f"{j} {v:.1f}" for j, v in m["per_joint_mm"].items()))
    print(
        "    per segment RMSE deg: "
        + ", ".join(f"{k} {v:.1f}" for k, v in m["per_segment_rmse_deg"].items())
    )
    if m.get("segment_direction_rmse_deg") is not None:
        print(
            f"    limb segments' long axes alone (no twist): "
            f"{m['segment_direction_rmse_deg']:.1f} deg RMSE; per segment: "
            + ", ".join(f"{k} {v:.1f}" for k, v in m["per_segment_direction_rmse_deg"].items())
        )
    if m.get("accel_error_mm") is not None:
        print(
            "    acceleration error (jitter against the truth): "
            f"{m['accel_error_mm']:.2f} mm/frame²"
        )
    t = r.get("tracked")
    if t and t["n"]:
        print(
            f"    tracked points against the truth's material points (the fit's input): "
            f"median {t['median_mm']:.1f} mm, 95th {t['p95_mm']:.1f} mm, "
            f"{t['gross_pct']:.2f}% beyond 5 cm ({t['n']} point-frames); worst frame "
            f"{t['worst_frame']} (mean {t['worst_frame_mean_mm']:.1f} mm)"
        )
    h = r["hidden"]
    print(
        f"    limb joints (elbows, wrists, knees, ankles) where their part was observed: "
        f"{h['seen_mm']:.1f} mm ({h['n_seen']} joint-frames); hidden (sigma of the "
        f"placing angle > {HIDDEN_SIGMA} rad): {h['hidden_mm']:.1f} mm "
        f"({h['n_hidden']}); hidden share: "
        + ", ".join(f"{j} {100 * v:.0f}%" for j, v in h["hidden_share"].items() if v > 0),
        flush=True,
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
