"""Global start search: the explain cost and the per-limb grid search."""

import numpy as np
import pytest

from core import metaball_surface as mbs
from core import metaballs as mb
from core import skeleton as sk
from core.attractor import attractor, gather, member_table
from core.fit_search import explain_cost, explain_distance, recentred_starts, search_limbs
from tests.core._bodyscene import model_points


@pytest.fixture
def body():
    skel = sk.make_skeleton()
    s = np.ones(skel.n_groups)
    return skel, s, mb.make_metaballs(skel, "simplified", s)


def _outer(skel, balls, theta, root, s, rng, per_bone=40):
    """Points on the whole body's surface (the parts' surfaces outside other parts)."""
    xyz, _ = model_points(skel, balls, theta, root, s, rng, per_bone=per_bone)
    pose = sk.forward(skel, theta[None], root[None], s)
    Rw, cw = mb.world_frames(skel, pose, balls, s)
    xs, ok = mbs.project_to_surface(xyz, Rw[0], cw[0], balls.radii)
    return xs[ok]


def test_explain_distance_is_the_whole_body_attractor_distance(body, rng):
    skel, s, balls = body
    theta = rng.normal(0, 0.2, skel.n_dof)
    root = np.array([0.1, -0.2, 1.0])
    x = _outer(skel, balls, theta, root, s, rng) + rng.normal(0, 0.03, (1, 3))
    d = explain_distance(x, skel, balls, s, balls.radii, theta, root)
    pose = sk.forward(skel, theta[None], root[None], s)
    Rw, cw = mb.world_frames(skel, pose, balls, s)
    idx, ok = gather(*member_table(skel, balls, "body"), np.zeros(len(x), int))
    ref = attractor(x, idx, ok, Rw[0], cw[0], balls.radii).dist
    assert np.allclose(d, ref, atol=1e-9)
    on = _outer(skel, balls, theta, root, s, rng)
    assert np.abs(explain_distance(on, skel, balls, s, balls.radii, theta, root)).max() < 1e-6
    # the cost of the right pose is lower than of a moved one, batched over poses
    th2 = np.stack([theta, theta + 0.3])
    c = explain_cost(on, skel, balls, s, balls.radii, th2, np.stack([root, root]))
    assert c[0] < 1e-6 < c[1]


def test_a_limb_that_moved_far_is_found_and_a_hidden_one_stays(body, rng):
    skel, s, balls = body
    root = np.array([0.0, 0.0, 1.0])
    true = np.zeros(skel.n_dof)
    true[skel.dof_index("l_hip_x")] = -0.9  # thigh raised forward (a kick)
    true[skel.dof_index("l_knee_x")] = 1.1
    true[skel.dof_index("r_shoulder_x")] = -1.2  # right arm raised forward
    x = _outer(skel, balls, true, root, s, rng)
    xs = sk.joint_positions(skel, true, root, s)
    # the left arm is hidden: none of its points are observed
    pose = sk.forward(skel, true[None], root[None], s)
    Rw, cw = mb.world_frames(skel, pose, balls, s)
    left_arm = np.isin(
        balls.bone, [skel.bone_index(b) for b in ("l_shoulder", "l_elbow", "l_wrist")]
    )
    near_arm = (
        np.abs(
            explain_distance(
                x,
                skel,
                mb.Metaballs(
                    balls.bone[left_arm],
                    balls.center0[left_arm],
                    balls.group[left_arm],
                    balls.rot[left_arm],
                    balls.radii[left_arm],
                ),
                s,
                balls.radii[left_arm],
                true,
                root,
            )
        )
        < 0.05
    )
    x = x[~near_arm]
    start = np.zeros(skel.n_dof)
    start[skel.dof_index("l_shoulder_x")] = -1.4  # the hidden arm, forward in free space
    res = search_limbs(x, skel, balls, s, balls.radii, start, root)
    got = sk.joint_positions(skel, res.theta, root, s)
    for j in ("l_knee", "l_ankle", "r_elbow", "r_wrist"):
        before = np.linalg.norm(
            sk.joint_positions(skel, start, root, s)[skel.joint_index(j)] - xs[skel.joint_index(j)]
        )
        after = np.linalg.norm(got[skel.joint_index(j)] - xs[skel.joint_index(j)])
        assert before > 0.25 and after < 0.1, (j, before, after)
    assert res.cost_after < 0.2 * res.cost_before
    assert set(res.moved) == {"l_leg", "r_arm"}
    assert res.theta[skel.dof_index("l_shoulder_x")] == pytest.approx(-1.4)


def test_a_hidden_limb_does_not_keep_points_another_limb_then_took(body):
    skel, s, balls = body
    rng = np.random.default_rng(1)  # a draw where the greedy moves the leg first
    root = np.array([0.0, 0.0, 1.0])
    true = np.zeros(skel.n_dof)
    true[skel.dof_index("r_shoulder_x")] = -0.6  # the right arm swung forward
    true[skel.dof_index("r_hip_x")] = -1.2  # the right leg raised, knee bent ...
    true[skel.dof_index("r_knee_x")] = 1.0
    x = _outer(skel, balls, true, root, s, rng)
    leg = np.isin(balls.bone, [skel.bone_index(b) for b in ("r_hip", "r_knee", "r_ankle")])
    on_leg = (
        np.abs(
            explain_distance(
                x,
                skel,
                mb.Metaballs(
                    balls.bone[leg],
                    balls.center0[leg],
                    balls.group[leg],
                    balls.rot[leg],
                    balls.radii[leg],
                ),
                s,
                balls.radii[leg],
                true,
                root,
            )
        )
        < 0.05
    )
    x = x[~on_leg]  # ... and hidden: none of its points are observed
    start = true.copy()
    start[skel.dof_index("r_shoulder_x")] = 0.0  # the arm moved since the last frame
    ankle = skel.joint_index("r_ankle")
    greedy = search_limbs(x, skel, balls, s, balls.radii, start, root, prune=False)
    assert set(greedy.moved) == {"r_arm", "r_leg"}  # the leg took arm points first
    res = search_limbs(x, skel, balls, s, balls.radii, start, root)
    assert res.moved == ["r_arm"]
    assert res.theta[skel.dof_index("r_hip_x")] == pytest.approx(-1.2)
    got, want = (sk.joint_positions(skel, th, root, s) for th in (res.theta, true))
    assert np.linalg.norm(got[ankle] - want[ankle]) < 1e-9
    assert (
        np.linalg.norm(got[skel.joint_index("r_wrist")] - want[skel.joint_index("r_wrist")]) < 0.02
    )
    assert res.cost_after <= greedy.cost_after + 100.0


def test_recentred_starts_carry_the_root_with_the_points_and_one_explains_them(body, rng):
    skel, s, balls = body
    theta = np.zeros(skel.n_dof)
    root0, root1 = np.array([0.0, 0.0, 1.0]), np.array([0.45, -0.3, 1.02])
    ref = _outer(skel, balls, theta, root0, s, rng)
    now = _outer(skel, balls, theta, root1, s, rng)[::2]  # other samples, fewer
    q = np.concatenate([theta, root0 + [0.05, 0.05, 0.0]])  # the stale prediction
    up = np.array([0.0, 0.0, 1.0])
    cands = recentred_starts(now, q, ref, root0, up)
    assert cands.shape == (25, skel.n_dof + 3)
    assert np.all(cands[:, : skel.n_dof] == theta)
    assert np.allclose(cands[:, -1], q[-1])  # the height is the prediction's
    centre = cands[12, skel.n_dof :]  # the zero offset: the points' median motion
    assert np.linalg.norm(centre[:2] - root1[:2]) < 0.05, centre
    cost = explain_cost(
        now, skel, balls, s, balls.radii, cands[:, : skel.n_dof], cands[:, skel.n_dof :]
    )
    stale = explain_cost(
        now, skel, balls, s, balls.radii, q[None, : skel.n_dof], q[None, skel.n_dof :]
    )[0]
    best = cands[int(np.argmin(cost)), skel.n_dof :]
    assert np.linalg.norm(best - root1) < 0.08 and cost.min() < 0.2 * stale, (best, stale)
    assert recentred_starts(np.zeros((0, 3)), q, ref, root0, up).shape == (0, skel.n_dof + 3)


def test_the_veto_keeps_a_limb_on_its_points_within_a_slack(body, rng):
    """``keeps_points``: a leg carrying points may not be moved off them, but a move
    that leaves the points' cost higher only by crumbs (less than ``slack``, a tenth of
    one point one σ off) is allowed; with no slack the crumbs veto it."""
    from core.fit_search import keeps_points

    skel, s, balls = body
    root = np.array([0.0, 0.0, 1.0])
    theta = np.zeros(skel.n_dof)
    x = _outer(skel, balls, theta, root, s, rng)
    hip = skel.dof_index("l_hip_x")
    kicked, nudged = theta.copy(), theta.copy()
    kicked[hip], nudged[hip] = -1.0, -0.0005
    poses, roots = np.stack([theta, kicked, nudged]), np.stack([root] * 3)
    c = explain_cost(x, skel, balls, s, balls.radii, poses, roots)
    assert c[1] - c[0] > 100.0  # the leg taken off its points
    assert 0.0 < c[2] - c[0] < 0.1  # crumbs
    allowed = keeps_points(x, skel, balls, s, balls.radii, root)
    assert not allowed(theta, kicked)
    assert allowed(theta, nudged)
    assert not keeps_points(x, skel, balls, s, balls.radii, root, slack=0.0)(theta, nudged)
