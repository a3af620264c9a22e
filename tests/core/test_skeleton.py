"""Skeleton: structure, forward kinematics, analytic Jacobians vs finite differences."""

import numpy as np
import pytest

from core import skeleton as sk
from core.landmarks import JOINTS


@pytest.fixture
def skel():
    return sk.make_skeleton()


def _random_pose(skel, rng, nf=3):
    theta = rng.normal(0.0, 0.5, (nf, skel.n_dof))
    root = rng.normal(0.0, 1.0, (nf, 3))
    s = 1.0 + 0.1 * rng.normal(size=skel.n_groups)
    return theta, root, s


def test_structure(skel):
    assert skel.validate() is None
    assert skel.joint_names == JOINTS
    # every DOF rotates about its own z: single-DOF chains, parents before children
    assert all(p < k for k, p in enumerate(skel.dof_parent))
    assert skel.dof_names[:3] == ("pelvis_z", "pelvis_x", "pelvis_y")
    assert skel.n_dof == 47


def test_rest_pose_is_template(skel):
    x = sk.joint_positions(skel, np.zeros(skel.n_dof), np.zeros(3), np.ones(skel.n_groups))
    # at theta = 0 the anatomical frames are world-aligned: offsets simply add up
    j = {n: i for i, n in enumerate(JOINTS)}
    np.testing.assert_allclose(x[j["l_elbow"]] - x[j["l_shoulder"]], [0, 0, -0.29], atol=1e-12)
    np.testing.assert_allclose(x[j["r_toe"]] - x[j["r_ankle"]], [0, -0.14, -0.06], atol=1e-12)
    assert x[j["head_top"], 2] - x[j["l_toe"], 2] == pytest.approx(1.64, abs=1e-9)


def test_each_dof_is_a_rotation_about_its_axis(skel, rng):
    theta, root, s = _random_pose(skel, rng, 1)
    k = skel.dof_index("l_elbow_x")
    pose = sk.forward(skel, theta, root, s)
    x0 = sk.joint_positions(skel, theta, root, s)[0]
    theta2 = theta.copy()
    theta2[0, k] += 0.3
    x1 = sk.joint_positions(skel, theta2, root, s)[0]
    w, p = pose.axes[0, k], pose.p[0, k]
    j = skel.joint_index("l_wrist")
    # the wrist turns by 0.3 rad about the elbow axis through the elbow
    a, b = x0[j] - p, x1[j] - p
    a_perp, b_perp = a - w * (a @ w), b - w * (b @ w)
    cosang = a_perp @ b_perp / (np.linalg.norm(a_perp) * np.linalg.norm(b_perp))
    assert np.arccos(np.clip(cosang, -1, 1)) == pytest.approx(0.3, abs=1e-9)
    np.testing.assert_allclose(x1[skel.joint_index("l_elbow")], x0[skel.joint_index("l_elbow")])
    np.testing.assert_allclose(x1[skel.joint_index("r_wrist")], x0[skel.joint_index("r_wrist")])


def test_joint_jacobians_match_finite_differences(skel, rng):
    theta, root, s = _random_pose(skel, rng)
    _, J_theta, J_s = sk.joint_jacobians(skel, theta, root, s)
    eps = 1e-6
    num = np.stack(
        [
            (
                sk.joint_positions(skel, theta + eps * e, root, s)
                - sk.joint_positions(skel, theta - eps * e, root, s)
            )
            / (2 * eps)
            for e in np.eye(skel.n_dof)
        ],
        axis=-1,
    )
    np.testing.assert_allclose(J_theta, num, atol=1e-8)
    num_s = np.stack(
        [
            (
                sk.joint_positions(skel, theta, root, s + eps * e)
                - sk.joint_positions(skel, theta, root, s - eps * e)
            )
            / (2 * eps)
            for e in np.eye(skel.n_groups)
        ],
        axis=-1,
    )
    np.testing.assert_allclose(J_s, num_s, atol=1e-8)


def test_attached_point_jacobians(skel, rng):
    theta, root, s = _random_pose(skel, rng, 2)
    bone = rng.integers(0, len(skel.bone_names), 40)
    q0 = rng.normal(0, 0.1, (40, 3))
    group = rng.integers(-1, skel.n_groups, 40)

    def pts(th, ss):
        return sk.points_world(skel, sk.forward(skel, th, root, ss), bone, q0, group, ss)

    x, J_theta, J_s = sk.point_jacobians(skel, sk.forward(skel, theta, root, s), bone, q0, group, s)
    np.testing.assert_allclose(x, pts(theta, s))
    eps = 1e-6
    k = rng.integers(0, skel.n_dof)
    e = np.zeros(skel.n_dof)
    e[k] = eps
    np.testing.assert_allclose(
        J_theta[..., k], (pts(theta + e, s) - pts(theta - e, s)) / (2 * eps), atol=1e-8
    )
    for g in range(skel.n_groups):
        e = np.zeros(skel.n_groups)
        e[g] = eps
        np.testing.assert_allclose(
            J_s[..., g], (pts(theta, s + e) - pts(theta, s - e)) / (2 * eps), atol=1e-8
        )
    # the rotation columns are np.cross's ω_k × (x − p_k) on the ancestors, to the bit
    pose = sk.forward(skel, theta, root, s)
    mask = skel.ancestors()[skel.bone_dof[bone]]
    ref = np.cross(pose.axes[:, None], x[:, :, None] - pose.p[:, None]) * mask[None, :, :, None]
    np.testing.assert_array_equal(J_theta, np.swapaxes(ref, 2, 3))
    # without the scales: the same positions and rotation columns, to the bit
    x2, J_theta2, J_s2 = sk.point_jacobians(skel, pose, bone, q0, group, s, scales=False)
    np.testing.assert_array_equal(x2, x)
    np.testing.assert_array_equal(J_theta2, J_theta)
    assert J_s2 is None


def test_unscaled_points_scale_jacobian_is_their_bones(skel, rng):
    """A point with no scale group moves with s only through the DOF offsets above
    it: its J_s is its bone's, wherever on the bone it sits (contour_pairs relies on
    this to take the scales from its rim points' own call)."""
    theta, root, s = _random_pose(skel, rng, 1)
    pose = sk.forward(skel, theta, root, s)
    bone = rng.integers(0, len(skel.bone_names), 30)
    none = np.full(30, -1)
    J_a = sk.point_jacobians(skel, pose, bone, rng.normal(0, 0.1, (30, 3)), none, s)[2]
    J_b = sk.point_jacobians(skel, pose, bone, np.zeros((30, 3)), none, s)[2]
    np.testing.assert_array_equal(J_a, J_b)


def test_bone_matrices_follow_bones(skel, rng):
    theta, root, s = _random_pose(skel, rng, 2)
    M = sk.bone_matrices(skel, theta, root, s)
    x = sk.joint_positions(skel, theta, root, s)
    assert M.shape == (2, len(skel.bone_names), 4, 4)
    R = M[..., :3, :3]
    np.testing.assert_allclose(
        R @ np.swapaxes(R, -1, -2), np.broadcast_to(np.eye(3), R.shape), atol=1e-12
    )
    for b, name in enumerate(skel.bone_names):
        head, tail = skel.joint_index(skel.bone_head[b]), skel.joint_index(skel.bone_tail[b])
        np.testing.assert_allclose(M[:, b, :3, 3], x[:, head], atol=1e-12)
        if name in ("pelvis",):
            continue
        d = x[:, tail] - x[:, head]
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
        np.testing.assert_allclose(M[:, b, :3, 1], d, atol=1e-12)


def test_soft_limits(skel):
    theta = np.zeros((1, skel.n_dof))
    k = skel.dof_index("l_knee_x")
    theta[0, k] = -0.5  # hyper-extension beyond -5 degrees
    r, J = sk.limit_residuals(skel, theta, sigma=0.1)
    assert r[0, k] == pytest.approx((skel.dof_lo[k] + 0.5) / 0.1)
    assert J[0, k] == pytest.approx(-10.0)
    assert np.count_nonzero(r) == 1


def test_dict_round_trip(skel):
    back = sk.Skeleton.from_dict(skel.to_dict())
    theta = np.linspace(-1, 1, skel.n_dof)[None]
    np.testing.assert_allclose(
        sk.joint_positions(back, theta, np.zeros(3), np.ones(11)),
        sk.joint_positions(skel, theta, np.zeros(3), np.ones(11)),
    )


def _moves_outward(skel, dof, val, joint):
    """Whether setting ``dof`` to ``val`` moves ``joint`` away from the body's midline (x = 0)
    or up, seen from the rest pose."""
    s = np.ones(skel.n_groups)
    root = np.array([0.0, 0.0, 1.0])
    th = np.zeros(skel.n_dof)
    before = sk.joint_positions(skel, th, root, s)[skel.joint_index(joint)]
    th[skel.dof_index(dof)] = val
    after = sk.joint_positions(skel, th, root, s)[skel.joint_index(joint)]
    return abs(after[0]) > abs(before[0]) + 1e-3, after[2] > before[2] + 1e-3


@pytest.mark.parametrize("side", ["l", "r"])
def test_limits_allow_abduction_more_than_adduction(skel, side):
    """Arms and legs abduct (away from the midline) further than they adduct across it;
    shoulders elevate further than they drop.  (LIMITS are in degrees.)"""
    for bone, joint, wide in (("shoulder", "elbow", 150), ("hip", "knee", 60)):
        dof = f"{side}_{bone}_y"
        lo, hi = sk.LIMITS[dof]
        outward_dir = 1.0 if _moves_outward(skel, dof, 0.3, f"{side}_{joint}")[0] else -1.0
        abduction = hi if outward_dir > 0 else -lo
        adduction = -lo if outward_dir > 0 else hi
        assert abduction >= wide and adduction <= 35, (dof, lo, hi)
    dof = f"{side}_clavicle_y"
    lo, hi = sk.LIMITS[dof]
    up_dir = 1.0 if _moves_outward(skel, dof, 0.3, f"{side}_shoulder")[1] else -1.0
    elevation = hi if up_dir > 0 else -lo
    depression = -lo if up_dir > 0 else hi
    assert elevation > depression, (dof, lo, hi)


def test_forward_of_some_dofs_is_the_full_forward_there(skel, rng):
    """forward(..., dofs=...) poses the DOFs asked for and their ancestors alone: the
    same bits as the full forward there, NaN elsewhere (the silhouette limb search poses
    one limb hundreds of times a frame)."""
    theta, root, s = _random_pose(skel, rng, nf=5)
    full = sk.forward(skel, theta, root, s)
    elbow = skel.dof_index("l_elbow_x")
    part = sk.forward(skel, theta, root, s, dofs=[elbow])
    chain = sk.dof_chains(skel, [elbow])
    assert chain[0] == 0 and chain[-1] == elbow and list(chain) == sorted(chain)
    assert all(skel.dof_parent[k] in chain for k in chain[1:])
    for a, b in ((part.R, full.R), (part.p, full.p), (part.R_parent, full.R_parent)):
        np.testing.assert_array_equal(a[:, chain], b[:, chain])
        assert np.isnan(np.delete(a, chain, axis=1)).all()
