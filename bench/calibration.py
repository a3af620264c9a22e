"""Calibration benchmark: ``python -m bench.calibration [--scene DIR ...]``.

1. Rendered wand sequences: ``sample_scenes/walk_line3`` (committed) and two wand-only
   renders of the studio cached under ``out/bench_calibration/`` (rendered on the first
   run when missing, about 7 min for ring4 and 5 min for interlaced line3 on two
   shared cores): ``--rig ring4 --wand-only`` and ``--rig line3 --interlace
   --wand-only`` (single odd fields, pixel aspect 2).  Each is calibrated from nothing
   but the images and L and compared with the scene's true ``calibration.toml`` after a
   similarity alignment (the adjustment's datum is camera 1 fixed, scale from L):
   reprojection RMSE, camera-centre errors, focal errors, pixel aspect, RMS bar-length
   residual of independently intersected bars.  Then the same with 5 % of the target
   detections replaced by wrong blobs (random image points), with the precision and
   recall of the bad-blob flags against the truth (an observation is truly bad when it
   is not within 1.5 px of its target's true projection: a wrong blob, or a good blob
   under the other target's label).
2. Synthetic single-field rig (projected points, pixel aspect 2): the recovered aspect.
3. Checkerboard intrinsics (``cv2.calibrateCamera``) of the shared Pose2Sim images
   beside the Qualisys values of ``Calib.qca.txt``.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import numpy as np

from core.calibrate import _WandImages, calibrate_detections, compare_to_reference
from core.calibration_io import read_calibration
from core.formats import checkerboard_intrinsics, read_qca
from core.scene import load_wand
from core.wand import detect_sequence

REPO = Path(__file__).resolve().parents[1]
CACHE = REPO / "out" / "bench_calibration"
RENDERS = {
    "ring4_wand": ["--rig", "ring4", "--wand-only"],
    "line3_interlaced_wand": ["--rig", "line3", "--interlace", "--wand-only"],
}
SHARED = REPO.parent / "shared" / "data" / "video" / "pose2sim_single"


def _row(label, rep, truth):
    cmp = compare_to_reference(rep.cameras, truth, "truth")
    b = rep.bundle
    print(
        f"{label:34s} RMSE px max {np.nanmax(b.rmse_px):.3f} | centre err mm max "
        f"{1e3 * cmp['centre_error_m'].max():.2f} | focal err % max "
        f"{100 * np.abs(cmp['focal_error']).max():.3f} | aspect "
        f"{', '.join(f'{a:.4f}' for a in cmp['aspect'])} | bar RMS mm {rep.bar_rms_mm:.3f}"
    )
    return cmp


def _truly_bad(uv, truth, wand_xyz):
    """(F, C, 2) observations not within 1.5 px of their target's true projection."""
    F = uv.shape[0]
    proj = np.stack([c.project(wand_xyz.reshape(-1, 3)).reshape(F, 2, 2) for c in truth], 1)
    d = np.linalg.norm(uv[:, :, :, None, :] - proj[:, :, None, :, :], axis=-1)
    m = np.where(d.min(-1) < 1.5, d.argmin(-1), -1)  # matched true target
    same = (m[..., 0] == 0).sum(1) >= (m[..., 0] == 1).sum(1)  # label map per location
    expect = np.where(same[:, None, None], np.arange(2), 1 - np.arange(2))
    return np.all(np.isfinite(uv), -1) & (m != expect)


def bench_scene(root: Path, frac: float = 0.05, seed: int = 0) -> None:
    scene = load_wand(root)
    truth = read_calibration(root / "calibration.toml")
    t0 = time.perf_counter()
    det = detect_sequence(_WandImages(scene))
    t_det = time.perf_counter() - t0
    sizes = [scene.camera_size(c) for c in scene.cameras]
    aspect = 1.0 if scene.field == "none" else 2.0
    free = ("f", "cx", "cy", "k1", "k2") + (("aspect",) if aspect != 1.0 else ())
    L = scene.wand_length()
    print(
        f"\n{root.name} (field {scene.field}): {len(scene.cameras)} cameras, "
        f"{det.summary()}; detection {t_det:.0f} s"
    )
    t0 = time.perf_counter()
    rep = calibrate_detections(
        det.uv, sizes, scene.cameras, L, free=free, aspect=aspect, detections=det
    )
    _row(f"images + L ({time.perf_counter() - t0:.0f} s)", rep, truth)
    rng = np.random.default_rng(seed)
    uv = det.uv.copy()
    seen = np.argwhere(np.all(np.isfinite(uv), axis=-1))
    pick = seen[rng.choice(len(seen), int(round(frac * len(seen))), replace=False)]
    w, h = sizes[0]
    uv[tuple(pick.T)] = rng.uniform([0, 0], [w - 1, h - 1], size=(len(pick), 2))
    t0 = time.perf_counter()
    rep2 = calibrate_detections(uv, sizes, scene.cameras, L, free=free, aspect=aspect)
    _row(f"+ {100 * frac:.0f} % wrong blobs ({time.perf_counter() - t0:.0f} s)", rep2, truth)
    fl = rep2.bundle.outliers
    line = (
        f"{'':34s} {len(pick)} wrong blobs; flagged {int(fl.sum())} of {len(seen)} "
        f"observations; locations used {int(rep2.bundle.used.sum())}/{len(uv)}; "
        f"labels repaired in {int(rep2.bundle.swapped.sum())} images"
    )
    wt = root / "wand_truth.npz"
    if wt.is_file():
        with np.load(wt) as z:
            bad = _truly_bad(rep2.uv, truth, z["xyz"])
        tp = int((fl & bad).sum())
        line += (
            f"\n{'':34s} flags vs truth: {int(bad.sum())} truly bad, precision "
            f"{tp / max(int(fl.sum()), 1):.3f}, recall {tp / max(int(bad.sum()), 1):.3f}"
        )
    print(line)


def _render(name: str) -> Path:
    """The cached studio render ``out/bench_calibration/<name>`` (rendered if missing)."""
    out = CACHE / name
    if (out / "wand").is_dir() and (out / "calibration.toml").is_file():
        return out
    CACHE.mkdir(parents=True, exist_ok=True)
    print(f"\nrendering {name} with the studio (minutes) ...", flush=True)
    t0 = time.perf_counter()
    subprocess.run(
        [sys.executable, "-m", "sample_scenes.studio", *RENDERS[name], "--out", str(out)],
        cwd=REPO,
        check=True,
        stdout=subprocess.DEVNULL,
    )
    print(f"rendered {name} in {time.perf_counter() - t0:.0f} s")
    return out


def bench_interlaced() -> None:
    sys.path.insert(0, str(REPO))
    from tests.core.wand_truth import rig, wand_capture

    cams = rig("line3", aspect=2.0)
    _, uv, _ = wand_capture(cams, n=150, noise_px=0.05, outlier_frac=0.05, seed=3)
    rep = calibrate_detections(
        uv,
        [c.size for c in cams],
        [c.name for c in cams],
        0.5,
        free=("f", "aspect", "cx", "cy", "k1", "k2"),
        aspect=2.0,
    )
    print(
        "\nsynthetic single-field line3 (512x192, true aspect 2, 0.05 px noise, 5 % wrong "
        "blobs, start aspect 2 from the scene's field):"
    )
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
    print(
        f"\ncheckerboard ({corners[0]}x{corners[1]} inner corners, {square * 1e3:.0f} mm) "
        "cv2.calibrateCamera vs Qualisys Calib.qca.txt:"
    )
    print(
        f"{'camera':7s} {'source':9s} {'n':>3s} {'rms':>5s} {'fx':>8s} {'fy':>8s} {'cx':>7s} "
        f"{'cy':>7s} {'k1':>8s} {'k2':>8s} {'p1':>8s} {'p2':>8s}"
    )
    for folder in sorted((SHARED / "calibration" / "intrinsics").iterdir()):
        name = folder.name.split("_")[1]
        imgs = sorted(folder.glob("*.jpg")) + sorted(folder.glob("*.png"))
        try:
            K, d, rms, _, n = checkerboard_intrinsics(imgs, corners, square)
            print(
                f"{name:7s} {'opencv':9s} {n:3d} {rms:5.2f} {K[0, 0]:8.1f} {K[1, 1]:8.1f} "
                f"{K[0, 2]:7.1f} {K[1, 2]:7.1f} {d[0]:8.4f} {d[1]:8.4f} {d[2]:8.5f} {d[3]:8.5f}"
            )
        except Exception as exc:  # noqa: BLE001 - a benchmark row, not a pipeline step
            print(f"{name:7s} {'opencv':9s} failed: {exc}")
        c = q.get(name)
        if c is not None:
            print(
                f"{'':7s} {'qualisys':9s} {'':3s} {'':5s} {c.K[0, 0]:8.1f} {c.K[1, 1]:8.1f} "
                f"{c.K[0, 2]:7.1f} {c.K[1, 2]:7.1f} {c.dist[0]:8.4f} {c.dist[1]:8.4f} "
                f"{c.dist[2]:8.5f} {c.dist[3]:8.5f}"
            )


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument(
        "--scene",
        type=Path,
        action="append",
        default=None,
        help="rendered scene folder(s) with wand/ and a true calibration.toml",
    )
    p.add_argument("--skip-checkerboard", action="store_true")
    p.add_argument(
        "--no-render", action="store_true", help="only the committed walk_line3 (no studio renders)"
    )
    args = p.parse_args(argv)
    if args.scene:
        scenes = args.scene
    else:
        scenes = [REPO / "sample_scenes" / "walk_line3"]
        if not args.no_render:
            scenes += [_render(n) for n in RENDERS]
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
