"""Measures of retargeting quality shared by the tests and bench/retarget.py (bpy)."""

from __future__ import annotations

import numpy as np

from addon import builders
from addon import retarget as rt
from core.retarget import angle_between


def direction_errors_deg(source, target, frames, pairs) -> np.ndarray:
    """Angle (degrees, (F, P)) between paired bones' world directions (head -> tail)."""
    S = builders.pose_world_matrices(source, frames)
    T = builders.pose_world_matrices(target, frames)
    sn = [b.name for b in source.data.bones]
    tn = [b.name for b in target.data.bones]
    si = [sn.index(s) for s in pairs]
    ti = [tn.index(t) for t in pairs.values()]
    return np.degrees(angle_between(S[:, si, :3, 1], T[:, ti, :3, 1]))


def root_path_error(source, target, frames, scale) -> np.ndarray:
    """Distance (m, (F,)) of the target's hips from the source's, scaled about the origins."""
    sm, tm = rt.rig_mapping(source), rt.rig_mapping(target)
    S = builders.pose_world_matrices(source, frames)
    T = builders.pose_world_matrices(target, frames)
    ps = S[:, [b.name for b in source.data.bones].index(sm.bones["pelvis"]), :3, 3]
    pt = T[:, [b.name for b in target.data.bones].index(tm.bones["pelvis"]), :3, 3]
    o_s = np.array(source.matrix_world)[:3, 3] * [1, 1, 0]
    o_t = np.array(target.matrix_world)[:3, 3] * [1, 1, 0]
    return np.linalg.norm(pt - (o_t + scale * (ps - o_s)), axis=1)


def rig_height(obj) -> float:
    """Rest height (m) of an armature: highest bone point above the lowest."""
    R = np.array(obj.matrix_world)[None] @ builders.armature_rest(obj)
    L = np.array([b.length for b in obj.data.bones])
    pts = np.concatenate([R[:, :3, 3], R[:, :3, 3] + R[:, :3, 1] * L[:, None]])
    return float(pts[:, 2].max() - pts[:, 2].min())


def copy_rig(obj, name):
    """A copy of an armature object (own armature data, no animation)."""
    import bpy

    new = obj.copy()
    new.data = obj.data.copy()
    new.name = name
    new.animation_data_clear()
    bpy.context.scene.collection.objects.link(new)
    return new


def rename_and_reroll(obj, names: dict, roll_deg: float, seed: int = 0):
    """Rename bones (``old -> new``) and add random rolls up to ``roll_deg`` (edit mode)."""
    import bpy

    rng = np.random.default_rng(seed)
    view_layer = bpy.context.view_layer
    view_layer.objects.active = obj
    bpy.ops.object.mode_set(mode="EDIT")
    for eb in obj.data.edit_bones:
        eb.roll += float(np.radians(rng.uniform(-roll_deg, roll_deg)))
    bpy.ops.object.mode_set(mode="OBJECT")
    for old, new in names.items():
        obj.data.bones[old].name = new
    return obj
