"""The compiled log field of :mod:`core.field_kernel` against its numpy reference."""

import numpy as np
import pytest

from core import field_kernel
from core.field_kernel import log_field, log_field_numpy


def _random_body(rng, H=4, M=9, N=50):
    q, _ = np.linalg.qr(rng.normal(size=(H * M, 3, 3)))
    Rw = q.reshape(H, M, 3, 3)
    cw = rng.normal(scale=0.2, size=(H, M, 3))
    radii = rng.uniform(0.03, 0.15, size=(M, 3))
    xyz = rng.normal(scale=0.3, size=(N, 3))
    return xyz, Rw, cw, radii


def test_compiled_matches_numpy():
    if not field_kernel.enabled():
        pytest.skip("numba not available: only the numpy path runs")
    xyz, Rw, cw, radii = _random_body(np.random.default_rng(3))
    L, g = log_field(xyz, Rw, cw, radii)
    L0, g0 = log_field_numpy(xyz, Rw, cw, radii)
    assert L.shape == (4, 50) and g.shape == (4, 50, 3)
    np.testing.assert_allclose(L, L0, rtol=1e-12, atol=1e-10)
    np.testing.assert_allclose(g, g0, rtol=1e-10, atol=1e-8)


def test_field_of_one_ball_and_its_gradient():
    """One sphere of radius r at c: L = −2|x−c|²/r², ∇L = −4(x−c)/r² (both paths)."""
    c = np.array([0.1, -0.2, 0.3])
    x = np.array([[0.2, -0.2, 0.3], [0.1, 0.0, 0.35]])
    Rw, cw, radii = np.eye(3)[None, None], c[None, None], np.full((1, 3), 0.1)
    for fn in (log_field, log_field_numpy):
        L, g = fn(x, Rw, cw, radii)
        np.testing.assert_allclose(L[0], -2 * np.sum((x - c) ** 2, 1) / 0.01)
        np.testing.assert_allclose(g[0], -4 * (x - c) / 0.01)


def test_gradient_matches_finite_differences():
    xyz, Rw, cw, radii = _random_body(np.random.default_rng(5), H=1, N=20)
    _, g = log_field(xyz, Rw, cw, radii)
    h = 1e-6
    for k in range(3):
        dx = np.zeros(3)
        dx[k] = h
        up, down = log_field(xyz + dx, Rw, cw, radii)[0], log_field(xyz - dx, Rw, cw, radii)[0]
        fd = (up - down) / (2 * h)
        np.testing.assert_allclose(g[..., k], fd, rtol=1e-5, atol=1e-4)


def test_numpy_path_when_switched_off(monkeypatch):
    monkeypatch.setenv("SOMACAP_NO_NUMBA", "1")
    assert not field_kernel.enabled()
    xyz, Rw, cw, radii = _random_body(np.random.default_rng(7), H=2, N=10)
    L, g = log_field(xyz, Rw, cw, radii)
    L0, g0 = log_field_numpy(xyz, Rw, cw, radii)
    np.testing.assert_array_equal(L, L0)
    np.testing.assert_array_equal(g, g0)


def test_inside_any_compiled_and_numpy_agree(monkeypatch):
    from core.model_contours import inside_any

    rng = np.random.default_rng(11)
    E, N = 12, 400
    axes, _ = np.linalg.qr(rng.normal(size=(E, 3, 3)))
    centers = rng.normal(scale=0.3, size=(E, 3))
    radii = rng.uniform(0.1, 0.3, size=(E, 3))
    xyz = rng.normal(scale=0.3, size=(N, 3))
    own = rng.integers(-1, E, size=N)
    # the truth, point by point
    u = np.einsum("eji,enj->eni", axes, xyz[None] - centers[:, None]) / radii[:, None]
    inside = np.sum(u**2, axis=-1) < 0.999**2
    inside[own[own >= 0], np.flatnonzero(own >= 0)] = False
    want = inside.any(axis=0)
    assert 0.1 < want.mean() < 0.9
    np.testing.assert_array_equal(inside_any(xyz, centers, axes, radii, exclude=own), want)
    monkeypatch.setenv("SOMACAP_NO_NUMBA", "1")
    np.testing.assert_array_equal(inside_any(xyz, centers, axes, radii, exclude=own), want)


def test_a_kernel_that_fails_switches_to_numpy(monkeypatch):
    """A compiled kernel that raises (a compile failing on this machine) turns the
    compiled paths off for the process; the call still answers, from numpy."""
    if not field_kernel.enabled():
        pytest.skip("numba not available: only the numpy path runs")
    monkeypatch.setitem(field_kernel._FAILED, "error", None)

    def broken(*args):
        raise RuntimeError("no compiler")

    monkeypatch.setattr(field_kernel, "_log_field_loops", broken)
    xyz, Rw, cw, radii = _random_body(np.random.default_rng(9), H=2, N=10)
    L, g = log_field(xyz, Rw, cw, radii)
    assert not field_kernel.enabled() and "no compiler" in field_kernel._FAILED["error"]
    L0, g0 = log_field_numpy(xyz, Rw, cw, radii)
    np.testing.assert_array_equal(L, L0)
    np.testing.assert_array_equal(g, g0)
