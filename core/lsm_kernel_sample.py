"""Compiled (numba) sampling of :mod:`core.lsm_kernel`: cv2.remap's bilinear sampling at
1/32-px positions, cubic-spline 2× upsampled search windows (the values of
:func:`core.image_stack._upsample_windows`) and the template windows at integer
centres (those of :func:`core.lsm_design.template_patches`); per patch.

Same values as the loops they replaced, bit for bit: vectorised over samples or
pixels only where every value keeps its operations and their order.
"""

from __future__ import annotations

import numpy as np

from .lsm_kernel_jit import jit


@jit()
def _bilinear(img, r0, rows, pu, pv):
    """cv2.remap's INTER_LINEAR / BORDER_REPLICATE at (pu, pv) (multiples of 1/32) of
    rows ``r0 .. r0 + rows`` of ``img``: float32, the same weights and sum order."""
    iu = int(np.rint(pu * 32.0))
    iv = int(np.rint(pv * 32.0))
    x0 = iu >> 5
    y0 = iv >> 5
    fx = np.float32((iu & 31) * (1.0 / 32.0))
    fy = np.float32((iv & 31) * (1.0 / 32.0))
    w = img.shape[1]
    xa = min(max(x0, 0), w - 1)
    xb = min(max(x0 + 1, 0), w - 1)
    ya = r0 + min(max(y0, 0), rows - 1)
    yb = r0 + min(max(y0 + 1, 0), rows - 1)
    one = np.float32(1.0)
    w00 = (one - fy) * (one - fx)
    w01 = (one - fy) * fx
    w10 = fy * (one - fx)
    w11 = fy * fx
    return img[ya, xa] * w00 + img[ya, xb] * w01 + img[yb, xa] * w10 + img[yb, xb] * w11


#: Bilinear weights of the 32 sub-pixel positions of cv2.remap, float32.
_FRACTION = (np.arange(32) / 32.0).astype(np.float32)


@jit()
def _sample_grid(img, r0, iu0, iv0, du_x, du_y, dv_x, dv_y, g0, gs, gn, S):
    """:func:`_bilinear` at the warped square grid of one patch, all of whose
    neighbours lie inside the source (no clamping): S (gn², ) float32, row-major.

    The grid offsets are ``g0 + gs k`` (k < gn) in x and y; the warp in units of
    1/32 px of the source: ``32 (u, v) = (iu0, iv0) + (du_x, dv_x) x + (du_y, dv_y) y``
    (integers: the warp is snapped to 1/32 px).  An axis-parallel grid of whole-pixel
    steps goes to :func:`_sample_grid_whole`.  Flat indices are unsigned (no
    negative-index wraparound: they all lie inside ``img``).
    """
    if du_y == 0 and dv_x == 0 and du_x & 31 == 0 and dv_y & 31 == 0:
        _sample_grid_whole(img, r0, iu0, iv0, du_x, dv_y, g0, gs, gn, S)
        return
    one = np.float32(1.0)
    ncol = img.shape[1]
    flat = img.ravel()
    ucol = np.uint64(ncol)
    for ky in range(gn):
        y = g0 + gs * ky
        iu = iu0 + du_x * g0 + du_y * y
        iv = iv0 + dv_x * g0 + dv_y * y
        row = S[ky * gn : (ky + 1) * gn]
        for kx in range(gn):
            u = iu + du_x * gs * kx
            v = iv + dv_x * gs * kx
            p = np.uint64((r0 + (v >> 5)) * ncol + (u >> 5))
            fx = _FRACTION[u & 31]
            fy = _FRACTION[v & 31]
            row[kx] = (
                flat[p] * ((one - fy) * (one - fx))
                + flat[p + np.uint64(1)] * ((one - fy) * fx)
                + flat[p + ucol] * (fy * (one - fx))
                + flat[p + ucol + np.uint64(1)] * (fy * fx)
            )


@jit()
def _sample_grid_whole(img, r0, iu0, iv0, du_x, dv_y, g0, gs, gn, S):
    """:func:`_sample_grid` of an axis-parallel grid whose steps ``du_x``, ``dv_y`` are
    whole pixels (multiples of 32): one sub-pixel fraction, so the same four weights
    for all samples (the same values and sum order)."""
    one = np.float32(1.0)
    fx = _FRACTION[iu0 & 31]
    fy = _FRACTION[iv0 & 31]
    w00 = (one - fy) * (one - fx)
    w01 = (one - fy) * fx
    w10 = fy * (one - fx)
    w11 = fy * fx
    ncol = img.shape[1]
    flat = img.ravel()
    ucol = np.uint64(ncol)
    su = (du_x >> 5) * gs  # pixels per grid step
    col = (iu0 + du_x * g0) >> 5
    for ky in range(gn):
        start = (r0 + ((iv0 + dv_y * (g0 + gs * ky)) >> 5)) * ncol + col
        row = S[ky * gn : (ky + 1) * gn]
        for kx in range(gn):
            p = np.uint64(start + su * kx)
            q = p + np.uint64(1)
            row[kx] = flat[p] * w00 + flat[q] * w01 + flat[p + ucol] * w10 + flat[q + ucol] * w11


@jit()
def _fill_window(img, u, v, ws, W):
    """Pixels ``u .. u + ws - 1`` of rows ``v .. v + ws - 1`` of ``img`` (those outside
    repeat its border) into W (ws², ) float32, row-major."""
    h, w = img.shape
    inside = u >= 0 and u + ws <= w
    for i in range(ws):
        r = min(max(v + i, 0), h - 1)
        dst = W[i * ws : (i + 1) * ws]
        if inside:
            src = img[r, u : u + ws]
            for j in range(ws):
                dst[j] = src[j]
        else:
            for j in range(ws):
                dst[j] = img[r, min(max(u + j, 0), w - 1)]


@jit()
def _half_pixel12(src, off, stride, taps, dst, n):
    """``dst[p] = Σ_t taps[t] src[off + t stride + p]`` for p < n: the 12-tap half-pixel
    filter (taps (12,) float32), float32 sums over t in ascending order from 0.

    One flat loop over p (vectorised), each p a straight sum of the 12 terms; ``src``
    must hold ``off + 11 stride + n`` values.
    """
    c0, c1, c2, c3, c4, c5 = taps[0], taps[1], taps[2], taps[3], taps[4], taps[5]
    c6, c7, c8, c9, c10, c11 = taps[6], taps[7], taps[8], taps[9], taps[10], taps[11]
    s0 = src[off : off + n]
    s1 = src[off + stride : off + stride + n]
    s2 = src[off + 2 * stride : off + 2 * stride + n]
    s3 = src[off + 3 * stride : off + 3 * stride + n]
    s4 = src[off + 4 * stride : off + 4 * stride + n]
    s5 = src[off + 5 * stride : off + 5 * stride + n]
    s6 = src[off + 6 * stride : off + 6 * stride + n]
    s7 = src[off + 7 * stride : off + 7 * stride + n]
    s8 = src[off + 8 * stride : off + 8 * stride + n]
    s9 = src[off + 9 * stride : off + 9 * stride + n]
    s10 = src[off + 10 * stride : off + 10 * stride + n]
    s11 = src[off + 11 * stride : off + 11 * stride + n]
    d = dst[:n]
    for p in range(n):
        a = np.float32(0.0)
        a += c0 * s0[p]
        a += c1 * s1[p]
        a += c2 * s2[p]
        a += c3 * s3[p]
        a += c4 * s4[p]
        a += c5 * s5[p]
        a += c6 * s6[p]
        a += c7 * s7[p]
        a += c8 * s8[p]
        a += c9 * s9[p]
        a += c10 * s10[p]
        a += c11 * s11[p]
        d[p] = a


@jit()
def _upsampled_windows(images, index, u0, v0, wr, taps, out):
    """Cubic-spline 2× upsampled windows (:func:`core.image_stack._upsample_windows`):
    out[k] (4 wr + 1)² covers pixels ``u0[k] .. u0[k] + 2 wr`` (and v) of image
    ``index[k]`` (pixels outside repeat the border), ``out[k, 2i, 2j]`` the pixels.

    The 12 ``taps`` (float32) give the half-pixel values, first along v (the odd
    rows), then along u of the even and the odd rows; each filter pass is one flat
    loop over a window's rows (:func:`_half_pixel12`, which also fills the unused
    columns past each row's last half-pixel value).
    """
    m = taps.size // 2 - 1  # pixels beyond the window that taps read
    ws = 2 * (wr + m) + 1
    size = 4 * wr + 1
    W = np.empty(ws * ws, np.float32)  # the pixels, row-major
    X = np.zeros(2 * wr * ws + 2 * m + 1, np.float32)  # odd rows (half-pixel v), padded
    Ye = np.empty((2 * wr + 1) * ws, np.float32)  # half-pixel u of the even rows
    Yo = np.empty(2 * wr * ws, np.float32)  # ... of the odd rows
    for k in range(index.size):
        _fill_window(images[index[k]], u0[k] - m, v0[k] - m, ws, W)
        _half_pixel12(W, 0, ws, taps, X, 2 * wr * ws)
        _half_pixel12(W, m * ws, 1, taps, Ye, (2 * wr + 1) * ws)
        _half_pixel12(X, 0, 1, taps, Yo, 2 * wr * ws)
        for i in range(2 * wr + 1):
            o = out[k, 2 * i]
            e = W[(m + i) * ws + m : (m + i + 1) * ws]
            y = Ye[i * ws : (i + 1) * ws]
            for j in range(2 * wr):
                q = np.uint64(2 * j)
                o[q] = e[j]
                o[q + np.uint64(1)] = y[j]
            o[size - 1] = e[2 * wr]
        for i in range(2 * wr):
            o = out[k, 2 * i + 1]
            e = X[i * ws + m : (i + 1) * ws]
            y = Yo[i * ws : (i + 1) * ws]
            for j in range(2 * wr):
                q = np.uint64(2 * j)
                o[q] = e[j]
                o[q + np.uint64(1)] = y[j]
            o[size - 1] = e[2 * wr]


@jit()
def _template_lines(images, index, u0, v0, b, T, rows, cols):
    """Template windows of ``s = m + 2 b`` pixels from ``(u0[k], v0[k])`` of image
    ``index[k]`` (pixels outside repeat the border), float32: T[k] (m, m) the central
    pixels, ``rows[k m + i]`` (s,) window row ``b + i`` and ``cols[k m + j]`` (s,) its
    column ``b + j`` (i, j < m)."""
    m = T.shape[1]
    s = m + 2 * b
    P = np.empty(s * s, np.float32)
    for k in range(index.size):
        _fill_window(images[index[k]], u0[k], v0[k], s, P)
        for i in range(m):
            line = P[(b + i) * s : (b + i + 1) * s]
            row = rows[k * m + i]
            for j in range(s):
                row[j] = line[j]
            t = T[k, i]
            for j in range(m):
                t[j] = line[b + j]
            col = cols[k * m + i]
            for j in range(s):
                col[j] = P[j * s + b + i]
