"""Compiled (numba) attractor terms and pose Jacobians of :mod:`core.attractor`; optional.

Every Gauss–Newton evaluation of the fit computes, for each of a frame's few thousand
points and its K ≈ 18 member metaballs, the log field and its gradient
(:func:`core.attractor.attractor`) and the derivatives of ``L`` with respect to the
joint angles and scale coefficients (:func:`core.attractor.attractor_jacobians`).  In
numpy those gather (N, K, 3, 3) rotations and build (N, n, 3) and (N, 3K, G)
temporaries; they were a quarter of the fit's time on the default scene.  Here one
loop per point keeps its K terms and accumulates each member's ``p_m ∇(−2 d_m)`` onto
the joints above the member's bone.  Same formulas, sums in a different order: the
results agree with numpy to ~1e-12 relative.

Runs where :func:`core.field_kernel.enabled` (numba imported, no failed compile,
``SOMACAP_NO_NUMBA`` unset); :mod:`core.attractor` keeps the numpy path otherwise.
"""

from __future__ import annotations

import numpy as np

from .lsm_kernel_jit import jit


@jit()
def attractor_terms(
    x, idx, valid, Rw, cw, radii, g_min, LN_T, L, grad, p, y, q, gx, dist, inv_g
):  # pragma: no cover - compiled
    """Fill the arrays of :class:`core.attractor.Attractor` (shapes as there)."""
    N, K = idx.shape
    a = np.empty(K)
    for n in range(N):
        top = -np.inf
        for j in range(K):
            m = idx[n, j]
            d0 = x[n, 0] - cw[m, 0]
            d1 = x[n, 1] - cw[m, 1]
            d2 = x[n, 2] - cw[m, 2]
            for k in range(3):
                yk = d0 * Rw[m, 0, k] + d1 * Rw[m, 1, k] + d2 * Rw[m, 2, k]
                y[n, j, k] = yk
                q[n, j, k] = yk / radii[m, k] ** 2
            for i in range(3):
                gx[n, j, i] = -4.0 * (
                    Rw[m, i, 0] * q[n, j, 0] + Rw[m, i, 1] * q[n, j, 1] + Rw[m, i, 2] * q[n, j, 2]
                )
            if valid[n, j]:
                a[j] = -2.0 * (
                    y[n, j, 0] * q[n, j, 0] + y[n, j, 1] * q[n, j, 1] + y[n, j, 2] * q[n, j, 2]
                )
                if a[j] > top:
                    top = a[j]
            else:
                a[j] = -np.inf
        top_f = top if np.isfinite(top) else 0.0
        tot = 0.0
        for j in range(K):
            p[n, j] = np.exp(a[j] - top_f)
            tot += p[n, j]
        den = max(tot, 1e-300)
        g0 = g1 = g2 = 0.0
        for j in range(K):
            p[n, j] = p[n, j] / den
            g0 += p[n, j] * gx[n, j, 0]
            g1 += p[n, j] * gx[n, j, 1]
            g2 += p[n, j] * gx[n, j, 2]
        grad[n, 0], grad[n, 1], grad[n, 2] = g0, g1, g2
        inv_g[n] = 1.0 / max(np.sqrt(g0 * g0 + g1 * g1 + g2 * g2), g_min)
        if np.isfinite(top) and tot > 0.0:
            L[n] = top_f + np.log(tot)
            dist[n] = (L[n] - LN_T) * inv_g[n]
        else:
            L[n] = -np.inf
            dist[n] = -np.inf


@jit()
def pose_jacobians(
    x, idx, p, gx, ball_anc, axes, pivots, dc, J_theta, J_s
):  # pragma: no cover - compiled
    """Fill ``J_theta`` (N, n) and ``J_s`` (N, G) of :func:`core.attractor.attractor_jacobians`.

    ``ball_anc`` (M, n) bool: DOF k moves metaball m; ``axes``, ``pivots`` (n, 3) the
    DOFs' world axes and points; ``dc`` (M, 3, G) the metaball centres' derivatives by
    the scale coefficients.
    """
    N, K = idx.shape
    n_dof = axes.shape[0]
    G = np.empty((n_dof, 3))
    for n in range(N):
        G[:] = 0.0
        for g in range(J_s.shape[1]):
            J_s[n, g] = 0.0
        for j in range(K):
            m = idx[n, j]
            pg0 = p[n, j] * gx[n, j, 0]
            pg1 = p[n, j] * gx[n, j, 1]
            pg2 = p[n, j] * gx[n, j, 2]
            for k in range(n_dof):
                if ball_anc[m, k]:
                    G[k, 0] += pg0
                    G[k, 1] += pg1
                    G[k, 2] += pg2
            for g in range(J_s.shape[1]):
                J_s[n, g] -= pg0 * dc[m, 0, g] + pg1 * dc[m, 1, g] + pg2 * dc[m, 2, g]
        for k in range(n_dof):
            d0 = x[n, 0] - pivots[k, 0]
            d1 = x[n, 1] - pivots[k, 1]
            d2 = x[n, 2] - pivots[k, 2]
            w0, w1, w2 = axes[k, 0], axes[k, 1], axes[k, 2]
            J_theta[n, k] = -(
                G[k, 0] * (w1 * d2 - w2 * d1)
                + G[k, 1] * (w2 * d0 - w0 * d2)
                + G[k, 2] * (w0 * d1 - w1 * d0)
            )


@jit()
def shape_jacobians(
    idx, p, y, q, rot, radii, scale, J_radii, J_centres
):  # pragma: no cover - compiled
    """Fill ``J_radii`` and ``J_centres`` (N, K, 3) of
    :func:`core.attractor.attractor_jacobians` (``rot`` (M, 3, 3) the metaballs' rest
    rotations, ``scale`` (M,) their scale coefficients)."""
    N, K = idx.shape
    for n in range(N):
        for j in range(K):
            m = idx[n, j]
            for k in range(3):
                J_radii[n, j, k] = 4.0 * p[n, j] * y[n, j, k] ** 2 / radii[m, k] ** 3
            c = 4.0 * (p[n, j] * scale[m])
            for i in range(3):
                J_centres[n, j, i] = c * (
                    rot[m, i, 0] * q[n, j, 0]
                    + rot[m, i, 1] * q[n, j, 1]
                    + rot[m, i, 2] * q[n, j, 2]
                )
