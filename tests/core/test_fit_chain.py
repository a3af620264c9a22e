"""The spine-chain prior: neighbouring links' changes tied, a shared bend or twist free."""

import numpy as np

from core import metaballs as mb
from core import skeleton as sk
from core.fit_chain import TRUNK_CHAIN, chain_prior
from core.fitting import FitSettings, Observations, fit


def _dof(skel, name):
    return skel.dof_names.index(name)


def test_a_shared_change_is_free_and_a_split_costs(rng):
    skel = sk.make_skeleton()
    theta0 = rng.normal(0, 0.2, skel.n_dof)
    A, b = chain_prior(skel, theta0, sigma=0.1)
    assert A.shape == (2 * 3, skel.n_dof)  # two neighbour pairs, three axes each
    np.testing.assert_allclose(A @ theta0 - b, 0.0, atol=1e-12)
    shared = theta0.copy()
    for link in TRUNK_CHAIN:  # the whole spine twists and bends together
        shared[_dof(skel, f"{link}_z")] += 0.4
        shared[_dof(skel, f"{link}_x")] -= 0.2
    np.testing.assert_allclose(A @ shared - b, 0.0, atol=1e-12)
    split = theta0.copy()  # the lower back twists one way, the spine back
    split[_dof(skel, "lowerback_z")] += 0.3
    split[_dof(skel, "spine_z")] -= 0.3
    r = A @ split - b
    assert np.isclose(np.abs(r).max(), 0.6 / 0.1)  # lowerback vs spine
    assert np.count_nonzero(np.abs(r) > 1e-12) == 2  # and spine vs chest; nothing else


def test_fit_weighs_the_chain_prior_against_the_pose_prior(rng):
    """Without points, the fit is the least-squares compromise of the two quadratic
    priors, which has a closed form on the three twists."""
    skel = sk.make_skeleton()
    balls = mb.make_metaballs(skel)
    theta0 = rng.normal(0, 0.2, skel.n_dof)
    pred = theta0.copy()
    p = np.array([0.3, -0.3, 0.1])  # the prediction's twists, from the reference
    z = [_dof(skel, f"{link}_z") for link in TRUNK_CHAIN]
    pred[z] += p
    sig_p, sig_c = 0.2, 0.05
    obs = Observations(
        theta_pred=pred,
        sigma_pred=sig_p,
        linear_prior=chain_prior(skel, theta0, sig_c),
    )
    res = fit(
        skel,
        balls,
        obs,
        pred.copy(),
        np.array([0.0, 0.0, 1.0]),
        np.ones(skel.n_groups),
        balls.radii,
        solve="pose",
        settings=FitSettings(use_limits=False),
    )
    lap = np.array([[1.0, -1.0, 0.0], [-1.0, 2.0, -1.0], [0.0, -1.0, 1.0]])
    x = np.linalg.solve(np.eye(3) / sig_p**2 + lap / sig_c**2, p / sig_p**2)
    np.testing.assert_allclose(res.theta[z] - theta0[z], x, atol=1e-6)
    assert np.ptp(x) < 0.25 * np.ptp(p)  # the split mostly undone, the mean kept
    assert np.isclose(x.mean(), p.mean())
    others = np.setdiff1d(np.arange(skel.n_dof), z)
    np.testing.assert_allclose(res.theta[others], pred[others], atol=1e-6)


def test_no_pairs_without_the_links(rng):
    skel = sk.make_skeleton()
    A, b = chain_prior(skel, np.zeros(skel.n_dof), 0.1, chain=("l_hip", "l_knee"), axes="z")
    assert A.shape == (0, skel.n_dof) and b.shape == (0,)
