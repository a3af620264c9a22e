"""Surface that the reference camera does not see, measured by the other cameras' pairs."""

from __future__ import annotations

import numpy as np

from core.surface import measure_surface
from core.surface_pairs import grow_pairs, widen
from core.surface_seed import grow_from_jumps
from tests.core._planescene import cameras, texture


def _squares(cam, back=True):
    """A textured square at y = 0 around x = -0.15 and, with ``back``, another 0.3 m
    behind it around x = +0.2 (another texture), on a plain background."""
    w, h = cam.size
    u, v = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    o, d = cam.rays(np.stack([u, v], -1))
    img = np.full((h, w), 120.0)
    for y, x0, seed in ((0.3, 0.2, 1), (0.0, -0.15, 0))[0 if back else 1 :]:
        p = o + ((y - o[1]) / d[..., 1])[..., None] * d
        s, t = p[..., 0] - x0, p[..., 2] - 0.0
        inside = (np.abs(s) < 0.12) & (np.abs(t) < 0.12)
        img[inside] = texture(s[inside], t[inside], seed=seed)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def _scene():
    """Three cameras; the middle one (the reference) sees the back square's place plain,
    as if a plain occluder stood before it."""
    cams = cameras()
    images = [_squares(c, back=j != 1) for j, c in enumerate(cams)]
    front = np.array([[-0.15, 0.0, 0.0], [-0.1, 0.0, 0.05]])
    surf = measure_surface(images, cams, np.stack([c.project(front) for c in cams], 1), step=4)
    return cams, images, surf


def test_the_outer_pair_measures_what_the_reference_camera_does_not_see():
    cams, images, surf = _scene()
    ref = surf.ref
    assert ref == 1 and len(surf) > 200 and np.all(surf.xyz[:, 0] < 0.0)
    # the reference camera's own search finds nothing behind the jump
    assert grow_from_jumps(images, cams, ref, surf.xyz, surf.uv[:, ref], step=4) is None
    occupied = [surf.uv[:, j] for j in range(3)]
    more = grow_pairs(images, cams, ref, surf.xyz, occupied, step=4)
    assert len(more) > 200 and more.ref == ref
    assert np.median(np.abs(more.xyz[:, 1] - 0.3)) < 0.001
    assert np.all(more.xyz[:, 0] > 0.05)  # the back square only
    assert np.all(np.isnan(more.uv[:, 1])) and np.all(np.isfinite(more.uv[:, [0, 2]]))
    np.testing.assert_array_equal(more.affine[:, 1], np.tile(np.eye(2), (len(more), 1, 1)))
    # nothing more once it is measured
    occupied = [np.concatenate([occupied[j], more.uv[:, j]]) for j in range(3)]
    assert len(grow_pairs(images, cams, ref, surf.xyz, occupied, step=4)) == 0


def test_widen_rebases_the_affine_parts_on_the_reference_camera(rng):
    cams, images, surf = _scene()
    sub = surf.__class__(
        xyz=surf.xyz,
        cov=surf.cov,
        uv=surf.uv[:, [0, 1]],
        affine=np.eye(2) + 0.1 * rng.standard_normal((len(surf), 2, 2, 2)),
        sigma_uv=surf.sigma_uv[:, [0, 1]],
        rms=surf.rms,
        ref=0,
    )
    sub.affine[:, 0] = np.eye(2)
    wide = widen(sub, [0, 1], 3, ref=1)
    assert wide.ref == 1 and np.all(np.isnan(wide.uv[:, 2]))
    np.testing.assert_allclose(wide.affine[:, 1], np.tile(np.eye(2), (len(surf), 1, 1)), atol=1e-12)
    # reference -> camera 0 is the inverse of camera 0 -> reference
    eye = np.tile(np.eye(2), (len(surf), 1, 1))
    np.testing.assert_allclose(wide.affine[:, 0] @ sub.affine[:, 1], eye, atol=1e-12)
    np.testing.assert_array_equal(wide.uv[:, :2], sub.uv)


def test_the_tracker_seeds_the_hidden_square_from_the_pair_when_regenerating():
    from core.tracking import track

    cams, images, surf = _scene()
    kw = dict(regen_every=2, step=6)
    plain = track(lambda i: images, cams, surf, 3, 25.0, pair_seeds=False, **kw)
    paired = track(lambda i: images, cams, surf, 3, 25.0, pair_seeds=True, **kw)
    last = paired.xyz[-1]
    back = np.isfinite(last[:, 1]) & (np.abs(last[:, 1] - 0.3) < 0.005)
    assert back.sum() > 50 and np.all(paired.start[back] == 2)  # born when regenerating
    y = plain.xyz[-1, :, 1]
    assert not np.any(np.abs(y[np.isfinite(y)] - 0.3) < 0.05)
