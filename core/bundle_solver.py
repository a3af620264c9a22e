"""Levenberg–Marquardt for the wand bundle adjustment, target blocks eliminated.

The normal equations of :class:`core.bundle._Problem` have a dense camera block and one
6×6 block per wand location (both targets, coupled by the bar-length condition); the
solver eliminates the location blocks through the Schur complement, so each step
solves a system of the camera unknowns only.  ``solver="scipy:analytic"`` or
``"scipy:sparsity"`` runs :func:`scipy.optimize.least_squares` (trf, LSMR) instead,
kept as a reference.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.optimize import least_squares


def _soft_l1(r2, f_scale):
    """Robust cost ``f² · 2 (sqrt(1 + r²/f²) - 1)`` and IRLS weights per residual pair."""
    z = r2 / f_scale**2
    return f_scale**2 * 2.0 * (np.sqrt(1.0 + z) - 1.0), 1.0 / np.sqrt(1.0 + z)


class _Solution:
    def __init__(self, x, success, message, nfev):
        self.x, self.success, self.message, self.nfev = x, success, message, nfev


def _lm(problem, x, loss, f_scale, max_iter, tol=1e-10):
    """Levenberg–Marquardt on the sparse normal equations, points eliminated (Schur).

    Every wand location owns a 6×6 diagonal block (both targets, coupled by the
    length condition), so the reduced system has only the camera unknowns.  A robust
    ``soft_l1`` loss is applied by iteratively reweighting the observation pairs.
    """
    nc, M = problem.n_cam, problem.M

    def cost_weights(r):
        r2 = np.sum(r[: 2 * M].reshape(M, 2) ** 2, axis=1)
        if loss == "linear":
            rho, w = r2, np.ones(M)
        else:
            rho, w = _soft_l1(r2, f_scale)
        return 0.5 * (rho.sum() + np.sum(r[2 * M :] ** 2)), np.concatenate(
            [np.repeat(w, 2), np.ones(problem.F)]
        )

    r, J = problem.residuals(x, jacobian=True)
    cost, w = cost_weights(r)
    lam, nfev = 1e-3, 1
    for it in range(max_iter):
        Jw = sp.diags(w) @ J
        N = (J.T @ Jw).tocsr()
        g = -(Jw.T @ r)
        step = _schur_solve(N, g, nc, problem.F, lam)
        while True:
            x_new = x + step
            r_new = problem.residuals(x_new)
            nfev += 1
            cost_new, _ = cost_weights(r_new)
            if np.isfinite(cost_new) and cost_new <= cost:
                break
            lam *= 10.0
            if lam > 1e12:
                return _Solution(x, True, "converged (no further decrease)", nfev)
            step = _schur_solve(N, g, nc, problem.F, lam)
        lam = max(lam / 10.0, 1e-12)
        rel = (cost - cost_new) / max(cost, 1e-300)
        x = x_new
        r, J = problem.residuals(x, jacobian=True)
        cost, w = cost_weights(r)
        if rel < tol or np.max(np.abs(step)) < 1e-12:
            return _Solution(x, True, f"converged after {it + 1} iterations", nfev)
    return _Solution(x, False, f"no convergence in {max_iter} iterations", nfev)


def normal_blocks(N, nc, F):
    """Split the normal matrix into its camera, coupling and wand-location blocks.

    ``N`` (nc + 6F, nc + 6F) sparse; returns the camera block (nc, nc) dense, the
    coupling (F, 6, nc) and the location blocks (F, 6, 6).
    """
    Ncc = N[:nc, :nc].toarray()
    Npc = N[nc:, :nc].toarray().reshape(F, 6, nc)
    Npp = N[nc:, nc:].tocoo()
    B = np.zeros((F, 6, 6))
    B[Npp.row // 6, Npp.row % 6, Npp.col % 6] = Npp.data
    return Ncc, Npc, B


def _schur_solve(N, g, nc, F, lam):
    Ncc, Npc, B = normal_blocks(N, nc, F)
    Ncc = Ncc + lam * np.diag(np.diag(Ncc))
    idx = np.arange(6)
    B = B.copy()
    B[:, idx, idx] *= 1.0 + lam
    Binv = np.linalg.inv(B)
    gc, gp = g[:nc], g[nc:].reshape(F, 6)
    E = np.einsum("fij,fjn->fin", Binv, Npc)  # B⁻¹ N_pc
    S = Ncc - np.einsum("fin,fim->nm", Npc, E)
    rhs = gc - np.einsum("fin,fi->n", E, gp)
    dc = np.linalg.solve(S, rhs) if nc else np.zeros(0)
    dp = np.einsum("fij,fj->fi", Binv, gp) - E @ dc
    return np.concatenate([dc, dp.ravel()])


def _scipy(problem, x0, loss, f_scale, jac_mode, max_nfev):
    """``scipy.optimize.least_squares`` path (slower to converge on large problems)."""
    kw = dict(
        x_scale="jac",
        loss=loss,
        f_scale=f_scale,
        method="trf",
        tr_solver="lsmr",
        max_nfev=max_nfev,
        ftol=1e-12,
        xtol=1e-12,
        gtol=1e-10,
    )
    if jac_mode == "analytic":
        sol = least_squares(
            problem.residuals, x0, jac=lambda x: problem.residuals(x, jacobian=True)[1], **kw
        )
    else:
        sol = least_squares(problem.residuals, x0, jac_sparsity=problem.sparsity(), **kw)
    return _Solution(sol.x, bool(sol.success), str(sol.message), int(sol.nfev))


def solve(problem, x0, loss, f_scale, solver, max_iter):
    """Minimise the bundle problem from ``x0``.

    Parameters
    ----------
    problem : core.bundle._Problem
        Residuals (pixels, and bar-length conditions scaled by σ_L) and their sparse
        Jacobian.
    x0 : ndarray (n,)
        Start: packed cameras, then the targets (F, 2, 3) in metres.
    loss : {"linear", "soft_l1"}
        Loss on each observation's residual pair.
    f_scale : float
        Soft-L1 scale, pixels.
    solver : str
        ``"lm"`` (Schur-complement Levenberg–Marquardt) or ``"scipy:analytic"`` /
        ``"scipy:sparsity"``.
    max_iter : int
        Iterations (LM) or function evaluations (scipy).

    Returns
    -------
    _Solution
        ``x``, ``success``, ``message``, ``nfev``.
    """
    if solver == "lm":
        return _lm(problem, x0, loss, f_scale, max_iter)
    return _scipy(problem, x0, loss, f_scale, solver.split(":")[1], max_iter)
