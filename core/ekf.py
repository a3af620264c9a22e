"""Extended Kalman filter over pose parameters (the second paper, sec. 3).

State ``x = [q, q_dot]`` (2n): ``q`` the pose parameters (joint angles θ in radians,
root translation in metres, ...) and their rates per frame.  System model: damped
constant velocity,

    q_{k+1} = q_k + q_dot_k,      q_dot_{k+1} = damping * q_dot_k,

with white acceleration noise of standard deviation ``accel_sigma`` (per parameter,
units of q per frame²) entering as the discretised white-noise-acceleration ``Q``.
Measurements ``z = h(q) + v`` with ``v ~ N(0, V)``; the caller supplies ``h`` and its
Jacobian ``H = dh/dq`` (contour residuals through ``L_p``, LSM 3-D points, clicked
joints, ...).  Joint limits are enforced after each update by clamping ``q`` into
``[lower, upper]`` and zeroing the rate that pushes outwards (a projection of the
estimate onto the constraint set).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.linalg


@dataclass
class EKF:
    """Filter state.

    Attributes
    ----------
    x : ndarray, shape (2n,)
        ``[q, q_dot]``.
    P : ndarray, shape (2n, 2n)
        Error covariance.
    accel_sigma : ndarray, shape (n,)
        Process noise (acceleration) per parameter, units of q per frame².
    damping : float
        Rate decay per frame (1: constant velocity).
    lower, upper : ndarray, shape (n,)
        Limits of q (±inf where free).
    """

    x: np.ndarray
    P: np.ndarray
    accel_sigma: np.ndarray
    damping: float = 1.0
    lower: np.ndarray | None = None
    upper: np.ndarray | None = None

    @classmethod
    def start(
        cls,
        q0: np.ndarray,
        q_sigma: np.ndarray | float,
        rate_sigma: np.ndarray | float,
        accel_sigma: np.ndarray | float,
        damping: float = 1.0,
        lower=None,
        upper=None,
    ) -> EKF:
        """A filter at pose ``q0`` (n,) with zero rate and the given uncertainties."""
        q0 = np.asarray(q0, float)
        n = q0.size
        var = np.concatenate(
            [np.broadcast_to(q_sigma, n) ** 2, np.broadcast_to(rate_sigma, n) ** 2]
        )
        return cls(
            np.concatenate([q0, np.zeros(n)]),
            np.diag(var),
            np.broadcast_to(np.asarray(accel_sigma, float), n).copy(),
            damping,
            None if lower is None else np.asarray(lower, float),
            None if upper is None else np.asarray(upper, float),
        )

    @property
    def n(self) -> int:
        return self.x.size // 2

    @property
    def q(self) -> np.ndarray:
        return self.x[: self.n]

    @property
    def q_dot(self) -> np.ndarray:
        return self.x[self.n :]

    @property
    def q_sigma(self) -> np.ndarray:
        """Standard deviation of every pose parameter, shape (n,)."""
        return np.sqrt(np.diag(self.P)[: self.n])

    def transition(self) -> np.ndarray:
        n = self.n
        F = np.eye(2 * n)
        F[:n, n:] = np.eye(n)
        F[n:, n:] *= self.damping
        return F

    def process_noise(self) -> np.ndarray:
        n = self.n
        a2 = self.accel_sigma**2
        Q = np.zeros((2 * n, 2 * n))
        idx = np.arange(n)
        Q[idx, idx] = a2 / 4.0
        Q[idx, idx + n] = Q[idx + n, idx] = a2 / 2.0
        Q[idx + n, idx + n] = a2
        return Q

    def predict(self) -> EKF:
        """Advance one frame: ``x <- F x``, ``P <- F P F^T + Q`` (in place; returns self)."""
        F = self.transition()
        self.x = F @ self.x
        self.P = F @ self.P @ F.T + self.process_noise()
        return self

    def predicted_q(self, steps: int = 1) -> np.ndarray:
        """Pose ``steps`` frames ahead without changing the filter, shape (n,)."""
        q, v = self.q.copy(), self.q_dot.copy()
        for _ in range(steps):
            q = q + v
            v = v * self.damping
        return q

    def update(
        self,
        z: np.ndarray,
        h: Callable[[np.ndarray], np.ndarray],
        H: np.ndarray | Callable[[np.ndarray], np.ndarray],
        V: np.ndarray | float,
        iterations: int = 1,
    ) -> EKF:
        """Measurement update (iterated EKF when ``iterations > 1``; in place).

        Parameters
        ----------
        z : ndarray, shape (m,)
            Measurements.
        h : callable
            ``h(q) -> (m,)`` predicted measurements.
        H : ndarray (m, n) or callable ``H(q) -> (m, n)``
            Jacobian of ``h`` w.r.t. q.
        V : ndarray (m, m), (m,) or float
            Measurement noise covariance (a vector or scalar means diagonal variances).
        iterations : int
            Gauss–Newton relinearisations of the update (iterated EKF).
        """
        z = np.asarray(z, float)
        m, n = z.size, self.n
        if m == 0:
            return self
        Vm = np.asarray(V, float)
        if Vm.ndim < 2:
            Vm = np.diag(np.broadcast_to(Vm, m))
        x_pred, P_pred = self.x.copy(), self.P
        x_i = x_pred.copy()
        for _ in range(max(1, iterations)):
            q_i = x_i[:n]
            Hq = H(q_i) if callable(H) else np.asarray(H, float)
            Hx = np.hstack([Hq, np.zeros((m, n))])
            S = Hx @ P_pred @ Hx.T + Vm
            PHt = P_pred @ Hx.T
            # innovation about the current linearisation point (iterated EKF form)
            innov = z - h(q_i) - Hx @ (x_pred - x_i)
            cho = scipy.linalg.cho_factor(S + 1e-12 * np.eye(m))
            G = scipy.linalg.cho_solve(cho, PHt.T).T
            x_i = x_pred + G @ innov
        I_GH = np.eye(2 * n) - G @ Hx
        # Joseph form keeps P symmetric and positive definite
        self.P = I_GH @ P_pred @ I_GH.T + G @ Vm @ G.T
        self.x = x_i
        self._apply_limits()
        return self

    def _apply_limits(self) -> None:
        if self.lower is None and self.upper is None:
            return
        n = self.n
        q, v = self.x[:n], self.x[n:]
        lo = self.lower if self.lower is not None else np.full(n, -np.inf)
        hi = self.upper if self.upper is not None else np.full(n, np.inf)
        below, above = q < lo, q > hi
        q[below], q[above] = lo[below], hi[above]
        v[below & (v < 0)] = 0.0
        v[above & (v > 0)] = 0.0
