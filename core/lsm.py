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

Where numba is installed, the normal matrices, their inverses, the template and the
upsampled search windows and the iterations run compiled (:mod:`core.lsm_kernel`, same
rules; ~2.3× the matches per CPU second).  Without numba (Blender), with
``SOMACAP_NO_NUMBA=1``, with a line constraint, or when compiling fails, this numpy
path runs: same statuses and iterations, positions to ~1e-6 px.

Optional geometric constraint (multi-photo geometrically constrained matching):
the matched point must lie on a given line ``n · uv = d`` in the search image (the
local epipolar line from the calibration, see :func:`epipolar_lines`), added as a
pseudo-observation with standard deviation ``sigma_line_px`` (a rank-one update of
``N⁻¹`` per iteration).

:func:`match` validates its input and splits the patches over threads; the iterations
of each part are :func:`core.lsm_solve._match_part`, the statuses and the result
arrays :class:`core.lsm_result.Status` and :class:`core.lsm_result.LSMResult`
(re-exported here).
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import fields

import numpy as np

from . import lsm_kernel
from .blas_threads import single_blas_thread
from .camera import Camera
from .image_stack import ImageStack, upsample2
from .lsm_design import template_patches
from .lsm_result import LSMResult, Status
from .lsm_solve import _match_part

__all__ = [
    "ImageStack",
    "LSMResult",
    "Status",
    "epipolar_lines",
    "match",
    "template_patches",
    "upsample2",
]


#: ``match(workers=0)`` splits its patches over threads only in parts of at least this many.
MIN_PATCHES_PER_WORKER = 512


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
