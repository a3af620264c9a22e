"""Levenberg–Marquardt on the normal equations, with bounds by projection.

The solver of the weighted least squares fits (:func:`core.fitting.fit`, the pose and
shape solves; :func:`core.shape_fit.fit_shape`, the whole-body shape): ``system(x)``
returns the weighted residuals ``r`` (m,) and their Jacobian ``J`` (m, p; an array, or a
``scipy.sparse`` matrix whose ``JᵀJ`` is then formed sparse and solved dense); a step solves
``(JᵀJ + μ·diag(JᵀJ)) δ = −Jᵀr`` (Marquardt's diagonal scaling), capped to
``max_step`` in parameter units (radians, metres) and projected onto the bounds.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse


@dataclass
class LMResult:
    """Outcome of :func:`levenberg_marquardt`: the solution ``x`` (p,), its cost
    ``r·r``, the number of ``system`` evaluations, a status and a message."""

    x: np.ndarray
    cost: float
    nfev: int
    status: int  # 1 converged, 0 iteration limit, -1 no progress possible
    message: str


def levenberg_marquardt(
    system,
    x0: np.ndarray,
    lo: np.ndarray,
    max_nfev: int,
    tol: float,
    max_step: float = 0.2,
    hi: np.ndarray | None = None,
) -> LMResult:
    """Levenberg–Marquardt on the normal equations (Marquardt's diagonal scaling),
    with bounds (``lo``, optional ``hi``) by projection.  ``system(x) -> (r, J)``."""
    hi = np.full(len(x0), np.inf) if hi is None else hi
    x = x0.copy()
    r, J = system(x)
    cost = float(r @ r)
    mu, nfev = 1e-3, 1
    A = None  # the normal equations of J, kept while steps are refused
    while nfev < max_nfev:
        if A is None:
            A = J.T @ J
            if sparse.issparse(A):  # a sparse J (the whole-body shape): dense JᵀJ
                A = A.toarray()
            g = J.T @ r
            d = np.diag(A).copy()
            d = np.maximum(d, 1e-12 * max(d.max(initial=0.0), 1e-30))
        try:
            step = np.linalg.solve(A + mu * np.diag(d), -g)
        except np.linalg.LinAlgError:
            mu *= 10.0
            continue
        big = np.abs(step).max(initial=0.0)
        if big > max_step:  # a trust region in parameter units (radians, metres)
            step *= max_step / big
        xn = np.clip(x + step, lo, hi)
        rn, Jn = system(xn)
        nfev += 1
        cn = float(rn @ rn)
        if np.isfinite(cn) and cn < cost:
            small = (cost - cn) <= tol * cost  # no longer a significant decrease
            small = small or float(np.abs(step).max(initial=0.0)) < 1e-10
            x, r, J, cost = xn, rn, Jn, cn
            A = None
            mu = max(mu / 5.0, 1e-15)
            if small or cost < 1e-28:
                return LMResult(x, cost, nfev, 1, "converged")
        else:
            mu *= 5.0
            if mu > 1e12:  # no step decreases the cost: a (robust-cost) minimum
                return LMResult(x, cost, nfev, 1, "converged (no further decrease)")
    return LMResult(x, cost, nfev, 0, "iteration limit")
