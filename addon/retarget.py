"""Retarget an armature's animation onto any humanoid rig (thin bpy layer over core).

Bone mapping: :mod:`core.bone_mapping` (automatic, or a preset / hand-edited mapping).
Maths: :mod:`core.retarget` (world-space rest alignment, root path scaled by leg length).
This module reads the rigs' rest and evaluated poses, and writes a **new** action on the
target named after the take; the target's existing actions are kept (given a fake user
so that they survive saving) and never modified.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from . import _core, action_api, builders


@dataclass
class RetargetResult:
    """What a retarget did (for reports)."""

    action: object
    pairs: dict  # source bone -> target bone
    unmapped_source: list = field(default_factory=list)
    unmapped_target: list = field(default_factory=list)
    scale: float = 1.0
    frames: tuple = (1, 1)
    #: with ``foot_lock``: side -> (skate before, skate after) in mm, contact frames only
    foot_skate_mm: dict = field(default_factory=dict)


def _check_target(obj, mapping, min_required: bool = True):
    errors = _core.errors
    if obj is None or obj.type != "ARMATURE":
        name = getattr(obj, "name", "None")
        raise errors.InputError(f"target '{name}' is not an armature: pick a rigged character")
    if min_required and not mapping.is_humanoid:
        raise errors.InputError(
            f"target '{obj.name}' does not look humanoid: no bones found for "
            f"{', '.join(mapping.missing_required)} (mapped {len(mapping.bones)} of "
            f"{len(_core.bone_mapping.CANONICAL_BONES)}; edit the mapping or load a preset)"
        )


def rig_mapping(obj, preset=None):
    """The bone mapping of armature ``obj``: automatic, or ``preset`` (a JSON preset path
    or a :class:`core.bone_mapping.BoneMapping`, e.g. edited in the panel)."""
    names = [b.name for b in obj.data.bones]
    if isinstance(preset, _core.bone_mapping.BoneMapping):
        absent = sorted(set(preset.bones.values()) - set(names))
        if absent:
            raise _core.errors.InputError(f"'{obj.name}' has no bones named {absent}")
        return preset
    if preset:
        return _core.bone_mapping.load_preset(preset, names)
    return _core.bone_mapping.map_bones(names)


def _rest_world(obj) -> np.ndarray:
    return np.array(obj.matrix_world)[None] @ builders.armature_rest(obj)


def _rotations(M: np.ndarray) -> np.ndarray:
    R = M[..., :3, :3]
    return R / np.linalg.norm(R, axis=-2, keepdims=True)


def retarget(
    source,
    target,
    take: str,
    frames=None,
    source_preset=None,
    target_preset=None,
    foot_lock: bool = False,
):
    """Retarget ``source``'s current animation onto ``target`` as a new action ``take``.

    Parameters
    ----------
    source, target : bpy armature objects.
    take : name of the new action (Blender appends ``.001`` … when it exists).
    frames : (first, last) frame range; default: the source action's range.
    foot_lock : pin each target foot while it is in contact (low and slow), bending the
        leg by analytic two-bone IK (:func:`core.foot_lock.lock_leg`).  Not available
        for constraint-driven rigs (generated Rigify) yet.

    Raises
    ------
    core.errors.InputError
        Target not an armature, or not humanoid — before anything is changed.
    """
    rt, bm = _core.retarget, _core.bone_mapping
    if source is None or source.type != "ARMATURE":
        raise _core.errors.InputError("the source is not an armature")
    target_type = getattr(target, "type", None)
    if target_type != "ARMATURE":
        _check_target(target, None)
    src_map = rig_mapping(source, source_preset)
    tgt_map = rig_mapping(target, target_preset)
    _check_target(target, tgt_map)
    if not src_map.is_humanoid:
        raise _core.errors.InputError(
            f"source '{source.name}' is not humanoid (missing {src_map.missing_required})"
        )
    canon = [c for c in bm.CANONICAL_BONES if c in src_map.bones and c in tgt_map.bones]
    if frames is None:
        ad = source.animation_data
        if ad is None or ad.action is None:
            raise _core.errors.InputError(f"source '{source.name}' has no action to retarget")
        frames = tuple(int(round(v)) for v in ad.action.frame_range)
    fr = np.arange(frames[0], frames[1] + 1)

    src_names = [b.name for b in source.data.bones]
    tgt_names = [b.name for b in target.data.bones]
    si = np.array([src_names.index(src_map.bones[c]) for c in canon])
    ti = np.array([tgt_names.index(tgt_map.bones[c]) for c in canon])

    src_pose = builders.pose_world_matrices(source, fr)  # (F, Bs, 4, 4)
    src_rest = _rest_world(source)
    tgt_rest = _rest_world(target)
    R_t = rt.transfer_rotations(
        _rotations(src_rest[si]), _rotations(src_pose[:, si]), _rotations(tgt_rest[ti])
    )  # world

    # Root path scaled by leg length, about each rig's floor origin.
    src_heads = {c: src_rest[src_names.index(src_map.bones[c]), :3, 3] for c in src_map.bones}
    tgt_heads = {c: tgt_rest[tgt_names.index(tgt_map.bones[c]), :3, 3] for c in tgt_map.bones}
    k = rt.leg_length(tgt_heads) / rt.leg_length(src_heads)
    o_s = np.array(source.matrix_world)[:3, 3] * [1, 1, 0]
    o_t = np.array(target.matrix_world)[:3, 3] * [1, 1, 0]
    hips_s = src_pose[:, src_names.index(src_map.bones["pelvis"]), :3, 3]
    hips_t = rt.scale_root_path(hips_s, k, o_s, o_t)

    if tgt_map.controls:  # constraint-driven rig (generated Rigify): key its controls
        if foot_lock:
            raise _core.errors.InputError(
                f"foot locking is not available for the constraint-driven rig "
                f"'{target.name}' yet: retarget without it"
            )
        from . import retarget_driven

        action = retarget_driven.key_controls(target, tgt_map, canon, ti, R_t, hips_t, fr, take)
        action["somacap_leg_scale"] = float(k)
        return RetargetResult(
            action=action,
            pairs={src_map.bones[c]: tgt_map.bones[c] for c in canon},
            unmapped_source=src_map.unmapped,
            unmapped_target=tgt_map.unmapped,
            scale=float(k),
            frames=(int(fr[0]), int(fr[-1])),
        )

    # World -> target armature space.
    M_obj = np.array(target.matrix_world)
    inv_obj = np.linalg.inv(M_obj)
    R_obj = _rotations(M_obj)
    rot = {int(b): R_obj.T[None] @ R_t[:, i] for i, b in enumerate(ti)}
    hip_b = tgt_names.index(tgt_map.bones["pelvis"])
    root = {hip_b: (hips_t @ inv_obj[:3, :3].T) + inv_obj[:3, 3]}
    rest = builders.armature_rest(target)
    parent = np.array(
        [tgt_names.index(b.parent.name) if b.parent else -1 for b in target.data.bones]
    )
    # Bones left unmapped keep their current local pose (Blender keeps unkeyed values).
    buf = np.zeros(len(tgt_names) * 16, dtype=np.float32)
    target.pose.bones.foreach_get("matrix_basis", buf)
    static = buf.reshape(-1, 4, 4).transpose(0, 2, 1).astype(float)
    pose = rt.pose_matrices(rest, parent, rot, root, len(fr), basis=static)
    skate = {}
    if foot_lock:
        skate = _lock_feet(target, canon, ti, tgt_names, R_t, rot, pose, rest, M_obj)
        pose = rt.pose_matrices(rest, parent, rot, root, len(fr), basis=static)
    basis = builders.basis_matrices(rest, parent, pose)

    # Nothing has been changed so far; now write the new action.
    ad = target.animation_data
    if ad is not None and ad.action is not None:
        ad.action.use_fake_user = True  # keep the user's action
    channels = {}
    quats = builders.matrices_to_quaternions(basis)
    for b in ti:
        name = tgt_names[b]
        pb = target.pose.bones[name]
        path = f'pose.bones["{name}"]'
        if pb.rotation_mode == "QUATERNION":
            channels[(path + ".rotation_quaternion", name)] = quats[:, b]
        elif pb.rotation_mode == "AXIS_ANGLE":
            pb.rotation_mode = "QUATERNION"
            channels[(path + ".rotation_quaternion", name)] = quats[:, b]
        else:
            from scipy.spatial.transform import Rotation

            # Blender's order "YXZ" applies Y, then X, then Z about fixed axes: scipy's
            # extrinsic "yxz"; the F-curves are indexed by axis (x, y, z), not by order.
            seq = pb.rotation_mode.lower()
            eul = Rotation.from_matrix(basis[:, b, :3, :3]).as_euler(seq)
            xyz = eul[:, [seq.index(a) for a in "xyz"]]
            channels[(path + ".rotation_euler", name)] = np.unwrap(xyz, axis=0)
    hip_bone = target.data.bones[hip_b]
    if not hip_bone.use_connect:
        channels[(f'pose.bones["{tgt_names[hip_b]}"].location', tgt_names[hip_b])] = basis[
            :, hip_b, :3, 3
        ]
    action = action_api.assign_new_action(target, take)
    action_api.key_channels(target, action, channels, fr)
    action["somacap_take"] = take
    action["somacap_leg_scale"] = float(k)
    action["somacap_foot_lock"] = bool(foot_lock)
    return RetargetResult(
        action=action,
        pairs={src_map.bones[c]: tgt_map.bones[c] for c in canon},
        unmapped_source=src_map.unmapped,
        unmapped_target=tgt_map.unmapped,
        scale=float(k),
        frames=(int(fr[0]), int(fr[-1])),
        foot_skate_mm=skate,
    )


def _lock_feet(target, canon, ti, tgt_names, R_t, rot, pose, rest, M_obj) -> dict:
    """Replace the thigh and shin rotations in ``rot`` by foot-locked ones (in place).

    Returns side -> (skate before, skate after) in mm over the contact frames.
    """
    import bpy

    fl = _core.foot_lock
    render = bpy.context.scene.render
    fps = render.fps / render.fps_base
    R_obj = _rotations(M_obj)
    scale = float(np.cbrt(abs(np.linalg.det(M_obj[:3, :3]))))
    out = {}
    for side in ("l", "r"):
        names = (f"{side}_thigh", f"{side}_shin", f"{side}_foot")
        if not all(n in canon for n in names):
            continue
        bt, bs, bf = (int(ti[canon.index(n)]) for n in names)
        l1 = scale * float(np.linalg.norm(rest[bs, :3, 3] - rest[bt, :3, 3]))
        l2 = scale * float(np.linalg.norm(rest[bf, :3, 3] - rest[bs, :3, 3]))
        hip = pose[:, bt, :3, 3] @ M_obj[:3, :3].T + M_obj[:3, 3]
        Rt, Rs, contact, before, after = fl.lock_leg(
            hip, R_t[:, canon.index(names[0])], R_t[:, canon.index(names[1])], l1, l2, fps
        )
        rot[bt] = R_obj.T[None] @ Rt
        rot[bs] = R_obj.T[None] @ Rs
        out[side] = (fl.skate_mm(before, contact), fl.skate_mm(after, contact))
    return out
