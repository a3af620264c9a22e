"""Synthetic textured patch pairs with exactly known warps (shared by benchmarks, tests).

The texture is a sum of random plane waves below the Nyquist frequency, evaluated
analytically, so a shift or affine warp is exact (the equivalent of a Fourier shift;
no interpolation error enters the truth, unlike ``cv2.warpAffine``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class PatchPairs:
    """N template / search image pairs.

    Attributes
    ----------
    template, search : ndarray, shape (N, S, S), uint8
        Template and search images (the pixel grid: row = v, column = u).
    centre : float
        Template point in the template image, both coordinates, pixels.
    uv_true : ndarray, shape (N, 2)
        The true position of the template point in the search image, pixels.
    affine : ndarray, shape (N, 2, 2)
        The true affine part (search offsets per template offset).
    """

    template: np.ndarray
    search: np.ndarray
    centre: float
    uv_true: np.ndarray
    affine: np.ndarray


def make_pairs(
    n: int,
    seed: int = 0,
    size: int = 41,
    max_shift: float = 1.5,
    scale=(1.0, 1.0),
    shear: float = 0.0,
    gain: float = 1.0,
    offset: float = 0.0,
    noise: float = 2.0,
    waves: int = 40,
    fmax: float = 0.25,
    mean: float = 100.0,
    std: float = 25.0,
) -> PatchPairs:
    """Make ``n`` textured image pairs related by a known warp plus noise.

    Search grey level at ``x'``: ``gain · f(A⁻¹ (x' - uv_true)) + offset + noise``,
    template: ``f(x - centre) + noise``; ``f`` has mean ``mean`` and std ``std`` grey
    levels (defaults leave room for a gain of 1.3 and offset of +20 below 255),
    frequencies up to ``fmax`` cycles per pixel.

    Parameters
    ----------
    scale : (float, float)
        Range of the two scale factors (uniform).
    shear : float
        Largest absolute value of the two shear terms.
    noise : float
        σ of the Gaussian noise added to both images, grey levels (before rounding).
    """
    rng = np.random.default_rng(seed)
    c = (size - 1) / 2.0
    # Random plane waves: frequency 0.03 .. 0.3 cycles/px, random direction and phase.
    fr = rng.uniform(0.03, fmax, (n, waves))
    ang = rng.uniform(0, np.pi, (n, waves))
    kx, ky = 2 * np.pi * fr * np.cos(ang), 2 * np.pi * fr * np.sin(ang)
    ph = rng.uniform(0, 2 * np.pi, (n, waves))
    amp = 1.0 / np.sqrt(fr / 0.1)
    amp *= std / np.sqrt(0.5 * np.sum(amp**2, axis=1, keepdims=True))
    shift = rng.uniform(-max_shift, max_shift, (n, 2))
    sx, sy = rng.uniform(*scale, (2, n))
    h1, h2 = rng.uniform(-shear, shear, (2, n))
    A = np.stack([np.stack([sx, h1], -1), np.stack([h2, sy], -1)], -2)
    Ainv = np.linalg.inv(A)
    uv_true = c + shift
    r = np.arange(size, dtype=float)
    yy, xx = np.meshgrid(r, r, indexing="ij")

    def texture(x, y):  # x, y: (n, S, S) offsets
        out = np.empty(x.shape)
        for i in range(0, n, 64):  # in chunks: (64, waves, S, S) at a time
            k = slice(i, i + 64)
            arg = (
                kx[k, :, None, None] * x[k, None]
                + ky[k, :, None, None] * y[k, None]
                + ph[k, :, None, None]
            )
            out[k] = mean + np.einsum("nw,nwij->nij", amp[k], np.cos(arg))
        return out

    x0 = np.broadcast_to(xx - c, (n, size, size))
    y0 = np.broadcast_to(yy - c, (n, size, size))
    tmpl = texture(x0, y0)
    dxs = xx[None] - uv_true[:, 0, None, None]
    dys = yy[None] - uv_true[:, 1, None, None]
    xt = Ainv[:, 0, 0, None, None] * dxs + Ainv[:, 0, 1, None, None] * dys
    yt = Ainv[:, 1, 0, None, None] * dxs + Ainv[:, 1, 1, None, None] * dys
    srch = gain * texture(xt, yt) + offset
    tmpl = tmpl + rng.normal(0, noise, tmpl.shape)
    srch = srch + rng.normal(0, noise, srch.shape)
    to8 = lambda a: np.clip(np.rint(a), 0, 255).astype(np.uint8)  # noqa: E731
    return PatchPairs(to8(tmpl), to8(srch), c, uv_true, A)
