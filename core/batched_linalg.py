"""Batched linear algebra of many small symmetric systems (LSM normal matrices).

All functions take stacks ``(N, u, u)`` and work without a Python loop over N.
"""

from __future__ import annotations

import numpy as np


def cholesky_solve(N: np.ndarray, B: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
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
            low = N[:, j + 1 :, j] - np.einsum("nik,nk->ni", L[:, j + 1 :, :j], L[:, j, :j])
            L[:, j + 1 :, j] = low / d[:, None]
    y = np.empty_like(B)
    for j in range(k):
        y[:, j] = (B[:, j] - np.einsum("nk,nkm->nm", L[:, j, :j], y[:, :j])) / L[:, j, j, None]
    x = np.empty_like(B)
    for j in range(k - 1, -1, -1):
        x[:, j] = (y[:, j] - np.einsum("nk,nkm->nm", L[:, j + 1 :, j], x[:, j + 1 :])) / L[
            :, j, j, None
        ]
    return x, ok


def spd_inverse(N: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inverses of SPD matrices (n, k, k) and an ok flag (n,) (False: not PD / not finite).

    Unit-diagonal scaling, then LAPACK Cholesky for the whole batch; the column-wise
    :func:`cholesky_solve` takes over only when some matrix is not positive definite.
    """
    n, k, _ = N.shape
    ok = np.isfinite(N).all(axis=(1, 2))
    r = 1.0 / np.sqrt(np.maximum(np.einsum("nii->ni", N), 1e-30))
    r[~ok] = 1.0
    scale = r[:, :, None] @ r[:, None, :]  # (outer products: fast small loops)
    Ns = N * scale
    Ns[~ok] = np.eye(k)
    try:
        L = np.linalg.cholesky(Ns)
        Li = np.linalg.solve(L, np.broadcast_to(np.eye(k), N.shape)) if n < 64 else lower_inverse(L)
        inv = np.matmul(Li.transpose(0, 2, 1), Li)
        pd = np.all(np.einsum("nii->ni", L) > 1e-6, axis=1)
    except np.linalg.LinAlgError:
        inv, pd = cholesky_solve(Ns, np.broadcast_to(np.eye(k), N.shape).copy())
    ok &= pd
    return inv * scale, ok


def lower_inverse(L: np.ndarray) -> np.ndarray:
    """Inverses of lower triangular matrices (n, k, k) by forward substitution."""
    n, k, _ = L.shape
    X = np.zeros_like(L)
    for i in range(k):
        rhs = -(L[:, i : i + 1, :i] @ X[:, :i, :])[:, 0] if i else np.zeros((n, k))
        rhs[:, i] += 1.0
        X[:, i, :] = rhs / L[:, i, i, None]
    return X


# -- the matcher ----------------------------------------------------------------------


def line_update(
    Ninv: np.ndarray, A: np.ndarray, normal: np.ndarray, d: np.ndarray, uv: np.ndarray, w: float
):
    """Add the line pseudo-observation ``normal · (uv - A Δt) = d`` with weight ``w``.

    Its design row is ``j = -Aᵀ normal`` on the shift parameters (0 and 3); ``N⁻¹`` is
    updated by Sherman–Morrison.  Returns the new ``N⁻¹`` (n, 8, 8), ``j`` (n, 8) and
    the misclosure ``d - normal · uv`` (n,), pixels.
    """
    mis = d - np.einsum("ni,ni->n", normal, uv)
    jv = np.zeros((len(d), 8))
    jv[:, [0, 3]] = -np.einsum("nji,nj->ni", A, normal)
    Nj = np.einsum("nij,nj->ni", Ninv, jv)
    k = w / (1.0 + w * np.einsum("ni,ni->n", jv, Nj))
    return Ninv - k[:, None, None] * Nj[:, :, None] * Nj[:, None, :], jv, mis


# Moments basis: m_i m_j for m = (1, x, y) -> index into (1, x, y, x², xy, y²).
