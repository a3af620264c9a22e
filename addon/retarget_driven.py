"""Retargeting onto a constraint-driven rig, e.g. a generated Rigify rig: key its controls.

The deform bones (``DEF-*``) of a generated Rigify rig follow constraints, so keys on
them would be overridden.  For such rigs the bone mapping (see
:data:`core.bone_mapping.CONTROL_SCHEMES`) names, per canonical bone, the *control*
that drives the deform bone (the FK controls, with the limbs' IK/FK switches set to FK),
and the root control that carries the root motion.  The wanted world rotations of the
deform bones come from :func:`core.retarget.transfer_rotations` as for any rig; this
module finds the control keys that produce them, using Blender's own evaluation of the
rig (its constraints and drivers are not modelled):

1. Controls are ordered by dependency: a control's parent and constraint targets are
   followed through the rig's mechanism bones to the keyed controls upstream.
2. Level by level (one evaluation of all frames each), a control ``c`` driving deform
   bone ``d`` is turned in world space by ``d``'s residual ``Δ = W_d R_dᵀ``:
   ``basis_c ← basis_c R_cᵀ Δ R_c`` (rotation parts; the evaluated pose of everything
   above ``c`` cancels).  Exact in one step when ``d`` follows ``c`` rigidly (FK chains,
   Rigify's FK spine), later sweeps mop up couplings until the worst residual is tiny.
3. The root control's location moves the whole rig rigidly: it takes the residual of the
   pelvis deform bone's head, ``loc ← loc + X⁻¹ Δp`` with ``X = M_c basis_c⁻¹``.

Keys are written in bulk (:mod:`addon.action_api`) on a new action named after the take.
"""

from __future__ import annotations

import numpy as np

from . import _core, action_api, builders

#: Stop refining when the worst deform-bone direction residual is below this (degrees).
TOL_DEG = 1e-3
MAX_SWEEPS = 4


def _inputs(obj, pb) -> list[str]:
    """Bones whose pose ``pb``'s pose depends on: parent and constraint targets."""
    out = [pb.parent.name] if pb.parent else []
    for c in pb.constraints:
        targets = list(getattr(c, "targets", [])) or [c]
        for t in targets:
            if getattr(t, "target", None) == obj and getattr(t, "subtarget", ""):
                out.append(t.subtarget)
        if getattr(c, "pole_target", None) == obj and getattr(c, "pole_subtarget", ""):
            out.append(c.pole_subtarget)
    return out


def control_levels(obj, controls: list[str]) -> list[list[str]]:
    """Keyed controls grouped by dependency level (level 0 depends on no other)."""
    keyed = set(controls)
    pbs = obj.pose.bones
    upstream: dict[str, frozenset] = {}

    def reach(name: str) -> frozenset:  # keyed controls upstream of bone ``name``
        if name in upstream:
            return upstream[name]
        upstream[name] = frozenset()  # cycle guard
        pb = pbs.get(name)
        found = set()
        for s in _inputs(obj, pb) if pb is not None else []:
            found |= {s} if s in keyed else reach(s)
        upstream[name] = frozenset(found)
        return upstream[name]

    level: dict[str, int] = {}

    def lev(c: str, depth: int = 0) -> int:
        if c not in level:
            deps = reach(c) - {c}
            level[c] = (
                0 if not deps or depth > len(keyed) else 1 + max(lev(d, depth + 1) for d in deps)
            )
        return level[c]

    for c in controls:
        lev(c)
    return [[c for c in controls if level[c] == k] for k in range(max(level.values()) + 1)]


def _rot(M: np.ndarray) -> np.ndarray:
    R = M[..., :3, :3]
    return R / np.linalg.norm(R, axis=-2, keepdims=True)


def _rotation_channel(pb, R: np.ndarray):
    """(data path, values (F, k)) keying local rotations ``R`` (F, 3, 3) of ``pb``."""
    path = f'pose.bones["{pb.name}"]'
    if pb.rotation_mode in ("QUATERNION", "AXIS_ANGLE"):
        pb.rotation_mode = "QUATERNION"
        return path + ".rotation_quaternion", builders.matrices_to_quaternions(R)
    from scipy.spatial.transform import Rotation

    seq = pb.rotation_mode.lower()  # Blender "YXZ" = scipy extrinsic "yxz"
    eul = Rotation.from_matrix(R).as_euler(seq)
    return path + ".rotation_euler", np.unwrap(eul[:, [seq.index(a) for a in "xyz"]], axis=0)


class _Keys:
    """The new action's F-curves for the controls, rewritten in place between sweeps."""

    def __init__(self, obj, action, frames):
        self.obj, self.action, self.frames = obj, action, np.asarray(frames, float)
        self.fcs: dict = {}

    def set(self, path: str, group: str, values: np.ndarray) -> None:
        values = np.asarray(values, float).reshape(len(self.frames), -1)
        for i in range(values.shape[1]):
            fc = self.fcs.get((path, i))
            if fc is None:
                fc = action_api.new_fcurve(self.obj, self.action, path, i, group)
                action_api.write_keys(fc, self.frames, values[:, i])
                self.fcs[(path, i)] = fc
            else:
                co = np.empty(2 * len(self.frames), dtype=np.float32)
                co[0::2], co[1::2] = self.frames, values[:, i]
                fc.keyframe_points.foreach_set("co", co)
                fc.update()


def key_controls(target, mapping, canon, ti, R_t, hips_t, frames, take: str):
    """Key ``target``'s controls so that its deform bones follow ``R_t``; returns the action.

    Parameters
    ----------
    target : the constraint-driven armature object.
    mapping : its :class:`core.bone_mapping.BoneMapping` (with ``controls``).
    canon : (P,) canonical bones retargeted; ``ti`` (P,) their deform-bone indices.
    R_t : (F, P, 3, 3) wanted world rotations of the deform bones.
    hips_t : (F, 3) wanted world position of the pelvis deform bone's head (metres).
    frames : (F,) frame numbers.
    """
    names = [b.name for b in target.data.bones]
    ctrl = [mapping.controls[c] for c in canon]
    ci = np.array([names.index(n) for n in ctrl])
    F = len(frames)
    basis = {n: np.tile(np.eye(3), (F, 1, 1)) for n in ctrl}
    root = mapping.root_control
    loc = np.zeros((F, 3))

    action = action_api.assign_new_action(target, take)
    keys = _Keys(target, action, frames)
    for path, value in mapping.switches.items():  # IK/FK switches to FK, keyed on the take
        bone = path.split('"')[1]
        target.pose.bones[bone][path.rsplit('"', 2)[-2]] = value
        keys.set(path, bone, np.full(F, value))
    target.update_tag()  # ID properties set from Python do not tag the depsgraph

    def write(which):
        for n in which:
            path, values = _rotation_channel(target.pose.bones[n], basis[n])
            keys.set(path, n, values)

    write(ctrl)
    keys.set(f'pose.bones["{root}"].location', root, loc)
    levels = control_levels(target, ctrl)
    index = {n: i for i, n in enumerate(ctrl)}
    for _sweep in range(MAX_SWEEPS):
        for lv in levels:
            W = builders.pose_world_matrices(target, frames)
            for n in lv:
                i = index[n]
                Rd, Rc = _rot(W[:, ti[i]]), _rot(W[:, ci[i]])
                delta = R_t[:, i] @ np.swapaxes(Rd, -1, -2)
                basis[n] = basis[n] @ np.swapaxes(Rc, -1, -2) @ delta @ Rc
            write(lv)
        W = builders.pose_world_matrices(target, frames)
        err = _core.retarget.angle_between(W[:, ti][..., :3, 1], R_t[..., :, 1])
        if np.degrees(err.max()) < TOL_DEG:
            break
    # Root motion: move the root control so that the pelvis deform bone's head follows.
    ri, pi = names.index(root), ti[list(canon).index("pelvis")]
    B = np.array(target.pose.bones[root].matrix_basis)  # static part (rotation, scale)
    Bf = np.tile(B, (F, 1, 1))
    Bf[:, :3, 3] = loc
    X = W[:, ri] @ np.linalg.inv(Bf)
    d = hips_t - W[:, pi, :3, 3]
    loc = loc + np.einsum("fij,fj->fi", np.linalg.inv(X[:, :3, :3]), d)
    keys.set(f'pose.bones["{root}"].location', root, loc)
    action["somacap_take"] = take
    action["somacap_controls"] = list(ctrl)
    return action
