"""Dense surface measurement on an analytically rendered textured plane."""

from __future__ import annotations

import numpy as np
import pytest

from core.errors import InputError
from core.surface import measure_surface, seeds_from_clicks
from tests.core._planescene import cameras, render


def test_plane_is_measured_densely_and_precisely():
    cams = cameras()
    images = [render(c) for c in cams]
    seeds = np.stack([c.project(np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.1]])) for c in cams], 1)
    surf = measure_surface(images, cams, seeds, step=4)
    assert len(surf) > 600
    # All points on the plane y = 0, within the textured square.
    assert np.median(np.abs(surf.xyz[:, 1])) < 0.0005
    # (a patch half on the texture still matches: up to half a patch, ~2.4 cm, beyond)
    assert np.max(np.abs(surf.xyz[:, [0, 2]])) < 0.28
    assert np.all(surf.rms < 1.0)
    assert np.all(np.isfinite(surf.cov))


def test_seeds_from_clicks_and_bad_clicks():
    clicks = {"frame": 0, "joints": {"pelvis": {"a": [1, 2], "b": [3, 4]}, "head": {"a": [5, 6]}}}
    s = seeds_from_clicks(clicks, ["a", "b"])
    assert s.shape == (1, 2, 2)
    with pytest.raises(InputError, match="two or more cameras"):
        seeds_from_clicks({"joints": {"head": {"a": [5, 6]}}}, ["a", "b"])
    with pytest.raises(InputError, match="^take/clicks.json: no joint"):
        seeds_from_clicks({"joints": {"head": {"a": [5, 6]}}}, ["a", "b"], path="take/clicks.json")


def test_depth_outliers_and_sigma_limit_of_the_surface():
    cams = cameras()
    images = [render(c) for c in cams]
    seeds = np.stack([c.project(np.array([[0.0, 0.0, 0.0]])) for c in cams], 1)
    full = measure_surface(images, cams, seeds, step=6)
    # a plane has no depth outliers: the 1 cm test keeps (nearly) every point
    smooth = measure_surface(images, cams, seeds, step=6, max_depth_dev_m=0.01)
    assert len(smooth) >= 0.98 * len(full)
    assert np.isin(smooth.xyz[:, 0], full.xyz[:, 0]).all()
    # a σ limit below the matches' precision rejects them (the seed too: nothing grows)
    sig = np.nanmax(np.where(np.arange(3) != full.ref, full.sigma_uv, np.nan), axis=1)
    strict = measure_surface(images, cams, seeds, step=6, max_sigma_px=0.5 * float(np.min(sig)))
    assert len(strict) == 0
