"""Depth outliers against the neighbours' median (core.track_smooth)."""

import numpy as np

from core.track_smooth import depth_deviation, depth_outliers


def test_points_off_a_curved_surface_in_depth_are_flagged(rng):
    # a cylinder of radius 15 cm (a trunk) seen from 7 m along -x, points 1 cm apart
    a, z = np.meshgrid(np.linspace(-1.2, 1.2, 36), np.arange(0.0, 0.4, 0.01))
    xyz = np.stack([0.15 * np.cos(a.ravel()), 0.15 * np.sin(a.ravel()), z.ravel()], axis=1)
    xyz += rng.normal(0, 0.001, xyz.shape)
    view = np.array([7.0, 0.0, 0.2])
    # isolated errors where the skin faces the cameras (at grazing views a depth error
    # runs along the surface and is no outlier)
    facing = np.flatnonzero((np.abs(a.ravel()) < 0.6) & (z.ravel() % 0.04 < 0.005))
    bad = rng.choice(facing[::2], 40, replace=False)
    ray = xyz[bad] - view
    ray /= np.linalg.norm(ray, axis=1, keepdims=True)
    xyz[bad] += ray * rng.choice([-1, 1], (40, 1)) * rng.uniform(0.02, 0.04, (40, 1))
    xyz[5] = np.nan
    out = depth_outliers(xyz, view, 0.01)
    assert out[bad].all()
    good = np.setdiff1d(np.arange(len(xyz)), bad)
    assert out[good].mean() < 0.01
    assert not out[5]


def test_small_clouds_are_not_tested():
    xyz = np.array([[0.0, 0, 0], [0, 0.01, 0], [0, 0, 0.5]])
    assert not depth_outliers(xyz, np.array([5.0, 0, 0]), 0.01).any()


def test_depth_deviation_is_signed_along_the_ray(rng):
    s = np.arange(-0.1, 0.1001, 0.01)
    x, z = np.meshgrid(s, s)
    ref = np.stack([x.ravel(), np.zeros(x.size), z.ravel()], axis=1)  # plane y = 0
    view = np.array([0.0, -3.0, 0.0])
    q = ref[[50, 200]].copy()
    ray = (q - view) / np.linalg.norm(q - view, axis=1, keepdims=True)
    q += ray * np.array([[0.02], [-0.015]])  # 2 cm behind, 1.5 in front
    dev = depth_deviation(np.vstack([q, [[np.nan] * 3]]), view, ref)
    assert np.allclose(dev[:2], [0.02, -0.015], atol=1e-3)
    assert np.isnan(dev[2])
