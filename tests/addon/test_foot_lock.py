"""Foot locking in the Blender retarget: the studio walk onto the Rigify meta-rig (bpy)."""

from __future__ import annotations

import numpy as np
import pytest

from tests.conftest import DEFAULT_SCENE

from .rig_checks import direction_errors_deg

pytestmark = [pytest.mark.blender, pytest.mark.slow]


@pytest.fixture(scope="module")
def walk(bpy_module):
    import addon_utils

    from addon import pipeline
    from core.scene import load_scene
    from core.truth_state import truth_to_state

    bpy = bpy_module
    bpy.ops.wm.read_factory_settings(use_empty=True)
    addon_utils.enable("rigify", default_set=True)
    scene = load_scene(DEFAULT_SCENE)
    state, _ = truth_to_state(scene.truth, scene.fps)
    bpy.context.scene.render.fps = int(round(scene.fps))
    arm, _, _ = pipeline.build_take(state, "walk")
    yield bpy, state, arm
    bpy.ops.wm.read_factory_settings(use_empty=True)


def _foot_heads(bpy, rig, mapping, frames):
    from addon import builders

    M = builders.pose_world_matrices(rig, frames)
    names = [b.name for b in rig.data.bones]
    return {s: M[:, names.index(mapping.bones[f"{s}_foot"]), :3, 3] for s in "lr"}


def test_foot_lock_removes_skate_and_leaves_the_rest(walk):
    from addon import retarget as rt
    from core.foot_lock import contact_mask, skate_mm

    bpy, state, arm = walk
    frames = np.arange(1, state.n_frames + 1)
    rigs = {}
    for lock in (False, True):
        bpy.ops.object.armature_human_metarig_add()
        rig = bpy.context.active_object
        rig.name = f"meta_lock_{lock}"
        res = rt.retarget(arm, rig, take=f"walk_{lock}", foot_lock=lock)
        rigs[lock] = (rig, res)
    mapping = rt.rig_mapping(rigs[True][0])
    free = _foot_heads(bpy, rigs[False][0], mapping, frames)
    locked = _foot_heads(bpy, rigs[True][0], mapping, frames)
    res = rigs[True][1]
    for s in "lr":
        contact = contact_mask(free[s], state.fps)
        assert contact.sum() >= 5, f"{s}: the walk should have a stance phase"
        before, after = skate_mm(free[s], contact), skate_mm(locked[s], contact)
        # measured on the evaluated rig, as the result reports it
        np.testing.assert_allclose([before, after], res.foot_skate_mm[s], atol=0.5)
        assert after < 0.2 * before and after < 5.0, (s, before, after)
    # the upper body is untouched; legs only move during contact
    upper = {
        k: v
        for k, v in res.pairs.items()
        if not any(
            p in k.lower() for p in ("leg", "foot", "toe", "thigh", "shin", "knee", "ankle", "hip")
        )
    }
    assert len(upper) >= 10
    assert direction_errors_deg(arm, rigs[True][0], frames, upper).max() < 1.0


def test_foot_lock_on_driven_rig_is_refused_cleanly(walk):
    from addon import retarget as rt
    from core.errors import InputError

    from .rig_checks import generate_rigify_human

    bpy, state, arm = walk
    rig = generate_rigify_human("gen_for_lock", face=False)
    actions = len(bpy.data.actions)
    with pytest.raises(InputError, match="foot locking is not available"):
        rt.retarget(arm, rig, take="x", foot_lock=True)
    assert len(bpy.data.actions) == actions
