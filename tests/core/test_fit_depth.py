"""Depth holds for parts that one camera's contours see (core.fit_depth)."""

import numpy as np

from core import skeleton as sk
from core.fit_depth import (
    DepthHolds,
    depth_holds,
    narrow_depth_holds,
    part_views,
    single_view_parts,
)
from tests.core._bodyscene import look_at


def _pose(skel, rng):
    theta = rng.normal(0.0, 0.2, skel.n_dof)
    return np.clip(theta, skel.dof_lo, skel.dof_hi), np.array([0.1, -0.2, 1.0])


def test_single_view_parts_names_the_one_camera_or_minus_one():
    # part 0: 12 pairs in camera 1; part 1: 12 in cameras 0 and 2; part 2: 5 in camera 0
    # (too few); part 3: 12 in camera 2 and 3 in camera 0
    bone = np.repeat([0, 1, 1, 2, 3, 3], [12, 12, 12, 5, 12, 3])
    camera = np.repeat([1, 0, 2, 0, 2, 0], [12, 12, 12, 5, 12, 3])
    np.testing.assert_array_equal(single_view_parts(bone, camera, 5, 3), [1, -1, -1, 2, -1])


def test_depth_hold_jacobians_match_finite_differences():
    rng = np.random.default_rng(4)
    skel = sk.make_skeleton()
    s = np.exp(rng.normal(0.0, 0.05, skel.n_groups))
    theta, root = _pose(skel, rng)
    cams = [
        look_at("cam01", (0.0, -4.0, 1.1), (0.0, 0.0, 1.0), f=700.0),
        look_at("cam02", (4.0, 0.0, 1.1), (0.0, 0.0, 1.0), f=700.0),
    ]
    B = len(skel.bone_names)
    view = np.full(B, -1)
    view[skel.bone_index("r_elbow")] = 0
    view[skel.bone_index("l_knee")] = 1
    view[skel.bone_index("l_shoulder")] = 1
    shown = np.ones(B, bool)
    shown[skel.bone_index("l_shoulder")] = False  # hidden: not held
    holds = depth_holds(skel, theta, root, s, view, cams, shown, 0.03)
    names = [skel.joint_names[j] for j in holds.joint]
    assert names == ["r_wrist", "l_ankle"]
    # rays from the camera centres through the joints, unit length
    x = sk.joint_positions(skel, theta, root, s)[holds.joint]
    np.testing.assert_allclose(np.cross(holds.direction, x - cams[0].center)[0], 0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(holds.direction, axis=1), 1.0)
    # at the held pose the residuals vanish; off it, only the depth counts
    th1 = theta + rng.normal(0.0, 0.05, theta.shape)
    rt1 = root + np.array([0.02, -0.01, 0.03])
    s1 = s * 1.02
    np.testing.assert_allclose(holds.block(skel, theta, root, s)[0], 0.0, atol=1e-12)
    r, Jt, Jr, Js = holds.block(skel, th1, rt1, s1)
    x1 = sk.joint_positions(skel, th1, rt1, s1)[holds.joint]
    np.testing.assert_allclose(r, np.sum((x1 - x) * holds.direction, axis=1) / 0.03)
    eps = 1e-6
    for J, base, setter in (
        (Jt, th1, lambda v: (v, rt1, s1)),
        (Jr, rt1, lambda v: (th1, v, s1)),
        (Js, s1, lambda v: (th1, rt1, v)),
    ):
        fd = np.zeros_like(J)
        for k in range(base.size):
            d = np.zeros_like(base)
            d[k] = eps
            fd[:, k] = (
                holds.block(skel, *setter(base + d))[0] - holds.block(skel, *setter(base - d))[0]
            ) / (2 * eps)
        np.testing.assert_allclose(J, fd, atol=1e-6)


def test_no_single_view_part_gives_no_holds():
    skel = sk.make_skeleton()
    theta, root = np.zeros(skel.n_dof), np.array([0.0, 0.0, 1.0])
    B = len(skel.bone_names)
    holds = depth_holds(
        skel,
        theta,
        root,
        np.ones(skel.n_groups),
        np.full(B, -1),
        [look_at("cam01", (0.0, -4.0, 1.1), (0.0, 0.0, 1.0))],
        np.ones(B, bool),
        0.03,
    )
    assert isinstance(holds, DepthHolds) and len(holds) == 0
    r, Jt, Jr, Js = holds.block(skel, theta, root, np.ones(skel.n_groups))
    assert r.shape == (0,) and Jt.shape == (0, skel.n_dof) and Jr.shape == (0, 3)


def test_narrow_views_hold_along_their_mean_ray_and_wide_views_do_not():
    """Three cameras in a line 36° apart see one limb's outline nearly alike: its joints
    are held along the mean of their rays.  A part two orthogonal views see is not held;
    with a spread of 0 only single-view parts are, exactly as :func:`depth_holds`."""
    rng = np.random.default_rng(7)
    skel = sk.make_skeleton()
    s = np.ones(skel.n_groups)
    theta, root = _pose(skel, rng)
    cams = [
        look_at(f"cam0{i + 1}", (x, -4.0, 1.1), (0.0, 0.0, 1.0), f=700.0)
        for i, x in enumerate((-1.3, 0.0, 1.3))
    ]
    cams.append(look_at("cam04", (4.0, 0.0, 1.1), (0.0, 0.0, 1.0), f=700.0))
    B = len(skel.bone_names)
    # r_elbow (forearm) in the three line cameras, l_knee (shin) in cam01 and the
    # orthogonal cam04, l_shoulder (upper arm) in cam02 alone
    bone = np.repeat(
        [skel.bone_index(b) for b in ("r_elbow", "l_knee", "l_shoulder")], [36, 24, 12]
    )
    camera = np.concatenate([np.repeat([0, 1, 2], 12), np.repeat([0, 3], 12), np.full(12, 1)])
    seen = part_views(bone, camera, B, 4)
    shown = np.ones(B, bool)
    holds = narrow_depth_holds(skel, theta, root, s, seen, cams, shown, 0.03, 40.0)
    assert [skel.joint_names[j] for j in holds.joint] == ["l_elbow", "r_wrist"]
    x = sk.joint_positions(skel, theta, root, s)[holds.joint]
    rays = x[1] - np.array([c.center for c in cams[:3]])
    mean = np.sum(rays / np.linalg.norm(rays, axis=1, keepdims=True), axis=0)
    np.testing.assert_allclose(holds.direction[1], mean / np.linalg.norm(mean), atol=1e-12)
    np.testing.assert_allclose(np.cross(holds.direction[0], x[0] - cams[1].center), 0.0, atol=1e-12)
    assert len(narrow_depth_holds(skel, theta, root, s, seen, cams, shown, 0.03, 30.0)) == 1
    single = narrow_depth_holds(skel, theta, root, s, seen, cams, shown, 0.03, 0.0)
    ref = depth_holds(
        skel, theta, root, s, single_view_parts(bone, camera, B, 4), cams, shown, 0.03
    )
    np.testing.assert_array_equal(single.joint, ref.joint)
    np.testing.assert_allclose(single.direction, ref.direction, atol=1e-12)
