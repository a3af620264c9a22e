"""Gruen's adaptive least squares matching (LSM), batched over thousands of patches.

A template patch of ``(2 h + 1)²`` pixels around ``uv_template`` in one image is
matched to a patch in a search image, warped by an affine transform and scaled in
its grey levels (Gruen 1985; D'Apuzzo et al. 1999, section 2.3)::

    T(x, y) + e(x, y) = r0 + r1 · S(a0 + a1 x + a2 y,  b0 + b1 x + b2 y)

with ``(x, y)`` the pixel offsets from the template centre, ``(a0, b0)`` the matched
point in the search image (pixels), ``[[a1, a2], [b1, b2]]`` the affine part (2
scales, 2 shears) and ``r0, r1`` the radiometric offset and gain.  The 8 parameters
are estimated by Gauss–Newton on the grey-level differences; the search image is
resampled by bicubic (default) or bilinear interpolation, and its gradients are the
central differences of the resampled patch, mapped back through the affine part.

Every iteration handles all still-active patches as arrays ``(N, P, 8)``: there is no
Python loop over patches.  Iteration stops per patch when the shift correction falls
below ``tol_px`` (0.01 px by default).  The precision follows from the normal matrix
of the last iteration: ``σ0² = vᵀv / (n - u)`` and ``Σ = σ0² N⁻¹``.

Optional geometric constraint (multi-photo geometrically constrained matching):
the matched point must lie on a given line ``n · uv = d`` in the search image (the
local epipolar line from the calibration, see :func:`epipolar_lines`), added as a
pseudo-observation with standard deviation ``sigma_line_px``.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

import cv2
import numpy as np
from scipy import ndimage

from .camera import Camera


class Status(IntEnum):
    """Per-match outcome of :func:`match` (``LSMResult.status``)."""

    OK = 0
    NOT_CONVERGED = 1     #: no convergence within ``max_iter`` iterations
    LARGE_SIGMA = 2       #: σ of the shifts above ``max_sigma_px``
    WEAK_TEXTURE = 3      #: template without texture (small gradient energy)
    OUT_OF_SEARCH = 4     #: the shift drifted more than ``max_shift_px`` from its start
    OUT_OF_IMAGE = 5      #: template or warped patch leaves its image
    DEGENERATE = 6        #: singular normal matrix, or affine scale / gain out of range
    INVALID = 7           #: NaN start position


@dataclass
class LSMResult:
    """Result of :func:`match` for N patches.

    Attributes
    ----------
    uv : ndarray, shape (N, 2)
        Matched point in the search image, pixels (the last estimate, also for failures).
    affine : ndarray, shape (N, 2, 2)
        ``[[a1, a2], [b1, b2]]``: search-image offsets per template pixel offset.
    gain, offset : ndarray, shape (N,)
        Radiometric parameters ``r1`` and ``r0`` (grey levels).
    sigma0 : ndarray, shape (N,)
        Standard deviation of unit weight: RMS grey-level residual, grey levels.
    cov_uv : ndarray, shape (N, 2, 2)
        Covariance of ``uv``, px².
    iterations : ndarray, shape (N,), int
    status : ndarray, shape (N,), int
        :class:`Status` codes; 0 = accepted.
    texture : ndarray, shape (N,)
        sqrt of the smaller eigenvalue of the template's structure tensor per pixel,
        grey levels per pixel (the "weak texture" measure).
    """

    uv: np.ndarray
    affine: np.ndarray
    gain: np.ndarray
    offset: np.ndarray
    sigma0: np.ndarray
    cov_uv: np.ndarray
    iterations: np.ndarray
    status: np.ndarray
    texture: np.ndarray

    @property
    def ok(self) -> np.ndarray:
        """Accepted matches, shape (N,) bool."""
        return self.status == Status.OK

    @property
    def sigma_uv(self) -> np.ndarray:
        """Standard deviations of u and v, shape (N, 2), pixels."""
        return np.sqrt(np.abs(np.diagonal(self.cov_uv, axis1=1, axis2=2)))


# -- image sampling -----------------------------------------------------------------

class ImageStack:
    """One or more grey images of equal size, tiled into one mosaic for batched sampling.

    Sampling uses ``cv2.remap`` (bilinear or bicubic), which rounds positions to 1/32
    px; :meth:`sample` returns that rounding so that callers correct it to first order
    with the local gradient (the remaining error is below 1e-4 grey levels per grey
    level of curvature).  Samples within ``margin`` of an image border are flagged by
    :meth:`inside`; tiles are separated by a gap so that they never mix.

    Parameters
    ----------
    images : ndarray (H, W) or (M, H, W), a sequence of (H, W) arrays, or ImageStack
        Grey levels (any real dtype).
    """

    GAP = 4

    def __init__(self, images):
        if isinstance(images, ImageStack):
            self.__dict__.update(images.__dict__)
            return
        arr = images if not isinstance(images, list | tuple) else np.stack(images)
        arr = np.asarray(arr)
        if arr.ndim == 2:
            arr = arr[None]
        if arr.ndim != 3 or arr.shape[0] == 0:
            raise ValueError(f"images must be (H, W) or (M, H, W), got shape {arr.shape}")
        m, h, w = arr.shape
        self.shape = arr.shape
        g = self.GAP
        cols = max(1, min(m, int(np.ceil(np.sqrt(m * (h + g) / (w + g))))))
        cols = min(cols, max(1, 30000 // (w + g)))
        rows = int(np.ceil(m / cols))
        if rows * (h + g) > 30000:
            raise ValueError(f"image stack {arr.shape} too large for one mosaic")
        tiles = np.zeros((rows * cols, h + g, w + g), np.float32)
        tiles[:m, g // 2:g // 2 + h, g // 2:g // 2 + w] = arr
        mosaic = tiles.reshape(rows, cols, h + g, w + g).transpose(0, 2, 1, 3).reshape(
            rows * (h + g), cols * (w + g))
        k = np.arange(m)
        self.origin_u = (k % cols) * (w + g) + g // 2
        self.origin_v = (k // cols) * (h + g) + g // 2
        self.mosaic = mosaic
        self._coef = None

    def inside(self, u: np.ndarray, v: np.ndarray, margin: float) -> np.ndarray:
        """Whether positions lie at least ``margin`` px inside the image."""
        _, h, w = self.shape
        return (u >= margin) & (v >= margin) & (u <= w - 1 - margin) & (v <= h - 1 - margin)

    def sample(self, index: np.ndarray, u: np.ndarray, v: np.ndarray,
               order: int = 3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Interpolate grey levels at ``(u, v)`` in image ``index`` (broadcast shapes).

        Parameters
        ----------
        order : {1, 3}
            1 = bilinear (``cv2.remap``, positions rounded to 1/32 px), 3 = cubic
            B-spline (``scipy.ndimage``, exact positions).

        Returns
        -------
        values : ndarray, float32
            Grey levels at the positions rounded to 1/32 px.
        du, dv : ndarray, float32
            ``position - rounded position``, px: add ``grad · (du, dv)`` for the value
            at the exact position.
        """
        index = np.asarray(index, dtype=np.int64)
        u, v, index = np.broadcast_arrays(np.asarray(u, np.float64), np.asarray(v, np.float64),
                                          index)
        shape = u.shape
        mu = (u + self.origin_u[index]).reshape(-1, shape[-1] if len(shape) else 1)
        mv = (v + self.origin_v[index]).reshape(mu.shape)
        if order == 3:
            # Cubic B-spline on prefiltered coefficients: exact positions, no rounding.
            if self._coef is None:
                self._coef = ndimage.spline_filter(self.mosaic, order=3, output=np.float32,
                                                   mode="mirror")
            vals = ndimage.map_coordinates(self._coef, np.stack([mv.ravel(), mu.ravel()]),
                                           order=3, prefilter=False, mode="mirror",
                                           output=np.float32)
            zero = np.zeros(shape, np.float32)
            return vals.reshape(shape), zero, zero
        mu32, mv32 = mu.astype(np.float32), mv.astype(np.float32)
        vals = _remap(self.mosaic, mu32, mv32, cv2.INTER_LINEAR)
        du = (mu - np.rint(mu32.astype(np.float64) * 32.0) / 32.0).astype(np.float32)
        dv = (mv - np.rint(mv32.astype(np.float64) * 32.0) / 32.0).astype(np.float32)
        return vals.reshape(shape), du.reshape(shape), dv.reshape(shape)


def _remap(img: np.ndarray, mu: np.ndarray, mv: np.ndarray, flag: int) -> np.ndarray:
    """cv2.remap in row blocks (its maps must stay below 32767 rows)."""
    rows = mu.shape[0]
    if rows <= 32000:
        return cv2.remap(img, mu, mv, flag, borderMode=cv2.BORDER_REPLICATE)
    return np.concatenate([
        cv2.remap(img, mu[i:i + 32000], mv[i:i + 32000], flag,
                  borderMode=cv2.BORDER_REPLICATE) for i in range(0, rows, 32000)])


def _grid(half: int, border: int = 0) -> tuple[np.ndarray, np.ndarray]:
    r = np.arange(-half - border, half + border + 1, dtype=np.float64)
    y, x = np.meshgrid(r, r, indexing="ij")
    return x, y


def _gradients(P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Central differences of patches with a 1-px border: (n, s, s) -> 2 x (n, s-2, s-2)."""
    return (0.5 * (P[:, 1:-1, 2:] - P[:, 1:-1, :-2]),
            0.5 * (P[:, 2:, 1:-1] - P[:, :-2, 1:-1]))


def template_patches(images, uv: np.ndarray, half: int = 6, index=None,
                     order: int = 3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Patches around ``uv`` (N, 2), with their gradients.

    Returns
    -------
    patch, gu, gv : ndarray, shape (N, 2h+1, 2h+1), float64
        Grey levels (row = v) and their derivatives along u and v, per pixel.
    """
    stack = ImageStack(images)
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    idx = np.zeros(len(uv), np.int64) if index is None else np.asarray(index, np.int64)
    x, y = _grid(half, 1)
    P, du, dv = stack.sample(idx[:, None, None], uv[:, 0, None, None] + x,
                             uv[:, 1, None, None] + y, order)
    P = P.astype(np.float64)
    gu, gv = _gradients(P)
    P = P[:, 1:-1, 1:-1] + gu * du[:, 1:-1, 1:-1] + gv * dv[:, 1:-1, 1:-1]
    return P, gu, gv


# -- the matcher ----------------------------------------------------------------------

def _cholesky_solve(N: np.ndarray, B: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Solve SPD systems ``N x = B`` batched: N (n, k, k), B (n, k, m) -> x, ok (n,).

    Column-wise Cholesky vectorised over the batch (k small); ``ok`` is False where
    N is not positive definite (x is then meaningless).
    """
    n, k, _ = N.shape
    L = np.zeros_like(N)
    ok = np.ones(n, bool)
    for j in range(k):
        s = N[:, j, j] - np.einsum("ni,ni->n", L[:, j, :j], L[:, j, :j])
        ok &= s > 1e-12
        d = np.sqrt(np.where(s > 1e-12, s, 1.0))
        L[:, j, j] = d
        if j + 1 < k:
            low = N[:, j + 1:, j] - np.einsum("nik,nk->ni", L[:, j + 1:, :j], L[:, j, :j])
            L[:, j + 1:, j] = low / d[:, None]
    y = np.empty_like(B)
    for j in range(k):
        y[:, j] = (B[:, j] - np.einsum("nk,nkm->nm", L[:, j, :j], y[:, :j])) / L[:, j, j, None]
    x = np.empty_like(B)
    for j in range(k - 1, -1, -1):
        x[:, j] = (y[:, j] - np.einsum("nk,nkm->nm", L[:, j + 1:, j], x[:, j + 1:])) / L[:, j, j,
                                                                                       None]
    return x, ok


# Moments basis: m_i m_j for m = (1, x, y) -> index into (1, x, y, x², xy, y²).
_MOM = np.array([[0, 1, 2], [1, 3, 4], [2, 4, 5]])


def match(template_images, search_images, uv_template, uv_search, *, half: int = 6,
          affine=None, template_index=None, search_index=None, order: int = 3,
          tol_px: float = 0.01, max_iter: int = 30, max_shift_px: float = 4.0,
          max_sigma_px: float = 0.2, min_texture: float = 3.0, lines=None,
          sigma_line_px: float = 0.05, sigma_grey: float = 2.0) -> LSMResult:
    """Least squares matching of N template patches into search images.

    Parameters
    ----------
    template_images, search_images : ndarray (H, W) or (M, H, W), or :class:`ImageStack`
        Grey images; with stacks, ``template_index`` / ``search_index`` (N,) int pick
        the image of each patch (default 0).
    uv_template : ndarray, shape (N, 2)
        Template centres, pixels (sub-pixel allowed: resampled).
    uv_search : ndarray, shape (N, 2)
        Start positions in the search images, pixels.
    half : int
        Half width ``h``: patches are ``(2h+1)²`` (default 13 × 13).
    affine : ndarray, shape (N, 2, 2) or (2, 2), optional
        Start of the affine part (default identity).
    order : {1, 3}
        Interpolation of the images: 1 bilinear, 3 bicubic.
    tol_px : float
        Convergence: both shift corrections below this, pixels.
    max_iter : int
    max_shift_px : float
        Reject when the match drifts farther than this from ``uv_search``, pixels.
    max_sigma_px : float
        Reject when the σ of u or v is larger, pixels.
    min_texture : float
        Reject templates whose :attr:`LSMResult.texture` is smaller, grey levels / px.
    lines : tuple (normal (N, 2), d (N,)), optional
        Geometric constraint ``normal · uv = d`` (unit normals) with σ ``sigma_line_px``.
    sigma_grey : float
        A-priori σ of a grey level, weighting the line constraint against the patch.

    Returns
    -------
    LSMResult
    """
    tstack, sstack = ImageStack(template_images), ImageStack(search_images)
    uv_t = np.asarray(uv_template, dtype=np.float64).reshape(-1, 2)
    uv_s0 = np.asarray(uv_search, dtype=np.float64).reshape(-1, 2)
    n = len(uv_t)
    if uv_s0.shape != uv_t.shape:
        raise ValueError(f"uv_template {uv_t.shape} and uv_search {uv_s0.shape} differ")
    ti = np.zeros(n, np.int64) if template_index is None else np.asarray(template_index,
                                                                         np.int64)
    si = np.zeros(n, np.int64) if search_index is None else np.asarray(search_index, np.int64)
    if not (np.all((ti >= 0) & (ti < tstack.shape[0]))
            and np.all((si >= 0) & (si < sstack.shape[0]))):
        raise ValueError("template_index / search_index outside the image stacks")
    A = np.broadcast_to(np.eye(2) if affine is None else np.asarray(affine, float),
                        (n, 2, 2)).copy()
    status = np.full(n, Status.NOT_CONVERGED, dtype=np.int8)
    iters = np.zeros(n, np.int32)
    uv = uv_s0.copy()
    gain = np.ones(n)
    offset = np.zeros(n)
    sigma0 = np.full(n, np.nan)
    cov = np.full((n, 2, 2), np.nan)

    finite = np.all(np.isfinite(uv_t), axis=1) & np.all(np.isfinite(uv_s0), axis=1)
    status[~finite] = Status.INVALID
    uv_t_safe = np.where(finite[:, None], uv_t, 0.0)
    uv = np.where(finite[:, None], uv, 0.0)
    margin = half + 3
    t_in = tstack.inside(uv_t_safe[:, 0], uv_t_safe[:, 1], margin)
    status[finite & ~t_in] = Status.OUT_OF_IMAGE

    # Template patch and its texture (smaller eigenvalue of the structure tensor).
    # Integer centres are sampled exactly by bilinear interpolation (no prefilter needed).
    integral = np.all(np.abs(uv_t_safe - np.rint(uv_t_safe)) < 1e-9)
    T, tx, ty = template_patches(tstack, uv_t_safe, half, ti, order=1 if integral else order)
    T = T.reshape(n, -1)
    npx = T.shape[1]
    sxx = np.mean(tx * tx, axis=(1, 2))
    syy = np.mean(ty * ty, axis=(1, 2))
    sxy = np.mean(tx * ty, axis=(1, 2))
    lam_min = 0.5 * (sxx + syy) - np.sqrt(0.25 * (sxx - syy) ** 2 + sxy ** 2)
    texture = np.sqrt(np.maximum(lam_min, 0.0))
    status[finite & t_in & (texture < min_texture)] = Status.WEAK_TEXTURE

    if lines is not None:
        ln_n = np.asarray(lines[0], float).reshape(n, 2)
        ln_d = np.asarray(lines[1], float).reshape(n)
    xg, yg = _grid(half, 1)                      # sampling grid with a 1-px border
    xi, yi = xg[1:-1, 1:-1].ravel(), yg[1:-1, 1:-1].ravel()
    basis = np.stack([np.ones_like(xi), xi, yi, xi * xi, xi * yi, yi * yi], axis=1)  # (P, 6)
    basis32 = basis.astype(np.float32)
    aff_idx = [1, 2, 4, 5]

    active = np.flatnonzero(status == Status.NOT_CONVERGED)
    shift_only = np.ones(n, bool)     # first iterations: shifts + radiometry only
    T32 = T.astype(np.float32)
    first = True
    for it in range(max_iter):
        if active.size == 0:
            break
        a = active
        na = len(a)
        Aa = A[a]
        # Warped sampling positions (n_a, 2h+3, 2h+3).
        pu = uv[a, 0, None, None] + Aa[:, 0, 0, None, None] * xg + Aa[:, 0, 1, None, None] * yg
        pv = uv[a, 1, None, None] + Aa[:, 1, 0, None, None] * xg + Aa[:, 1, 1, None, None] * yg
        inside = np.all(sstack.inside(pu, pv, 1.0 + (order == 3)), axis=(1, 2))
        Sb, du, dv = sstack.sample(si[a, None, None], pu, pv, order)
        # Gradients of the resampled patch w.r.t. template offsets, mapped to search px.
        dx, dy = _gradients(Sb)
        dx = dx.reshape(na, -1)
        dy = dy.reshape(na, -1)
        det = Aa[:, 0, 0] * Aa[:, 1, 1] - Aa[:, 0, 1] * Aa[:, 1, 0]
        safe_det = np.where(np.abs(det) > 1e-6, det, 1.0)
        # grad_S = A^-T grad_(S∘A)
        i00 = (Aa[:, 1, 1] / safe_det).astype(np.float32)[:, None]
        i01 = (-Aa[:, 1, 0] / safe_det).astype(np.float32)[:, None]
        i10 = (-Aa[:, 0, 1] / safe_det).astype(np.float32)[:, None]
        i11 = (Aa[:, 0, 0] / safe_det).astype(np.float32)[:, None]
        gx = i00 * dx + i01 * dy
        gy = i10 * dx + i11 * dy
        S = Sb[:, 1:-1, 1:-1].reshape(na, -1)
        if order == 1:
            # First-order correction of the 1/32-px rounding of the sample positions.
            S = S + gx * du[:, 1:-1, 1:-1].reshape(na, -1) + gy * dv[:, 1:-1, 1:-1].reshape(na, -1)
        if first:
            # Radiometric start: match the mean and spread of the grey levels.
            sd_s = S.std(axis=1, dtype=np.float64)
            g0 = np.where(sd_s > 1e-6, T[a].std(axis=1) / np.maximum(sd_s, 1e-6), 1.0)
            gain[a] = g0
            offset[a] = T[a].mean(axis=1) - g0 * S.mean(axis=1, dtype=np.float64)
            first = False
        r1 = gain[a]
        res = T32[a] - (offset[a, None].astype(np.float32)
                        + r1[:, None].astype(np.float32) * S)      # observed - computed
        # Normal equations from weighted moments: one GEMM (Q, n_a, P) @ (P, 6).
        Q = np.empty((13, na, npx), np.float32)
        np.multiply(gx, gx, out=Q[0])
        np.multiply(gx, gy, out=Q[1])
        np.multiply(gy, gy, out=Q[2])
        Q[3] = gx
        Q[4] = gy
        np.multiply(gx, S, out=Q[5])
        np.multiply(gy, S, out=Q[6])
        np.multiply(gx, res, out=Q[7])
        np.multiply(gy, res, out=Q[8])
        Q[9] = S
        np.multiply(S, S, out=Q[10])
        Q[11] = res
        np.multiply(S, res, out=Q[12])
        M = (Q.reshape(-1, npx) @ basis32).reshape(13, na, 6).astype(np.float64)
        Nm = np.empty((na, 8, 8))
        r1s = r1 * r1
        for i in range(3):
            for j in range(3):
                k = _MOM[i, j]
                Nm[:, i, j] = r1s * M[0, :, k]
                Nm[:, i, 3 + j] = r1s * M[1, :, k]
                Nm[:, 3 + i, j] = r1s * M[1, :, k]
                Nm[:, 3 + i, 3 + j] = r1s * M[2, :, k]
            Nm[:, i, 6] = Nm[:, 6, i] = r1 * M[3, :, i]
            Nm[:, 3 + i, 6] = Nm[:, 6, 3 + i] = r1 * M[4, :, i]
            Nm[:, i, 7] = Nm[:, 7, i] = r1 * M[5, :, i]
            Nm[:, 3 + i, 7] = Nm[:, 7, 3 + i] = r1 * M[6, :, i]
        Nm[:, 6, 6] = npx
        Nm[:, 6, 7] = Nm[:, 7, 6] = M[9, :, 0]
        Nm[:, 7, 7] = M[10, :, 0]
        b = np.concatenate([r1[:, None] * M[7, :, :3], r1[:, None] * M[8, :, :3],
                            M[11, :, :1], M[12, :, :1]], axis=1)   # (n_a, 8)
        vv = np.einsum("np,np->n", res, res, dtype=np.float64)
        if lines is not None:
            # Pseudo-observation n·(uv + d_uv) = d, weight σ_grey² / σ_line².
            w = (sigma_grey / sigma_line_px) ** 2
            nrm = ln_n[a]
            mis = ln_d[a] - np.einsum("ni,ni->n", nrm, uv[a])
            vv += w * mis * mis
            for i, pi in enumerate((0, 3)):
                b[:, pi] += w * nrm[:, i] * mis
                for j, pj in enumerate((0, 3)):
                    Nm[:, pi, pj] += w * nrm[:, i] * nrm[:, j]
        so = shift_only[a]
        if np.any(so):
            sub = Nm[so]
            sub[:, aff_idx, :] = 0.0
            sub[:, :, aff_idx] = 0.0
            sub[:, aff_idx, aff_idx] = 1.0
            Nm[so] = sub
            bs = b[so]
            bs[:, aff_idx] = 0.0
            b[so] = bs
        ok_solve = np.isfinite(Nm).all(axis=(1, 2)) & (np.abs(det) > 1e-3)
        # Unit-diagonal scaling, then one solve for the update and two covariance columns.
        dg = np.sqrt(np.maximum(np.einsum("nii->ni", Nm), 1e-30))
        Ns = Nm / dg[:, :, None] / dg[:, None, :]
        Ns[~ok_solve] = np.eye(8)
        rhs = np.zeros((na, 8, 3))
        rhs[:, :, 0] = b / dg
        rhs[:, 0, 1] = 1.0
        rhs[:, 3, 2] = 1.0
        sol, pd = _cholesky_solve(Ns, rhs)
        ok_solve &= pd
        sol = sol / dg[:, :, None]
        dp = sol[:, :, 0]
        ok_solve &= np.isfinite(dp).all(axis=1)
        dp[~ok_solve] = 0.0
        uv[a, 0] += dp[:, 0]
        uv[a, 1] += dp[:, 3]
        A[a, 0, 0] += dp[:, 1]
        A[a, 0, 1] += dp[:, 2]
        A[a, 1, 0] += dp[:, 4]
        A[a, 1, 1] += dp[:, 5]
        offset[a] += dp[:, 6]
        gain[a] += dp[:, 7]
        iters[a] = it + 1
        # Precision from this linearisation: σ0² = vᵀv / (n - u), Σ = σ0² N⁻¹.
        dof = npx - (8 - 4 * so) + (lines is not None)
        vtv = vv - np.einsum("ni,ni->n", dp, b)
        s0 = np.sqrt(np.maximum(vtv, 0.0) / dof)
        sigma0[a] = s0
        Ninv_uv = sol[:, [0, 3], 1:] / dg[:, None, [0, 3]]
        cov[a] = (s0 ** 2)[:, None, None] * Ninv_uv

        small = (np.abs(dp[:, 0]) < tol_px) & (np.abs(dp[:, 3]) < tol_px)
        # Leave the shift-only phase once the shift settles to 0.2 px (or after 3 steps).
        leave = so & ((np.abs(dp[:, 0]) < 0.2) & (np.abs(dp[:, 3]) < 0.2) | (it >= 2))
        shift_only[a[leave]] = False
        conv = small & ~so
        drift = np.hypot(*(uv[a] - uv_s0[a]).T) > max_shift_px
        sc = np.abs(det)
        degen = ~ok_solve | (sc < 0.25) | (sc > 4.0) | (gain[a] < 0.1) | (gain[a] > 10.0)
        st = np.full(na, Status.NOT_CONVERGED, dtype=np.int8)
        st[conv] = Status.OK
        st[drift] = Status.OUT_OF_SEARCH
        st[degen] = Status.DEGENERATE
        st[~inside] = Status.OUT_OF_IMAGE
        status[a] = st
        active = a[st == Status.NOT_CONVERGED]

    sig = np.sqrt(np.abs(np.diagonal(cov, axis1=1, axis2=2)))
    big = (status == Status.OK) & ~(np.all(sig <= max_sigma_px, axis=1))
    status[big] = Status.LARGE_SIGMA
    return LSMResult(uv=uv, affine=A, gain=gain, offset=offset, sigma0=sigma0, cov_uv=cov,
                     iterations=iters, status=status, texture=texture)


# -- geometric constraint -------------------------------------------------------------

def epipolar_lines(cam_template: Camera, cam_search: Camera, uv_template: np.ndarray,
                   uv_near: np.ndarray, depth_range=(0.3, 30.0),
                   n_samples: int = 256) -> tuple[np.ndarray, np.ndarray]:
    """Local epipolar lines in the search camera, with lens distortion.

    The ray of each template point is sampled in depth, projected into the search
    camera, and the line is the tangent of that (curved, when distorted) image of the
    ray at the sample nearest ``uv_near``.

    Parameters
    ----------
    cam_template, cam_search : Camera
    uv_template : ndarray, shape (N, 2)
        Points in the template camera, pixels.
    uv_near : ndarray, shape (N, 2)
        Approximate positions in the search camera, pixels.
    depth_range : (float, float)
        Distances along the ray to sample, metres.

    Returns
    -------
    normal : ndarray, shape (N, 2)
        Unit normals of the lines in the search image.
    d : ndarray, shape (N,)
        Offsets: ``normal · uv = d`` on the line, pixels.
    """
    uv_template = np.asarray(uv_template, float).reshape(-1, 2)
    uv_near = np.asarray(uv_near, float).reshape(-1, 2)
    origin, ray = cam_template.rays(uv_template)                    # (N, 3)
    s = np.geomspace(depth_range[0], depth_range[1], n_samples)
    xyz = origin + ray[:, None, :] * s[None, :, None]               # (N, S, 3)
    p = cam_search.project(xyz)                                     # (N, S, 2)
    dist = np.linalg.norm(p - uv_near[:, None], axis=2)
    dist = np.where(np.isfinite(dist), dist, np.inf)
    k = np.clip(np.argmin(dist, axis=1), 1, n_samples - 2)
    rows = np.arange(len(k))
    tangent = p[rows, k + 1] - p[rows, k - 1]
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    normal = np.stack([-tangent[:, 1], tangent[:, 0]], axis=1)
    d = np.einsum("ni,ni->n", normal, p[rows, k])
    return normal, d
