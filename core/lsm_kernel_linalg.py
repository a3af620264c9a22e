"""Compiled (numba) small linear algebra of :mod:`core.lsm_kernel`: normal matrices from
moment sums, SPD inverses, the closed-form shift-and-radiometry solve; per patch (the
inverses :data:`_LANES` patches side by side, each with the operations of its own).

The same algebra as :mod:`core.lsm_design` and :mod:`core.batched_linalg` (sums in
float64 here); plain Python functions where numba is missing (never called then).
"""

from __future__ import annotations

import numpy as np

from .lsm_design import _N_SRC
from .lsm_kernel_jit import jit


@jit()
def _eye(M):
    for i in range(M.shape[0]):
        for j in range(M.shape[1]):
            M[i, j] = 1.0 if i == j else 0.0


#: Matrices that :func:`_spd_inverses` inverts side by side (the lanes of its vector loops).
_LANES = 8


@jit()
def _spd_inverse_lanes(A, Ainv, ok, r, L, X, s, t):
    """Inverses of ``_LANES`` SPD matrices side by side by unit-diagonal scaling and Cholesky.

    A (k, k, B) holds matrix q in ``A[:, :, q]`` (B = ``_LANES``); its inverse goes to
    ``Ainv[:, :, q]`` and ``ok[q]`` (B,) says whether it was finite and positive
    definite.  Every step runs over the B lanes in an inner loop (vectorised), the
    operations and their order per matrix those of a scalar Cholesky, so a lane's
    values do not depend on the others.  A lane that fails continues with a unit pivot
    (no division by zero); its result is meaningless.  Work arrays: r, s, t (k, B), L,
    X (k, k, B), float64.
    """
    k = A.shape[0]
    for q in range(_LANES):
        ok[q] = True
    for i in range(k):
        for j in range(k):
            for q in range(_LANES):
                ok[q] = ok[q] and np.isfinite(A[i, j, q])
        for q in range(_LANES):
            r[i, q] = 1.0 / np.sqrt(max(A[i, i, q], 1e-30))
    for j in range(k):
        for q in range(_LANES):
            s[j, q] = A[j, j, q] * r[j, q] * r[j, q]
        for m in range(j):
            for q in range(_LANES):
                s[j, q] -= L[j, m, q] * L[j, m, q]
        for q in range(_LANES):
            pivot = s[j, q] > 1e-12
            ok[q] = ok[q] and pivot
            L[j, j, q] = np.sqrt(s[j, q] if pivot else 1.0)
        for i in range(j + 1, k):
            for q in range(_LANES):
                t[i, q] = A[i, j, q] * r[i, q] * r[j, q]
            for m in range(j):
                for q in range(_LANES):
                    t[i, q] -= L[i, m, q] * L[j, m, q]
            for q in range(_LANES):
                L[i, j, q] = t[i, q] / L[j, j, q]
    # X = L⁻¹ (lower), then A⁻¹ = r Xᵀ X r.
    for i in range(k):
        for q in range(_LANES):
            X[i, i, q] = 1.0 / L[i, i, q]
        for j in range(i):
            for q in range(_LANES):
                t[j, q] = 0.0
            for m in range(j, i):
                for q in range(_LANES):
                    t[j, q] += L[i, m, q] * X[m, j, q]
            for q in range(_LANES):
                X[i, j, q] = -t[j, q] / L[i, i, q]
    for i in range(k):
        for j in range(i, k):
            for q in range(_LANES):
                t[j, q] = 0.0
            for m in range(j, k):
                for q in range(_LANES):
                    t[j, q] += X[m, i, q] * X[m, j, q]
            for q in range(_LANES):
                Ainv[i, j, q] = Ainv[j, i, q] = t[j, q] * r[i, q] * r[j, q]


@jit(fastmath={"reassoc"})
def _moments6(f, g, w, xs, ys, a):
    """``Σ w f g (1, x, y, x², xy, y²)`` into a[:6]."""
    a0 = a1 = a2 = a3 = a4 = a5 = 0.0
    for j in range(f.size):
        x = xs[j]
        y = ys[j]
        q = f[j] * g[j] * w[j]
        a0 += q
        a1 += q * x
        a2 += q * y
        a3 += q * x * x
        a4 += q * x * y
        a5 += q * y * y
    a[0], a[1], a[2], a[3], a[4], a[5] = a0, a1, a2, a3, a4, a5


@jit(fastmath={"reassoc"})
def _moments3(f, g, w, xs, ys, a):
    """``Σ w f (1, x, y)`` into a[:3] and ``Σ w g (1, x, y)`` into a[3:6]."""
    a0 = a1 = a2 = a3 = a4 = a5 = 0.0
    for j in range(f.size):
        p = f[j] * w[j]
        q = g[j] * w[j]
        a0 += p
        a1 += p * xs[j]
        a2 += p * ys[j]
        a3 += q
        a4 += q * xs[j]
        a5 += q * ys[j]
    a[0], a[1], a[2], a[3], a[4], a[5] = a0, a1, a2, a3, a4, a5


@jit(fastmath={"reassoc"})
def _moments3T(f, g, T, w, xs, ys, a):
    """:func:`_moments3` of ``f T`` and ``g T``."""
    a0 = a1 = a2 = a3 = a4 = a5 = 0.0
    for j in range(f.size):
        p = f[j] * T[j] * w[j]
        q = g[j] * T[j] * w[j]
        a0 += p
        a1 += p * xs[j]
        a2 += p * ys[j]
        a3 += q
        a4 += q * xs[j]
        a5 += q * ys[j]
    a[0], a[1], a[2], a[3], a[4], a[5] = a0, a1, a2, a3, a4, a5


@jit(fastmath={"reassoc"})
def _moments(T, gx, gy, w, xs, ys, mom, a):
    """The 33 packed moment sums of :func:`core.lsm_design._normal_index` of one patch
    (a: work array (6,) float64)."""
    for i in range(6):
        a[i] = 0.0
    for j in range(T.size):
        x = xs[j]
        y = ys[j]
        q = gx[j] * gx[j] * w[j]
        a[0] += q
        a[1] += q * x
        a[2] += q * y
        a[3] += q * x * x
        a[4] += q * x * y
        a[5] += q * y * y
    for i in range(6):
        mom[i] = a[i]
    _moments6(gx, gy, w, xs, ys, a)
    for i in range(6):
        mom[6 + i] = a[i]
    _moments6(gy, gy, w, xs, ys, a)
    for i in range(6):
        mom[12 + i] = a[i]
    _moments3(gx, gy, w, xs, ys, a)
    mom[18], mom[19], mom[20], mom[21], mom[22], mom[23] = a[0], a[1], a[2], a[3], a[4], a[5]
    _moments3T(gx, gy, T, w, xs, ys, a)
    for i in range(6):
        mom[24 + i] = a[i]
    s0 = s1 = s2 = 0.0
    for j in range(T.size):
        wt = T[j] * w[j]
        s0 += w[j]
        s1 += wt
        s2 += wt * T[j]
    mom[30], mom[31], mom[32] = s0, s1, s2


@jit()
def _normal_matrices(T, gx, gy, w, xs, ys, N):
    """Normal matrices ``N = JᵀWJ`` (n, 8, 8) of the design ``[gx (1, x, y), gy (1, x, y),
    1, T]``, as :func:`core.lsm_design.normal_matrix` (sums in float64 here)."""
    mom = np.empty(33)
    a = np.empty(6)
    for k in range(T.shape[0]):
        _moments(T[k], gx[k], gy[k], w, xs, ys, mom, a)
        for i in range(8):
            for j in range(8):
                N[k, i, j] = mom[_N_SRC[i * 8 + j]]


@jit()
def _spd_inverses(N, use, Ninv, pd):
    """Inverses and flags as :func:`core.batched_linalg.spd_inverse` (unit-diagonal
    scaling, Cholesky; ``pd`` False and ``Ninv`` = I where not positive definite);
    rows not in ``use`` become N = Ninv = I (pd True), as :mod:`core.lsm` sets them.
    ``_LANES`` matrices at a time (:func:`_spd_inverse_lanes`)."""
    n, k, _ = N.shape
    A = np.empty((k, k, _LANES))
    Ainv = np.empty((k, k, _LANES))
    ok = np.empty(_LANES, np.bool_)
    r = np.empty((k, _LANES))
    L = np.empty((k, k, _LANES))
    X = np.empty((k, k, _LANES))
    s = np.empty((k, _LANES))
    t = np.empty((k, _LANES))
    for k0 in range(0, n, _LANES):
        nb = min(_LANES, n - k0)
        for q in range(_LANES):
            live = q < nb and use[k0 + q]
            for i in range(k):
                for j in range(k):
                    A[i, j, q] = N[k0 + q, i, j] if live else (1.0 if i == j else 0.0)
        _spd_inverse_lanes(A, Ainv, ok, r, L, X, s, t)
        for q in range(nb):
            c = k0 + q
            if not use[c]:
                _eye(N[c])
                _eye(Ninv[c])
                pd[c] = True
            elif ok[q]:
                for i in range(k):
                    for j in range(k):
                        Ninv[c, i, j] = Ainv[i, j, q]
                pd[c] = True
            else:
                _eye(Ninv[c])
                pd[c] = False


@jit()
def _solve4(m, b0, b1, b2, b3, out):
    """Closed-form solve of the shift-and-radiometry system (moments m (10,), see
    :func:`core.lsm_design.solve_shift_radiometry`); writes (du, dv, dr0, dr1) to out,
    NaN when singular."""
    sxx, sxy, syy, sx1, sy1, sxt, syt, s11, s1t, stt = (
        m[0],
        m[1],
        m[2],
        m[3],
        m[4],
        m[5],
        m[6],
        m[7],
        m[8],
        m[9],
    )
    dc = s11 * stt - s1t * s1t
    if dc == 0.0:
        out[:] = np.nan
        return
    c00, c01, c11 = stt / dc, -s1t / dc, s11 / dc
    k00, k01 = sx1 * c00 + sxt * c01, sx1 * c01 + sxt * c11
    k10, k11 = sy1 * c00 + syt * c01, sy1 * c01 + syt * c11
    a00 = sxx - (k00 * sx1 + k01 * sxt)
    a01 = sxy - (k00 * sy1 + k01 * syt)
    a11 = syy - (k10 * sy1 + k11 * syt)
    r0 = b0 - (k00 * b2 + k01 * b3)
    r1 = b1 - (k10 * b2 + k11 * b3)
    da = a00 * a11 - a01 * a01
    if da == 0.0:
        out[:] = np.nan
        return
    du = (a11 * r0 - a01 * r1) / da
    dv = (a00 * r1 - a01 * r0) / da
    q0 = b2 - (sx1 * du + sy1 * dv)
    q1 = b3 - (sxt * du + syt * dv)
    out[0] = du
    out[1] = dv
    out[2] = c00 * q0 + c01 * q1
    out[3] = c01 * q0 + c11 * q1
    for i in range(4):
        if not np.isfinite(out[i]):
            out[i] = np.nan


@jit()
def _inv4(M, out):
    """Inverse of a 4 × 4 matrix by Gauss–Jordan with partial pivoting; False if singular."""
    a = np.empty((4, 8))
    for i in range(4):
        for j in range(4):
            a[i, j] = M[i, j]
            a[i, 4 + j] = 1.0 if i == j else 0.0
    for c in range(4):
        p = c
        for r in range(c + 1, 4):
            if abs(a[r, c]) > abs(a[p, c]):
                p = r
        if a[p, c] == 0.0:
            return False
        if p != c:
            for j in range(8):
                a[c, j], a[p, j] = a[p, j], a[c, j]
        d = a[c, c]
        for j in range(8):
            a[c, j] /= d
        for r in range(4):
            if r != c:
                fct = a[r, c]
                for j in range(8):
                    a[r, j] -= fct * a[c, j]
    for i in range(4):
        for j in range(4):
            out[i, j] = a[i, 4 + j]
    return True
