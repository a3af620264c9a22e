"""Weak texture: texture, contours and both on the ``sweater`` and ``skin`` looks (issue 7).

``python -m bench.looks [--frames N] [--cues texture,contours,both] [--looks sweater,skin]``

The same clip twice: the default sample scene ``sample_scenes/walk_line3`` (``02_01.bvh``
from frame 0, ``line3`` rig, 50 frames, 512x384, 25 fps, the ``sweater`` look) and the
same clip rendered by ``python -m sample_scenes.studio ... --look skin`` (cached under
``out/bench_fit/walk_skin_line3``, rendered first when missing, in a subprocess, like
:func:`bench.fit.render_studio_scene`).  For each look:

* the real tracker, ``python -m core track SCENE -o out/bench_fit/looks/<name>.tracks.npz``
  (run when missing): LSM surface points at frame 0 and the share of them tracked
  through every frame;
* the sequence fit (:func:`core.fit_scene.run_scene`, in-process, ``complete`` model)
  with ``cues`` = texture (those tracks), contours (the silhouettes alone, no tracker)
  and both, scored against the truth (:func:`core.evaluate.evaluate_state`): MPJPE,
  segment orientation RMSE (upper/lower arms and legs), diverged frames, CPU seconds.

One table per look, the cues side by side.  The machine is shared: CPU seconds and the
load average are printed with the wall time.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DEFAULT = ROOT / "sample_scenes" / "walk_line3"
MOCAP = ROOT.parent / "shared" / "data" / "mocap"
RENDERS = ROOT / "out" / "bench_fit"
TRACKS = RENDERS / "looks"
CUES = ("texture", "contours", "both")


def skin_scene(root: Path = RENDERS, name: str = "walk_skin_line3") -> tuple[Path, float | None]:
    """The default scene's clip with the ``skin`` look, rendered when missing.

    Settings from ``sample_scenes/walk_line3/scene.toml`` (BVH, start frame, rig, frames,
    fps, size); no wand sequence.  Returns the folder and the render wall time (None
    when cached).
    """
    import tomllib

    from bench.fit import render_cached

    meta = tomllib.loads((DEFAULT / "scene.toml").read_text())
    src = meta["source"]
    w, h = meta["size"]
    return render_cached(
        name,
        root / name,
        [
            "--bvh",
            str(MOCAP / src["bvh"]),
            "--rig",
            src["rig"],
            "--start",
            str(src["bvh_start_frame"]),
            "--frames",
            str(meta["frames"]),
            "--fps",
            str(meta["fps"]),
            "--size",
            f"{w}x{h}",
            "--wand-positions",
            "0",
            "--look",
            "skin",
            "--seed",
            str(src.get("seed", 0)),
        ],
    )


def tracks_of(scene: Path, name: str) -> tuple[Path, float | None]:
    """The tracker's output for a scene (``python -m core track``, run when missing)."""
    TRACKS.mkdir(parents=True, exist_ok=True)
    out = TRACKS / f"{name}.tracks.npz"
    if out.is_file():
        return out, None
    cmd = [sys.executable, "-m", "core", "track", str(scene), "-o", str(out)]
    print(f"tracking {name}: python {' '.join(cmd[1:])}", flush=True)
    t0 = time.perf_counter()
    p = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
    if p.returncode != 0 or not out.is_file():
        raise RuntimeError(f"tracking failed for {name}: {p.stderr.strip().splitlines()[-1:]}")
    return out, time.perf_counter() - t0


def track_survival(path: Path, n_frames: int | None = None) -> dict:
    """Frame-0 points of a ``tracks.npz`` and the share of them measured in every frame."""
    with np.load(path) as z:
        xyz = np.asarray(z["xyz"], float)
    if n_frames is not None:
        xyz = xyz[:n_frames]
    seen = np.all(np.isfinite(xyz), axis=2)  # (F, P)
    at0 = seen[0] if len(seen) else np.zeros(0, bool)
    n0 = int(at0.sum())
    through = int((seen[:, at0].all(axis=0)).sum()) if n0 else 0
    return {
        "n0": n0,
        "through": through,
        "share": through / n0 if n0 else 0.0,
        "median_per_frame": float(np.median(seen.sum(axis=1))) if len(seen) else 0.0,
    }


def fit_cue(
    scene_dir: Path, cues: str, tracks: Path, frames: int | None, model: str = "complete"
) -> dict:
    """One fit of a scene with the given cues, scored against the truth."""
    from core.evaluate import evaluate_state
    from core.fit_cli import _pad
    from core.fit_scene import run_scene
    from core.scene import load_scene

    scene = load_scene(scene_dir, check_images=False)
    t0, c0 = time.perf_counter(), time.process_time()
    try:
        res = run_scene(
            scene, observations="tracks", model=model, frames=frames, cues=cues, tracks=tracks
        )
    except Exception as exc:  # noqa: BLE001 — a failed configuration is a table entry
        return {"cues": cues, "error": f"{type(exc).__name__}: {exc}"}
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    st = res.state
    full = _pad(st, scene.n_frames) if st.n_frames < scene.n_frames else st
    ev = evaluate_state(full, scene.truth)
    return {
        "cues": cues,
        "eval": ev,
        "wall_s": wall,
        "cpu_s": cpu,
        "n_frames": st.n_frames,
        "diverged": int(st.quality.diverged.sum()),
        "points": float(np.median(res.n_points)) if len(res.n_points) else 0.0,
        "pairs": (
            float(np.median(res.contour_matches))
            if res.contour_matches is not None
            else float("nan")
        ),
        "messages": res.messages,
    }


def print_look(look: str, scene: Path, surv: dict, rows: list[dict], track_s) -> None:
    print(
        f"\n{look}: {scene}  (tracker: {surv['n0']} LSM surface points at frame 0, "
        f"{surv['through']} = {100 * surv['share']:.1f} % of them tracked through every "
        f"frame, median {surv['median_per_frame']:.0f} points per frame"
        + (f"; tracked now in {track_s:.0f} s" if track_s else "")
        + ")"
    )
    print(f"{'':30s}" + "".join(f"{r['cues']:>12s}" for r in rows))
    lines = [
        ("MPJPE mm", lambda r: r["eval"].mpjpe_mm),
        ("segment orient. RMSE deg", lambda r: r["eval"].segment_orientation_rmse_deg),
        ("max joint err % height", lambda r: r["eval"].max_joint_error_pct_height),
        ("diverged frames (not scored)", lambda r: r["diverged"]),
        ("frames fitted", lambda r: r["n_frames"]),
        ("points per frame (median)", lambda r: r["points"]),
        ("contour pairs/frame (median)", lambda r: r["pairs"]),
        ("fit wall s", lambda r: r["wall_s"]),
        ("fit CPU s", lambda r: r["cpu_s"]),
    ]
    for name, get in lines:
        cells = []
        for r in rows:
            cells.append(f"{'failed':>12s}" if "error" in r else f"{get(r):12.1f}")
        print(f"{name:30s}" + "".join(cells))
    for r in rows:
        if "error" in r:
            print(f"  {r['cues']}: {r['error']}")
        else:
            pj = r["eval"].per_joint_mm
            print(
                f"  {r['cues']} per joint mm: " + ", ".join(f"{j} {v:.0f}" for j, v in pj.items())
            )
    print(flush=True)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.looks", description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=None, help="fit only the first N frames")
    ap.add_argument("--cues", default=",".join(CUES), help="comma-separated, of " + str(CUES))
    ap.add_argument("--looks", default="sweater,skin", help="comma-separated: sweater, skin")
    ap.add_argument("--model", default="complete", choices=("simplified", "complete"))
    args = ap.parse_args(argv)
    cues = [c for c in args.cues.split(",") if c]
    bad = [c for c in cues if c not in CUES]
    if bad:
        ap.error(f"unknown cues {bad}; choose from {CUES}")
    looks = [x for x in args.looks.split(",") if x]
    for look in looks:
        if look == "sweater":
            scene, name = DEFAULT, "walk_line3"
        elif look == "skin":
            scene, wall = skin_scene()
            name = scene.name
            if wall is not None:
                print(f"rendered {name} in {wall:.0f} s", flush=True)
        else:
            ap.error(f"unknown look {look!r}; choose sweater or skin")
        tracks, track_s = tracks_of(scene, name)
        surv = track_survival(tracks, args.frames)
        rows = [fit_cue(scene, c, tracks, args.frames, args.model) for c in cues]
        print_look(look, scene, surv, rows, track_s)
    from core.fit import SequenceSettings
    from core.fit_contours import ContourSettings
    from core.fit_scene import CONTOUR_SKIP_PARTS

    print(
        f"contour observations: {ContourSettings()}; in the scene fits: skip_parts "
        f"{CONTOUR_SKIP_PARTS}"
    )
    seq = SequenceSettings()
    print(
        f"tracked trajectories as rigid-motion observations: {seq.trajectories} (slip "
        f"{1000 * seq.traj_slip_m:.0f} mm, Cauchy knee {seq.traj_robust:g} sigma); hidden "
        f"parts held: {seq.hold_hidden}; silhouette limb search (contours alone): "
        f"{seq.silhouette_search}, in frames with points too (vetoed where it takes a "
        f"limb off its points): {seq.silhouette_search and seq.silhouette_search_points}"
    )
    print(f"load average {os.getloadavg()[0]:.1f} (2 shared cores: wall times are noisy)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
