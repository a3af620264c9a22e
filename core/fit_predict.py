"""Prediction of the next frame's pose for the sequence fit (paper 2's filter).

A damped constant-velocity extended Kalman filter over ``q = [θ, root]``
(:class:`core.ekf.EKF`) or plain damped constant-velocity extrapolation.  Fitted frames
are fed back as direct measurements; an angle that was not measured (a hidden part)
is left to the prediction, so its σ grows frame by frame.
"""

from __future__ import annotations

import numpy as np

from .ekf import EKF


class PosePredictor:
    """Prediction of ``q = [θ, root]`` (n + 3,) from the fitted frames so far.

    ``cfg`` is the fit's :class:`core.fit.SequenceSettings` (``predictor``: ``"ekf"``
    or ``"constant_velocity"``, ``damping``, ``accel_sigma``, ``sigma_pred``,
    ``sigma_pred_max``); angles in radians, the root in metres.
    """

    def __init__(self, q0: np.ndarray, cfg, n_theta: int):
        self.cfg, self.n = cfg, n_theta
        self.hist: list[np.ndarray] = [q0.copy()]
        self.ekf = None
        if cfg.predictor == "ekf":
            sig = np.full(q0.size, 0.05)
            self.ekf = EKF.start(q0, sig, 0.05, cfg.accel_sigma, damping=cfg.damping)
        elif cfg.predictor != "constant_velocity":
            raise ValueError(f"unknown predictor {cfg.predictor!r}")

    def predict(self) -> tuple[np.ndarray, np.ndarray]:
        """Predicted q (n+3,) and the prior σ of the angles (n,)."""
        cfg = self.cfg
        if self.ekf is not None:
            self.ekf.predict()
            q = self.ekf.q.copy()
            sig = np.clip(self.ekf.q_sigma[: self.n], cfg.sigma_pred, cfg.sigma_pred_max)
            return q, sig
        h = self.hist
        q = h[-1] + (cfg.damping * (h[-1] - h[-2]) if len(h) > 1 else 0.0)
        return q, np.full(self.n, cfg.sigma_pred)

    def accept(self, q: np.ndarray, q_sigma: np.ndarray | None) -> np.ndarray:
        """Feed a fitted frame (σ inf: that parameter was not measured, e.g. a hidden
        part's angle); returns the filter's σ of the angles (n,) after it — for
        unmeasured angles the prediction's, growing frame by frame."""
        self.hist.append(q.copy())
        if q_sigma is None:
            q_sigma = np.full(q.size, 0.01)
        meas = np.isfinite(q_sigma)
        if self.ekf is not None:
            if meas.any():
                sig = np.maximum(q_sigma[meas], 0.005)
                H = np.eye(q.size)[meas]
                self.ekf.update(q[meas], lambda x: x[meas], H, sig**2)
            return self.ekf.q_sigma[: self.n].copy()
        self.n_hidden = np.where(meas[: self.n], 0, getattr(self, "n_hidden", 0) + 1)
        return self.cfg.sigma_pred * np.sqrt(1.0 + self.n_hidden)

    def skip(self) -> None:
        """A diverged frame: the prediction stands in for it."""
        if self.ekf is None:
            h = self.hist
            self.hist.append(h[-1] + (self.cfg.damping * (h[-1] - h[-2]) if len(h) > 1 else 0))
