"""Least squares matching on seeded synthetic patches with exactly known warps.

Every test runs twice: with the compiled steps of :mod:`core.lsm_kernel` (skipped
where numba is not installed) and on the numpy path (``SOMACAP_NO_NUMBA=1``).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from bench.patches import make_pairs
from core import lsm_kernel
from core.batched_linalg import cholesky_solve as _cholesky_solve
from core.camera import Camera
from core.lsm import Status, epipolar_lines, match, template_patches, upsample2
from core.lsm_design import (
    BORDER,
    normal_matrix,
    shift_moments,
    shift_moments_from_normal,
    solve_shift_radiometry,
    template_slopes,
)


@pytest.fixture(autouse=True, params=["numba", "numpy"])
def lsm_path(request, monkeypatch):
    """Run the test on the compiled path (numba) and on the numpy path."""
    if request.param == "numba" and lsm_kernel.numba is None:
        pytest.skip("numba is not installed")
    monkeypatch.setenv(lsm_kernel.ENV_OFF, "0" if request.param == "numba" else "1")
    assert lsm_kernel.enabled() == (request.param == "numba")
    return request.param


def _match(P, **kw):
    n = len(P.template)
    start = np.full((n, 2), P.centre)
    return match(
        P.template,
        P.search,
        start,
        start,
        template_index=np.arange(n),
        search_index=np.arange(n),
        **kw,
    )


def test_shift_precision_matches_predicted_sigma():
    P = make_pairs(300, seed=3, max_shift=1.0, noise=2.0)
    r = _match(P)
    assert r.ok.mean() > 0.98
    err = (r.uv - P.uv_true)[r.ok]
    rms = np.sqrt(np.mean(err**2))
    pred = np.sqrt(np.mean(r.sigma_uv[r.ok] ** 2))
    assert rms < 0.03
    assert 0.8 < rms / pred < 1.25
    assert np.all(r.iterations[r.ok] <= 10)
    # Spline slopes of the template: ~3 iterations (shift-only, full, check) from 1 px.
    assert r.iterations[r.ok].mean() < 3.6


def test_gain_and_offset_do_not_change_the_match():
    a = _match(make_pairs(200, seed=4, max_shift=1.0, noise=2.0))
    P = make_pairs(200, seed=4, max_shift=1.0, noise=2.0, gain=1.3, offset=20.0)
    b = _match(P)
    assert b.ok.mean() > 0.98
    assert np.sqrt(np.mean((b.uv - P.uv_true)[b.ok] ** 2)) < 0.03
    # The model is template = offset + gain * search: the inverse radiometry (to a few
    # per cent: noise and the smoothing of resampling bias the spread of S).
    assert abs(np.median(b.gain[b.ok]) - 1 / 1.3) < 0.03
    assert abs(np.median(b.offset[b.ok]) + 20 / 1.3) < 2.5
    assert abs(np.median(b.sigma_uv) - np.median(a.sigma_uv)) < 0.01


def test_affine_warp_recovered():
    P = make_pairs(200, seed=5, max_shift=1.0, noise=2.0, scale=(0.9, 1.1), shear=0.1)
    r = _match(P)
    assert r.ok.mean() > 0.98
    assert np.sqrt(np.mean((r.uv - P.uv_true)[r.ok] ** 2)) < 0.03
    assert np.max(np.abs(r.affine - P.affine)[r.ok]) < 0.05


def test_one_gauss_newton_step_is_quadratic():
    """The analytic normal equations: from a small offset, one step lands almost exactly."""
    P = make_pairs(50, seed=6, max_shift=0.0, noise=0.0, fmax=0.15)
    n = len(P.template)
    start = np.full((n, 2), P.centre) + np.array([0.05, -0.04])
    r = match(
        P.template,
        P.search,
        np.full((n, 2), P.centre),
        start,
        template_index=np.arange(n),
        search_index=np.arange(n),
        max_iter=2,
    )
    before = np.linalg.norm(start - P.uv_true, axis=1)
    after = np.linalg.norm(r.uv - P.uv_true, axis=1)
    assert np.median(after / before) < 0.1


def test_bilinear_without_upsampling_also_works():
    P = make_pairs(300, seed=7, max_shift=1.0, noise=2.0)
    r = _match(P, upsample=False)
    assert r.ok.mean() > 0.97
    rms = np.sqrt(np.mean((r.uv - P.uv_true)[r.ok] ** 2))
    assert rms < 0.035
    # The covariance allows for the noise that bilinear resampling averages away.
    assert 0.8 < rms / np.sqrt(np.mean(r.sigma_uv[r.ok] ** 2)) < 1.25


def test_template_slopes_are_the_cubic_spline_derivative():
    y, x = np.mgrid[0:21, 0:21].astype(float)
    ramp = 3.0 * x - 2.0 * y
    f = 0.2  # cycles / px: central differences lose 24 %
    wave = np.sin(2 * np.pi * f * x + 0.3)
    gu, gv = template_slopes(np.stack([ramp, wave]).astype(np.float32))
    assert np.allclose(gu[0], 3.0, atol=1e-4) and np.allclose(gv[0], -2.0, atol=1e-4)
    b = BORDER
    exact = 2 * np.pi * f * np.cos(2 * np.pi * f * x[b:-b, b:-b] + 0.3)
    assert np.max(np.abs(gu[1] - exact)) < 0.03 * 2 * np.pi * f
    assert np.allclose(gv[1], 0.0, atol=1e-5)


def test_rejections_are_flagged_per_patch():
    P = make_pairs(5, seed=8, max_shift=0.5)
    T = P.template.copy()
    T[1] = 100  # textureless template
    S = P.search.copy()
    S[4] = 115  # flat search image (e.g. a saturated background): gain undetermined
    start = np.full((5, 2), P.centre)
    start[2] = [2.0, 2.0]  # template leaves the image
    uv_s = np.full((5, 2), P.centre)
    uv_s[3] = np.nan  # no start
    r = match(T, S, start, uv_s, template_index=np.arange(5), search_index=np.arange(5))
    assert r.status[0] == Status.OK
    assert r.status[1] == Status.WEAK_TEXTURE
    assert r.status[2] == Status.OUT_OF_IMAGE
    assert r.status[3] == Status.INVALID
    assert r.status[4] == Status.DEGENERATE and r.iterations[4] == 1


def test_drift_out_of_search_area_is_flagged():
    P = make_pairs(50, seed=9, max_shift=0.0, noise=2.0)
    n = len(P.template)
    c = np.full((n, 2), P.centre)
    r = match(
        P.template,
        P.search,
        c,
        c + 1.5,
        template_index=np.arange(n),
        search_index=np.arange(n),
        max_shift_px=0.5,
    )
    assert np.all(r.status[~r.ok] == Status.OUT_OF_SEARCH)
    assert (r.status == Status.OUT_OF_SEARCH).mean() > 0.9


def test_search_leaving_the_image_is_flagged():
    P = make_pairs(3, seed=10, max_shift=0.0)
    c = np.full((3, 2), P.centre)
    r = match(
        P.template,
        P.search,
        c,
        c + np.array([13.0, 0.0]),
        template_index=np.arange(3),
        search_index=np.arange(3),
        max_shift_px=50,
    )
    assert np.all(r.status == Status.OUT_OF_IMAGE)


def test_cholesky_solve_matches_numpy(rng):
    J = rng.normal(size=(20, 30, 8))
    N = J.transpose(0, 2, 1) @ J
    B = rng.normal(size=(20, 8, 3))
    x, ok = _cholesky_solve(N, B)
    assert ok.all()
    assert np.allclose(x, np.linalg.solve(N, B))
    N[0] = 0.0
    assert not _cholesky_solve(N, B)[1][0]


def test_upsampling_is_exact_at_pixels_and_cubic_spline_between(rng):
    img = ndimage.gaussian_filter(rng.uniform(0, 255, (40, 50)), 1.5)
    up = upsample2(img)
    assert up.shape == (80, 100)
    assert np.allclose(up[::2, ::2], img, atol=1e-3)
    # Half-pixel values against scipy's cubic spline (away from the reflected border).
    v, u = np.mgrid[10:30, 10:40] + 0.5
    ref = ndimage.map_coordinates(img, [v.ravel(), u.ravel()], order=3, mode="mirror")
    assert np.max(np.abs(up[21:61:2, 21:81:2].ravel() - ref)) < 0.05


def test_template_near_the_border_is_centred_on_its_point(rng, lsm_path):
    """A template 8 px from the border (inside the matcher's 7 px margin, but its
    slope border of 4 px leaves the image): the patch is still centred on uv."""
    img = rng.uniform(0, 255, (40, 50)).astype(np.float32)
    T, gu, _ = template_patches(
        img, np.array([[8.0, 20.0], [25.0, 31.0]]), kernel=lsm_path == "numba"
    )
    assert np.array_equal(T[0], img[14:27, 2:15]) and np.array_equal(T[1], img[25:38, 19:32])
    # Slopes from the border pixels repeated beyond the image (row 31 + 4 > 39).
    ref = template_patches(np.pad(img, 10, mode="edge"), np.array([[35.0, 41.0]]))[1]
    assert np.allclose(gu[1], ref[0], atol=1e-4)


def test_subpixel_template_is_resampled(rng):
    img = ndimage.gaussian_filter(rng.uniform(0, 255, (40, 50)), 1.5)
    uv = np.array([[20.3, 18.8], [25.0, 21.45]])
    T = template_patches(img, uv)[0]
    y, x = np.mgrid[-6:7, -6:7]
    ref = [ndimage.map_coordinates(img, [p[1] + y.ravel(), p[0] + x.ravel()], order=3) for p in uv]
    # Bilinear between the 2x samples: a small symmetric smoothing (spread ~15 grey).
    assert np.max(np.abs(T.reshape(2, -1) - np.array(ref))) < 0.6
    assert np.median(np.abs(T.reshape(2, -1) - np.array(ref))) < 0.15


def _stereo_pair():
    K = [[400.0, 0, 160], [0, 400.0, 120], [0, 0, 1]]
    left = Camera("a", (320, 240), K, R=np.eye(3), t=[0.0, 0, 0])
    right = Camera("b", (320, 240), K, dist=[0.05, 0, 0, 0, 0], R=np.eye(3), t=[-0.2, 0, 0])
    return left, right


def test_epipolar_lines_contain_the_true_match(rng):
    left, right = _stereo_pair()
    xyz = np.column_stack(
        [rng.uniform(-0.3, 0.3, 20), rng.uniform(-0.2, 0.2, 20), rng.uniform(1.5, 3.0, 20)]
    )
    uv_l, uv_r = left.project(xyz), right.project(xyz)
    normal, d = epipolar_lines(left, right, uv_l, uv_r + 3.0)
    assert np.allclose(np.linalg.norm(normal, axis=1), 1.0)
    assert np.max(np.abs(np.einsum("ni,ni->n", normal, uv_r) - d)) < 0.05


def test_epipolar_constraint_pulls_the_match_onto_the_line():
    P = make_pairs(100, seed=11, max_shift=1.0, noise=2.0)
    n = len(P.template)
    c = np.full((n, 2), P.centre)
    normal = np.tile([0.0, 1.0], (n, 1))  # horizontal line v = true v + 0.3
    d = P.uv_true[:, 1] + 0.3
    r = match(
        P.template,
        P.search,
        c,
        c,
        template_index=np.arange(n),
        search_index=np.arange(n),
        lines=(normal, d),
        sigma_line_px=0.001,
    )
    free = _match(P)
    assert np.median(np.abs(r.uv[:, 1] - d)) < 0.01
    assert np.median(np.abs(free.uv[:, 1] - d)) > 0.25


def test_mismatched_inputs_raise():
    P = make_pairs(2, seed=12)
    with pytest.raises(ValueError, match="differ"):
        match(P.template, P.search, np.zeros((2, 2)), np.zeros((3, 2)))
    with pytest.raises(ValueError, match="outside the image stacks"):
        match(P.template, P.search, np.zeros((2, 2)), np.zeros((2, 2)), search_index=[0, 5])


def test_gaussian_weighting_keeps_predicted_sigma_consistent():
    P = make_pairs(400, seed=14, max_shift=1.0, noise=2.0, scale=(0.95, 1.05), shear=0.05)
    r = _match(P, weight_sigma=2.5)
    u = _match(P)
    assert r.ok.mean() > 0.98
    err = (r.uv - P.uv_true)[r.ok]
    rms = np.sqrt(np.mean(err**2))
    assert 0.8 < rms / np.sqrt(np.mean(r.sigma_uv[r.ok] ** 2)) < 1.25
    # Fewer effective pixels: larger predicted and real errors than the uniform patch.
    assert np.median(r.sigma_uv) > 1.1 * np.median(u.sigma_uv)
    assert abs(np.median(r.sigma0) - np.median(u.sigma0)) < 0.3


def test_normal_matrix_is_the_weighted_design_product(rng):
    n, half = 20, 6
    r = np.arange(-half, half + 1, dtype=np.float32)
    yg, xg = np.meshgrid(r, r, indexing="ij")
    xs, ys = xg.ravel(), yg.ravel()
    T = (100 + 25 * rng.normal(size=(n, xs.size))).astype(np.float32)
    gx, gy = (8 * rng.normal(size=(2, n, xs.size))).astype(np.float32)
    w = np.exp(-(xs**2 + ys**2) / 18.0).astype(np.float32)
    m = np.stack([np.ones_like(xs), xs, ys]).astype(float)
    J = np.concatenate(
        [gx[:, None] * m, gy[:, None] * m, np.ones((n, 1, xs.size)), T[:, None]], axis=1
    )  # (n, 8, P) float64
    exact = np.einsum("nip,p,njp->nij", J, w.astype(float), J)
    N = normal_matrix(T, gx, gy, xs, ys, w)
    scale = np.sqrt(np.einsum("nii->ni", exact))
    assert np.max(np.abs(N - exact) / (scale[:, :, None] * scale[:, None, :])) < 1e-5


def test_threads_split_the_patches_without_changing_the_matches():
    P = make_pairs(300, seed=15, max_shift=1.0, noise=2.0, scale=(0.95, 1.05), shear=0.05)
    one = _match(P, workers=1)
    three = _match(P, workers=3)
    assert np.array_equal(one.status, three.status)
    assert np.max(np.abs(one.uv - three.uv)) < 1e-6
    # float32 sums in other chunk sizes: equal to 1e-5 of each patch's σ_u σ_v (an
    # element-wise rtol fails on near-zero off-diagonals under numpy 2's BLAS)
    sd = np.sqrt(np.einsum("nii->ni", one.cov_uv))
    rel = np.abs(one.cov_uv - three.cov_uv) / (sd[:, :, None] * sd[:, None, :])
    assert np.max(rel) < 1e-5
    assert np.array_equal(one.iterations, three.iterations)


def test_shift_radiometry_solve_matches_the_normal_matrix_block(rng):
    """The first iteration's closed-form 4 × 4 solve against numpy on the same block."""
    n, half = 40, 6
    r = np.arange(-half, half + 1, dtype=np.float32)
    yg, xg = np.meshgrid(r, r, indexing="ij")
    T = (100 + 25 * rng.normal(size=(n, r.size**2))).astype(np.float32)
    gx, gy = (8 * rng.normal(size=(2, n, r.size**2))).astype(np.float32)
    w = np.ones(r.size**2, np.float32)
    N = normal_matrix(T, gx, gy, xg.ravel(), yg.ravel(), w)
    m = shift_moments(T, gx, gy, w)
    m_n = shift_moments_from_normal(N)
    assert np.max(np.abs(m - m_n) / np.abs(m_n).max(axis=0)) < 1e-5  # float32 sums
    b = rng.normal(size=(n, 4)) * 50
    sub = [0, 3, 6, 7]
    exact = np.linalg.solve(N[:, sub][:, :, sub], b[:, :, None])[:, :, 0]
    got = solve_shift_radiometry(shift_moments_from_normal(N), b)
    assert np.allclose(got, exact, rtol=1e-6, atol=1e-9 * np.abs(exact).max())
    m[0] = 0.0  # no texture, no grey-level spread
    assert np.all(np.isnan(solve_shift_radiometry(m, b)[0]))
