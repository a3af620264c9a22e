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
    clicks = {"frame": 0, "joints": {"pelvis": {"a": [1, 2], "b": [3, 4]},
                                     "head": {"a": [5, 6]}}}
    s = seeds_from_clicks(clicks, ["a", "b"])
    assert s.shape == (1, 2, 2)
    with pytest.raises(InputError, match="two or more cameras"):
        seeds_from_clicks({"joints": {"head": {"a": [5, 6]}}}, ["a", "b"])
