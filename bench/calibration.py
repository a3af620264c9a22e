"""Calibration benchmark: ``python -m bench.calibration [--scene DIR ...] [--quick]``.

1. Rendered wand sequences (default ``sample_scenes/walk_line3``; more with ``--scene``,
   e.g. a ring4 or interlaced render of ``python -m sample_scenes.studio --wand-only``):
   calibrated from nothing but the images and L, compared with the scene's true
   ``calibration.toml`` after a similarity alignment (the adjustment's datum is camera 1
   fixed, scale from L): reprojection RMSE, camera-centre errors, focal errors, pixel
   aspect, RMS bar-length residual of independently intersected bars.  Then the same
   with 5 % of the target detections replaced by wrong blobs (random image points):
   the same figures and how many wrong blobs were flagged.
2. Synthetic single-field rig (projected points, pixel aspect 2): the recovered aspect.
3. Checkerboard intrinsics (``cv2.calibrateCamera``) of the shared Pose2Sim images
   beside the Qualisys values of ``Calib.qca.txt``.
"""

from __future__ import annotations

import argparse
import sys
import tomllib
from pathlib import Path

import numpy as np

from core.calibrate import calibrate_detections, compare_to_reference
from core.calibration_io import read_calibration
from core.formats import checkerboard_intrinsics, read_qca
from core.scene import load_scene
from core.wand import detect_sequence

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared" / "data" / "video" / "pose2sim_single"


def _row(label, rep, truth):
    cmp = compare_to_reference(rep.cameras, truth, "truth")
    b = rep.bundle
    print(f"{label:34s} RMSE px max {np.nanmax(b.rmse_px):.3f} | centre err mm max "
          f"{1e3 * cmp['centre_error_m'].max():.2f} | focal err % max "
          f"{100 * np.abs(cmp['focal_error']).max():.3f} | aspect "
          f"{', '.join(f'{a:.4f}' for a in cmp['aspect'])} | bar RMS mm {rep.bar_rms_mm:.3f}")
    return cmp


def bench_scene(root: Path, frac: float = 0.05, seed: int = 0) -> None:
    from core.calibrate import _WandImages
    from core.calibrate_cli import _has_images, _wand_only_scene

    scene = load_scene(root, check_images=False) if _has_images(root) else _wand_only_scene(root)
    truth = read_calibration(root / "calibration.toml")
    det = detect_sequence(_WandImages(scene))
    sizes = [scene.camera_size(c) for c in scene.cameras]
    aspect = 1.0 if scene.field == "none" else 2.0
    free = ("f", "cx", "cy", "k1", "k2") + (("aspect",) if aspect != 1.0 else ())
    L = scene.wand_length()
    print(f"\n{root.name}: {len(scene.cameras)} cameras, {det.summary()}")
    rep = calibrate_detections(det.uv, sizes, scene.cameras, L, free=free, aspect=aspect,
                               detections=det)
    _row("images + L", rep, truth)
    rng = np.random.default_rng(seed)
    uv = det.uv.copy()
    seen = np.argwhere(np.all(np.isfinite(uv), axis=-1))
    pick = seen[rng.choice(len(seen), int(round(frac * len(seen))), replace=False)]
    w, h = sizes[0]
    uv[tuple(pick.T)] = rng.uniform([0, 0], [w - 1, h - 1], size=(len(pick), 2))
    rep2 = calibrate_detections(uv, sizes, scene.cameras, L, free=free, aspect=aspect)
    _row(f"+ {100 * frac:.0f} % wrong blobs", rep2, truth)
    flagged = rep2.bundle.outliers[tuple(pick.T)].sum()
    print(f"{'':34s} wrong blobs flagged: {flagged}/{len(pick)}; observations flagged in "
          f"all: {int(rep2.bundle.outliers.sum())} of {len(seen)}")


def bench_interlaced() -> None:
    sys.path.insert(0, str(REPO))
    from tests.core.wand_truth import rig, wand_capture

    cams = rig("line3", aspect=2.0)
    _, uv, _ = wand_capture(cams, n=150, noise_px=0.05, outlier_frac=0.05, seed=3)
    rep = calibrate_detections(uv, [c.size for c in cams], [c.name for c in cams], 0.5,
                               free=("f", "aspect", "cx", "cy", "k1", "k2"), aspect=2.0)
    print("\nsynthetic single-field line3 (512x192, true aspect 2, 0.05 px noise, 5 % wrong "
          "blobs, start aspect 2 from the scene's field):")
    _row("projected points + L", rep, cams)


def bench_checkerboard() -> None:
    qca = SHARED / "calibration" / "Calib.qca.txt"
    if not qca.is_file():
        print("\n(shared Pose2Sim data absent: checkerboard table skipped)")
        return
    cfg = tomllib.loads((SHARED / "Config.toml").read_text())
    intr = cfg["calibration"]["calculate"]["intrinsics"]
    corners, square = tuple(intr["intrinsics_corners_nb"]), intr["intrinsics_square_size"] / 1e3
    q = {c.name: c for c in read_qca(qca)}
    print(f"\ncheckerboard ({corners[0]}x{corners[1]} inner corners, {square * 1e3:.0f} mm) "
          "cv2.calibrateCamera vs Qualisys Calib.qca.txt:")
    print(f"{'camera':7s} {'source':9s} {'n':>3s} {'rms':>5s} {'fx':>8s} {'fy':>8s} {'cx':>7s} "
          f"{'cy':>7s} {'k1':>8s} {'k2':>8s} {'p1':>8s} {'p2':>8s}")
    for folder in sorted((SHARED / "calibration" / "intrinsics").iterdir()):
        name = folder.name.split("_")[1]
        imgs = sorted(folder.glob("*.jpg")) + sorted(folder.glob("*.png"))
        try:
            K, d, rms, _, n = checkerboard_intrinsics(imgs, corners, square)
            print(f"{name:7s} {'opencv':9s} {n:3d} {rms:5.2f} {K[0, 0]:8.1f} {K[1, 1]:8.1f} "
                  f"{K[0, 2]:7.1f} {K[1, 2]:7.1f} {d[0]:8.4f} {d[1]:8.4f} {d[2]:8.5f} {d[3]:8.5f}")
        except Exception as exc:  # noqa: BLE001 - a benchmark row, not a pipeline step
            print(f"{name:7s} {'opencv':9s} failed: {exc}")
        c = q.get(name)
        if c is not None:
            print(f"{'':7s} {'qualisys':9s} {'':3s} {'':5s} {c.K[0, 0]:8.1f} {c.K[1, 1]:8.1f} "
                  f"{c.K[0, 2]:7.1f} {c.K[1, 2]:7.1f} {c.dist[0]:8.4f} {c.dist[1]:8.4f} "
                  f"{c.dist[2]:8.5f} {c.dist[3]:8.5f}")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scene", type=Path, action="append", default=None,
                   help="rendered scene folder(s) with wand/ and a true calibration.toml")
    p.add_argument("--skip-checkerboard", action="store_true")
    args = p.parse_args(argv)
    scenes = args.scene or [REPO / "sample_scenes" / "walk_line3"]
    for s in scenes:
        if (s / "wand").is_dir() and (s / "calibration.toml").is_file():
            bench_scene(s)
        else:
            print(f"\n{s}: no wand/ or calibration.toml, skipped")
    bench_interlaced()
    if not args.skip_checkerboard:
        bench_checkerboard()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
