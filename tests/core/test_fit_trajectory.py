"""Tracked trajectories as rigid-motion observations (core.fit_trajectory)."""

import numpy as np

from core.fit_trajectory import TrajectoryAnchors, TrajectoryObs, bone_local
from core.fitting import FitSettings, Observations, fit
from core.metaballs import make_metaballs
from core.skeleton import forward, make_skeleton, points_world


def _body(seed=0):
    skel = make_skeleton()
    rng = np.random.default_rng(seed)
    theta = rng.normal(0.0, 0.2, skel.n_dof)
    root = np.array([0.1, -0.2, 1.0])
    s = np.ones(skel.n_groups) * 1.05
    return skel, theta, root, s, rng


def _points(skel, theta, root, s, rng, n=300):
    """n points fixed in random bones (bone-frame coordinates within 8 cm)."""
    bone = rng.integers(0, len(skel.bone_names), n)
    q0 = rng.normal(0.0, 0.04, (n, 3))
    pose = forward(skel, theta[None], root[None], s)
    return bone, q0, points_world(skel, pose, bone, q0, np.full(n, -1), s)[0]


def test_bone_local_inverts_points_world():
    skel, theta, root, s, rng = _body()
    bone, q0, xyz = _points(skel, theta, root, s, rng)
    np.testing.assert_allclose(bone_local(skel, theta, root, s, xyz, bone), q0, atol=1e-12)


def test_block_jacobians_match_finite_differences():
    skel, theta, root, s, rng = _body(1)
    bone, q0, xyz = _points(skel, theta, root, s, rng, 40)
    obs = TrajectoryObs(bone, q0, xyz + rng.normal(0, 0.01, xyz.shape), np.full(40, 0.005))
    obs.freeze(skel, theta, root, s)
    r, Jt, Jr, Js, _, _ = obs.block(skel, theta, root, s)
    h = 1e-6
    for k in rng.choice(skel.n_dof, 8, replace=False):
        d = np.zeros(skel.n_dof)
        d[k] = h
        fd = obs.block(skel, theta + d, root, s)[0] - obs.block(skel, theta - d, root, s)[0]
        np.testing.assert_allclose(fd / (2 * h), Jt[:, k], atol=1e-5 * np.abs(Jt).max())
    for k in range(3):
        d = np.zeros(3)
        d[k] = h
        fd = obs.block(skel, theta, root + d, s)[0] - obs.block(skel, theta, root - d, s)[0]
        np.testing.assert_allclose(fd / (2 * h), Jr[:, k], atol=1e-6 * np.abs(Jr).max())
    for g in range(skel.n_groups):
        d = np.zeros(skel.n_groups)
        d[g] = h
        fd = obs.block(skel, theta, root, s + d)[0] - obs.block(skel, theta, root, s - d)[0]
        np.testing.assert_allclose(fd / (2 * h), Js[:, g], atol=1e-5 * max(np.abs(Js).max(), 1))


def test_anchors_pair_by_id_and_weigh_outliers_down():
    skel, theta, root, s, rng = _body(2)
    bone, q0, xyz = _points(skel, theta, root, s, rng, 50)
    ids = rng.permutation(1000)[:50]
    part = bone.copy()
    part[:5] = -1  # unassigned points are not kept
    a = TrajectoryAnchors()
    a.set(skel, theta, root, s, xyz, np.full(50, 0.002), ids, part)
    # the next frame: a subset, shuffled, one gross outlier
    pick = rng.permutation(np.arange(50))[:30]
    moved = xyz[pick].copy()
    moved[0] += 0.3
    obs = a.observations(moved, np.full(30, 0.002), ids[pick], slip_m=0.004, robust_scale=3.0)
    keep = part[pick] >= 0
    assert len(obs) == keep.sum()
    np.testing.assert_array_equal(obs.bone, bone[pick][keep])
    np.testing.assert_allclose(obs.q0, q0[pick][keep], atol=1e-12)
    obs.freeze(skel, theta, root, s)
    w = obs.weights * obs.sigma
    assert np.all(w[1:] > 0.99) if keep[0] else True
    if keep[0]:
        assert w[0] < 0.05


def test_trajectories_recover_a_twist_the_surface_cannot_see():
    """Points on a lone round upper arm: twisting it about its own axis leaves the
    attractor residuals unchanged, the trajectories see it."""
    skel, _, root, s, rng = _body(3)
    theta0 = np.zeros(skel.n_dof)
    balls = make_metaballs(skel, "simplified", s)
    b = skel.bone_index("l_shoulder")
    on = balls.bone == b
    balls.radii[on] = balls.radii[on][:, :1].mean()  # round: twist-invariant surface
    k_twist = skel.dof_index("l_shoulder_z") if "l_shoulder_z" in skel.dof_names else None
    assert k_twist is not None
    theta1 = theta0.copy()
    theta1[k_twist] = 0.25
    # material points on the arm's surface at theta0, carried rigidly to theta1
    pose0 = forward(skel, theta0[None], root[None], s)
    from core.metaballs import world_frames

    Rw, cw = world_frames(skel, pose0, balls, s)
    idx = np.flatnonzero(on)
    m = rng.choice(idx, 200)
    u = rng.normal(size=(200, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    from core.metaballs import VISIBLE

    x0 = cw[0, m] + np.einsum("nij,nj->ni", Rw[0, m], VISIBLE * balls.radii[m] * u)
    bone = np.full(200, b)
    q0 = bone_local(skel, theta0, root, s, x0, bone)
    pose1 = forward(skel, theta1[None], root[None], s)
    x1 = points_world(skel, pose1, bone, q0, np.full(200, -1), s)[0]
    cfg = FitSettings(
        members="part", robust_scale=0.0, irls_rounds=2, max_nfev=50, use_limits=False
    )
    mask = np.zeros(skel.n_dof, bool)
    mask[[skel.dof_index(d) for d in skel.dof_names if d.startswith("l_shoulder")]] = True
    sig_prior = np.where(mask, 10.0, 1e-4)  # everything else held by the prior
    plain = Observations(xyz=x1, part=bone, sigma=0.002, theta_pred=theta0, sigma_pred=sig_prior)
    with_traj = Observations(
        xyz=x1,
        part=bone,
        sigma=0.002,
        theta_pred=theta0,
        sigma_pred=sig_prior,
        trajectory=TrajectoryObs(bone, q0, x1, np.full(200, 0.002)),
    )
    r0 = fit(skel, balls, plain, theta0, root, s, solve="pose", settings=cfg)
    r1 = fit(skel, balls, with_traj, theta0, root, s, solve="pose", settings=cfg)
    assert abs(r0.theta[k_twist] - 0.25) > 0.2  # the surface alone does not see the twist
    # (not exact: the points lie on each lone ellipsoid, not on the summed field's surface)
    assert abs(r1.theta[k_twist] - 0.25) < 0.015
