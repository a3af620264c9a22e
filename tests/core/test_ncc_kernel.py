"""Correlation maps of the NCC search (:mod:`core.ncc_kernel`): compiled against FFT."""

import numpy as np
import pytest

from core import field_kernel
from core.ncc import search
from core.ncc_kernel import ncc_maps, ncc_maps_numpy


def _windows(rng, n=40, k=13, r=5):
    S = rng.uniform(0, 255, size=(n, k + 2 * r, k + 2 * r))
    T = rng.uniform(0, 255, size=(n, k, k))
    S[1] = 90.0  # a flat search window
    T[2] = 40.0  # a flat template
    if r >= 4:  # a template that sits at offset (row 2, column 7)
        T[3] = S[3, 2 : 2 + k, 7 : 7 + k]
    T0 = T - T.mean(axis=(1, 2), keepdims=True)
    return S, T0, np.sqrt(np.sum(T0 * T0, axis=(1, 2)))


@pytest.mark.parametrize("r", [0, 3, 16])
def test_compiled_matches_fft(r):
    if not field_kernel.enabled():
        pytest.skip("numba not available: only the numpy path runs")
    S, T0, tn = _windows(np.random.default_rng(r), r=r)
    got, got_tex = ncc_maps(S, T0, tn)
    ref, ref_tex = ncc_maps_numpy(S, T0, tn)
    assert got.shape == (40, 2 * r + 1, 2 * r + 1)
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(got_tex, ref_tex)
    assert not got_tex[1] and np.all(got[1] == -1.0) and np.all(got[2] == -1.0)
    assert np.all(np.abs(got[np.isfinite(got)]) <= 1 + 1e-12)


def test_exact_copy_scores_one_at_its_offset():
    S, T0, tn = _windows(np.random.default_rng(1), r=8)
    for fn in (ncc_maps, ncc_maps_numpy):
        ncc, _ = fn(S, T0, tn)
        assert np.unravel_index(np.argmax(ncc[3]), ncc[3].shape) == (2, 7)
        assert ncc[3, 2, 7] == pytest.approx(1.0, abs=1e-12)


def test_search_is_the_same_on_both_paths(monkeypatch):
    """The search's positions, scores and statuses do not depend on the path."""
    rng = np.random.default_rng(7)
    img = rng.uniform(0, 255, size=(120, 140))
    nxt = np.roll(img, (2, -3), axis=(0, 1))  # moved by (u -3, v +2) px
    uv = rng.uniform(30, 100, size=(50, 2))
    first = search(img, nxt, uv, uv, radius=6)
    monkeypatch.setenv("SOMACAP_NO_NUMBA", "1")
    second = search(img, nxt, uv, uv, radius=6)
    np.testing.assert_array_equal(first.status, second.status)
    np.testing.assert_allclose(first.uv, second.uv, atol=1e-9)
    np.testing.assert_allclose(first.score, second.score, atol=1e-9)
    assert first.ok.mean() > 0.9  # the parabola's sub-pixel step on white noise: < 0.1 px
    step = first.uv[first.ok] - uv[first.ok]
    np.testing.assert_allclose(step, np.broadcast_to([-3.0, 2.0], step.shape), atol=0.1)
