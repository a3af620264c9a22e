"""A textured plane seen by three pinhole cameras, rendered analytically (test helper)."""

from __future__ import annotations

import numpy as np

from core.camera import Camera, rodrigues_to_matrix


def cameras() -> list[Camera]:
    K = [[500.0, 0, 160], [0, 500.0, 120], [0, 0, 1]]
    cams = []
    for j, x in enumerate((-0.4, 0.0, 0.4)):
        # Looking along +y (world) from y = -2, slightly converging on the origin.
        R0 = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])
        R = rodrigues_to_matrix([0, np.arctan2(x, 2.0), 0]) @ R0
        C = np.array([x, -2.0, 0.0])
        cams.append(Camera(f"cam{j + 1:02d}", (320, 240), K, R=R, t=-R @ C))
    return cams


def texture(s, t, seed=0):
    rng = np.random.default_rng(seed)
    f = rng.uniform(15, 60, 30)
    ang = rng.uniform(0, np.pi, 30)
    ph = rng.uniform(0, 2 * np.pi, 30)
    val = sum(
        np.cos(2 * np.pi * fk * (np.cos(a) * s + np.sin(a) * t) + p)
        for fk, a, p in zip(f, ang, ph, strict=True)
    )
    return 120 + 12 * val


def render(cam: Camera, offset=(0.0, 0.0, 0.0), half_size=0.25) -> np.ndarray:
    """Plane y = offset_y through x, z; texture moves with the plane's x, z offset."""
    w, h = cam.size
    u, v = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    o, d = cam.rays(np.stack([u, v], -1))
    lam = (offset[1] - o[1]) / d[..., 1]
    p = o + lam[..., None] * d
    s, t = p[..., 0] - offset[0], p[..., 2] - offset[2]
    img = np.full((h, w), 120.0)
    inside = (np.abs(s) < half_size) & (np.abs(t) < half_size)
    img[inside] = texture(s[inside], t[inside])
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)
