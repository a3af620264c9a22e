"""World-space retargeting maths (no Blender): rest alignment, round trip, root path."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from core import retarget as rt


def _rot(rng, n):
    return Rotation.random(n, random_state=rng).as_matrix()


def test_swing_is_minimal_rotation(rng):
    a = rng.normal(size=(200, 3))
    b = rng.normal(size=(200, 3))
    b[:3] = -a[:3]  # anti-parallel
    b[3:6] = a[3:6] * 2.0  # parallel
    R = rt.swing(a, b)
    np.testing.assert_allclose(
        R @ np.swapaxes(R, -1, -2), np.broadcast_to(np.eye(3), R.shape), atol=1e-12
    )
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    au = a / np.linalg.norm(a, axis=1, keepdims=True)
    bu = b / np.linalg.norm(b, axis=1, keepdims=True)
    np.testing.assert_allclose(np.einsum("nij,nj->ni", R, au), bu, atol=1e-12)
    # Minimal: the rotation angle equals the angle between the vectors.
    angle = np.arccos(np.clip((np.trace(R, axis1=1, axis2=2) - 1) / 2, -1, 1))
    np.testing.assert_allclose(angle, rt.angle_between(a, b), atol=1e-6)


def test_transfer_puts_bones_along_source_and_round_trips(rng):
    F, P = 30, 14
    src_rest, tgt_rest = _rot(rng, P), _rot(rng, P)  # any rest poses and rolls
    src_pose = _rot(rng, F * P).reshape(F, P, 3, 3)
    tgt_pose = rt.transfer_rotations(src_rest, src_pose, tgt_rest)
    np.testing.assert_allclose(tgt_pose[..., :, 1], src_pose[..., :, 1], atol=1e-12)
    back = rt.transfer_rotations(tgt_rest, tgt_pose, src_rest)
    np.testing.assert_allclose(back, src_pose, atol=1e-12)
    # Twist follows the source: a pure twist of the source about its bone axis
    # gives the same twist angle on the target.
    twist = Rotation.from_rotvec(src_rest[:, :, 1] * 0.7).as_matrix()
    out = rt.transfer_rotations(src_rest, (twist @ src_rest)[None], tgt_rest)[0]
    delta = out @ np.swapaxes(rt.transfer_rotations(src_rest, src_rest[None], tgt_rest)[0], -1, -2)
    np.testing.assert_allclose(Rotation.from_matrix(delta).magnitude(), 0.7, atol=1e-9)


def test_rest_pose_maps_to_aligned_rest(rng):
    """Source standing in its rest pose: the target's bones point along the source's."""
    P = 6
    src_rest, tgt_rest = _rot(rng, P), _rot(rng, P)
    out = rt.transfer_rotations(src_rest, src_rest[None], tgt_rest)[0]
    np.testing.assert_allclose(out[:, :, 1], src_rest[:, :, 1], atol=1e-12)


def test_leg_length_and_root_path():
    heads = {
        "l_thigh": [0.1, 0, 1.0],
        "l_shin": [0.1, 0, 0.55],
        "l_foot": [0.1, 0.05, 0.1],
        "r_thigh": [-0.1, 0, 1.0],
        "r_shin": [-0.1, 0, 0.5],
        "r_foot": [-0.1, 0, 0.1],
    }
    want = (0.45 + np.hypot(0.45, 0.05) + 0.5 + 0.4) / 2
    assert rt.leg_length(heads) == pytest.approx(want)
    with pytest.raises(ValueError, match="no leg"):
        rt.leg_length({"pelvis": [0, 0, 1]})
    path = np.array([[0.0, 0.0, 1.0], [0.0, -1.0, 1.1]])
    out = rt.scale_root_path(path, 0.5, np.array([0.0, 0, 0]), np.array([2.0, 0, 0]))
    np.testing.assert_allclose(out, [[2.0, 0, 0.5], [2.0, -0.5, 0.55]])


def test_pose_matrices_follow_hierarchy(rng):
    # chain 0 -> 1 -> 2, bone 3 child of 0
    rest = np.tile(np.eye(4), (4, 1, 1))
    rest[:, :3, :3] = _rot(rng, 4)
    rest[:, :3, 3] = rng.normal(size=(4, 3))
    parent = np.array([-1, 0, 1, 0])
    F = 5
    rot = {1: _rot(rng, F)}
    root = {0: rng.normal(size=(F, 3))}
    pose = rt.pose_matrices(rest, parent, rot, root, F)
    np.testing.assert_allclose(pose[:, 0, :3, 3], root[0])
    np.testing.assert_allclose(pose[:, 0, :3, :3], np.broadcast_to(rest[0, :3, :3], (F, 3, 3)))
    np.testing.assert_allclose(pose[:, 1, :3, :3], rot[1])
    # Unmapped child 2 keeps its rest offset and orientation relative to bone 1.
    rel = np.linalg.inv(rest[1]) @ rest[2]
    np.testing.assert_allclose(pose[:, 2], pose[:, 1] @ rel, atol=1e-12)
    # Head of 1 rides rigidly on 0.
    np.testing.assert_allclose(
        pose[:, 1, :3, 3], (pose[:, 0] @ (np.linalg.inv(rest[0]) @ rest[1]))[:, :3, 3]
    )


def test_unkeyed_bones_keep_their_static_pose(rng):
    rest = np.tile(np.eye(4), (3, 1, 1))
    rest[:, :3, 3] = [[0, 0, 1], [0, 0.2, 1], [0, 0.4, 1]]
    parent = np.array([-1, 0, 1])
    basis = np.tile(np.eye(4), (3, 1, 1))
    basis[1, :3, :3] = _rot(rng, 1)[0]  # the user's static pose of unmapped bone 1
    rot = {2: _rot(rng, 4)}
    pose = rt.pose_matrices(rest, parent, rot, {}, 4, basis=basis)
    np.testing.assert_allclose(
        pose[:, 1, :3, :3], np.broadcast_to(basis[1, :3, :3], (4, 3, 3)), atol=1e-12
    )
    np.testing.assert_allclose(pose[:, 2, :3, :3], rot[2])  # mapped: absolute world rotation
