"""Images as one mosaic for batched sub-pixel sampling (used by LSM, NCC, tracking).

:class:`ImageStack` tiles any number of grey images into one float32 mosaic with a
border gap, so that patches from many images are sampled by one ``cv2.remap`` call;
:func:`upsample2` doubles an image's resolution by cubic B-spline interpolation (a
symmetric 12-tap half-pixel filter: no phase error); :class:`PatchSource` samples N
patches bilinearly from the 2× upsampled mosaic, or from a stack of upsampled windows
around the patches when that is smaller.  Pixel coordinates as in :mod:`core.camera`.
"""

from __future__ import annotations

import functools
import threading

import cv2
import numpy as np


def _cardinal_spline_taps(n: int = 6) -> np.ndarray:
    """Weights of pixels ``j-n+1 .. j+n`` for the cubic-spline value at ``j + 0.5``.

    The cardinal cubic B-spline ``η(s) = Σ_k (√3 - 2)^|k| √3 β³(s - k)`` (its
    prefilter pole is ``√3 - 2``), sampled at half-pixel offsets; normalised to sum 1.
    """
    z = np.sqrt(3.0) - 2.0
    k = np.arange(-40, 41)
    d = np.arange(-n + 1, n + 1)
    s = 0.5 - d[:, None] - k[None, :]
    a = np.abs(s)
    beta = np.where(a < 1, 2 / 3 - a**2 + a**3 / 2, np.where(a < 2, (2 - a) ** 3 / 6, 0.0))
    w = (np.sqrt(3.0) * z ** np.abs(k) * beta).sum(axis=1)
    return w / w.sum()


_HALF_TAPS = _cardinal_spline_taps(6).astype(np.float32)


def upsample2(img: np.ndarray) -> np.ndarray:
    """Cubic-spline 2× upsampling: (H, W) -> (2H, 2W) float32, ``out[2i, 2j] = img[i, j]``.

    Odd rows / columns are the half-pixel values of the cubic spline interpolant
    (12-tap symmetric FIR, borders reflected; within 0.2 % of the spread of grey
    levels of the exact spline values on smooth texture), so a position ``(u, v)`` of the input
    is ``(2u, 2v)`` of the output.
    """
    img = np.ascontiguousarray(img, dtype=np.float32)
    h, w = img.shape
    n = len(_HALF_TAPS) // 2
    hx = cv2.filter2D(
        img, -1, _HALF_TAPS[None, :], anchor=(n - 1, 0), borderType=cv2.BORDER_REFLECT_101
    )
    even = cv2.merge([img, hx]).reshape(h, 2 * w)  # columns interleaved
    odd = cv2.filter2D(
        even, -1, _HALF_TAPS[:, None], anchor=(0, n - 1), borderType=cv2.BORDER_REFLECT_101
    )
    out = np.empty((h, 2, 2 * w), np.float32)
    out[:, 0] = even
    out[:, 1] = odd
    return out.reshape(2 * h, 2 * w)


def _tile(arr: np.ndarray, gap: int, narrow: bool = False):
    """Tile (M, H, W) images into one mosaic, ``gap`` px of edge replication between.

    The mosaic stays below 30000 rows and columns (15000 with ``narrow``, whose 2×
    upsampled copy must stay below cv2.remap's 32767).

    Returns the mosaic (float32) and the column / row of each image's pixel (0, 0).
    """
    m, h, w = arr.shape
    g = gap
    if narrow:
        # As few columns as the row limit allows: each tile is then (almost) one
        # contiguous block of memory, which keeps sampling cache friendly.
        cols = int(np.ceil(m / max(1, 15000 // (h + 2 * g))))
    else:
        cols = max(1, min(m, int(np.ceil(np.sqrt(m * (h + 2 * g) / (w + 2 * g))))))
    cols = min(cols, max(1, 30000 // (w + 2 * g)))
    rows = int(np.ceil(m / cols))
    if rows * (h + 2 * g) > 30000:
        raise ValueError(f"image stack {arr.shape} too large for one mosaic")
    tiles = np.zeros((rows * cols, h + 2 * g, w + 2 * g), np.float32)
    if g:
        tiles[:m] = np.pad(np.asarray(arr, np.float32), ((0, 0), (g, g), (g, g)), mode="edge")
    else:
        tiles[:m] = arr
    mosaic = (
        tiles.reshape(rows, cols, h + 2 * g, w + 2 * g)
        .transpose(0, 2, 1, 3)
        .reshape(rows * (h + 2 * g), cols * (w + 2 * g))
    )
    k = np.arange(m)
    return np.ascontiguousarray(mosaic), (k % cols) * (w + 2 * g) + g, (k // cols) * (h + 2 * g) + g


class ImageStack:
    """One or more grey images of equal size, tiled into one mosaic for batched sampling.

    Images are separated by replicated borders (``GAP`` px), so filters and bilinear
    sampling near an image border behave as if the border pixels continued.  The 2×
    cubic-spline upsampled mosaic (:func:`upsample2`) is computed on first use and
    kept, so several :func:`match` calls on one stack share it.

    Parameters
    ----------
    images : ndarray (H, W) or (M, H, W), a sequence of (H, W) arrays, or ImageStack
        Grey levels (any real dtype).
    """

    GAP = 8

    def __init__(self, images):
        if isinstance(images, ImageStack):
            self.__dict__ = images.__dict__  # share the cached mosaics
            return
        arr = images if not isinstance(images, list | tuple) else np.stack(images)
        arr = np.asarray(arr)
        if arr.ndim == 2:
            arr = arr[None]
        if arr.ndim != 3 or arr.shape[0] == 0:
            raise ValueError(f"images must be (H, W) or (M, H, W), got shape {arr.shape}")
        self.shape = arr.shape
        self.images = arr
        self._mosaic = None
        self._up = None
        self._lock = threading.RLock()  # threads sharing the stack build it once

    def _build(self):
        mosaic, self.origin_u, self.origin_v = _tile(self.images, self.GAP)
        self._mosaic = mosaic

    @property
    def mosaic(self) -> np.ndarray:
        """All images tiled into one float32 mosaic (``origin_u``, ``origin_v`` per image)."""
        if self._mosaic is None:
            with self._lock:
                if self._mosaic is None:
                    self._build()
        return self._mosaic

    @property
    def up(self) -> np.ndarray:
        """The mosaic upsampled 2× (:func:`upsample2`), float32."""
        if self._up is None:
            with self._lock:
                if self._up is None:
                    self._up = upsample2(self.mosaic)
        return self._up

    def inside(self, u: np.ndarray, v: np.ndarray, margin: float) -> np.ndarray:
        """Whether positions lie at least ``margin`` px inside the image."""
        _, h, w = self.shape
        return (u >= margin) & (v >= margin) & (u <= w - 1 - margin) & (v <= h - 1 - margin)

    def pixels(self, index: np.ndarray, iu: np.ndarray, iv: np.ndarray) -> np.ndarray:
        """Grey levels (float32) at integer positions (broadcast shapes); positions
        outside the image take the nearest border pixel."""
        _, h, w = self.shape
        iu = np.clip(np.asarray(iu, np.int64), 0, w - 1)
        iv = np.clip(np.asarray(iv, np.int64), 0, h - 1)
        return self.images[np.asarray(index, np.int64), iv, iu].astype(np.float32)

    def windows(self, index: np.ndarray, u0: np.ndarray, v0: np.ndarray, size: int) -> np.ndarray:
        """Square windows ``size`` × ``size`` with top-left pixels ``(u0, v0)`` (N,), which
        must lie inside the image: (N, size, size) float32."""
        view = np.lib.stride_tricks.sliding_window_view(self.images, (size, size), axis=(1, 2))
        return view[np.asarray(index, np.int64), v0, u0].astype(np.float32)


_TAP_MARGIN = len(_HALF_TAPS) // 2 - 1  # input pixels beyond a window that its taps read


@functools.lru_cache(maxsize=16)
def _half_matrix(wr: int) -> np.ndarray:
    """Half-pixel matrix (ws, 2 wr) of a window of ``ws = 2 (wr + m) + 1`` pixels
    (m = ``_TAP_MARGIN``): a row of the window @ it gives the cubic-spline values
    half-way between pixels ``m + k`` and ``m + k + 1``, k = 0 .. 2 wr - 1."""
    m = _TAP_MARGIN
    n = len(_HALF_TAPS) // 2
    H = np.zeros((2 * (wr + m) + 1, 2 * wr), np.float32)
    for k in range(2 * wr):
        H[m + k - n + 1 : m + k + n + 1, k] = _HALF_TAPS
    return H


@functools.lru_cache(maxsize=16)
def _upsample_matrix(wr: int) -> np.ndarray:
    """Upsampling matrix (ws, 4 wr + 1): a row of a window of ``ws`` pixels @ it gives
    its central ``2 wr + 1`` pixels (even outputs, copied) interleaved with the
    half-pixel values between them (odd outputs, :func:`_half_matrix`)."""
    m = _TAP_MARGIN
    U = np.zeros((2 * (wr + m) + 1, 4 * wr + 1), np.float32)
    U[:, 1::2] = _half_matrix(wr)
    U[m + np.arange(2 * wr + 1), np.arange(0, 4 * wr + 1, 2)] = 1.0
    return U


def _windows(
    stack: ImageStack,
    index: np.ndarray,
    u0: np.ndarray,
    v0: np.ndarray,
    ws: int,
    transposed: bool = False,
) -> np.ndarray:
    """Windows ``ws`` × ``ws`` with top-left pixels ``(u0, v0)`` (N,), float32 (N, ws, ws)
    (row = v, or row = u when ``transposed``); pixels outside the image repeat its border."""
    _, h, w = stack.shape
    n = len(index)
    inside = (u0 >= 0) & (v0 >= 0) & (u0 + ws <= w) & (v0 + ws <= h)
    if inside.any():
        view = np.lib.stride_tricks.sliding_window_view(stack.images, (ws, ws), axis=(1, 2))
        if transposed:
            view = view.swapaxes(3, 4)
    if inside.all():
        return view[index, v0, u0].astype(np.float32)
    out = np.empty((n, ws, ws), np.float32)
    k = np.flatnonzero(inside)
    if k.size:
        out[k] = view[index[k], v0[k], u0[k]]
    k = np.flatnonzero(~inside)
    if k.size:
        r = np.arange(ws)
        iu = np.clip(u0[k, None] + r, 0, w - 1)
        iv = np.clip(v0[k, None] + r, 0, h - 1)
        g = stack.images[index[k, None, None], iv[:, :, None], iu[:, None, :]]
        out[k] = g.swapaxes(1, 2) if transposed else g
    return out


def _upsample_windows(win_t: np.ndarray, wr: int) -> np.ndarray:
    """Cubic-spline 2× upsampling of the centres of transposed windows.

    ``win_t`` (N, ws, ws) with row = u, ``ws = 2 (wr + m) + 1``: returns (N, 4 wr + 1,
    4 wr + 1) float32 (row = v) covering the central ``2 wr + 1`` pixels, the same
    values as :func:`upsample2`.  Along v, the pixels are copied to the even samples
    and one GEMM with the banded half-pixel matrix gives the odd ones; along u, one
    GEMM with the interleaving :func:`_upsample_matrix` gives both.
    """
    n, ws, _ = win_t.shape
    m = _TAP_MARGIN
    H = _half_matrix(wr)  # (ws, 2 wr): odd outputs only
    size = 4 * wr + 1
    x = np.empty((n, size, ws), np.float32)  # (n, v', u)
    x[:, 0::2, :] = win_t[:, :, m : m + 2 * wr + 1].transpose(0, 2, 1)
    x[:, 1::2, :] = (win_t.reshape(n * ws, ws) @ H).reshape(n, ws, 2 * wr).transpose(0, 2, 1)
    return (x.reshape(n * size, ws) @ _upsample_matrix(wr)).reshape(n, size, size)


class PatchSource:
    """Bilinear sampling of 2× upsampled images for N patches.

    A position ``(u, v)`` of patch k's image lies at ``(bu[k] + f u, bv[k] + f v)``
    (``f`` = 2 upsampled, 1 not) in the image ``chunk_image(chunk[k])``: either the
    stack's whole (upsampled) mosaic, or a stack of small windows around the
    patches, upsampled only where they are sampled (when that is smaller), in chunks
    below cv2.remap's 32767 rows.  ``lo``/``hi`` (N, 2) bound the positions whose
    samples are valid (inside the window), pixels.

    Parameters
    ----------
    stack : ImageStack
    index : ndarray, shape (N,), int
        Image of each patch.
    centre : ndarray, shape (N, 2)
        Centres of the windows, pixels (NaN: a dummy window at (0, 0)).
    reach : float or ndarray, shape (N,)
        Largest distance from the centre (per axis) at which a patch is sampled, px.
    upsample : bool
        Sample the 2× cubic-spline upsampled images (default) or the originals.
    upsampler : callable, optional
        ``upsampler(stack, index, u0, v0, wr) -> (N, 4 wr + 1, 4 wr + 1)`` float32: the
        upsampled windows whose original pixel ``(u0, v0)`` + ``(wr, wr)`` is the centre
        (the values of :func:`_upsample_windows`, e.g. compiled by
        :func:`core.lsm_kernel.upsampled_windows`); default the numpy GEMMs.
    """

    MAX_ROWS = 32000  # cv2.remap: images and maps below 32767 rows

    def __init__(
        self,
        stack: ImageStack,
        index: np.ndarray,
        centre: np.ndarray,
        reach: np.ndarray | float,
        upsample: bool = True,
        upsampler=None,
    ):
        n = len(index)
        f = 2 if upsample else 1
        self.f = float(f)
        m, h, w = stack.shape
        reach = np.broadcast_to(np.asarray(reach, float), (n,))
        # Windows of ±wr px around the rounded centres (reach + 0.5 px of rounding).
        wr = int(np.ceil(reach.max() + 0.51)) if n else 0
        size = 2 * f * wr + 1  # samples per window side
        cached = stack._up if upsample else stack._mosaic
        if (
            n == 0
            or cached is not None
            or n * size * size >= (f * f * m * (h + 2 * stack.GAP) * (w + 2 * stack.GAP))
        ):
            self.up = stack.up if upsample else stack.mosaic
            self.rows_per_chunk = max(n, 1)
            self.bu = f * stack.origin_u[index].astype(np.float64)
            self.bv = f * stack.origin_v[index].astype(np.float64)
            self.lo = np.full((n, 2), -1e9)
            self.hi = np.full((n, 2), 1e9)
            self._whole = True
            return
        self._whole = False
        c = np.rint(np.where(np.isfinite(centre), centre, 0.0)).astype(np.int64)
        mg = _TAP_MARGIN if upsample else 0
        if upsample and upsampler is not None:
            win = upsampler(stack, index, c[:, 0] - wr, c[:, 1] - wr, wr)
        else:
            win = _windows(
                stack,
                index,
                c[:, 0] - wr - mg,
                c[:, 1] - wr - mg,
                2 * (wr + mg) + 1,
                transposed=upsample,
            )
            if upsample:
                win = _upsample_windows(win, wr)
        self.up = win.reshape(n * size, size)
        self.rows_per_chunk = max(1, self.MAX_ROWS // size)
        k = np.arange(n)
        self.bu = -f * (c[:, 0] - wr).astype(np.float64)
        self.bv = ((k % self.rows_per_chunk) * size - f * (c[:, 1] - wr)).astype(np.float64)
        self.size = size
        self.lo = (c - wr + 0.01).astype(np.float64)
        self.hi = (c + wr - 0.01).astype(np.float64)

    def sample(
        self,
        pu: np.ndarray,
        pv: np.ndarray,
        rows: np.ndarray | None = None,
        out: np.ndarray | None = None,
    ) -> np.ndarray:
        """Values at positions ``pu``, ``pv`` (n_a, P) float32 of patches ``rows``.

        ``rows`` (n_a,) ascending indices of the patches (default all, in order);
        positions are ``(bu + f u, bv + f v)`` of those patches.  Returns the values
        (n_a, P) float32, written into ``out`` when given (one remap per chunk).
        """
        na = len(pu)
        if out is None:
            out = np.empty(pu.shape, np.float32)
        if self._whole:
            for i in range(0, na, self.MAX_ROWS):
                j = slice(i, i + self.MAX_ROWS)
                cv2.remap(
                    self.up,
                    pu[j],
                    pv[j],
                    cv2.INTER_LINEAR,
                    dst=out[j],
                    borderMode=cv2.BORDER_REPLICATE,
                )
            return out
        rows = np.arange(na) if rows is None else rows
        rpc = self.rows_per_chunk
        # Chunks of ascending rows: contiguous row ranges of the positions.
        cuts = np.searchsorted(rows, np.arange(rpc, rows[-1] + 1, rpc)) if na else []
        start = 0
        for stop in [*cuts, na]:
            if stop > start:
                ch = rows[start] // rpc
                r0 = ch * rpc * self.size
                img = self.up[r0 : r0 + rpc * self.size]
                j = slice(start, stop)
                cv2.remap(
                    img, pu[j], pv[j], cv2.INTER_LINEAR, dst=out[j], borderMode=cv2.BORDER_REPLICATE
                )
            start = stop
        return out


def resampling_noise_factor(u: np.ndarray, v: np.ndarray, upsample: bool = True) -> np.ndarray:
    """Variance of white pixel noise after :class:`PatchSource` resampling at ``(u, v)``,
    per unit of the pixel noise variance (1 at pixel centres, less in between).

    The sample is a weighted sum of the original pixels, separable in u and v: with
    ``upsample``, bilinear between the 2× samples (pixels at even, cubic-spline
    half-pixel values at odd positions), else bilinear between the pixels; the factor
    is the sum of the squared weights.  Same shapes as ``u``, ``v``; float32.
    """
    n = len(_HALF_TAPS) // 2
    rho_h = float(np.sum(_HALF_TAPS.astype(np.float64) ** 2))  # half-pixel value
    c = float(_HALF_TAPS[n - 1])  # its weight on a neighbour

    def axis(p):
        q = np.asarray(p, np.float32) * np.float32(2.0 if upsample else 1.0)
        k = np.floor(q)
        t = q - k
        s = 1.0 - t
        if not upsample:
            return s * s + t * t
        odd = (k.astype(np.int64) & 1).astype(np.float32) * np.float32(rho_h - 1.0)
        return s * s * (1.0 + odd) + t * t * (rho_h - odd) + np.float32(2.0 * c) * s * t

    return axis(u) * axis(v)


def remap_bilinear(img: np.ndarray, mu: np.ndarray, mv: np.ndarray) -> np.ndarray:
    """Bilinear cv2.remap in row blocks (its maps must stay below 32767 rows)."""
    rows = mu.shape[0]
    if rows <= 32000:
        return cv2.remap(img, mu, mv, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return np.concatenate(
        [
            cv2.remap(
                img,
                mu[i : i + 32000],
                mv[i : i + 32000],
                cv2.INTER_LINEAR,
                borderMode=cv2.BORDER_REPLICATE,
            )
            for i in range(0, rows, 32000)
        ]
    )
