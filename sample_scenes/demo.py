"""``make demo``: the main job on the default sample scene, step by step.

Runs, each as the command a user would type, and says what it wrote:

1. ``python -m core calibrate`` — self-calibration from the scene's reference-bar
   images alone, compared with the true cameras;
2. ``python -m core track`` — the surface measured at frame 0 by least squares matching
   from the clicked seeds, then tracked through every frame (``out/demo/tracks.npz``);
3. ``python -m core fit --cues both`` — initialisation from the key-joint clicks and the
   weighted least-squares fit of the metaball body across frames, from the tracked
   points and trajectories and the occluding contours of every camera;
4. ``python -m core evaluate`` — the fit against the scene's ground truth, with a PNG of
   the per-frame errors;
5. ``python -m addon.launch fit`` — Blender (the ``bpy`` module): cameras with the
   footage, the metaball body, its action, and the motion retargeted onto a Rigify
   human rig generated from Blender's meta-rig; saved as ``out/demo.blend``.

Outputs go to ``out/`` (created; existing files there are replaced, nothing outside it
is touched).  Exit status is non-zero when a step fails.
"""

from __future__ import annotations

import importlib.util
import shutil
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SCENE = REPO / "sample_scenes" / "walk_line3"
OUT = REPO / "out"
FIT_FRAMES = 50


def _step(title: str, args: list[str]) -> float:
    print(f"\n== {title}\n$ {' '.join(str(a) for a in args)}", flush=True)
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, *map(str, args)], cwd=REPO)
    dt = time.perf_counter() - t0
    if proc.returncode != 0:
        print(f"demo: step '{title}' failed (exit {proc.returncode})", file=sys.stderr)
        sys.exit(proc.returncode)
    print(f"-- {title}: {dt:.1f} s", flush=True)
    return dt


def main() -> int:
    OUT.mkdir(exist_ok=True)
    demo = OUT / "demo"
    if demo.exists():
        shutil.rmtree(demo)
    demo.mkdir()
    wrote: list[tuple[Path, str]] = []

    calib = demo / "calibration.toml"
    _step(
        "calibrate from the reference bar",
        ["-m", "core", "calibrate", SCENE, "-o", calib, "--reference", SCENE / "calibration.toml"],
    )
    wrote.append((calib, "cameras calibrated from the wand images and the bar length"))

    fit = demo / "fit.json"
    if importlib.util.find_spec("core.fit_cli") is not None:
        tracks = demo / "tracks.npz"
        _step(
            f"measure the surface and track it ({FIT_FRAMES} frames)",
            ["-m", "core", "track", SCENE, "-o", tracks, "--frames", str(FIT_FRAMES)],
        )
        wrote.append((tracks, "tracked surface points: 3-D trajectories with their precision"))
        _step(
            f"fit the body ({FIT_FRAMES} frames) to the tracks and the contours",
            [
                "-m",
                "core",
                "fit",
                SCENE,
                "-o",
                fit,
                "--observations",
                "tracks",
                "--tracks",
                tracks,
                "--cues",
                "both",
                "--frames",
                str(FIT_FRAMES),
            ],
        )
        wrote.append(
            (
                fit,
                "fitted state: skeleton, metaball shape, per-frame joint angles "
                f"({FIT_FRAMES} frames, tracked points and contours)",
            )
        )
        plot = demo / "errors.png"
        _step("evaluate against the truth", ["-m", "core", "evaluate", SCENE, fit, "--plot", plot])
        wrote.append((plot, "per-frame joint and segment errors"))
    else:
        print(
            "\n== fit: the fitting stage is not in this checkout yet; "
            "the Blender step builds the studio's truth instead",
            flush=True,
        )
        _step("truth as a fitted state", ["-m", "core.truth_state", SCENE, "-o", fit])
        wrote.append((fit, "the scene's ground truth written as a fitted state"))

    blend = OUT / "demo.blend"
    _step(
        "build in Blender",
        ["-m", "addon.launch", "fit", SCENE, "--fit", fit, "--out", blend, "--target", "rigify"],
    )
    wrote.append(
        (
            blend,
            "cameras + footage, armature, metaball body, action, the motion "
            "retargeted onto a generated Rigify human (FK controls keyed)",
        )
    )

    print("\nThe demo wrote:")
    for path, what in wrote:
        print(f"  {path.relative_to(REPO)}  — {what}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
