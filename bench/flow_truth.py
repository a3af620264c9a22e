"""The texture flow's corners against the true mesh: Lucas–Kanade alone, and refined by LSM.

``python -m bench.flow_truth SCENE [--parts head,pelvis,...] [--step K]``

The fit's texture flow (:mod:`core.fit_flow`) follows image corners from one frame to
the next in each camera.  Here the same corners are followed on a studio scene whose
true mesh is known (``truth.npz`` ``vertices``, ``faces``), so each corner's true
motion is known too:

* corners: ``cv2.goodFeaturesToTrack`` with the flow's settings, on one body region
  per part (the true mesh within 12 cm of the truth's joint; the head's between its
  ``head`` and ``head_top`` joints, within 14 cm), inside the truth's foreground mask
  eroded by 3 px — as the fit lifts them, but on the true body instead of the fitted
  one;
* the true point: the corner's pixel ray meets the true mesh's depth map
  (:func:`core.truth_points.depth_map`); the nearest triangle there
  (:func:`bench.meshtruth.nearest_on_mesh`) and its barycentric coordinates carry it
  into the next frame's mesh, which is projected;
* ``LK``: :func:`core.fit_flow.follow_corners` (pyramidal Lucas–Kanade, 15 px window,
  forward–backward check); ``LK + LSM``: the same, then
  :func:`core.fit_flow.refine_corners` (least squares matching, affine + radiometric,
  from the previous image; a corner it rejects is dropped).

Per part and per band of distance from the foreground's outline (pixels): the number
of corners each method keeps, the median and 90th-percentile error against the true
point (px), and the mean error along the true motion's direction (px; negative: the
corner trails its material point), beside the median true motion.

Frames: image pixels with integer coordinates at pixel centres.
"""

from __future__ import annotations

import argparse
import sys

import cv2
import numpy as np

BANDS = ((3, 6), (6, 8), (8, 11), (11, 15), (15, 999))


def _region_centre(truth: dict, names: list, part: str, f: int):
    """Centre (3,) and radius (m) of the true mesh region standing for ``part``."""
    J = truth["joints_xyz"]
    if part == "head":
        return 0.5 * (J[f, names.index("head")] + J[f, names.index("head_top")]), 0.14
    return J[f, names.index(part)], 0.12


def measure(scene, parts: list[str], step: int = 1, progress=None) -> dict:
    """Rows per (part, method) (K, 6): frame, camera, distance from the outline (px),
    error (px), true motion (px), error along the motion (px).  ``progress``: a
    :class:`core.progress.Progress` or None."""
    from bench.meshtruth import nearest_on_mesh
    from core.fit_flow import FlowSettings, follow_corners, refine_corners
    from core.truth_points import depth_map

    cams = scene.calibration()
    truth = scene.truth
    V, F = truth["vertices"].astype(float), truth["faces"]
    names = list(truth["joint_names"])
    masks = scene.truth_masks()
    cfg = FlowSettings()
    kernel = np.ones((2 * cfg.erode_px + 1,) * 2, np.uint8)
    rows = {(p, m): [] for p in parts for m in ("LK", "LK + LSM")}
    nf = V.shape[0]
    for f in range(0, nf - 1, step):
        tri = V[f][F]
        for c, cam in enumerate(cams):
            z = depth_map(cam, tri)
            h, w = z.shape
            vv, uu = np.nonzero(np.isfinite(z))
            _, d = cam.rays(np.column_stack([uu, vv]).astype(float))
            X = np.full((h, w, 3), np.nan)
            X[vv, uu] = cam.center + d * (z[vv, uu] / (d @ cam.R.T)[:, 2])[:, None]
            fg = masks[c, f].astype(np.uint8)
            outline = cv2.distanceTransform(fg, cv2.DIST_L2, 5)
            img0, img1 = scene.image(c, f), scene.image(c, f + 1)
            for part in parts:
                c0, rad = _region_centre(truth, names, part, f)
                inside = np.zeros((h, w), np.uint8)
                inside[vv, uu] = np.linalg.norm(X[vv, uu] - c0, axis=1) < rad
                m = cv2.erode(inside, kernel) & cv2.erode(fg, kernel)
                if m.sum() < 9:
                    continue
                pts = cv2.goodFeaturesToTrack(
                    img0, cfg.per_part, cfg.quality, cfg.min_distance_px, mask=m
                )
                if pts is None:
                    continue
                uv = pts.reshape(-1, 2).astype(float)
                iu, iv = np.rint(uv[:, 0]).astype(int), np.rint(uv[:, 1]).astype(int)
                _, du = cam.rays(uv)
                P = cam.center + du * (z[iv, iu] / (du @ cam.R.T)[:, 2])[:, None]
                _, face, bary = nearest_on_mesh(P, V[f], F)
                true0 = cam.project(np.einsum("kj,kji->ki", bary, tri[face]))
                true1 = cam.project(np.einsum("kj,kji->ki", bary, V[f + 1][F[face]]))
                true1 = true1 + (uv - true0)  # the corner's own sub-pixel offset
                lk, ok = follow_corners(img0, img1, uv, cfg)
                fine, ok_fine = refine_corners(img0, img1, uv, lk, ok, cfg)
                move = true1 - uv
                unit = move / np.maximum(np.linalg.norm(move, axis=1, keepdims=True), 1e-9)
                for method, got, keep in (("LK", lk, ok), ("LK + LSM", fine, ok_fine)):
                    e = got - true1
                    for k in np.flatnonzero(keep):
                        rows[part, method].append(
                            (
                                f,
                                c,
                                outline[iv[k], iu[k]],
                                np.linalg.norm(e[k]),
                                np.linalg.norm(move[k]),
                                e[k] @ unit[k],
                            )
                        )
        if progress is not None:
            progress.update(f + 1, nf - 1, "frame pairs")
    return {k: np.array(v).reshape(-1, 6) for k, v in rows.items()}


def report(rows: dict, parts: list[str]) -> None:
    """Print :func:`measure`'s rows, the two methods side by side per part and band."""
    print(
        f"{'part':8s} {'outline px':>10s} | "
        + " | ".join(f"{m:^36s}" for m in ("LK (Lucas–Kanade)", "LK + LSM (refined)"))
    )
    print(
        f"{'':8s} {'':>10s} | "
        + " | ".join(
            f"{'n':>5s} {'median':>7s} {'p90':>6s} {'along':>7s} {'move':>6s}" for _ in range(2)
        )
    )
    for part in parts:
        for lo, hi in BANDS:
            cells = []
            for m in ("LK", "LK + LSM"):
                r = rows[part, m]
                s = r[(r[:, 2] >= lo) & (r[:, 2] < hi)] if len(r) else r
                if not len(s):
                    cells.append(f"{0:5d} {'–':>7s} {'–':>6s} {'–':>7s} {'–':>6s}")
                    continue
                cells.append(
                    f"{len(s):5d} {np.median(s[:, 3]):7.2f} {np.percentile(s[:, 3], 90):6.2f} "
                    f"{s[:, 5].mean():+7.2f} {np.median(s[:, 4]):6.1f}"
                )
            band = f"{lo}–{hi}" if hi < 999 else f"≥ {lo}"
            print(f"{part:8s} {band:>10s} | " + " | ".join(cells))


def main(argv: list[str] | None = None) -> int:
    from core.errors import InputError
    from core.progress import Progress
    from core.scene import load_scene

    ap = argparse.ArgumentParser(
        prog="python -m bench.flow_truth", description=__doc__.split("\n")[0]
    )
    ap.add_argument("scene", help="a studio scene folder with truth.npz (vertices, faces, masks)")
    ap.add_argument("--parts", default="head,pelvis,chest,l_knee,r_wrist")
    ap.add_argument("--step", type=int, default=1, help="every K-th frame pair")
    a = ap.parse_args(argv)
    try:
        scene = load_scene(a.scene)
        truth = scene.truth
    except InputError as exc:
        print(exc, file=sys.stderr)
        return 2
    if "vertices" not in truth or "faces" not in truth:
        print(f"{scene.root / 'truth.npz'}: no mesh (vertices, faces)", file=sys.stderr)
        return 2
    parts = a.parts.split(",")
    names = list(truth["joint_names"])
    bad = [p for p in parts if p != "head" and p not in names]
    if bad:
        print(f"--parts: {bad} are not truth joints ({', '.join(names)})", file=sys.stderr)
        return 2
    rows = measure(scene, parts, a.step, progress=Progress())
    print(f"{scene.root.name}: corners followed one frame, against the true mesh's material points")
    report(rows, parts)
    return 0


if __name__ == "__main__":
    sys.exit(main())
