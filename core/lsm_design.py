"""The design of batched least squares matching: template slopes, normal matrices, warps.

Helpers of :func:`core.lsm.match` (inverse compositional LSM with 8 parameters
``a0, a1, a2, b0, b1, b2, r0, r1``): the cubic-spline slopes of template patches, the
normal matrix ``N = JᵀWJ`` of the design ``J = [gx·(1, x, y), gy·(1, x, y), 1, T]``
built from weighted moments with one GEMM, small batched inverses, row statistics
and the composition of an affine warp with an inverse update.  All batched over
patches (leading axis ``n``); no Python loop over patches.
"""

from __future__ import annotations

import functools

import numpy as np

from .batched_linalg import spd_inverse


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
    D = derivative_matrix(m)
    rows = np.ascontiguousarray(P[:, BORDER:s - BORDER, :], dtype=np.float32).reshape(n * m, s)
    gu = (rows @ D).reshape(n, m, m)
    cols = np.ascontiguousarray(P.transpose(0, 2, 1)[:, BORDER:s - BORDER, :],
                                dtype=np.float32).reshape(n * m, s)
    gv = np.ascontiguousarray((cols @ D).reshape(n, m, m).transpose(0, 2, 1))
    return gu, gv


# -- linear algebra -------------------------------------------------------------------

_MOM = np.array([[0, 1, 2], [1, 3, 4], [2, 4, 5]])


def normal_matrix(T: np.ndarray, gx: np.ndarray, gy: np.ndarray, xs: np.ndarray,
                   ys: np.ndarray, w: np.ndarray) -> np.ndarray:
    """``N = JᵀWJ`` (n, 8, 8) of the design ``J = [gx·(1, x, y), gy·(1, x, y), 1, T]``.

    Built from weighted moments with one GEMM: T, gx, gy (n, P) float32; xs, ys (P,)
    the template pixel offsets; w (P,) the pixel weights.  Parameter order: a0, a1,
    a2, b0, b1, b2, r0, r1.
    """
    n, npx = T.shape
    basis = np.stack([np.ones_like(xs), xs, ys, xs * xs, xs * ys, ys * ys], axis=1)  # (P, 6)
    basis = (basis * w[:, None]).astype(np.float32)
    Q = np.empty((9, n, npx), np.float32)
    np.multiply(gx, gx, out=Q[0])
    np.multiply(gx, gy, out=Q[1])
    np.multiply(gy, gy, out=Q[2])
    Q[3] = gx
    Q[4] = gy
    np.multiply(gx, T, out=Q[5])
    np.multiply(gy, T, out=Q[6])
    Q[7] = T
    np.multiply(T, T, out=Q[8])
    M = (Q.reshape(9 * n, npx) @ basis).reshape(9, n, 6).astype(np.float64)
    N = np.empty((n, 8, 8))
    for i in range(3):
        for j in range(3):
            k = _MOM[i, j]
            N[:, i, j] = M[0, :, k]
            N[:, i, 3 + j] = N[:, 3 + j, i] = M[1, :, k]
            N[:, 3 + i, 3 + j] = M[2, :, k]
        N[:, i, 6] = N[:, 6, i] = M[3, :, i]
        N[:, 3 + i, 6] = N[:, 6, 3 + i] = M[4, :, i]
        N[:, i, 7] = N[:, 7, i] = M[5, :, i]
        N[:, 3 + i, 7] = N[:, 7, 3 + i] = M[6, :, i]
    N[:, 6, 6] = float(np.sum(w))
    N[:, 6, 7] = N[:, 7, 6] = M[7, :, 0]
    N[:, 7, 7] = M[8, :, 0]
    return N

def normal_matrix_from_design(gx: np.ndarray, gy: np.ndarray, T: np.ndarray, Jw: np.ndarray,
                               xs: np.ndarray, ys: np.ndarray, w: np.ndarray) -> np.ndarray:
    """``N = JᵀWJ`` (n, 8, 8) as :func:`normal_matrix`, reusing the weighted design
    rows ``Jw`` (n, 8, P): the columns of the offset and gain are ``Jw 1`` and ``Jw T``,
    and only the 6 × 6 geometric block needs moments of ``∇T ∇Tᵀ`` (one GEMM)."""
    n, npx = T.shape
    basis = np.stack([np.ones_like(xs), xs, ys, xs * xs, xs * ys, ys * ys], axis=1)  # (P, 6)
    basis = (basis * w[:, None]).astype(np.float32)
    Q = np.empty((3, n, npx), np.float32)
    np.multiply(gx, gx, out=Q[0])
    np.multiply(gx, gy, out=Q[1])
    np.multiply(gy, gy, out=Q[2])
    M = (Q.reshape(3 * n, npx) @ basis).reshape(3, n, 6).astype(np.float64)
    N = np.empty((n, 8, 8))
    for i in range(3):
        for j in range(3):
            k = _MOM[i, j]
            N[:, i, j] = M[0, :, k]
            N[:, i, 3 + j] = N[:, 3 + j, i] = M[1, :, k]
            N[:, 3 + i, 3 + j] = M[2, :, k]
    c67 = (Jw @ np.stack([np.ones_like(T), T], axis=2)).astype(np.float64)  # Σ w J_i (1, T)
    N[:, :, 6] = N[:, 6, :] = c67[:, :, 0]
    N[:, :, 7] = N[:, 7, :] = c67[:, :, 1]
    return N


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
    step = np.stack([An[:, 0, 0] * dq[:, 0] + An[:, 0, 1] * dq[:, 3],
                     An[:, 1, 0] * dq[:, 0] + An[:, 1, 1] * dq[:, 3]], axis=1)
    return An, step
