"""The compiled LSM steps (core.lsm_kernel*) against the numpy reference path."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from bench.patches import make_pairs
from core import image_stack, lsm_kernel, lsm_kernel_jit
from core.batched_linalg import spd_inverse
from core.lsm import Status, match
from core.lsm_design import normal_matrix, template_patches

needs_numba = pytest.mark.skipif(lsm_kernel.numba is None, reason="numba is not installed")


def _both(monkeypatch, T, S, uv_t, uv_s, **kw):
    """match() on the numpy path and on the compiled path, same inputs."""
    n = len(uv_t)
    kw = dict(template_index=np.arange(n) % len(T), search_index=np.arange(n) % len(S), **kw)
    monkeypatch.setenv(lsm_kernel.ENV_OFF, "1")
    ref = match(T, S, uv_t, uv_s, **kw)
    monkeypatch.setenv(lsm_kernel.ENV_OFF, "0")
    assert lsm_kernel.enabled()
    return ref, match(T, S, uv_t, uv_s, **kw)


def _assert_same(ref, got, tol_px=1e-5):
    """Same decisions; accepted positions within ``tol_px`` (measured: < 5e-7 px under
    numpy 1.26, ~1e-6 under numpy 2); the last estimates of rejected matches (e.g.
    drifting away) within 1e-3 px."""
    assert np.array_equal(ref.status, got.status)
    assert np.array_equal(ref.iterations, got.iterations)
    fin = np.isfinite(ref.sigma0)
    assert np.array_equal(fin, np.isfinite(got.sigma0))
    d = np.max(np.abs(ref.uv - got.uv), axis=1)
    assert np.max(d[ref.ok]) < tol_px
    assert np.max(d) < 1e-3
    assert np.max(np.abs(ref.affine - got.affine)) < 1e-5
    assert np.allclose(ref.gain, got.gain, rtol=1e-4)
    assert np.allclose(ref.sigma0[fin], got.sigma0[fin], rtol=1e-4)
    s_ref = ref.sigma_uv[fin]
    assert np.all(np.abs(got.sigma_uv[fin] - s_ref) <= 1e-3 * s_ref + 1e-9)
    assert np.allclose(ref.texture, got.texture, rtol=1e-5)


CASES = {
    "shift": ({}, {}),
    "gain and offset": ({"gain": 1.3, "offset": 20.0}, {}),
    "affine": ({"scale": (0.9, 1.1), "shear": 0.1}, {}),
    "weighted": ({"scale": (0.95, 1.05), "shear": 0.05}, {"weight_sigma": 2.5}),
    "bilinear": ({}, {"upsample": False}),
}


@needs_numba
@pytest.mark.parametrize("case", list(CASES))
def test_compiled_and_numpy_paths_agree(monkeypatch, case):
    pairs_kw, match_kw = CASES[case]
    P = make_pairs(150, seed=21, max_shift=1.0, noise=2.0, **pairs_kw)
    n = len(P.template)
    T = P.template.copy()
    T[0] = 90  # no texture
    uv_t = np.full((n, 2), P.centre)
    uv_s = uv_t.copy()
    uv_t[1] = [3.0, 3.0]  # template leaves its image
    uv_s[2] = np.nan  # no start
    uv_s[3] += [14.0, 0.0]  # search patch leaves the image
    uv_s[4] += [1.6, -1.2]  # far start: drifts or converges
    S = P.search.copy()
    S[5] = 115  # flat search image
    S[6, 18:23] = 250  # a saturated stripe through the patch
    ref, got = _both(monkeypatch, T, S, uv_t, uv_s, **match_kw)
    assert ref.status[0] == Status.WEAK_TEXTURE and ref.status[1] == Status.OUT_OF_IMAGE
    assert ref.status[2] == Status.INVALID and ref.status[3] == Status.OUT_OF_IMAGE
    assert ref.status[5] == Status.DEGENERATE
    assert ref.ok.mean() > 0.9
    _assert_same(ref, got)


@needs_numba
def test_a_rewindowed_and_drifting_start_agrees(monkeypatch):
    """Starts 1.5-2.5 px off walk out of their first search window (a second window
    round) or out of the search area; both paths take the same steps."""
    P = make_pairs(120, seed=22, max_shift=0.0, noise=2.0, fmax=0.12)
    n = len(P.template)
    rng = np.random.default_rng(5)
    off = rng.uniform(1.5, 2.5, (n, 2)) * rng.choice([-1, 1], (n, 2))
    c = np.full((n, 2), P.centre)
    rounds = []
    real = lsm_kernel.iterate_round

    def spy(*args):
        rounds.append(len(args[8]))  # the patches of the round
        real(*args)

    monkeypatch.setattr(lsm_kernel, "iterate_round", spy)
    ref, got = _both(monkeypatch, P.template, P.search, c, c + off, max_shift_px=3.0)
    assert len(rounds) >= 2 and rounds[0] == n  # some patches got a new window
    assert (ref.status == Status.OUT_OF_SEARCH).any() and ref.ok.any()
    _assert_same(ref, got)


@needs_numba
def test_float_images_and_threads_agree(monkeypatch):
    P = make_pairs(200, seed=23, max_shift=1.0, noise=2.0)
    n = len(P.template)
    c = np.full((n, 2), P.centre)
    ref, got = _both(
        monkeypatch, P.template.astype(np.float32), P.search.astype(np.float64), c, c, workers=3
    )
    _assert_same(ref, got)


@needs_numba
def test_line_constraint_runs_the_numpy_path(monkeypatch):
    P = make_pairs(40, seed=24, max_shift=1.0, noise=2.0)
    n = len(P.template)
    c = np.full((n, 2), P.centre)
    lines = (np.tile([0.0, 1.0], (n, 1)), P.uv_true[:, 1])

    def boom(*args):
        raise AssertionError("compiled iterations called with a line constraint")

    monkeypatch.setattr(lsm_kernel, "iterate_round", boom)
    ref, got = _both(monkeypatch, P.template, P.search, c, c, lines=lines)
    assert np.array_equal(ref.uv, got.uv) and np.array_equal(ref.status, got.status)


def test_without_numba_or_with_the_switch_the_numpy_path_runs(monkeypatch):
    P = make_pairs(30, seed=25, max_shift=1.0, noise=2.0)
    n = len(P.template)
    c = np.full((n, 2), P.centre)

    def boom(*args):
        raise AssertionError("compiled step called")

    for name in ("iterate_round", "normal_matrices", "spd_inverses", "upsampled_windows"):
        monkeypatch.setattr(lsm_kernel, name, boom)
    monkeypatch.setenv(lsm_kernel.ENV_OFF, "1")
    assert not lsm_kernel.enabled()
    r = match(P.template, P.search, c, c, template_index=np.arange(n), search_index=np.arange(n))
    assert r.ok.mean() > 0.9
    monkeypatch.setenv(lsm_kernel.ENV_OFF, "0")
    monkeypatch.setattr(lsm_kernel, "numba", None)  # as inside Blender
    assert not lsm_kernel.enabled()
    r2 = match(P.template, P.search, c, c, template_index=np.arange(n), search_index=np.arange(n))
    assert np.array_equal(r.uv, r2.uv)


@needs_numba
def test_normal_matrices_and_inverses_match_numpy(rng):
    n, half = 30, 6
    r = np.arange(-half, half + 1, dtype=np.float32)
    yg, xg = np.meshgrid(r, r, indexing="ij")
    xs, ys = xg.ravel(), yg.ravel()
    T = (100 + 25 * rng.normal(size=(n, xs.size))).astype(np.float32)
    gx, gy = (8 * rng.normal(size=(2, n, xs.size))).astype(np.float32)
    gx[1] = gy[1] = 0.0  # singular: no gradients
    w = np.exp(-(xs**2 + ys**2) / 18.0).astype(np.float32)
    N = lsm_kernel.normal_matrices(T, gx, gy, w, xs, ys)
    ref = normal_matrix(T, gx, gy, xs, ys, w)
    sc = np.sqrt(np.maximum(np.einsum("nii->ni", ref), 1e-9))
    assert np.max(np.abs(N - ref) / (sc[:, :, None] * sc[:, None, :])) < 1e-5
    use = np.ones(n, bool)
    use[2] = False
    N[3, 0, 0] = np.nan
    Ninv, pd = lsm_kernel.spd_inverses(N, use)
    N_ref = ref.copy()
    N_ref[3, 0, 0] = np.nan
    N_ref[2] = np.eye(8)
    inv_ref, pd_ref = spd_inverse(N_ref)
    assert np.array_equal(pd, pd_ref) and not pd[1] and not pd[3] and pd[2]
    assert np.array_equal(N[2], np.eye(8)) and np.array_equal(Ninv[2], np.eye(8))
    k = np.flatnonzero(pd)
    assert np.allclose(Ninv[k] @ N[k], np.eye(8), atol=1e-8)
    assert np.allclose(
        Ninv[k],
        inv_ref[k],
        rtol=1e-4,
        atol=1e-6 * np.abs(inv_ref[k]).max(axis=(1, 2), keepdims=True),
    )


@needs_numba
def test_upsampled_windows_match_numpy_also_at_the_border(rng):
    imgs = rng.integers(0, 256, (3, 30, 40)).astype(np.uint8)
    stack = image_stack.ImageStack(imgs)
    idx = np.array([0, 1, 2, 1])
    u0 = np.array([10, -4, 30, 5])  # 2nd and 3rd leave the image
    v0 = np.array([8, 12, -3, 20])
    wr = 5
    got = lsm_kernel.upsampled_windows(stack, idx, u0, v0, wr)
    m = image_stack._TAP_MARGIN
    win = image_stack._windows(stack, idx, u0 - m, v0 - m, 2 * (wr + m) + 1, transposed=True)
    ref = image_stack._upsample_windows(win, wr)
    assert got.shape == ref.shape == (4, 4 * wr + 1, 4 * wr + 1)
    assert np.max(np.abs(got - ref)) < 1e-3  # float32 sums, grey levels 0-255
    assert np.array_equal(got[0, ::2, ::2], imgs[0, 8 : 8 + 2 * wr + 1, 10 : 10 + 2 * wr + 1])


@needs_numba
def test_bilinear_is_cv2_remap_at_thirty_seconds(rng):
    from core.lsm_kernel_sample import _bilinear

    img = rng.uniform(0, 255, (12, 9)).astype(np.float32)
    pu = (np.round(rng.uniform(-2, 10, 200) * 32) / 32).astype(np.float32)
    pv = (np.round(rng.uniform(-2, 13, 200) * 32) / 32).astype(np.float32)
    ref = cv2.remap(img, pu[None], pv[None], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)[0]
    got = np.array([_bilinear(img, 0, img.shape[0], u, v) for u, v in zip(pu, pv, strict=True)])
    assert np.max(np.abs(got - ref)) < 1e-4


#: (du_x, du_y, dv_x, dv_y) in 1/32 px per grid offset, and the grid step: whole-pixel
#: steps (full and coarse grid, not upsampled, a mirrored u), and an affine warp.
WARPS = [(64, 0, 0, 64, 1), (64, 0, 0, 64, 2), (32, 0, 0, 32, 1), (-64, 0, 0, 96, 1)]
WARPS += [(67, -2, 1, 61, 1)]


@needs_numba
@pytest.mark.parametrize("warp", WARPS)
def test_grid_samples_are_the_bilinear_samples(rng, warp):
    """_sample_grid, with whole-pixel steps (one set of weights) or not, gives
    _bilinear's value at every point of the warped grid, bit for bit."""
    from core.lsm_kernel_sample import _bilinear, _sample_grid

    du_x, du_y, dv_x, dv_y, gs = warp
    img = rng.uniform(0, 255, (90, 70)).astype(np.float32)
    g0, gn, r0 = -6, 13 if gs == 1 else 7, 10
    iu0, iv0 = 35 * 32 + 5, 30 * 32 + 17
    S = np.empty(gn * gn, np.float32)
    _sample_grid(img, r0, iu0, iv0, du_x, du_y, dv_x, dv_y, g0, gs, gn, S)
    y, x = np.meshgrid(*2 * [g0 + gs * np.arange(gn)], indexing="ij")
    pu = (iu0 + du_x * x + du_y * y).ravel() / 32.0
    pv = (iv0 + dv_x * x + dv_y * y).ravel() / 32.0
    ref = [_bilinear(img, r0, img.shape[0] - r0, u, v) for u, v in zip(pu, pv, strict=True)]
    assert np.array_equal(S, np.array(ref, np.float32))


@needs_numba
@pytest.mark.parametrize("dtype", [np.uint8, np.float64])
def test_compiled_template_windows_are_the_numpy_ones(rng, dtype):
    imgs = (rng.uniform(0, 255, (3, 30, 40)) * (1.37 if dtype == np.float64 else 1)).astype(dtype)
    uv = np.array([[20.0, 15.0], [2.0, 3.0], [38.0, 28.0], [10.0, 25.0]])  # 2nd, 3rd: at borders
    idx = np.array([0, 1, 2, 1])
    ref = template_patches(imgs, uv, 6, idx, kernel=False)
    got = template_patches(imgs, uv, 6, idx, kernel=True)
    for a, b in zip(ref, got, strict=True):
        assert a.shape == b.shape == (4, 13, 13) and np.array_equal(a, b)


@needs_numba
def test_jit_falls_back_without_a_cache_location(monkeypatch):
    import numba

    real = numba.njit

    def njit(**kw):
        if kw.get("cache"):
            raise RuntimeError("cannot cache function: no locator available")
        return real(**kw)

    monkeypatch.setattr(numba, "njit", njit)

    @lsm_kernel_jit.jit()
    def twice(x):
        return 2.0 * x

    assert twice(1.5) == 3.0 and hasattr(twice, "py_func")


def test_switch_at_start_up_does_not_import_numba():
    """SOMACAP_NO_NUMBA=1 before the import: numba is never imported, match works."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    code = (
        "import sys, numpy as np; from bench.patches import make_pairs; "
        "from core.lsm import match; from core import lsm_kernel; "
        "P = make_pairs(20, seed=3); c = np.full((20, 2), P.centre); "
        "r = match(P.template, P.search, c, c, template_index=np.arange(20), "
        "search_index=np.arange(20)); "
        "print('numba' in sys.modules, lsm_kernel.enabled(), r.ok.mean())"
    )
    env = dict(os.environ, SOMACAP_NO_NUMBA="1")
    out = subprocess.run(
        [sys.executable, "-c", code],
        env=env,
        capture_output=True,
        text=True,
        check=True,
        cwd=Path(__file__).resolve().parents[2],
    ).stdout.split()
    assert out[:2] == ["False", "False"] and float(out[2]) > 0.9


@needs_numba
def test_a_failed_compilation_falls_back_to_numpy(monkeypatch):
    """A compiled step that cannot be compiled (e.g. a future numba): the call is
    redone on the numpy path and the kernel stays off, reporting why."""
    P = make_pairs(30, seed=26, max_shift=1.0, noise=2.0)
    n = len(P.template)
    c = np.full((n, 2), P.centre)
    kw = dict(template_index=np.arange(n), search_index=np.arange(n))
    monkeypatch.setenv(lsm_kernel.ENV_OFF, "1")
    ref = match(P.template, P.search, c, c, **kw)
    monkeypatch.setenv(lsm_kernel.ENV_OFF, "0")

    def untypable(*args):
        raise TypeError("cannot determine Numba type")

    monkeypatch.setattr(lsm_kernel, "_iterate_round", untypable)
    monkeypatch.setattr(lsm_kernel, "_COMPILED", {})
    monkeypatch.setitem(lsm_kernel._FAILED, "error", None)
    got = match(P.template, P.search, c, c, **kw)
    assert not lsm_kernel.enabled() and "iterate: TypeError" in lsm_kernel.failure()
    assert np.array_equal(got.uv, ref.uv) and np.array_equal(got.status, ref.status)
