"""Normalised cross-correlation search around predicted positions, batched.

For each of N points, the ``(2h+1)²`` template around ``uv_template`` is correlated
with every integer offset of a ``(2r+1)²`` search box around ``uv_predicted``; the
best offset is refined to sub-pixel by a parabola through its neighbours along u
and v.  The correlations of all points are computed at once, in one compiled loop or
by FFT convolution over the batch axis (:mod:`core.ncc_kernel`): no Python loop per
point.  This gives least squares matching (:mod:`core.lsm`) its start.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from .lsm import ImageStack
from .ncc_kernel import ncc_maps


class NCCStatus(IntEnum):
    """Per-point outcome of :func:`search`."""

    OK = 0
    LOW_SCORE = 1  #: best correlation below ``min_score``
    AT_BORDER = 2  #: the best offset lies on the border of the search box
    OUT_OF_IMAGE = 3  #: template or search box leaves its image
    FLAT = 4  #: template or search window without grey-level variation
    INVALID = 5  #: NaN input position


@dataclass
class NCCResult:
    """Result of :func:`search` for N points.

    Attributes
    ----------
    uv : ndarray, shape (N, 2)
        Best position in the search image, pixels (sub-pixel).
    score : ndarray, shape (N,)
        Correlation coefficient at the best integer offset, in [-1, 1].
    status : ndarray, shape (N,), int
        :class:`NCCStatus` codes; 0 = accepted.
    """

    uv: np.ndarray
    score: np.ndarray
    status: np.ndarray

    @property
    def ok(self) -> np.ndarray:
        return self.status == NCCStatus.OK


def search(
    template_images,
    search_images,
    uv_template,
    uv_predicted,
    *,
    half: int = 6,
    radius: int = 6,
    template_index=None,
    search_index=None,
    min_score: float = 0.5,
) -> NCCResult:
    """Best normalised cross-correlation in a box around predicted positions.

    Parameters
    ----------
    template_images, search_images : ndarray (H, W) or (M, H, W), or ImageStack
        Grey images; ``template_index`` / ``search_index`` (N,) pick one per point.
    uv_template : ndarray, shape (N, 2)
        Points in the template images, pixels.
    uv_predicted : ndarray, shape (N, 2)
        Predicted positions in the search images, pixels (centre of the box).
    half : int
        Template half width (13 × 13 for 6).
    radius : int
        Search box half width, pixels: offsets -radius..radius along u and v.
    min_score : float
        Lowest accepted correlation coefficient.

    Returns
    -------
    NCCResult
    """
    tstack, sstack = ImageStack(template_images), ImageStack(search_images)
    uv_t = np.asarray(uv_template, float).reshape(-1, 2)
    uv_p = np.asarray(uv_predicted, float).reshape(-1, 2)
    n = len(uv_t)
    if uv_p.shape != uv_t.shape:
        raise ValueError(f"uv_template {uv_t.shape} and uv_predicted {uv_p.shape} differ")
    ti = np.zeros(n, np.int64) if template_index is None else np.asarray(template_index, np.int64)
    si = np.zeros(n, np.int64) if search_index is None else np.asarray(search_index, np.int64)
    status = np.zeros(n, np.int8)
    finite = np.all(np.isfinite(uv_t), axis=1) & np.all(np.isfinite(uv_p), axis=1)
    status[~finite] = NCCStatus.INVALID
    ct = np.rint(np.where(finite[:, None], uv_t, 0.0))
    cs = np.rint(np.where(finite[:, None], uv_p, 0.0))
    ins = tstack.inside(ct[:, 0], ct[:, 1], half) & sstack.inside(cs[:, 0], cs[:, 1], half + radius)
    status[finite & ~ins] = NCCStatus.OUT_OF_IMAGE
    out_uv = np.full((n, 2), np.nan)
    score = np.full(n, np.nan)
    use = np.flatnonzero(status == 0)
    if use.size == 0:
        return NCCResult(out_uv, score, status)

    # Integer positions, inside the images (checked above): plain windows.
    ct_i = ct[use].astype(np.int64)
    cs_i = cs[use].astype(np.int64)
    T = tstack.windows(ti[use], ct_i[:, 0] - half, ct_i[:, 1] - half, 2 * half + 1).astype(
        np.float64
    )
    S = sstack.windows(
        si[use], cs_i[:, 0] - half - radius, cs_i[:, 1] - half - radius, 2 * (half + radius) + 1
    ).astype(np.float64)
    T0 = T - T.mean(axis=(1, 2), keepdims=True)
    tnorm = np.sqrt(np.sum(T0 * T0, axis=(1, 2)))
    ncc, textured = ncc_maps(S, T0, tnorm)  # (n, 2r+1, 2r+1)
    flat = (tnorm < 1e-6) | ~textured
    w = 2 * radius + 1
    best = np.argmax(ncc.reshape(len(use), -1), axis=1)
    iy, ix = np.divmod(best, w)
    rows = np.arange(len(use))
    sc = ncc[rows, iy, ix]
    border = (ix == 0) | (iy == 0) | (ix == w - 1) | (iy == w - 1)

    def parabola(cm, c0, cp):
        d = cm - 2 * c0 + cp
        with np.errstate(divide="ignore", invalid="ignore"):
            off = np.where(d < -1e-12, 0.5 * (cm - cp) / d, 0.0)
        return np.clip(off, -0.5, 0.5)

    ixc, iyc = np.clip(ix, 1, w - 2), np.clip(iy, 1, w - 2)
    fu = parabola(ncc[rows, iy, ixc - 1], ncc[rows, iy, ixc], ncc[rows, iy, ixc + 1])
    fv = parabola(ncc[rows, iyc - 1, ix], ncc[rows, iyc, ix], ncc[rows, iyc + 1, ix])
    fu = np.where(border, 0.0, fu)
    fv = np.where(border, 0.0, fv)
    frac = uv_t[use] - ct[use]
    out_uv[use, 0] = cs[use, 0] + (ix - radius) + fu + frac[:, 0]
    out_uv[use, 1] = cs[use, 1] + (iy - radius) + fv + frac[:, 1]
    score[use] = sc
    st = np.zeros(len(use), np.int8)
    st[sc < min_score] = NCCStatus.LOW_SCORE
    st[border] = NCCStatus.AT_BORDER
    st[flat] = NCCStatus.FLAT
    status[use] = st
    return NCCResult(out_uv, score, status)
