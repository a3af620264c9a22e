"""Pixels inside image ellipses (:mod:`core.ellipse_kernel`): compiled against numpy."""

import numpy as np
import pytest

from core import field_kernel
from core.ellipse_kernel import covered, covered_numpy


def _ellipses(rng, lead=(6,), E=9, G=400):
    uv = rng.uniform(0, 100, size=(G, 2))
    mu = rng.uniform(0, 100, size=lead + (E, 2))
    A = rng.normal(size=lead + (E, 2, 2))
    inv = (A @ np.swapaxes(A, -1, -2) + 0.1 * np.eye(2)) * rng.uniform(2e-3, 2e-2, lead + (E, 1, 1))
    inv[..., 0, :, :] = 0.0  # an ellipsoid behind the camera: covers nothing
    return uv, mu, inv


def test_compiled_matches_numpy_bit_for_bit():
    if not field_kernel.enabled():
        pytest.skip("numba not available: only the numpy path runs")
    uv, mu, inv = _ellipses(np.random.default_rng(3))
    got = covered(uv, mu, inv)
    ref = covered_numpy(uv, mu, inv)
    assert got.shape == (6, 400) and 0.05 < ref.mean() < 0.95  # some in, some out
    np.testing.assert_array_equal(got, ref)


def test_circle_boundary_and_dead_ellipse():
    """A circle of radius 10 px at (50, 50): inside up to its rim; a zero shape covers
    nothing even where its centre lies (both paths, with and without leading axes)."""
    uv = np.array([[50.0, 50.0], [60.0, 50.0], [50.0, 60.1], [80.0, 80.0], [80.0, 81.0]])
    mu = np.array([[50.0, 50.0], [80.0, 80.0]])
    inv = np.stack([np.eye(2) / 100.0, np.zeros((2, 2))])
    for fn in (covered, covered_numpy):
        np.testing.assert_array_equal(fn(uv, mu, inv), [True, True, False, False, False])
        lead = fn(uv, mu[None, None], inv[None, None])
        np.testing.assert_array_equal(lead[0, 0], fn(uv, mu, inv))


def test_empty_inputs():
    assert covered(np.zeros((5, 2)), np.zeros((3, 0, 2)), np.zeros((3, 0, 2, 2))).shape == (3, 5)
    assert not covered(np.zeros((5, 2)), np.zeros((3, 0, 2)), np.zeros((3, 0, 2, 2))).any()
    assert covered(np.zeros((0, 2)), np.zeros((4, 2)), np.zeros((4, 2, 2))).shape == (0,)


def test_numpy_path_when_switched_off(monkeypatch):
    monkeypatch.setenv("SOMACAP_NO_NUMBA", "1")
    assert not field_kernel.enabled()
    uv, mu, inv = _ellipses(np.random.default_rng(5), lead=(2, 3), G=50)
    np.testing.assert_array_equal(covered(uv, mu, inv), covered_numpy(uv, mu, inv))
