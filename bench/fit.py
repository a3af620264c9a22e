"""Benchmark of ``core fit`` + ``core evaluate`` on studio scenes.

``python -m bench.fit [SCENE ...] [--frames N] [--observations truth]``

For each scene: runs ``python -m core fit`` (timed end to end) and ``python -m core
evaluate --json``, measures the fitted metaball surface against the true mesh (mean
distance of the true vertices to the fitted surface, by projection onto ``Σ f = 0.5``
in :mod:`core.metaballs`), and the skeleton floor (the truth expressed in our
skeleton, :mod:`core.truth_state`).  With ``--observations truth`` the fit uses
truth-derived surface points — a development stand-in for the tracker, labelled as
such in the table, never the pipeline's result.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

DEFAULT = Path(__file__).resolve().parents[1] / "sample_scenes" / "walk_line3"


def surface_distance_mm(state, vertices: np.ndarray, frames: list[int], per_frame: int = 2000,
                        seed: int = 0) -> float:
    """Mean distance (mm) of true mesh vertices to the fitted metaball surface."""
    from core import metaballs as mb
    from core.skeleton import forward

    rng = np.random.default_rng(seed)
    out = []
    for f in frames:
        pose = forward(state.skeleton, state.theta[f][None], state.root_xyz[f][None], state.s)
        Rw, cw = mb.world_frames(state.skeleton, pose, state.metaballs, state.s)
        v = vertices[f][rng.choice(len(vertices[f]), min(per_frame, len(vertices[f])), False)]
        xs, ok = mb.project_to_surface(v.astype(float), Rw[0], cw[0], state.metaballs.radii,
                                       iterations=60, tol=1e-6)
        out.append(np.linalg.norm(xs - v, axis=1)[ok])
    return float(np.mean(np.concatenate(out)) * 1000.0)


def run_one(scene: Path, frames: int | None, observations: str, model: str) -> dict:
    from core.scene import load_scene
    from core.state import read_state

    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "fit.json"
        cmd = [sys.executable, "-m", "core", "fit", str(scene), "-o", str(out),
               "--observations", observations, "--model", model]
        if frames:
            cmd += ["--frames", str(frames)]
        t0 = time.perf_counter()
        p = subprocess.run(cmd, capture_output=True, text=True)
        wall = time.perf_counter() - t0
        if p.returncode != 0:
            return {"scene": scene.name, "error": p.stderr.strip().splitlines()[-1:]}
        ev = subprocess.run([sys.executable, "-m", "core", "evaluate", str(scene), str(out),
                             "--json"], capture_output=True, text=True)
        metrics = json.loads(ev.stdout.strip().splitlines()[-1])
        state = read_state(out)
        fit_line = [ln for ln in p.stdout.splitlines() if ln.startswith("seconds:")]
        pts_line = [ln for ln in p.stdout.splitlines() if ln.startswith("points per frame")]
    sc = load_scene(scene, check_images=False)
    ok = [f for f in range(state.n_frames) if not state.quality.diverged[f]]
    surf = surface_distance_mm(state, sc.truth["vertices"], ok[:: max(1, len(ok) // 5)])
    return {"scene": scene.name, "size": sc.image_size, "frames": len(ok),
            "metrics": metrics, "surface_mm": surf, "wall_s": wall,
            "fit_line": fit_line[0] if fit_line else "", "pts": pts_line[0] if pts_line else ""}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.fit", description=__doc__.splitlines()[0])
    ap.add_argument("scenes", nargs="*", type=Path, default=[DEFAULT])
    ap.add_argument("--frames", type=int, default=None)
    ap.add_argument("--observations", default="truth", choices=("truth", "tracks", "auto"))
    ap.add_argument("--model", default="complete", choices=("simplified", "complete"))
    args = ap.parse_args(argv)
    label = ("TRUTH-DERIVED OBSERVATIONS (points sampled on the true mesh, 1.5 mm noise, "
             "5 % outliers) — not the image pipeline's result"
             if args.observations == "truth" else f"observations: {args.observations}")
    print(label)
    hdr = (f"{'scene':<14}{'frames':>7}{'MPJPE mm':>10}{'max %h':>8}{'<=1% fr':>9}"
           f"{'seg deg':>9}{'surf mm':>9}{'wall s':>8}  fit timing / points")
    print(hdr)
    for scene in args.scenes:
        r = run_one(scene, args.frames, args.observations, args.model)
        if "error" in r:
            print(f"{r['scene']:<14} failed: {r['error']}")
            continue
        m = r["metrics"]
        print(f"{r['scene']:<14}{r['frames']:>7}{m['mpjpe_mm']:>10.1f}"
              f"{m['max_joint_error_pct_height']:>8.2f}"
              f"{100 * m['frames_within_1pct_height']:>8.0f}%"
              f"{m['segment_orientation_rmse_deg']:>9.1f}{r['surface_mm']:>9.1f}"
              f"{r['wall_s']:>8.0f}  {r['size'][0]}x{r['size'][1]}; {r['fit_line']}; {r['pts']}")
        print("    per joint mm: " + ", ".join(
            f"{j} {v:.1f}" for j, v in m["per_joint_mm"].items()))
        print("    per segment RMSE deg: " + ", ".join(
            f"{k} {v:.1f}" for k, v in m["per_segment_rmse_deg"].items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
