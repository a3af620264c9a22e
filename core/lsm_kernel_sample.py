"""Compiled (numba) sampling of :mod:`core.lsm_kernel`: cv2.remap's bilinear sampling at
1/32-px positions, and cubic-spline 2× upsampled search windows (the values of
:func:`core.image_stack._upsample_windows`); per patch.
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


@jit()
def _sample_grid(img, r0, iu0, iv0, du_x, du_y, dv_x, dv_y, g0, gs, gn, S):
    """:func:`_bilinear` at the warped square grid of one patch, all of whose
    neighbours lie inside the source (no clamping): S (gn², ) float32, row-major.

    The grid offsets are ``g0 + gs k`` (k < gn) in x and y; the warp in units of
    1/32 px of the source: ``32 (u, v) = (iu0, iv0) + (du_x, dv_x) x + (du_y, dv_y) y``
    (integers: the warp is snapped to 1/32 px), stepped incrementally per pixel.
    """
    one = np.float32(1.0)
    wt = np.empty(32, np.float32)
    for q in range(32):
        wt[q] = np.float32(q / 32.0)
    ncol = img.shape[1]
    flat = img.ravel()
    sx_u = du_x * gs
    sx_v = dv_x * gs
    j = 0
    for ky in range(gn):
        y = g0 + gs * ky
        iu = iu0 + du_x * g0 + du_y * y
        iv = iv0 + dv_x * g0 + dv_y * y
        for _ in range(gn):
            base = (r0 + (iv >> 5)) * ncol + (iu >> 5)
            fx = wt[iu & 31]
            fy = wt[iv & 31]
            S[j] = (
                flat[base] * ((one - fy) * (one - fx))
                + flat[base + 1] * ((one - fy) * fx)
                + flat[base + ncol] * (fy * (one - fx))
                + flat[base + ncol + 1] * (fy * fx)
            )
            iu += sx_u
            iv += sx_v
            j += 1


@jit()
def _upsampled_windows(images, index, u0, v0, wr, taps, out):
    """Cubic-spline 2× upsampled windows (:func:`core.image_stack._upsample_windows`):
    out[k] (4 wr + 1)² covers pixels ``u0[k] .. u0[k] + 2 wr`` (and v) of image
    ``index[k]`` (pixels outside repeat the border), ``out[k, 2i, 2j]`` the pixels."""
    n = index.size
    _, h, w = images.shape
    nt = taps.size
    m = nt // 2 - 1  # pixels beyond the window that taps read
    ws = 2 * (wr + m) + 1
    size = 4 * wr + 1
    W = np.empty((ws, ws), np.float32)
    X = np.empty((size, ws), np.float32)
    Y = np.empty(2 * wr, np.float32)
    cols = np.empty(ws, np.int64)
    for k in range(n):
        img = images[index[k]]
        for j in range(ws):
            cols[j] = min(max(u0[k] - m + j, 0), w - 1)
        for i in range(ws):
            r = min(max(v0[k] - m + i, 0), h - 1)
            for j in range(ws):
                W[i, j] = img[r, cols[j]]
        # Along v: even rows the pixels, odd rows the half-pixel values.
        for i in range(2 * wr + 1):
            for j in range(ws):
                X[2 * i, j] = W[m + i, j]
        for i in range(2 * wr):
            for j in range(ws):
                X[2 * i + 1, j] = 0.0
            for t in range(nt):
                c = taps[t]
                for j in range(ws):
                    X[2 * i + 1, j] += c * W[i + t, j]
        # Along u, likewise.
        for i in range(size):
            for j in range(2 * wr):
                Y[j] = 0.0
            for t in range(nt):
                c = taps[t]
                for j in range(2 * wr):
                    Y[j] += c * X[i, j + t]
            for j in range(2 * wr):
                out[k, i, 2 * j] = X[i, m + j]
                out[k, i, 2 * j + 1] = Y[j]
            out[k, i, size - 1] = X[i, m + 2 * wr]
