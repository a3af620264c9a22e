"""The silhouette search's image-ellipse kernels (:mod:`core.ellipse_kernel`): compiled
against numpy, bit for bit."""

import numpy as np
import pytest

from core import field_kernel
from core.ellipse_kernel import (
    background_area,
    background_area_numpy,
    covered,
    covered_numpy,
    image_covariances,
    image_covariances_numpy,
)


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


def test_covered_near_the_rim_of_thin_ellipses():
    """Pixels a hair inside and outside the rims of thin, tilted ellipses: the compiled
    path's bounding boxes change no answer."""
    if not field_kernel.enabled():
        pytest.skip("numba not available: only the numpy path runs")
    rng = np.random.default_rng(11)
    E = 40
    ang = rng.uniform(0, np.pi, E)
    axes = np.stack([np.cos(ang), np.sin(ang), -np.sin(ang), np.cos(ang)], 1).reshape(E, 2, 2)
    half = np.stack([rng.uniform(20, 60, E), rng.uniform(0.3, 3, E)], 1)  # px
    inv = np.einsum("eij,ej,ekj->eik", axes, half**-2.0, axes)
    mu = rng.uniform(100, 300, (E, 2))
    t = rng.uniform(0, 2 * np.pi, 2000)
    e = rng.integers(0, E, 2000)
    rim = np.stack([np.cos(t), np.sin(t)], 1) * half[e]
    scale = rng.choice([1 - 1e-9, 1 + 1e-9, 0.5, 2.0], 2000)[:, None]
    uv = mu[e] + np.einsum("gij,gj->gi", axes[e], rim * scale)
    for lead in ((), (3,)):
        m, s = np.broadcast_to(mu, lead + mu.shape), np.broadcast_to(inv, lead + inv.shape)
        np.testing.assert_array_equal(covered(uv, m, s), covered_numpy(uv, m, s))


def test_image_covariances_match_numpy_and_einsum():
    """The compiled image covariances, numpy's and the einsum they replaced: the same
    bits; the covariance is that of the projected ellipsoid (J C Jᵀ)."""
    rng = np.random.default_rng(4)
    M = 500
    q, _ = np.linalg.qr(rng.normal(size=(M, 3, 3)))
    radii = rng.uniform(0.02, 0.2, (M, 3))
    J = rng.normal(size=(M, 2, 3)) * 400.0
    got = image_covariances(q, radii, J)
    np.testing.assert_array_equal(got, image_covariances_numpy(q, radii**2, J))
    cov3 = np.einsum("mij,mj,mkj->mik", q, radii**2, q)
    np.testing.assert_array_equal(got, np.einsum("mai,mij,mbj->mab", J, cov3, J))
    C = q @ (radii[:, :, None] ** 2 * np.swapaxes(q, 1, 2))
    np.testing.assert_allclose(got, J @ C @ np.swapaxes(J, 1, 2), rtol=1e-10)


def test_background_area_matches_numpy():
    """Background covered by ellipses over a blob mask, partly outside the image:
    compiled = numpy to the bit; an ellipse deep inside the blob covers none, one far
    outside it covers its whole area (π / sqrt(det))."""
    rng = np.random.default_rng(8)
    mask = np.zeros((120, 160), bool)
    mask[30:90, 40:120] = True
    uv, mu, inv = _ellipses(rng, lead=(5,), E=12)
    mu = mu * 1.8 - 10  # some beyond the image's edges
    got = background_area(mask, mu, inv)
    np.testing.assert_array_equal(got, background_area_numpy(mask, mu, inv))
    assert got.shape == (5, 12) and (got[:, 0] == 0).all()  # the dead ellipses
    one = np.eye(2)[None] / 25.0  # a circle of radius 5 px
    area = background_area(mask, np.array([[80.0, 60.0], [10.0, 10.0]]), np.repeat(one, 2, 0))
    np.testing.assert_allclose(area, [0.0, np.pi * 25.0])
