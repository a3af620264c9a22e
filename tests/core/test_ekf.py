"""The EKF tracks a planar two-link arm from its noisy end-point and elbow positions."""

import numpy as np
from scipy.optimize import least_squares

from core.ekf import EKF


def _arm(q):
    """Elbow and hand positions (4,) of a two-link planar arm, links 0.3 m and 0.25 m."""
    a, b = q
    elbow = 0.3 * np.array([np.cos(a), np.sin(a)])
    hand = elbow + 0.25 * np.array([np.cos(a + b), np.sin(a + b)])
    return np.concatenate([elbow, hand])


def _arm_jac(q):
    a, b = q
    return np.array(
        [
            [-0.3 * np.sin(a), 0.0],
            [0.3 * np.cos(a), 0.0],
            [-0.3 * np.sin(a) - 0.25 * np.sin(a + b), -0.25 * np.sin(a + b)],
            [0.3 * np.cos(a) + 0.25 * np.cos(a + b), 0.25 * np.cos(a + b)],
        ]
    )


def _truth(n=80):
    t = np.arange(n)
    return np.stack([0.4 + 0.8 * np.sin(t / 15.0), 1.0 + 0.6 * np.sin(t / 9.0)], axis=1)


def test_tracks_nonlinear_motion_and_beats_measurement_noise(rng):
    truth = _truth()
    noise = 0.005  # 5 mm
    f = EKF.start(truth[0], q_sigma=0.05, rate_sigma=0.05, accel_sigma=0.01)
    est, single, pred_err = [], [], []
    for k, q in enumerate(truth):
        if k:
            f.predict()
            pred_err.append(np.abs(f.q - q))
        z = _arm(q) + rng.normal(0, noise, 4)
        f.update(z, _arm, _arm_jac, noise**2, iterations=3)
        est.append(f.q.copy())
        single.append(least_squares(lambda p, z=z: _arm(p) - z, q).x)  # frame by frame
    err = np.abs(np.array(est) - truth)[10:]
    err_single = np.abs(np.array(single) - truth)[10:]
    # filtering over time beats fitting each frame alone, for both angles
    assert np.all(np.sqrt(np.mean(err**2, 0)) < 0.95 * np.sqrt(np.mean(err_single**2, 0)))
    # and the filter's σ is consistent with its errors
    z_scores = err / np.array([f.q_sigma])
    assert 0.5 < np.sqrt(np.mean(z_scores**2)) < 2.0
    # the constant-velocity prediction is much closer than "no motion" would be
    steps = np.abs(np.diff(truth, axis=0))[9:]
    assert np.mean(np.array(pred_err)[9:]) < 0.75 * np.mean(steps)


def test_limits_are_respected():
    f = EKF.start([0.0, 0.0], 0.1, 0.1, 0.05, lower=[-0.1, -np.inf], upper=[0.1, np.inf])
    for _ in range(5):
        f.predict()
        f.update(_arm([1.0, 0.5]), _arm, _arm_jac, 1e-6)
    assert f.q[0] <= 0.1 + 1e-12 and f.q_dot[0] <= 0.0 + 1e-12
    assert abs(f.q[1] - 1.4) < 0.5  # the free parameter compensates


def test_no_measurements_keeps_predicting_with_growing_uncertainty():
    f = EKF.start([0.0, 0.0], 0.01, 0.01, 0.01)
    f.x[2:] = [0.02, -0.01]
    s0 = f.q_sigma.copy()
    for _ in range(5):
        f.predict()
        f.update(np.zeros(0), _arm, _arm_jac, 1.0)
    np.testing.assert_allclose(f.q, [0.1, -0.05])
    assert np.all(f.q_sigma > 2 * s0)
