"""Seeds along the epipolar lines: surface beyond a depth jump that growth cannot reach."""

from __future__ import annotations

import numpy as np

from core.surface import measure_surface
from core.surface_seed import cloud_depth_range, epipolar_seeds, grow_from_jumps
from tests.core._planescene import cameras, texture


def _two_squares(cam):
    """A textured square at y = 0 (x, z in ±0.12 around x = -0.15) and another 0.3 m
    behind it (y = 0.3, around x = +0.2, a different texture), on a plain background."""
    w, h = cam.size
    u, v = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    o, d = cam.rays(np.stack([u, v], -1))
    img = np.full((h, w), 120.0)
    for y, x0, seed in ((0.3, 0.2, 1), (0.0, -0.15, 0)):  # back first: the front covers it
        p = o + ((y - o[1]) / d[..., 1])[..., None] * d
        s, t = p[..., 0] - x0, p[..., 2]
        inside = (np.abs(s) < 0.12) & (np.abs(t) < 0.12)
        img[inside] = texture(s[inside], t[inside], seed=seed)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def test_growth_stops_at_the_jump_and_the_epipolar_seeds_cross_it():
    cams = cameras()
    images = [_two_squares(c) for c in cams]
    front = np.array([[-0.15, 0.0, 0.0], [-0.1, 0.0, 0.05]])
    seeds = np.stack([c.project(front) for c in cams], 1)
    surf = measure_surface(images, cams, seeds, step=4)
    assert len(surf) > 200 and np.all(surf.xyz[:, 0] < 0.0)  # the front square only
    ref = surf.ref
    found = epipolar_seeds(
        images, cams, ref, cloud_depth_range(cams, ref, surf.xyz), surf.uv[:, ref]
    )
    assert len(found) >= 5
    # every seed is on the back square: back-projected at its depth, y = 0.3
    from core.intersect import triangulate

    xyz = triangulate(cams, found).xyz
    np.testing.assert_allclose(xyz[:, 1], 0.3, atol=0.02)  # depth steps of ~1 px
    assert np.all(xyz[:, 0] > 0.05)
    more = grow_from_jumps(images, cams, ref, surf.xyz, surf.uv[:, ref], step=4)
    assert len(more) > 200
    assert np.median(np.abs(more.xyz[:, 1] - 0.3)) < 0.001
    # nothing left to seed once both squares are measured
    occ = np.concatenate([surf.uv[:, ref], more.uv[:, ref]])
    assert grow_from_jumps(images, cams, ref, surf.xyz, occ, step=4) is None


def test_plain_images_give_no_seeds():
    cams = cameras()
    images = [np.full((240, 320), 120, np.uint8) for _ in cams]
    assert epipolar_seeds(images, cams, 1, (1.5, 2.5)).shape == (0, 3, 2)
    assert cloud_depth_range(cams, 1, np.full((3, 3), np.nan)) is None


def test_tracker_seeds_the_far_square_when_regenerating():
    from core.tracking import track

    cams = cameras()
    images = [_two_squares(c) for c in cams]
    front = np.array([[-0.15, 0.0, 0.0]])
    surf = measure_surface(images, cams, np.stack([c.project(front) for c in cams], 1), step=6)
    kw = dict(regen_every=2, step=6)
    plain = track(lambda i: images, cams, surf, 3, 25.0, jump_seeds=False, **kw)
    jumped = track(lambda i: images, cams, surf, 3, 25.0, **kw)  # jump_seeds: the default
    last = jumped.xyz[-1]
    back = np.isfinite(last[:, 1]) & (np.abs(last[:, 1] - 0.3) < 0.005)
    assert back.sum() > 50 and np.all(jumped.start[back] == 2)  # born when regenerating
    y = plain.xyz[-1, :, 1]
    assert not np.any(np.abs(y[np.isfinite(y)] - 0.3) < 0.05)  # growth alone never gets there
