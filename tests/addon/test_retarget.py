"""Retargeting a fitted body onto other rigs (bpy): directions, round trip, root path,
the target's own actions kept, and refusals that leave the scene untouched."""

from __future__ import annotations

import json

import numpy as np
import pytest

from core.bone_mapping import SCHEMES
from core.errors import InputError

from .rig_checks import (
    copy_rig,
    direction_errors_deg,
    rename_and_reroll,
    rig_height,
    root_path_error,
)
from .state_fixtures import synthetic_state

pytestmark = pytest.mark.blender


@pytest.fixture(scope="module")
def body(bpy_module):
    import addon_utils

    from addon import pipeline

    bpy = bpy_module
    bpy.ops.wm.read_factory_settings(use_empty=True)
    addon_utils.enable("rigify", default_set=True)
    state = synthetic_state(n_frames=10, seed=11, amplitude=0.5)
    arm, _, _ = pipeline.build_take(state, "walk")
    yield bpy, state, arm
    bpy.ops.wm.read_factory_settings(use_empty=True)


def _metarig(bpy, name, location=(0.0, 0.0, 0.0)):
    bpy.ops.object.armature_human_metarig_add()
    rig = bpy.context.active_object
    rig.name = name
    rig.location = location
    return rig


def test_onto_rigify_metarig_with_other_rolls_and_mixamo_names(body):
    from addon import retarget as rt

    bpy, state, arm = body
    frames = np.arange(1, state.n_frames + 1)
    rigify = _metarig(bpy, "rigify_target", location=(2.0, 0.5, 0.0))
    res = rt.retarget(arm, rigify, take="walk")
    assert res.action.name == "walk.001"  # the body's own "walk" is kept
    assert bpy.data.actions["walk"].users >= 1
    assert len(res.pairs) >= 18 and res.pairs["l_shoulder"] == "upper_arm.L"
    assert "face" in res.unmapped_target
    err = direction_errors_deg(arm, rigify, frames, res.pairs)
    assert err.max() < 1.0, err.max()
    height = rig_height(rigify)
    assert root_path_error(arm, rigify, frames, res.scale).max() < 0.01 * height

    # A second rig: Rigify names turned into Mixamo ones, rolls changed by up to 90°.
    mix = copy_rig(rigify, "mixamo_target")
    to_mixamo = {
        SCHEMES["rigify_metarig"][c]: "mixamorig3:" + SCHEMES["mixamo"][c]
        for c in SCHEMES["mixamo"]
    }
    rename_and_reroll(mix, to_mixamo, roll_deg=90.0)
    res2 = rt.retarget(arm, mix, take="walk")
    assert rt.rig_mapping(mix).scheme == "mixamo"
    err2 = direction_errors_deg(arm, mix, frames, res2.pairs)
    assert err2.max() < 1.0, err2.max()

    # Round trip A -> B -> A: a fresh copy of the body driven by the Mixamo rig.
    back = copy_rig(arm, "walk_back")
    res3 = rt.retarget(mix, back, take="walk_back")
    same = {b: b for b in res3.pairs.values()}
    err3 = direction_errors_deg(arm, back, frames, same)
    assert err3.max() < 0.5, err3.max()


def test_onto_makehuman_keeps_its_actions(body, makehuman):
    from addon import action_api, pipeline
    from addon import retarget as rt

    bpy, state, arm = body
    char = pipeline.load_character(makehuman)
    own = action_api.assign_new_action(char, "users_idle")
    fc = action_api.new_fcurve(char, own, 'pose.bones["Hips"].location', 2, "Hips")
    action_api.write_keys(fc, np.array([1.0, 5.0]), np.array([0.0, 0.1]))
    own.use_fake_user = False
    res = rt.retarget(arm, char, take="walk_mh")
    assert res.action.name == "walk_mh" and char.animation_data.action == res.action
    assert own.name == "users_idle" and own.use_fake_user  # survives saving
    np.testing.assert_allclose(
        [tuple(k.co) for k in fc.keyframe_points], [(1, 0), (5, 0.1)], atol=1e-6
    )
    frames = np.arange(1, state.n_frames + 1)
    assert direction_errors_deg(arm, char, frames, res.pairs).max() < 1.0
    assert root_path_error(arm, char, frames, res.scale).max() < 0.01 * rig_height(char)
    assert 0.7 < res.scale < 1.3


def _scene_fingerprint(bpy):
    return (
        sorted(o.name for o in bpy.data.objects),
        sorted(a.name for a in bpy.data.actions),
        {
            o.name: (
                o.animation_data.action.name
                if o.animation_data and o.animation_data.action
                else None
            )
            for o in bpy.data.objects
        },
    )


def test_bad_targets_change_nothing(body, tmp_path):
    from addon import pipeline
    from addon import retarget as rt

    bpy, state, arm = body
    mesh = bpy.data.objects.new("a_mesh", bpy.data.meshes.new("m"))
    bpy.context.scene.collection.objects.link(mesh)
    before = _scene_fingerprint(bpy)
    with pytest.raises(InputError, match="'a_mesh' is not an armature"):
        rt.retarget(arm, mesh, take="x")
    # A non-humanoid rig: a three-bone tail.
    tail = bpy.data.objects.new("tail", bpy.data.armatures.new("tail"))
    bpy.context.scene.collection.objects.link(tail)
    bpy.context.view_layer.objects.active = tail
    bpy.ops.object.mode_set(mode="EDIT")
    prev = None
    for i in range(3):
        eb = tail.data.edit_bones.new(f"tail.{i:03d}")
        eb.head, eb.tail = (0, i * 0.1, 1), (0, (i + 1) * 0.1, 1)
        eb.parent = prev
        prev = eb
    bpy.ops.object.mode_set(mode="OBJECT")
    before = _scene_fingerprint(bpy)
    with pytest.raises(InputError, match="does not look humanoid.*l_thigh"):
        rt.retarget(arm, tail, take="x")
    assert _scene_fingerprint(bpy) == before
    # A state written by a newer Somacap.
    from core.state import state_to_dict

    d = state_to_dict(state)
    d["version"] = 99
    (tmp_path / "new.json").write_text(json.dumps(d))
    with pytest.raises(InputError, match="new.json: is version 99.*newer"):
        pipeline.read_state(tmp_path / "new.json")
    assert _scene_fingerprint(bpy) == before
    # A character file without an armature.
    bpy.data.libraries.write(str(tmp_path / "noarm.blend"), {mesh.data})
    with pytest.raises(InputError, match="noarm.blend: has no armature"):
        pipeline.load_character(tmp_path / "noarm.blend")
    assert _scene_fingerprint(bpy) == before
