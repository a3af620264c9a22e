"""Patch sampling from image stacks: compact upsampled windows against the whole image."""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from core.image_stack import ImageStack, PatchSource, resampling_noise_factor


def _sample(src: PatchSource, uv: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Sample patch k at uv[k] + offsets (P, 2), pixels."""
    pu = (src.bu[:, None] + src.f * (uv[:, 0, None] + offsets[None, :, 0])).astype(np.float32)
    pv = (src.bv[:, None] + src.f * (uv[:, 1, None] + offsets[None, :, 1])).astype(np.float32)
    return src.sample(pu, pv)


def _images(rng, m=3, h=60, w=70):
    return np.stack([ndimage.gaussian_filter(rng.uniform(0, 255, (h, w)), 1.2) for _ in range(m)])


def test_windows_sample_like_the_whole_upsampled_image(rng):
    n = 300
    imgs = _images(rng, m=n, h=40, w=44)  # one image per patch (as in tracking)
    index = np.arange(n)
    # Centres anywhere, also within a few pixels of the image borders.
    # Positions on cv2.remap's 1/32 px grid (as LSM snaps them): exact in both paths.
    uv = np.rint(32 * np.column_stack([rng.uniform(0, 43, n), rng.uniform(0, 39, n)])) / 32
    offsets = np.rint(32 * rng.uniform(-5.0, 5.0, (30, 2))) / 32
    pos = uv[:, None, :] + offsets[None]
    keep = np.all((pos >= 0) & (pos <= [43, 39]), axis=(1, 2))
    uv, index, pos = uv[keep], index[keep], pos[keep]
    for upsample in (True, False):
        win = PatchSource(ImageStack(imgs), index, uv, 5.0, upsample)
        assert not win._whole  # compact windows: fewer samples
        stack = ImageStack(imgs)
        _ = stack.up, stack.mosaic  # cached: the whole image is sampled
        whole = PatchSource(stack, index, uv, 5.0, upsample)
        assert whole._whole
        a, b = _sample(win, uv, offsets), _sample(whole, uv, offsets)
        assert np.max(np.abs(a - b)) < 1e-3
        # The windows hold every sampled position.
        assert np.all(pos >= win.lo[:, None] - 1e-9)
        assert np.all(pos <= win.hi[:, None] + 1e-9)


def test_many_windows_are_split_into_remap_sized_chunks(rng):
    n = 2000  # more windows than one remap image holds
    imgs = _images(rng, m=n, h=30, w=30)
    uv = np.rint(32 * rng.uniform(10, 19, (n, 2))) / 32
    offsets = np.rint(32 * rng.uniform(-4.0, 4.0, (10, 2))) / 32
    win = PatchSource(ImageStack(imgs), np.arange(n), uv, 4.0, True)
    assert not win._whole and win.rows_per_chunk < n
    stack = ImageStack(imgs)
    _ = stack.up
    got = _sample(win, uv, offsets)
    assert (
        np.max(np.abs(got - _sample(PatchSource(stack, np.arange(n), uv, 4.0), uv, offsets))) < 1e-3
    )
    # A subset of rows (ascending, crossing chunks) samples the same values.
    rows = np.sort(rng.choice(n, 300, replace=False))
    pu = (win.bu[rows, None] + 2 * (uv[rows, 0, None] + offsets[None, :, 0])).astype(np.float32)
    pv = (win.bv[rows, None] + 2 * (uv[rows, 1, None] + offsets[None, :, 1])).astype(np.float32)
    assert np.allclose(win.sample(pu, pv, rows), got[rows])


def test_resampling_noise_factor_matches_monte_carlo(rng):
    """Resample white noise at fixed sub-pixel phases: the variance is the factor."""
    noise = rng.normal(0.0, 1.0, (400, 40, 40))
    stack = ImageStack(noise)
    uv = np.full((400, 2), 20.0)
    for phase in [(0.0, 0.0), (0.5, 0.0), (0.25, 0.75), (0.5, 0.5), (0.1, 0.3)]:
        p = uv + phase
        for upsample in (True, False):
            src = PatchSource(stack, np.arange(400), p, 2.0, upsample)
            vals = _sample(src, p, np.zeros((1, 2)))[:, 0]
            expected = resampling_noise_factor(p[0, 0], p[0, 1], upsample)
            assert abs(vals.var() / expected - 1.0) < 0.2, (phase, upsample)
    assert resampling_noise_factor(3.0, 7.0) == 1.0
    assert resampling_noise_factor(3.5, 7.0) < 0.8
