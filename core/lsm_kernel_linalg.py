"""Compiled (numba) small linear algebra of :mod:`core.lsm_kernel`: normal matrices from
moment sums, SPD inverses, the closed-form shift-and-radiometry solve; per patch.

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


@jit()
def _spd_inverse1(N, Ninv, L):
    """Inverse of one SPD matrix (k, k) into Ninv by unit-diagonal scaling and
    Cholesky; False (and Ninv = I) when not finite or not positive definite."""
    k = N.shape[0]
    r = np.empty(k)
    for i in range(k):
        for j in range(k):
            if not np.isfinite(N[i, j]):
                _eye(Ninv)
                return False
        r[i] = 1.0 / np.sqrt(max(N[i, i], 1e-30))
    for j in range(k):
        s = N[j, j] * r[j] * r[j]
        for m in range(j):
            s -= L[j, m] * L[j, m]
        if not s > 1e-12:
            _eye(Ninv)
            return False
        d = np.sqrt(s)
        L[j, j] = d
        for i in range(j + 1, k):
            t = N[i, j] * r[i] * r[j]
            for m in range(j):
                t -= L[i, m] * L[j, m]
            L[i, j] = t / d
    # X = L⁻¹ (lower), then N⁻¹ = r Xᵀ X r.
    X = np.zeros((k, k))
    for i in range(k):
        X[i, i] = 1.0 / L[i, i]
        for j in range(i):
            t = 0.0
            for m in range(j, i):
                t += L[i, m] * X[m, j]
            X[i, j] = -t / L[i, i]
    for i in range(k):
        for j in range(i, k):
            t = 0.0
            for m in range(j, k):
                t += X[m, i] * X[m, j]
            Ninv[i, j] = Ninv[j, i] = t * r[i] * r[j]
    return True


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
def _moments(T, gx, gy, w, xs, ys, mom):
    """The 33 packed moment sums of :func:`core.lsm_design._normal_index` of one patch."""
    a = np.zeros(9)
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
    for k in range(T.shape[0]):
        _moments(T[k], gx[k], gy[k], w, xs, ys, mom)
        for i in range(8):
            for j in range(8):
                N[k, i, j] = mom[_N_SRC[i * 8 + j]]


@jit()
def _spd_inverses(N, use, Ninv, pd):
    """Inverses and flags as :func:`core.batched_linalg.spd_inverse` (unit-diagonal
    scaling, Cholesky; ``pd`` False and ``Ninv`` = I where not positive definite);
    rows not in ``use`` become N = Ninv = I (pd True), as :mod:`core.lsm` sets them."""
    L = np.empty((8, 8))
    for k in range(N.shape[0]):
        if use[k]:
            pd[k] = _spd_inverse1(N[k], Ninv[k], L)
        else:
            _eye(N[k])
            _eye(Ninv[k])
            pd[k] = True


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
