"""Tracking a moving textured plane; trajectory filters on injected false trajectories."""

from __future__ import annotations

import numpy as np

from core.surface import measure_surface
from core.tracking import filter_trajectories, track
from tests.core._planescene import cameras, render


def test_moving_plane_is_tracked_and_a_missing_image_is_survived():
    cams = cameras()
    motion = np.array([0.004, 0.0, -0.003])          # metres per frame
    frames = [[render(c, offset=k * motion) for c in cams] for k in range(5)]
    frames[2][0] = None                              # cam01 lost its image in frame 2
    seeds = np.stack([c.project(np.array([[0.0, 0.0, 0.0]])) for c in cams], 1)
    surf = measure_surface(frames[0], cams, seeds, step=6)
    tr = track(lambda i: frames[i], cams, surf, 5, 25.0, regen_every=0)
    p0 = len(surf)
    through = tr.alive[:, :p0].all(axis=0)
    assert through.mean() > 0.8
    err = tr.xyz[-1, through] - (surf.xyz[through] + 4 * motion)
    assert np.median(np.linalg.norm(err, axis=1)) < 0.001
    assert np.all(np.isnan(tr.uv[2, :, 0]))          # nothing matched in the missing image
    v = tr.velocity()[2, through]
    assert np.allclose(np.median(v, axis=0), motion * 25.0, atol=0.01)


def test_filters_remove_false_trajectories(rng):
    F, P = 30, 400
    base = rng.uniform(-0.2, 0.2, (P, 3))
    t = np.arange(F)[:, None, None] / 25.0
    xyz = base[None] + t * np.array([1.0, 0.2, 0.0]) + rng.normal(0, 0.001, (F, P, 3))
    false = rng.choice(P, 20, replace=False)
    kind = np.arange(20) % 3
    for j, p in enumerate(false):
        k0 = rng.integers(3, F - 5)
        if kind[j] == 0:       # jump to a wrong match
            xyz[k0:, p] += rng.choice([-1, 1], 3) * 0.03
        elif kind[j] == 1:     # random-walk drift
            xyz[:, p] += np.cumsum(rng.normal(0, 0.01, (F, 3)), axis=0)
        else:                  # stuck in space
            xyz[k0:, p] = xyz[k0, p]
    res = filter_trajectories(xyz, 25.0, radius_m=0.08)
    hit = res.removed | res.truncated
    good = np.setdiff1d(np.arange(P), false)
    assert hit[false].mean() >= 0.95
    assert hit[good].mean() < 0.05
