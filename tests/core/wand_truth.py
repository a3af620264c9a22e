"""Seeded synthetic wand captures for the calibration tests (cameras + bar positions)."""

from __future__ import annotations

import numpy as np

from core.calibrate import similarity  # noqa: F401  (re-exported for the tests)
from core.camera import Camera


def look_at(name, center, target, size=(512, 384), f=560.0, aspect=1.0, dist=None):
    """A camera at ``center`` looking at ``target`` (world Z up), OpenCV frame."""
    center = np.asarray(center, dtype=float)
    z = np.asarray(target, dtype=float) - center
    z = z / np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    K = np.array(
        [[f, 0, size[0] / 2 - 0.5 + 3.0], [0, f / aspect, size[1] / 2 - 0.5 - 2.0], [0, 0, 1]]
    )
    return Camera(name, size, K, dist if dist is not None else np.zeros(5), R, -R @ center)


def rig(kind="line3", aspect=1.0, f=560.0):
    """Cameras of a small studio: ``line3`` (left, centre, right) or ``ring4``; focal
    length ``f`` px (a longer one leaves more of the wand volume outside some images)."""
    target = np.array([0.0, 0.0, 1.0])
    h = 384 if aspect == 1.0 else 192
    if kind == "line3":
        centers = [(-2.0, -4.0, 1.4), (0.0, -4.5, 1.2), (2.2, -3.8, 1.6)]
    else:
        centers = [(0.0, -4.5, 1.5), (4.2, 0.3, 1.3), (0.2, 4.4, 1.7), (-4.3, -0.2, 1.4)]
    dists = [np.array([-0.08, 0.02, 0.0, 0.0, 0.0]), np.zeros(5)]
    return [
        look_at(f"cam{i + 1:02d}", c, target, size=(512, h), f=f, aspect=aspect, dist=dists[i % 2])
        for i, c in enumerate(centers)
    ]


def wand_capture(
    cams,
    n=120,
    length=0.5,
    noise_px=0.05,
    outlier_frac=0.0,
    seed=0,
    half_width=0.8,
    hidden_frac=0.0,
):
    """Wand locations and their image points (bar centres uniform in a box of
    ``±half_width`` m in x and y, 0.4–1.8 m high; a wider box leaves more targets
    outside some cameras' images).  ``hidden_frac`` of the locations are hidden from
    one random camera (occluded), so that their targets are seen in one camera fewer.

    Returns ``xyz`` (n, 2, 3) true targets, ``uv`` (n, C, 2, 2) noisy image points with
    NaN outside the image, and ``bad`` (n, C, 2) where a detection was replaced by a
    wrong blob (a random point of the image).
    """
    rng = np.random.default_rng(seed)
    mid = rng.uniform([-half_width, -half_width, 0.4], [half_width, half_width, 1.8], size=(n, 3))
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    xyz = np.stack([mid - d * length / 2, mid + d * length / 2], axis=1)
    uv = np.stack([c.project(xyz) for c in cams], axis=1)  # (n, C, 2, 2)
    uv = uv + rng.normal(scale=noise_px, size=uv.shape)
    for j, c in enumerate(cams):
        w, h = c.size
        out = (
            (uv[:, j, :, 0] < 0)
            | (uv[:, j, :, 0] > w - 1)
            | (uv[:, j, :, 1] < 0)
            | (uv[:, j, :, 1] > h - 1)
        )
        uv[:, j][out] = np.nan
    hide = np.flatnonzero(rng.random(n) < hidden_frac)
    uv[hide, rng.integers(0, len(cams), hide.size)] = np.nan
    bad = np.zeros(uv.shape[:3], dtype=bool)
    if outlier_frac > 0:
        seen = np.all(np.isfinite(uv), axis=-1)
        idx = np.argwhere(seen)
        pick = idx[rng.choice(len(idx), int(round(outlier_frac * len(idx))), replace=False)]
        for f, j, k in pick:  # test fixture, a few dozen entries
            w, h = cams[j].size
            uv[f, j, k] = rng.uniform([0, 0], [w - 1, h - 1])
            bad[f, j, k] = True
    return xyz, uv, bad
