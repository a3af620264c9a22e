"""Gruen's adaptive least squares matching (LSM), batched over thousands of patches.

A template patch of ``(2 h + 1)²`` pixels around ``uv_template`` in one image is
matched to a patch in a search image, warped by an affine transform and scaled in
its grey levels (Gruen 1985; D'Apuzzo et al. 1999, section 2.3)::

    T(x, y) + e(x, y) = r0 + r1 · S(a0 + a1 x + a2 y,  b0 + b1 x + b2 y)

with ``(x, y)`` the pixel offsets from the template centre, ``(a0, b0)`` the matched
point in the search image (pixels), ``[[a1, a2], [b1, b2]]`` the affine part (2
scales, 2 shears) and ``r0, r1`` the radiometric offset and gain.

The 8 parameters are estimated by Gauss–Newton in the inverse compositional form
(Baker & Matthews 2004): the update is computed on the template side, so the design
matrix ``[∇T·∂W/∂p, 1, T]`` (template gradients, offset, gain) and its normal matrix
``N`` (from packed moments, two GEMMs for all patches) are computed and inverted
once per patch; every iteration then only resamples the search patch, forms ``Jᵀe``
(``∇T e`` against the moments 1, x, y: GEMVs over all patches) and multiplies by
``N⁻¹``.  The
warp is composed with the inverse update (``W ← W ∘ ΔW⁻¹``) and the radiometry with
its inverse.  The fixed point is the same as that of the forward-additive
Gauss–Newton up to terms of the order of the noise in the template gradients.  The
template gradients are the slopes of the cubic spline through the template (not
central differences, which damp fine texture by up to a third and make the steps
overshoot): from 1 px off, most patches converge in 3 iterations (shift and
radiometry only, then all 8 parameters, then the check).

Resampling: windows of the search images around the start positions (the patch
footprint and 1 px of drift) are upsampled 2× by cubic B-spline interpolation (a
symmetric 12-tap half-pixel filter, so no phase error; two GEMMs per window stack),
and the iterations sample them bilinearly (``cv2.remap``, one call per 32000 rows of
windows).  The warp is snapped to cv2.remap's 1/32 px grid before sampling
(so every sample is exact) and the update starts from the snapped warp.  This keeps
the precision of cubic-spline resampling at the cost of bilinear sampling;
``upsample=False`` samples the original image bilinearly (~25 % larger errors on
fine texture).  When the windows would be larger than the images (or the stack's
upsampled mosaic is cached), the whole upsampled mosaic is sampled instead.

All patches are handled as arrays: there is no Python loop over patches.  Iteration
stops per patch when the matched point moves less than ``tol_px`` (0.01 px by
default) in both coordinates.  Precision from the normal matrix: ``σ0² = vᵀv / (n - u)``,
``Σ = κ σ0² N⁻¹``, mapped to the search image through the affine part; ``κ`` puts
back the noise of the search patch that its resampling averaged out of the residuals
(see :func:`core.image_stack.resampling_noise_factor`; equal noise in both images
assumed).  OpenBLAS runs on one thread inside :func:`match` (:mod:`core.blas_threads`):
the many skinny GEMMs gain nothing from threads and lose a lot to their spinning.
Optionally (``workers``), the patches are split into parts matched in parallel threads
(the heavy steps release the GIL): for idle cores (on 2 busy cores it gained nothing).

Where numba is installed, the normal matrices, their inverses, the upsampled windows
and the iterations run compiled (:mod:`core.lsm_kernel`, same rules; ~1.6× the matches
per CPU second).  Without numba (Blender), with ``SOMACAP_NO_NUMBA=1``, with a line
constraint, or when compiling fails, this numpy path runs: same statuses and
iterations, positions to ~1e-6 px.

Optional geometric constraint (multi-photo geometrically constrained matching):
the matched point must lie on a given line ``n · uv = d`` in the search image (the
local epipolar line from the calibration, see :func:`epipolar_lines`), added as a
pseudo-observation with standard deviation ``sigma_line_px`` (a rank-one update of
``N⁻¹`` per iteration).
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, fields
from enum import IntEnum

import numpy as np

from . import lsm_kernel
from .batched_linalg import line_update, spd_inverse
from .blas_threads import single_blas_thread
from .camera import Camera
from .image_stack import ImageStack, PatchSource, resampling_noise_factor, upsample2
from .lsm_design import (
    FLAT_SD,
    _grid,
    coarse_shift_step,
    compose_inverse,
    inverse_blocks,
    normal_matrix,
    row_mean_sd,
    shift_moments,
    template_patches,
)

__all__ = [
    "ImageStack",
    "LSMResult",
    "Status",
    "epipolar_lines",
    "match",
    "template_patches",
    "upsample2",
]


#: Drift allowed for in a search window beyond the patch footprint, px (then a new window).
_DRIFT_PX = 1.0

#: ``match(workers=0)`` splits its patches over threads only in parts of at least this many.
MIN_PATCHES_PER_WORKER = 512


class Status(IntEnum):
    """Per-match outcome of :func:`match` (``LSMResult.status``)."""

    OK = 0
    NOT_CONVERGED = 1  #: no convergence within ``max_iter`` iterations
    LARGE_SIGMA = 2  #: σ of the shifts above ``max_sigma_px``
    WEAK_TEXTURE = 3  #: template without texture (small gradient energy)
    OUT_OF_SEARCH = 4  #: the shift drifted more than ``max_shift_px`` from its start
    OUT_OF_IMAGE = 5  #: template or warped patch leaves its image
    DEGENERATE = 6  #: singular normal matrix, affine scale / gain out of range, or a
    #: flat search patch (grey-level spread below :data:`core.lsm_design.FLAT_SD`)
    INVALID = 7  #: NaN start position


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
        Covariance of ``uv``, px² (``κ σ0² N⁻¹`` mapped by the affine part, see above).
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


@single_blas_thread()
def match(
    template_images,
    search_images,
    uv_template,
    uv_search,
    *,
    half: int = 6,
    affine=None,
    template_index=None,
    search_index=None,
    upsample: bool = True,
    tol_px: float = 0.01,
    max_iter: int = 20,
    max_shift_px: float = 4.0,
    max_sigma_px: float = 0.15,
    min_texture: float = 3.0,
    lines=None,
    sigma_line_px: float = 0.05,
    sigma_grey: float = 2.0,
    weight_sigma: float | None = None,
    workers: int = 1,
) -> LSMResult:
    """Least squares matching of N template patches into search images.

    Parameters
    ----------
    template_images, search_images : ndarray (H, W) or (M, H, W), or :class:`ImageStack`
        Grey images; with stacks, ``template_index`` / ``search_index`` (N,) int pick
        the image of each patch (default 0).  Pass the same ImageStack to several
        calls to share its upsampled copy.
    uv_template : ndarray, shape (N, 2)
        Template centres, pixels (sub-pixel allowed: resampled).
    uv_search : ndarray, shape (N, 2)
        Start positions in the search images, pixels.
    half : int
        Half width ``h``: patches are ``(2h+1)²`` (default 13 × 13).
    affine : ndarray, shape (N, 2, 2) or (2, 2), optional
        Start of the affine part (default identity).
    upsample : bool
        Resample the 2× cubic-spline upsampled images (default) or the originals.
    tol_px : float
        Convergence: the matched point moved less than this in u and v, pixels.
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
    weight_sigma : float, optional
        Weight the template pixels by a Gaussian of this σ (pixels) around the centre:
        on curved surfaces the affine model holds over a smaller area, and a smaller
        effective patch biases the match less, while the whole patch still helps
        convergence.  The covariance is then the sandwich ``N⁻¹ (JᵀW²J) N⁻¹ σ²`` with
        ``σ² = vᵀWv / (tr W - tr(N⁻¹ JᵀW²J))``.  Default: uniform weights (Gruen).
    workers : int, optional
        Threads over which the patches are split (contiguous parts, matched
        independently); 0: one per usable CPU core, at most one per
        ``MIN_PATCHES_PER_WORKER`` patches.  Default 1: the calling thread only.
        Search windows are sized per part: a split changes matches within ``tol_px``.

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
    ti = np.zeros(n, np.int64) if template_index is None else np.asarray(template_index, np.int64)
    si = np.zeros(n, np.int64) if search_index is None else np.asarray(search_index, np.int64)
    if not (
        np.all((ti >= 0) & (ti < tstack.shape[0])) and np.all((si >= 0) & (si < sstack.shape[0]))
    ):
        raise ValueError("template_index / search_index outside the image stacks")
    A = np.broadcast_to(
        np.eye(2) if affine is None else np.asarray(affine, float), (n, 2, 2)
    ).copy()
    if lines is not None:
        lines = (np.asarray(lines[0], float).reshape(n, 2), np.asarray(lines[1], float).reshape(n))
    opts = dict(
        half=half,
        upsample=upsample,
        tol_px=tol_px,
        max_iter=max_iter,
        max_shift_px=max_shift_px,
        max_sigma_px=max_sigma_px,
        min_texture=min_texture,
        sigma_line_px=sigma_line_px,
        sigma_grey=sigma_grey,
        weight_sigma=weight_sigma,
    )
    nw = _n_workers(workers, n)

    def part(k=slice(None)):
        args = (tstack, sstack, uv_t[k], uv_s0[k], ti[k], si[k])
        ln = None if lines is None else (lines[0][k], lines[1][k])
        try:
            return _match_part(*args, A[k].copy(), ln, **opts)
        except lsm_kernel.KernelError:  # compiling failed: the numpy path
            return _match_part(*args, A[k].copy(), ln, **opts)

    if nw <= 1:
        return part()

    with ThreadPoolExecutor(nw) as ex:
        res = list(ex.map(part, np.array_split(np.arange(n), nw)))
    return LSMResult(
        **{f.name: np.concatenate([getattr(r, f.name) for r in res]) for f in fields(LSMResult)}
    )


def _n_workers(workers: int, n: int) -> int:
    if workers:
        return max(1, min(int(workers), n))
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # not on every platform
        cores = os.cpu_count() or 1
    return max(1, min(cores, n // MIN_PATCHES_PER_WORKER))


def _match_part(
    tstack: ImageStack,
    sstack: ImageStack,
    uv_t,
    uv_s0,
    ti,
    si,
    A,
    lines,
    *,
    half,
    upsample,
    tol_px,
    max_iter,
    max_shift_px,
    max_sigma_px,
    min_texture,
    sigma_line_px,
    sigma_grey,
    weight_sigma,
) -> LSMResult:
    """:func:`match` of validated arrays (uv_t, uv_s0 (n, 2), ti, si (n,), A (n, 2, 2)
    owned here, lines None or (normal (n, 2), d (n,)))."""
    n = len(uv_t)
    status = np.full(n, Status.NOT_CONVERGED, dtype=np.int8)
    iters = np.zeros(n, np.int32)
    gain = np.ones(n)
    offset = np.zeros(n)
    sigma0 = np.full(n, np.nan)
    cov = np.full((n, 2, 2), np.nan)

    finite = (
        np.all(np.isfinite(uv_t), axis=1)
        & np.all(np.isfinite(uv_s0), axis=1)
        & np.all(np.isfinite(A), axis=(1, 2))
    )
    status[~finite] = Status.INVALID
    uv_t = np.where(finite[:, None], uv_t, 0.0)
    uv = np.where(finite[:, None], uv_s0, 0.0)
    A[~finite] = np.eye(2)
    t_in = tstack.inside(uv_t[:, 0], uv_t[:, 1], half + 1)
    status[finite & ~t_in] = Status.OUT_OF_IMAGE

    # Template, its gradients and texture (smaller eigenvalue of the structure tensor).
    kernel = lines is None and lsm_kernel.enabled()  # compiled steps (core.lsm_kernel)
    T, tx, ty = template_patches(
        tstack, np.where(t_in[:, None], uv_t, half + 1.0), half, ti, upsample, kernel
    )
    npx = T[0].size
    T = T.reshape(n, npx)
    gx = tx.reshape(n, npx)
    gy = ty.reshape(n, npx)
    t_mean, t_sd = row_mean_sd(T)
    t_sq = npx * (t_sd**2 + t_mean**2)  # Σ T²
    # Normal matrix of the inverse compositional step, inverted once per patch.
    xg, yg = _grid(half)
    xs = xg.ravel().astype(np.float32)
    ys = yg.ravel().astype(np.float32)
    basis = np.stack([np.ones_like(xs), xs, ys])  # (3, P)
    if weight_sigma is None:
        wpx = np.ones(npx, np.float32)
        Tw = T
    else:
        wpx = np.exp(-(xs * xs + ys * ys) / (2.0 * weight_sigma**2)).astype(np.float32)
        Tw = T * wpx
    # b = Jᵀ W e: (w gx e, w gy e, w e) against 1, x, y (three GEMVs, faster than a GEMM).
    basis_w = basis * wpx  # (3, P)
    if kernel:
        T, gx, gy = (np.ascontiguousarray(x) for x in (T, gx, gy))
        N = lsm_kernel.normal_matrices(T, gx, gy, wpx, xs, ys)
    else:
        N = normal_matrix(T, gx, gy, xs, ys, wpx)
    if weight_sigma is None:
        N2 = N
    elif kernel:
        N2 = lsm_kernel.normal_matrices(T, gx, gy, wpx * wpx, xs, ys)
    else:
        N2 = normal_matrix(T, gx, gy, xs, ys, wpx * wpx)
    sw = float(wpx.sum())
    # Texture: smaller eigenvalue of the (weighted) structure tensor, mean of ∇T ∇Tᵀ.
    sxx, syy, sxy = N[:, 0, 0] / sw, N[:, 3, 3] / sw, N[:, 0, 3] / sw
    lam_min = 0.5 * (sxx + syy) - np.sqrt(0.25 * (sxx - syy) ** 2 + sxy**2)
    texture = np.sqrt(np.maximum(lam_min, 0.0))
    status[finite & t_in & (texture < min_texture)] = Status.WEAK_TEXTURE
    if kernel:
        Ninv, pd = lsm_kernel.spd_inverses(N, status == Status.NOT_CONVERGED)
    else:
        N[status != Status.NOT_CONVERGED] = np.eye(8)
        Ninv, pd = spd_inverse(N)
    # Shifts and radiometry only in the first iteration (and until the shift settles
    # below 1 px, at most 3): the affine part of a far-off start would diverge.  The
    # first iteration of all patches (without a line constraint) uses every other
    # pixel in u and v, unweighted (a quarter of the samples; its step only brings the
    # patch near the match) and solves its 4 × 4 system in closed form.
    sub = [0, 3, 6, 7]
    shift_only = np.ones(n, bool)
    side = 2 * half + 1
    even = slice(half % 2, side, 2)  # even offsets x, y

    def coarse(X):
        return np.ascontiguousarray(X.reshape(-1, side, side)[:, even, even]).reshape(len(X), -1)

    basis_c = coarse(basis)
    w_c = np.ones(basis_c.shape[1], np.float32)
    T_c, gx_c, gy_c = coarse(T), coarse(gx), coarse(gy)
    mom_c = shift_moments(T_c, gx_c, gy_c, w_c)
    dof_c = len(w_c) - 4.0
    # Redundancy: tr W - tr(N⁻¹ JᵀW²J) (= n - u for uniform weights).
    if weight_sigma is None:
        dof = np.full(n, npx - 8.0)
    else:
        dof = float(np.sum(wpx)) - np.einsum("nij,nji->n", Ninv, N2)
    dof = dof + (lines is not None)
    status[(status == Status.NOT_CONVERGED) & ~pd] = Status.DEGENERATE

    if lines is not None:
        ln_n, ln_d = lines
        w_line = (sigma_grey / sigma_line_px) ** 2
    _, h_img, w_img = sstack.shape
    img_lo = np.array([1.0, 1.0])
    img_hi = np.array([w_img - 2.0, h_img - 2.0])
    fresh = np.ones(n, bool)  # radiometry not yet initialised
    it_left = np.full(n, max_iter, np.int64)
    uv_s0 = np.ascontiguousarray(uv_s0)

    todo = np.flatnonzero(status == Status.NOT_CONVERGED)
    while todo.size:
        # Search windows around the current positions: the patch footprint and
        # ``_DRIFT_PX`` of drift; patches that walk out of their window (within
        # max_shift_px) get a new one in the next round.
        reach = half * np.max(np.abs(A[todo]).sum(axis=2), axis=1) + _DRIFT_PX
        src = PatchSource(
            sstack,
            si[todo],
            uv[todo],
            reach,
            upsample,
            lsm_kernel.upsampled_windows if kernel else None,
        )
        f = src.f
        bases, w_lo, w_hi = np.stack([src.bu, src.bv]), src.lo, src.hi
        if kernel:
            rew = np.zeros(len(todo), bool)
            lsm_kernel.iterate_round(
                src.up,
                src.rows_per_chunk if not src._whole else 0,
                getattr(src, "size", 0),
                src.bu,
                src.bv,
                src.lo,
                src.hi,
                float(f),
                todo,
                T,
                gx,
                gy,
                wpx,
                xs,
                ys,
                T_c,
                gx_c,
                gy_c,
                basis_c[1],
                basis_c[2],
                mom_c,
                Ninv,
                N,
                pd,
                uv,
                A,
                gain,
                offset,
                fresh,
                shift_only,
                iters,
                it_left,
                sigma0,
                status,
                uv_s0,
                t_mean,
                t_sd,
                t_sq,
                dof,
                float(dof_c),
                float(tol_px),
                float(max_shift_px),
                float(half),
                float(img_hi[0]),
                float(img_hi[1]),
                weight_sigma is not None,
                rew,
            )
            todo = todo[rew]
            continue
        # Working set: the patches still iterating in this window round, with their
        # template arrays (compacted as patches finish).
        a, wrow = todo, np.arange(len(todo))
        if len(todo) == n:
            Ta, Twa, gxa, gya = T, Tw, gx, gy
        else:
            Ta, Twa, gxa, gya = T[todo], Tw[todo], gx[todo], gy[todo]
        rewindow = []
        while a.size:
            na = len(a)
            Aa = A[a]
            # Sampling positions in the source: one GEMM for u and v.
            # cv2.remap samples at positions rounded to 1/32 px of its source: the warp
            # is snapped to that grid (offset and slopes multiples of 1/32, so that
            # every sample position is exact in float32 and for cv2), and the update
            # below starts from the snapped warp actually sampled.
            so = shift_only[a]
            coarse = lines is None and so.all()
            base = bases[:, wrow]  # (2, n_a)
            M = np.empty((2, na, 3))  # [u; v] x (1, x, y)
            M[:, :, 0] = base + f * uv[a].T
            M[:, :, 1:] = f * Aa.transpose(1, 0, 2)
            M = np.rint(M * 32.0) * (1 / 32.0)
            uv_s = ((M[:, :, 0] - base) / f).T
            A_s = M[:, :, 1:].transpose(1, 0, 2) / f
            puv = M.reshape(2 * na, 3).astype(np.float32) @ (basis_c if coarse else basis)
            S = src.sample(puv[:na], puv[na:], wrow)  # (n_a, P or P/4)
            new = fresh[a]
            flat = np.zeros(na, bool)
            if new.any():
                # Radiometric start: match the mean and spread of the grey levels; a
                # flat search patch (no spread: the gain is undetermined) is rejected.
                k = a[new]
                s_mean, s_sd = row_mean_sd(S[new] if not new.all() else S)
                flat[new] = s_sd <= FLAT_SD
                g0 = np.where(s_sd > FLAT_SD, t_sd[k] / np.maximum(s_sd, FLAT_SD), 1.0)
                gain[k] = g0
                offset[k] = t_mean[k] - g0 * s_mean
                fresh[k] = False
            g_old, o_old = gain[a], offset[a]
            if coarse:
                rows = slice(None) if na == n else a
                dq, b, vv = coarse_shift_step(
                    S, g_old, o_old, T_c[rows], gx_c[rows], gy_c[rows], w_c, mom_c[rows]
                )
                dof_a = dof_c
            else:
                # Residuals e = r1 S + r0 - T; b = Jᵀ W e (n_a, 8) and vᵀWv.
                dof_a = dof[a]
                Q = np.empty((3, na, npx), np.float32)
                e = Q[2]
                np.multiply(S, gain[a, None].astype(np.float32), out=e)
                e += offset[a, None].astype(np.float32)
                e -= Ta
                np.multiply(gxa, e, out=Q[0])
                np.multiply(gya, e, out=Q[1])
                Q2 = Q.reshape(3 * na, npx)
                b = np.empty((na, 8))
                b[:, [0, 3, 6]] = (Q2 @ basis_w[0]).reshape(3, na).T
                b[:, 1] = Q2[:na] @ basis_w[1]
                b[:, 2] = Q2[:na] @ basis_w[2]
                b[:, 4] = Q2[na : 2 * na] @ basis_w[1]
                b[:, 5] = Q2[na : 2 * na] @ basis_w[2]
                b[:, 7] = np.einsum("np,np->n", Twa, e)
                ew = e if weight_sigma is None else e * wpx
                vv = np.einsum("np,np->n", ew, e).astype(np.float64)
                b67, vv0 = b[:, 6:8].copy(), vv
                Ninv_a = Ninv[a]
                if so.any():
                    # Still shift-only on the full grid: the 4 × 4 sub-block's inverse.
                    k = np.flatnonzero(so)
                    blk = np.zeros((len(k), 8, 8))
                    blk[:, np.ix_(sub, sub)[0], np.ix_(sub, sub)[1]] = inverse_blocks(
                        N[a[k]][:, sub][:, :, sub], pd[a[k]]
                    )
                    Ninv_a[k] = blk
                if lines is not None:
                    Ninv_a, jv, mis = line_update(Ninv_a, Aa, ln_n[a], ln_d[a], uv[a], w_line)
                    b = b + (w_line * mis)[:, None] * jv
                    vv = vv + w_line * mis * mis
                dq = np.einsum("nij,nj->ni", Ninv_a, b)
            ok_step = np.isfinite(dq).all(axis=1)
            dq[~ok_step] = 0.0
            # Compose W <- W ∘ ΔW⁻¹ with ΔW(x) = Δt + (I + ΔA) x; radiometry likewise.
            An, step = compose_inverse(A_s, dq)
            uv_new = uv_s - step
            change = uv_new - uv[a]  # of the estimate since the last iteration
            uv[a] = uv_new
            A[a] = An
            den = 1.0 + dq[:, 7]
            den = np.where(np.abs(den) > 1e-6, den, 1.0)
            gain[a] /= den
            offset[a] = (offset[a] - dq[:, 6]) / den
            iters[a] += 1
            it_left[a] -= 1
            # Precision from this linearisation: σ0² = vᵀv / (n - u), Σ = σ0² N⁻¹.
            vtv = vv - np.einsum("ni,ni->n", dq, b)
            sigma0[a] = np.sqrt(np.maximum(vtv, 0.0) / dof_a)

            conv = np.all(np.abs(change) < tol_px, axis=1) & ~so
            leave = so & (np.all(np.abs(change) < 1.0, axis=1) | (iters[a] >= 3))
            shift_only[a[leave]] = False
            drift = np.hypot(*(uv_new - uv_s0[a]).T) > max_shift_px
            # Footprint of the warped patch: half-extent per axis, pixels.
            ext = half * np.abs(An).sum(axis=2)
            e_lo, e_hi = uv_new - ext, uv_new + ext
            in_img = np.all((e_lo >= img_lo) & (e_hi <= img_hi), axis=1)
            in_win = np.all((e_lo >= w_lo[wrow]) & (e_hi <= w_hi[wrow]), axis=1)
            sc = np.abs(An[:, 0, 0] * An[:, 1, 1] - An[:, 0, 1] * An[:, 1, 0])
            g = gain[a]
            degen = ~ok_step | (sc < 0.25) | (sc > 4.0) | (g < 0.1) | (g > 10.0) | flat
            st = np.full(na, Status.NOT_CONVERGED, dtype=np.int8)
            st[conv] = Status.OK
            st[drift] = Status.OUT_OF_SEARCH
            st[degen] = Status.DEGENERATE
            st[~in_img] = Status.OUT_OF_IMAGE
            status[a] = st
            if conv.any():
                # Report the radiometry as the symmetric fit T ≈ r1 S + r0 (spread
                # ratio): the inverse compositional r1 regresses T on S, biased by noise.
                k = a[conv]
                if weight_sigma is None:
                    # Mean and spread of S = (e + T - r0) / r1 from Σe, ΣTe, Σe² (b, vv).
                    m_et = b67[conv, 0] / npx + t_mean[k]
                    v_et = (vv0[conv] + 2.0 * b67[conv, 1] + t_sq[k]) / npx - m_et**2
                    go = np.where(np.abs(g_old[conv]) > 1e-9, g_old[conv], 1e-9)
                    s_mean = (m_et - o_old[conv]) / go
                    s_sd = np.sqrt(np.maximum(v_et, 0.0)) / np.abs(go)
                else:
                    s_mean, s_sd = row_mean_sd(S[conv])
                g1 = np.where(s_sd > FLAT_SD, t_sd[k] / np.maximum(s_sd, FLAT_SD), gain[k])
                offset[k] = t_mean[k] - g1 * s_mean
                gain[k] = g1
            going = st == Status.NOT_CONVERGED
            left = it_left[a] > 0
            rewindow.append(a[going & ~in_win & left])
            keep = going & in_win & left
            if not keep.all():
                a, wrow = a[keep], wrow[keep]
                Ta, gxa, gya = Ta[keep], gxa[keep], gya[keep]
                Twa = Ta if weight_sigma is None else Twa[keep]
        todo = np.sort(np.concatenate(rewindow))

    # Covariance of the matched point: Σ = σ0² N⁻¹ (shifts), mapped by the affine part.
    done = np.flatnonzero(np.isfinite(sigma0))
    Nd = Ninv[done]
    if lines is not None and done.size:
        Nd, jv, _ = line_update(Nd, A[done], ln_n[done], ln_d[done], uv[done], w_line)
    if weight_sigma is not None and done.size:
        M2 = N2[done]
        if lines is not None:
            M2 = M2 + w_line * jv[:, :, None] * jv[:, None, :]
        Nd = Nd @ M2 @ Nd
    ct = Nd[:, [0, 3]][:, :, [0, 3]]
    Ad = A[done]
    # σ0 measures the noise of T plus that of the resampled S, which resampling has
    # reduced (averaged neighbours) without reducing its effect on the match.  With
    # equal noise in both images, the noise that enters the shifts is σ0² κ with
    # κ = (1 + r1²) / (1 + r1² ρ), ρ the mean variance factor of the resampling over
    # the patch at the match (:func:`resampling_noise_factor`).
    sub_grid = np.stack(np.meshgrid(*2 * [np.linspace(-half, half, 5)]), 0).reshape(2, -1)
    pos = uv[done, :, None] + Ad @ sub_grid  # (n_d, 2, 25): a 5 × 5 subgrid
    rho = resampling_noise_factor(pos[:, 0], pos[:, 1], upsample).mean(axis=1)
    g2 = gain[done] ** 2
    kappa = (1.0 + g2) / (1.0 + g2 * rho)
    cov[done] = (kappa * sigma0[done] ** 2)[:, None, None] * (Ad @ ct @ Ad.transpose(0, 2, 1))
    sig = np.sqrt(np.abs(np.diagonal(cov, axis1=1, axis2=2)))
    big = (status == Status.OK) & ~(np.all(sig <= max_sigma_px, axis=1))
    status[big] = Status.LARGE_SIGMA
    return LSMResult(
        uv=uv,
        affine=A,
        gain=gain,
        offset=offset,
        sigma0=sigma0,
        cov_uv=cov,
        iterations=iters,
        status=status,
        texture=texture,
    )


# -- geometric constraint -------------------------------------------------------------


def epipolar_lines(
    cam_template: Camera,
    cam_search: Camera,
    uv_template: np.ndarray,
    uv_near: np.ndarray,
    depth_range=(0.3, 30.0),
    n_samples: int = 256,
) -> tuple[np.ndarray, np.ndarray]:
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
    origin, ray = cam_template.rays(uv_template)  # (N, 3)
    s = np.geomspace(depth_range[0], depth_range[1], n_samples)
    xyz = origin + ray[:, None, :] * s[None, :, None]  # (N, S, 3)
    p = cam_search.project(xyz)  # (N, S, 2)
    dist = np.linalg.norm(p - uv_near[:, None], axis=2)
    dist = np.where(np.isfinite(dist), dist, np.inf)
    k = np.clip(np.argmin(dist, axis=1), 1, n_samples - 2)
    rows = np.arange(len(k))
    tangent = p[rows, k + 1] - p[rows, k - 1]
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    normal = np.stack([-tangent[:, 1], tangent[:, 0]], axis=1)
    d = np.einsum("ni,ni->n", normal, p[rows, k])
    return normal, d
