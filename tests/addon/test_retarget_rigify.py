"""Retargeting onto a rig *generated* by Rigify: its DEF bones follow constraints, so the
FK controls are keyed (IK/FK switches to FK) and the DEF bones must follow the source."""

from __future__ import annotations

import numpy as np
import pytest

from .rig_checks import (
    copy_rig,
    direction_errors_deg,
    generate_rigify_human,
    rig_height,
    root_path_error,
)
from .state_fixtures import synthetic_state

pytestmark = [pytest.mark.blender, pytest.mark.slow]


@pytest.fixture(scope="module")
def generated(bpy_module):
    """A posed body (8 frames) and a Rigify human generated once for the module."""
    import addon_utils

    from addon import pipeline

    bpy = bpy_module
    bpy.ops.wm.read_factory_settings(use_empty=True)
    addon_utils.enable("rigify", default_set=True)
    state = synthetic_state(n_frames=8, seed=3, amplitude=0.6)
    arm, _, _ = pipeline.build_take(state, "walk")
    rig = generate_rigify_human("gen_rig", location=(1.5, -0.5, 0.0), face=False)
    yield bpy, state, arm, rig
    bpy.ops.wm.read_factory_settings(use_empty=True)


def test_mapping_measures_def_bones_and_keys_fk_controls(generated):
    from addon import retarget as rt

    bpy, state, arm, rig = generated
    m = rt.rig_mapping(rig)
    assert m.scheme == "rigify_def" and m.is_humanoid
    assert m.bones["l_upper_arm"] == "DEF-upper_arm.L"
    assert m.controls["l_upper_arm"] == "upper_arm_fk.L"
    assert m.controls["r_foot"] == "foot_fk.R" and m.root_control == "torso"


def test_def_bones_follow_the_source_on_every_frame(generated):
    from addon import action_api
    from addon import retarget as rt

    bpy, state, arm, rig = generated
    frames = np.arange(1, state.n_frames + 1)
    res = rt.retarget(arm, rig, take="walk")
    assert res.action.name == "walk.001" and rig.animation_data.action == res.action
    assert len(res.pairs) >= 18 and res.pairs["l_shoulder"] == "DEF-upper_arm.L"
    # Keys on controls and switches only; none on the constraint-driven DEF/ORG bones.
    paths = {fc.data_path for fc in action_api.fcurves(rig, res.action)}
    assert 'pose.bones["upper_arm_fk.L"].rotation_quaternion' in paths
    assert 'pose.bones["torso"].location' in paths
    assert not any('"DEF-' in p or '"ORG-' in p for p in paths)
    assert rig.pose.bones["thigh_parent.R"]["IK_FK"] == 1.0  # FK
    err = direction_errors_deg(arm, rig, frames, res.pairs)
    assert err.max() < 1.0, err.max()
    assert root_path_error(arm, rig, frames, res.scale).max() < 0.01 * rig_height(rig)
    # The FK switch matters: with the arms back in IK the DEF arm no longer follows.
    rig.pose.bones["upper_arm_parent.L"]["IK_FK"] = 0.0
    fc = next(
        f
        for f in action_api.fcurves(rig, res.action)
        if f.data_path == 'pose.bones["upper_arm_parent.L"]["IK_FK"]'
    )
    fc.mute = True
    rig.update_tag()  # an ID property set from Python does not tag the depsgraph
    arm_pairs = {k: v for k, v in res.pairs.items() if v == "DEF-forearm.L"}
    assert direction_errors_deg(arm, rig, frames, arm_pairs).max() > 1.0
    fc.mute = False
    rig.update_tag()
    assert direction_errors_deg(arm, rig, frames, arm_pairs).max() < 1.0

    # Round trip A -> generated rig -> A (read back from the DEF bones).
    back = copy_rig(arm, "walk_back")
    res2 = rt.retarget(rig, back, take="walk_back")
    err2 = direction_errors_deg(arm, back, frames, {b: b for b in res2.pairs.values()})
    assert err2.max() < 0.5, err2.max()
