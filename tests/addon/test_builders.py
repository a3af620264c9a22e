"""Armature, metaballs and action built from a fitted state match core's kinematics."""

from __future__ import annotations

import numpy as np
import pytest

from core.skeleton import joint_positions

from .state_fixtures import synthetic_state

pytestmark = pytest.mark.blender


@pytest.fixture(scope="module")
def built(bpy_module):
    from addon import builders

    bpy = bpy_module
    bpy.ops.wm.read_factory_settings(use_empty=True)
    state = synthetic_state(n_frames=12)
    arm, balls, action = builders.build_body(state, take="walk01")
    yield bpy, state, arm, balls, action
    bpy.ops.wm.read_factory_settings(use_empty=True)


def test_armature_joints_equal_core_kinematics_every_frame(built):
    from addon import builders

    bpy, state, arm, _, _ = built
    skel = state.skeleton
    frames = np.arange(1, state.n_frames + 1)
    M = builders.pose_world_matrices(arm, frames)  # (F, B, 4, 4)
    names = [pb.name for pb in arm.pose.bones]
    assert names == list(skel.bone_names)
    lengths = np.array([b.length for b in arm.data.bones])
    heads = M[..., :3, 3]
    tails = heads + M[..., :3, 1] * lengths[None, :, None]
    truth = joint_positions(skel, state.theta, state.root_xyz, state.s)  # (F, J, 3)
    checked = set()
    for b in range(len(names)):
        for pos, joint in ((heads, skel.bone_head[b]), (tails, skel.bone_tail[b])):
            j = skel.joint_index(joint)
            if pos is tails and skel.joint_bone[j] != b:
                continue  # e.g. the pelvis' tail (spine joint) rides on the lowerback
            err = np.linalg.norm(pos[:, b] - truth[:, j], axis=1)
            assert err.max() < 1e-5, (names[b], joint, err.max())
            checked.add(joint)
    assert checked == set(skel.joint_names)
    # Bone orientation too (roll included): Blender's bone frames = core's bone matrices.
    np.testing.assert_allclose(M[..., :3, :3], state.bone_matrices()[..., :3, :3], atol=1e-5)


def test_action_range_and_key_count(built):
    from addon import action_api

    bpy, state, arm, _, action = built
    assert action.name == "walk01"
    assert arm.animation_data.action == action
    fcs = list(action_api.fcurves(arm, action))
    n_bones = len(arm.pose.bones)
    rot = [fc for fc in fcs if fc.data_path.endswith("rotation_quaternion")]
    loc = [fc for fc in fcs if fc.data_path.endswith("location")]
    assert len(rot) == 4 * n_bones
    assert [fc.data_path for fc in loc] == ['pose.bones["pelvis"].location'] * 3
    for fc in fcs:
        assert len(fc.keyframe_points) == state.n_frames
        assert tuple(fc.range()) == (1.0, float(state.n_frames))
    assert tuple(action.frame_range) == (1.0, float(state.n_frames))
    scene = bpy.context.scene
    assert (scene.frame_start, scene.frame_end) == (1, state.n_frames)


def test_metaballs_one_family_parented_to_bones(built):
    bpy, state, arm, balls, _ = built
    assert len(balls) == len(set(state.metaballs.bone))
    family = {o.name.split(".")[0] for o in balls}
    assert family == {"walk01_body"}
    assert sum(len(o.data.elements) for o in balls) == len(state.metaballs.bone)
    for o in balls:
        assert o.type == "META" and o.parent == arm and o.parent_type == "BONE"
        assert o.parent_bone in arm.data.bones
    # An element centre follows its bone: world position = core's metaball centre.
    from core.metaballs import world_frames
    from core.skeleton import forward

    bpy.context.scene.frame_set(5)
    pose = forward(state.skeleton, state.theta[4:5], state.root_xyz[4:5], state.s)
    _, cw = world_frames(state.skeleton, pose, state.metaballs, state.s)
    got = []
    for o in balls:
        mw = np.array(o.matrix_world)
        got += [(mw @ np.r_[np.array(e.co), 1.0])[:3] for e in o.data.elements]
    order = np.argsort(state.metaballs.bone, kind="stable")
    np.testing.assert_allclose(np.array(got), cw[0][order], atol=1e-5)


def test_second_take_never_overwrites_the_first(built):
    from addon import builders

    bpy, state, arm, _, action = built
    keys_before = [tuple(k.co) for k in action.fcurves[0].keyframe_points] if hasattr(
        action, "fcurves") else None
    action2 = builders.keyframe_state(arm, synthetic_state(5, seed=3), "walk01")
    assert action2.name != "walk01" and action2.name.startswith("walk01")
    assert bpy.data.actions["walk01"] == action
    if keys_before is not None:
        assert [tuple(k.co) for k in action.fcurves[0].keyframe_points] == keys_before
    arm.animation_data.action = action


def test_unobserved_frames_are_breakdown_keys(bpy_module):
    from addon import action_api, builders

    bpy = bpy_module
    bpy.ops.wm.read_factory_settings(use_empty=True)
    state = synthetic_state(n_frames=8, seed=5)
    skel = state.skeleton
    un = np.zeros((8, skel.n_dof), bool)
    un[3:6, skel.dof_index("r_elbow_x")] = True  # the forearm unseen in frames 3-5
    state.quality.unobserved = un
    arm, _, action = builders.build_body(state, take="hidden")
    kinds = {}
    for fc in action_api.fcurves(arm, action):
        bone = fc.data_path.split('"')[1]
        kinds.setdefault(bone, set()).add(tuple(k.type for k in fc.keyframe_points))
    want = tuple("BREAKDOWN" if 3 <= f < 6 else "KEYFRAME" for f in range(8))
    assert kinds["r_elbow"] == {want}
    assert all(v == {("KEYFRAME",) * 8} for b, v in kinds.items() if b != "r_elbow")
    bpy.ops.wm.read_factory_settings(use_empty=True)
