"""The design of batched least squares matching: template slopes, normal matrices, warps.

Helpers of :func:`core.lsm.match` (inverse compositional LSM with 8 parameters
``a0, a1, a2, b0, b1, b2, r0, r1``): the cubic-spline slopes of template patches, the
normal matrix ``N = JᵀWJ`` of the design ``J = [gx·(1, x, y), gy·(1, x, y), 1, T]``
built from weighted moments with two GEMMs, the first iteration's shift-and-radiometry
step on a coarse pixel subset (closed-form 4 × 4 solve), small batched inverses, row
statistics and the composition of an affine warp with an inverse update.  All batched over
patches (leading axis ``n``); no Python loop over patches.
"""

from __future__ import annotations

import functools

import numpy as np

from .batched_linalg import spd_inverse
from .image_stack import ImageStack, PatchSource, _windows


def spline_derivative_taps(n: int = 4) -> np.ndarray:
    """Weights ``w_1 .. w_n`` of the cubic-spline derivative at a pixel:
    ``f'(m) = Σ_d w_d (f[m + d] - f[m - d])``.

    ``w_d = -η'(d)`` of the cardinal cubic spline ``η`` (pole ``z = √3 - 2``):
    ``(√3 / 2) (z^(d-1) - z^(d+1))``, truncated and scaled to an exact unit slope.
    Unlike central differences (which damp the slope of fine texture by up to 1/3
    and make the Gauss–Newton steps overshoot), this is the slope of the same
    spline interpolant that resamples the search patches.
    """
    z = np.sqrt(3.0) - 2.0
    d = np.arange(1, n + 1)
    w = 0.5 * np.sqrt(3.0) * (z ** (d - 1) - z ** (d + 1))
    return w / np.sum(2 * d * w)


#: Grey-level spread (standard deviation) below which a search patch counts as flat for
#: the radiometry: its gain is then not estimated from the spread (it stays 1 at the
#: start, unchanged at convergence).  Far above the rounding of the float32 row sums of
#: :func:`row_mean_sd` (up to ~0.03 grey levels on a flat patch of 169 pixels near 115),
#: so that the numpy and the compiled path (float64 sums) take the same decision.
FLAT_SD = 0.1

DERIV = spline_derivative_taps(4)
BORDER = len(DERIV)


@functools.lru_cache(maxsize=8)
def derivative_matrix(m: int) -> np.ndarray:
    """(m + 2B, m) float32: a row of m + 2B pixels @ it = the spline slopes of the
    central m."""
    D = np.zeros((m + 2 * BORDER, m), np.float32)
    c = np.arange(m)
    for d, wd in enumerate(DERIV, start=1):
        D[BORDER + c + d, c] = wd
        D[BORDER + c - d, c] = -wd
    return D


def template_slopes(P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cubic-spline slopes of patches with a border of ``BORDER`` px (one GEMM per axis):
    (n, s, s) -> 2 x (n, s - 2B, s - 2B) float32."""
    n, s, _ = P.shape
    m = s - 2 * BORDER
    rows = np.ascontiguousarray(P[:, BORDER : s - BORDER, :], dtype=np.float32).reshape(n * m, s)
    cols = np.ascontiguousarray(
        P.transpose(0, 2, 1)[:, BORDER : s - BORDER, :], dtype=np.float32
    ).reshape(n * m, s)
    return slopes_of_lines(rows, cols)


def slopes_of_lines(rows: np.ndarray, cols: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`template_slopes` from the central rows and columns of the patches: rows,
    cols (n m, s) float32, ``rows[k m + i]`` row ``B + i`` of patch k and ``cols[k m +
    j]`` its column ``B + j`` (s = m + 2B) -> gu, gv (n, m, m) float32."""
    m = rows.shape[1] - 2 * BORDER
    n = len(rows) // m
    D = derivative_matrix(m)
    gu = (rows @ D).reshape(n, m, m)
    gv = np.ascontiguousarray((cols @ D).reshape(n, m, m).transpose(0, 2, 1))
    return gu, gv


# -- linear algebra -------------------------------------------------------------------

_MOM = np.array([[0, 1, 2], [1, 3, 4], [2, 4, 5]])


def _normal_index():
    """Where the entries of N (8 × 8, flattened) come from in the packed moment sums."""
    # Packed sums (per patch): [0:6] gx² m6, [6:12] gx gy m6, [12:18] gy² m6,
    # [18:21] gx m3, [21:24] gy m3, [24:27] gx T m3, [27:30] gy T m3, [30] Σw, [31] ΣwT,
    # [32] ΣwT², with m6 = w (1, x, y, x², xy, y²) and m3 = w (1, x, y).
    src = np.empty((8, 8), np.int64)
    for i in range(3):
        for j in range(3):
            k = _MOM[i, j]
            src[i, j] = k
            src[i, 3 + j] = src[3 + j, i] = 6 + k
            src[3 + i, 3 + j] = 12 + k
        src[i, 6] = src[6, i] = 18 + i
        src[3 + i, 6] = src[6, 3 + i] = 21 + i
        src[i, 7] = src[7, i] = 24 + i
        src[3 + i, 7] = src[7, 3 + i] = 27 + i
    src[6, 6] = 30
    src[6, 7] = src[7, 6] = 31
    src[7, 7] = 32
    return src.ravel()


_N_SRC = _normal_index()


def normal_matrix(
    T: np.ndarray, gx: np.ndarray, gy: np.ndarray, xs: np.ndarray, ys: np.ndarray, w: np.ndarray
) -> np.ndarray:
    """``N = JᵀWJ`` (n, 8, 8) of the design ``J = [gx·(1, x, y), gy·(1, x, y), 1, T]``.

    Built from weighted moments with two GEMMs: T, gx, gy (n, P) float32; xs, ys (P,)
    the template pixel offsets; w (P,) the pixel weights.  Parameter order: a0, a1,
    a2, b0, b1, b2, r0, r1.  Sums in float32 over the P pixels, N in float64.
    """
    n, npx = T.shape
    # Moments (P, 8): w (1, x, y, x², xy, y²) and two zero columns (OpenBLAS runs
    # (M, K) @ (K, 8) about twice as fast as (M, K) @ (K, 6) or (K, 3)).
    m6 = np.zeros((npx, 8), np.float32)
    m6[:, :6] = np.stack([np.ones_like(xs), xs, ys, xs * xs, xs * ys, ys * ys], axis=1) * w[:, None]
    Q = np.empty((3, n, npx), np.float32)
    np.multiply(gx, gx, out=Q[0])
    np.multiply(gx, gy, out=Q[1])
    np.multiply(gy, gy, out=Q[2])
    R = np.empty((4, n, npx), np.float32)
    R[0] = gx
    R[1] = gy
    np.multiply(gx, T, out=R[2])
    np.multiply(gy, T, out=R[3])
    sums = np.empty((n, 33))
    sums[:, 0:18] = (
        (Q.reshape(3 * n, npx) @ m6).reshape(3, n, 8)[:, :, :6].transpose(1, 0, 2).reshape(n, 18)
    )
    sums[:, 18:30] = (
        (R.reshape(4 * n, npx) @ m6).reshape(4, n, 8)[:, :, :3].transpose(1, 0, 2).reshape(n, 12)
    )
    sums[:, 30] = float(np.sum(w))
    wT = T * w.astype(np.float32)
    sums[:, 31] = wT.sum(axis=1)
    sums[:, 32] = np.einsum("np,np->n", wT, T)
    return sums[:, _N_SRC].reshape(n, 8, 8)


# Shift-and-radiometry system of the first iteration: unknowns a0, b0, r0, r1, design
# (gx, gy, 1, T); its normal matrix as 10 weighted sums per patch, in this order.
SHIFT_MOMENTS = ("gx gx", "gx gy", "gy gy", "gx", "gy", "gx T", "gy T", "1", "T", "T T")


def shift_moments(T: np.ndarray, gx: np.ndarray, gy: np.ndarray, w: np.ndarray) -> np.ndarray:
    """The sums :data:`SHIFT_MOMENTS` ``Σ_p w_p (…)``, (n, 10) float64, of T, gx, gy
    (n, P) float32 with pixel weights w (P,) (GEMVs)."""
    n, npx = T.shape
    w = w.astype(np.float32)
    Q = np.empty((6, n, npx), np.float32)
    np.multiply(gx, gx, out=Q[0])
    np.multiply(gx, gy, out=Q[1])
    np.multiply(gy, gy, out=Q[2])
    np.multiply(gx, T, out=Q[3])
    np.multiply(gy, T, out=Q[4])
    np.multiply(T, T, out=Q[5])
    m = np.empty((n, 10))
    m[:, [0, 1, 2, 5, 6, 9]] = (Q.reshape(6 * n, npx) @ w).reshape(6, n).T
    m[:, 3] = gx @ w
    m[:, 4] = gy @ w
    m[:, 7] = float(w.sum())
    m[:, 8] = T @ w
    return m


def shift_moments_from_normal(N: np.ndarray) -> np.ndarray:
    """:func:`shift_moments` read from full normal matrices N (n, 8, 8)."""
    i = [0, 0, 3, 0, 3, 0, 3, 6, 6, 7]
    j = [0, 3, 3, 6, 6, 7, 7, 6, 7, 7]
    return N[:, i, j]


def solve_shift_radiometry(m: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Solve the 4 × 4 normal equations of (a0, b0, r0, r1) with moments m (n, 10)
    (:data:`SHIFT_MOMENTS`) and right-hand sides b (n, 4): (n, 4), NaN where singular.

    By 2 × 2 blocks (shift, radiometry): the radiometric block is eliminated and the
    shift solved from its Schur complement, all in closed form over the batch.
    """
    sxx, sxy, syy, sx1, sy1, sxt, syt, s11, s1t, stt = m.T
    with np.errstate(divide="ignore", invalid="ignore"):
        dc = s11 * stt - s1t * s1t  # det of the radiometric block
        c00, c01, c11 = stt / dc, -s1t / dc, s11 / dc  # its inverse
        # K = B C⁻¹ with B = [[sx1, sxt], [sy1, syt]] (rows: a0, b0).
        k00, k01 = sx1 * c00 + sxt * c01, sx1 * c01 + sxt * c11
        k10, k11 = sy1 * c00 + syt * c01, sy1 * c01 + syt * c11
        a00 = sxx - (k00 * sx1 + k01 * sxt)  # Schur complement A - K Bᵀ
        a01 = sxy - (k00 * sy1 + k01 * syt)
        a11 = syy - (k10 * sy1 + k11 * syt)
        r0 = b[:, 0] - (k00 * b[:, 2] + k01 * b[:, 3])
        r1 = b[:, 1] - (k10 * b[:, 2] + k11 * b[:, 3])
        da = a00 * a11 - a01 * a01
        du = (a11 * r0 - a01 * r1) / da
        dv = (a00 * r1 - a01 * r0) / da
        q0 = b[:, 2] - (sx1 * du + sy1 * dv)
        q1 = b[:, 3] - (sxt * du + syt * dv)
        out = np.stack([du, dv, c00 * q0 + c01 * q1, c01 * q0 + c11 * q1], axis=1)
    return np.where(np.isfinite(out), out, np.nan)


def coarse_shift_step(
    S: np.ndarray,
    gain: np.ndarray,
    offset: np.ndarray,
    T: np.ndarray,
    gx: np.ndarray,
    gy: np.ndarray,
    w: np.ndarray,
    mom: np.ndarray,
):
    """Shift-and-radiometry step of the first iteration on the coarse pixel subset.

    S, T, gx, gy (n_a, P') float32, w (P') weights, mom (n_a, 10) the subset's
    :func:`shift_moments`; gain, offset (n_a,) the radiometry.  Returns dq (n_a, 8)
    (zero for the affine parameters), b (n_a, 8) and vᵀWv (n_a,) as the full
    iteration does.
    """
    na = len(S)
    Q = np.empty((3, na, S.shape[1]), np.float32)
    e = Q[2]
    np.multiply(S, gain[:, None].astype(np.float32), out=e)
    e += offset[:, None].astype(np.float32)
    e -= T
    np.multiply(gx, e, out=Q[0])
    np.multiply(gy, e, out=Q[1])
    b = np.zeros((na, 8))
    b[:, [0, 3, 6]] = (Q.reshape(3 * na, -1) @ w).reshape(3, na).T
    ew = e * w
    b[:, 7] = np.einsum("np,np->n", ew, T)
    vv = np.einsum("np,np->n", ew, e).astype(np.float64)
    dq = np.zeros((na, 8))
    dq[:, [0, 3, 6, 7]] = solve_shift_radiometry(mom, b[:, [0, 3, 6, 7]])
    return dq, b, vv


def inverse_blocks(N: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """Inverses of the (n, k, k) sub-blocks of positive definite normal matrices (``ok``);
    identity where not ``ok``."""
    M = np.where(ok[:, None, None], N, np.eye(N.shape[1]))
    try:
        return np.linalg.inv(M)
    except np.linalg.LinAlgError:
        return spd_inverse(M)[0]


def row_mean_sd(S: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean and standard deviation of each row of S (n, P) float32, float64 (n,)."""
    p = S.shape[1]
    m = S.sum(axis=1).astype(np.float64) / p
    sq = np.einsum("np,np->n", S, S).astype(np.float64) / p
    return m, np.sqrt(np.maximum(sq - m * m, 0.0))


def compose_inverse(A: np.ndarray, dq: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``W ∘ ΔW⁻¹`` for the affine parts A (n, 2, 2) and updates dq (n, 8) (a0, a1, a2,
    b0, b1, b2, …): the new affine part and the shift step ``A ΔM⁻¹ Δt`` (n, 2)."""
    m00, m01, m10, m11 = 1 + dq[:, 1], dq[:, 2], dq[:, 4], 1 + dq[:, 5]
    dd = m00 * m11 - m01 * m10
    dd = np.where(np.abs(dd) > 1e-6, dd, 1.0)
    i00, i01, i10, i11 = m11 / dd, -m01 / dd, -m10 / dd, m00 / dd
    An = np.empty_like(A)
    An[:, 0, 0] = A[:, 0, 0] * i00 + A[:, 0, 1] * i10
    An[:, 0, 1] = A[:, 0, 0] * i01 + A[:, 0, 1] * i11
    An[:, 1, 0] = A[:, 1, 0] * i00 + A[:, 1, 1] * i10
    An[:, 1, 1] = A[:, 1, 0] * i01 + A[:, 1, 1] * i11
    step = np.stack(
        [
            An[:, 0, 0] * dq[:, 0] + An[:, 0, 1] * dq[:, 3],
            An[:, 1, 0] * dq[:, 0] + An[:, 1, 1] * dq[:, 3],
        ],
        axis=1,
    )
    return An, step


# -- template patches ---------------------------------------------------------------


def _grid(half: int, border: int = 0) -> tuple[np.ndarray, np.ndarray]:
    r = np.arange(-half - border, half + border + 1, dtype=np.float64)
    y, x = np.meshgrid(r, r, indexing="ij")
    return x, y


def template_patches(
    images, uv: np.ndarray, half: int = 6, index=None, upsample: bool = True, kernel: bool = False
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Patches around ``uv`` (N, 2), with their gradients.

    Integer centres are read directly (pixels beyond the image border repeat it);
    sub-pixel centres are resampled like the search patches of :func:`match`.
    Gradients are the cubic-spline slopes.  ``kernel``: read the windows and resample
    with the compiled steps of :mod:`core.lsm_kernel` (numba must be there; the same
    values).

    Returns
    -------
    patch, gu, gv : ndarray, shape (N, 2h+1, 2h+1), float32
        Grey levels (row = v) and their derivatives along u and v, per pixel.
    """
    stack = ImageStack(images)
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    n = len(uv)
    idx = np.zeros(n, np.int64) if index is None else np.asarray(index, np.int64)
    x, y = _grid(half, BORDER)
    c = np.rint(uv)
    frac = uv - c
    if kernel:
        from .lsm_kernel import template_lines, upsampled_windows
    else:
        upsampled_windows = None
    if np.all(np.abs(frac) < 1e-9):
        ci = c.astype(np.int64) - half - BORDER
        if kernel:
            T, rows, cols = template_lines(stack, idx, ci[:, 0], ci[:, 1], half, BORDER)
            return (T, *slopes_of_lines(rows, cols))
        P = _windows(stack, idx, ci[:, 0], ci[:, 1], 2 * (half + BORDER) + 1)
    else:
        src = PatchSource(stack, idx, uv, half + BORDER + 1, upsample, upsampled_windows)
        pu = (src.bu[:, None, None] + src.f * (uv[:, 0, None, None] + x)).astype(np.float32)
        pv = (src.bv[:, None, None] + src.f * (uv[:, 1, None, None] + y)).astype(np.float32)
        s = pu.shape
        P = src.sample(pu.reshape(n, -1), pv.reshape(n, -1)).reshape(s)
        du = (pu - np.rint(pu * 32.0) * (1 / 32.0)) * (1.0 / src.f)
        dv = (pv - np.rint(pv * 32.0) * (1 / 32.0)) * (1.0 / src.f)
        gu, gv = template_slopes(P)
        P = P.copy()
        b = BORDER
        P[:, b:-b, b:-b] += gu * du.reshape(s)[:, b:-b, b:-b] + gv * dv.reshape(s)[:, b:-b, b:-b]
    gu, gv = template_slopes(P)
    b = BORDER
    return P[:, b:-b, b:-b], gu, gv
