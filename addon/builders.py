"""Build Blender data from a fitted state: armature, metaball body, keyframed action.

Core computes everything (bone world matrices per frame, metaball frames); this module
only turns those arrays into Blender data.

* **Armature** — one bone per :attr:`core.skeleton.Skeleton.bone_names` (stable names:
  ``pelvis``, ``lowerback``, ``spine``, ``chest``, ``neck``, ``head``, ``l_clavicle``,
  ``l_shoulder`` (upper arm), ``l_elbow`` (forearm), ``l_wrist`` (hand), ``l_hip``
  (thigh), ``l_knee`` (shin), ``l_ankle`` (foot) and the ``r_`` side).  The rest pose is
  θ = 0 (upright, arms down, facing −Y) with the soles on z = 0; each bone's head is its
  head joint, its Y axis points to its tail joint, X to the subject's left.  Bones are
  not "connected", so every pose of core's kinematics is reproduced exactly.
* **Metaballs** — one metaball object per bone, parented to the bone, named
  ``<body>``, ``<body>.001``, ``<body>.002`` … (the bone in the object's
  ``somacap_bone`` property and the metaball data's name): Blender blends metaball
  objects into one surface only when their names differ by a *numeric* suffix — named
  ``<body>.<bone>`` each bone's metaballs were tessellated on their own.  Each element
  is an ellipsoid whose field is matched to core's (:data:`KERNEL_SCALE`,
  :data:`STIFFNESS`), so that Blender's blended surface is the fitted ``Σ f = 0.5``.
* **Action** — named after the take; bones in quaternion mode, one key per frame on
  every rotation channel and on the root's location (bulk ``foreach_set``).  A bone's
  keys at frames where the cameras did not observe it (the state's
  ``quality.unobserved``: held, or interpolated across the gap) are *breakdown* keys,
  so the dope sheet shows an animator which poses were inferred.
"""

from __future__ import annotations

import numpy as np

from . import _core, action_api

#: Blender's metaball field.  An element of radius ``R`` and stiffness ``a`` adds
#: ``a · (1 − d²/R²)³`` inside ``R`` (``d`` measured in the element's scaled frame) and
#: the surface is where the sum reaches the threshold ``T``; core's metaball adds
#: ``exp(−2 t)`` with ``t = Σ (y_i / l_i)²`` and the surface is at 0.5.  The element's
#: semi-axes are ``KERNEL_SCALE · l`` and its stiffness ``A · T``, with ``(A, k)``
#: fitted so that Blender's field reaches ``T`` on core's surface: least squares of the
#: normal offset ``(H/T − 1) / |∇(H/T)|`` at points of ``Σ f = 0.5`` of four fitted
#: bodies (make demo's walk with its per-part and its whole-body shape, jumps_line3's
#: and walk_ortho3's whole-body shape; two frames each): mean offset 0.4 mm, RMS 2.5 mm.
#: Matching a lone metaball's surface and the junction of two equal ones exactly
#: instead (A 1.755, k 1.424) leaves Blender's body 5.1 mm inside core's on average,
#: since three or more metaballs overlap on a body; matching the lone surface alone
#: (stiffness 2, the former mapping) left the junctions 16 % of a radius thinner.
THRESHOLD = 0.6
KERNEL_SCALE = 1.516
STIFFNESS = 1.660 * THRESHOLD


def rest_matrices(state) -> np.ndarray:
    """Rest bone matrices (B, 4, 4), armature space: θ = 0, soles on z = 0."""
    skel = state.skeleton
    theta0 = np.zeros((1, skel.n_dof))
    root0 = np.zeros((1, 3))
    joints = _core.skeleton.joint_positions(skel, theta0, root0, state.s)[0]
    root0[0, 2] = -joints[:, 2].min()
    return _core.skeleton.bone_matrices(skel, theta0, root0, state.s)[0]


def bone_lengths(state) -> np.ndarray:
    """Head-to-tail rest lengths (B,), metres (at least 1 cm)."""
    skel = state.skeleton
    j = _core.skeleton.joint_positions(skel, np.zeros(skel.n_dof), np.zeros(3), state.s)
    j = j.reshape(-1, 3)
    head = np.array([skel.joint_index(h) for h in skel.bone_head])
    tail = np.array([skel.joint_index(t) for t in skel.bone_tail])
    return np.maximum(np.linalg.norm(j[tail] - j[head], axis=1), 0.01)


def basis_matrices(rest: np.ndarray, parent: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """Pose-bone ``matrix_basis`` (F, B, 4, 4) that give armature-space poses ``pose``.

    Blender: ``pose_b = pose_parent @ inv(rest_parent) @ rest_b @ basis_b`` (bones
    inheriting rotation and scale), hence
    ``basis_b = inv(rest_b) @ rest_parent @ inv(pose_parent) @ pose_b``.

    Parameters
    ----------
    rest : (B, 4, 4) rest matrices (``Bone.matrix_local``), armature space.
    parent : (B,) parent index, −1 for roots.
    pose : (F, B, 4, 4) wanted pose matrices (``PoseBone.matrix``), armature space.
    """
    inv_rest = np.linalg.inv(rest)
    rel = np.broadcast_to(inv_rest, pose.shape).copy()
    has = parent >= 0
    p = parent[has]
    rel[:, has] = inv_rest[has][None] @ rest[p][None] @ np.linalg.inv(pose[:, p])
    return rel @ pose


def matrices_to_quaternions(M: np.ndarray) -> np.ndarray:
    """Rotation parts of (..., 4, 4) or (..., 3, 3) -> quaternions (..., 4) as (w, x, y, z),
    sign-continuous along axis 0 (so linear interpolation between keys stays short)."""
    from scipy.spatial.transform import Rotation

    R = np.asarray(M)[..., :3, :3]
    shape = R.shape[:-2]
    q = Rotation.from_matrix(R.reshape(-1, 3, 3)).as_quat().reshape(shape + (4,))
    q = q[..., [3, 0, 1, 2]]
    if q.ndim >= 2 and q.shape[0] > 1:
        flip = np.einsum("f...i,f...i->f...", q[1:], q[:-1]) < 0
        sign = np.cumprod(np.where(flip, -1.0, 1.0), axis=0)
        q[1:] *= sign[..., None]
    return q


def build_armature(state, name: str = "Somacap", collection=None):
    """Create the armature object (rest pose) for ``state``'s skeleton."""
    import bpy
    from mathutils import Matrix

    skel = state.skeleton
    rest = rest_matrices(state)
    lengths = bone_lengths(state)
    arm = bpy.data.armatures.new(name)
    obj = bpy.data.objects.new(name, arm)
    (collection or bpy.context.scene.collection).objects.link(obj)
    obj["somacap_armature"] = 1
    view_layer = bpy.context.view_layer
    prev_active = view_layer.objects.active
    view_layer.objects.active = obj
    bpy.ops.object.mode_set(mode="EDIT")
    try:
        ebs = []
        for b, bname in enumerate(skel.bone_names):
            eb = arm.edit_bones.new(bname)
            eb.head = (0.0, 0.0, 0.0)
            eb.tail = (0.0, float(lengths[b]), 0.0)
            eb.matrix = Matrix(rest[b].tolist())
            eb.use_connect = False
            ebs.append(eb)
        for b, p in enumerate(skel.bone_parent):
            if p >= 0:
                ebs[b].parent = ebs[p]
    finally:
        bpy.ops.object.mode_set(mode="OBJECT")
        view_layer.objects.active = prev_active or obj
    for pb in obj.pose.bones:
        pb.rotation_mode = "QUATERNION"
    return obj


def armature_rest(obj) -> np.ndarray:
    """The armature's actual rest matrices (B, 4, 4) as Blender stores them (float32)."""
    bones = obj.data.bones
    buf = np.zeros(len(bones) * 16, dtype=np.float32)
    bones.foreach_get("matrix_local", buf)
    return buf.reshape(-1, 4, 4).transpose(0, 2, 1).astype(float)


def keyframe_state(obj, state, action_name: str, frame_start: int = 1):
    """Key the state's motion on armature ``obj`` as a new action named ``action_name``.

    Returns the action.  Frames ``frame_start … frame_start + F − 1``; the scene's frame
    range and fps are left to the caller.
    """
    skel = state.skeleton
    names = [b.name for b in obj.data.bones]
    order = np.array([skel.bone_index(n) for n in names])
    parent_of = {b.name: (b.parent.name if b.parent else None) for b in obj.data.bones}
    parent = np.array([names.index(parent_of[n]) if parent_of[n] else -1 for n in names])
    pose = state.bone_matrices()[:, order]  # world == armature space (identity object)
    M_obj = np.array(obj.matrix_world)
    pose = np.linalg.inv(M_obj)[None, None] @ pose
    basis = basis_matrices(armature_rest(obj), parent, pose)
    quats = matrices_to_quaternions(basis)
    frames = frame_start + np.arange(state.n_frames)
    channels = {}
    for i, n in enumerate(names):
        pb_path = f'pose.bones["{n}"]'
        channels[(pb_path + ".rotation_quaternion", n)] = quats[:, i]
        loc = basis[:, i, :3, 3]
        if parent[i] < 0 or np.abs(loc).max() > 1e-6:
            channels[(pb_path + ".location", n)] = loc
    action = action_api.assign_new_action(obj, action_name)
    action_api.key_channels(obj, action, channels, frames, unobserved_bones(state, names))
    action["somacap_take"] = action_name
    return action


def unobserved_bones(state, names: list) -> dict:
    """``bone name -> (F,) bool``: frames at which any of the bone's own angles was not
    observed (the state's ``quality.unobserved``); bones never unobserved are left out."""
    un = state.quality.unobserved
    if un is None:
        return {}
    dof_bone = [d.rsplit("_", 1)[0] for d in state.skeleton.dof_names]
    out = {}
    for n in names:
        cols = [k for k, b in enumerate(dof_bone) if b == n]
        flags = np.asarray(un)[:, cols].any(axis=1) if cols else None
        if flags is not None and flags.any():
            out[n] = flags
    return out


def _free_family(name: str, taken: set) -> str:
    """``name``, or ``name_2``, ``name_3`` …: a metaball family name no object uses yet
    (Blender would rename a second ``name`` to ``name.001`` — a member of the first
    body's family)."""
    base, k = name, 1

    def used(n):
        return any(t == n or (t.startswith(n + ".") and t[len(n) + 1 :].isdigit()) for t in taken)

    while used(name):
        k += 1
        name = f"{base}_{k}"
    return name


def build_metaballs(
    state, armature, name: str = "SomacapBody", collection=None, resolution: float = 0.02
):
    """Metaball objects parented to ``armature``'s bones, one family named ``name``.

    Returns the list of objects; the first (``name`` itself, on the first bone that has
    metaballs) is the family's basis object, which carries the resolution.
    """
    import bpy
    from mathutils import Matrix, Quaternion

    skel, balls = state.skeleton, state.metaballs
    collection = collection or bpy.context.scene.collection
    name = _free_family(name, {o.name for o in bpy.data.objects})
    rest = armature_rest(armature)
    names = [b.name for b in armature.data.bones]
    align = skel.bone_align()  # anatomical -> Blender bone frame
    scale = np.where(balls.group >= 0, np.asarray(state.s)[np.maximum(balls.group, 0)], 1.0)
    centre = balls.center0 * scale[:, None]
    axes = KERNEL_SCALE * balls.radii  # Blender element semi-axes, metres
    objects = []
    for b in np.unique(balls.bone):
        bname = skel.bone_names[b]
        idx = np.flatnonzero(balls.bone == b)
        mb = bpy.data.metaballs.new(f"{name}.{bname}")
        mb.resolution = mb.render_resolution = resolution
        mb.threshold = THRESHOLD
        obj_name = name if not objects else f"{name}.{len(objects):03d}"
        obj = bpy.data.objects.new(obj_name, mb)
        collection.objects.link(obj)
        A = align[b].T  # anatomical -> Blender bone frame coordinates
        c_bl = centre[idx] @ A.T
        R_bl = A[None] @ balls.rot[idx]
        quats = matrices_to_quaternions(R_bl[None])[0]
        for m, k in enumerate(idx):
            el = mb.elements.new(type="ELLIPSOID")
            el.co = c_bl[m].tolist()
            el.rotation = Quaternion(quats[m].tolist())
            r = float(axes[k].max())
            el.radius = r
            el.size_x, el.size_y, el.size_z = (axes[k] / r).tolist()
            el.stiffness = STIFFNESS
        # Bone parenting: the parent frame is the bone's tail in pose space.
        bone = armature.data.bones[names.index(bname)]
        obj.parent = armature
        obj.parent_type = "BONE"
        obj.parent_bone = bname
        tail_frame = rest[names.index(bname)].copy()
        tail_frame[:3, 3] += tail_frame[:3, 1] * bone.length
        obj.matrix_parent_inverse = Matrix.Identity(4)
        obj.matrix_basis = Matrix((np.linalg.inv(tail_frame) @ rest[names.index(bname)]).tolist())
        obj["somacap_bone"] = bname
        objects.append(obj)
    return objects


def build_body(state, take: str = "take", collection=None, frame_start: int = 1):
    """Armature + metaballs + action for a state; sets the scene's range and fps.

    Returns ``(armature, metaball_objects, action)``.
    """
    import bpy

    scene = bpy.context.scene
    if collection is None:
        collection = bpy.data.collections.new(f"Somacap {take}")
        scene.collection.children.link(collection)
    arm = build_armature(state, name=f"{take}_armature", collection=collection)
    balls = build_metaballs(state, arm, name=f"{take}_body", collection=collection)
    action = keyframe_state(arm, state, take, frame_start=frame_start)
    scene.frame_start = frame_start
    scene.frame_end = frame_start + state.n_frames - 1
    scene.render.fps = max(1, int(round(state.fps)))
    scene.render.fps_base = scene.render.fps / state.fps
    return arm, balls, action


def pose_world_matrices(obj, frames) -> np.ndarray:
    """Evaluated pose-bone world matrices (F, B, 4, 4) of armature ``obj`` at ``frames``."""
    import bpy

    scene = bpy.context.scene
    pbs = obj.pose.bones
    out = np.zeros((len(frames), len(pbs), 4, 4))
    buf = np.zeros(len(pbs) * 16, dtype=np.float32)
    current = scene.frame_current
    for i, f in enumerate(frames):
        scene.frame_set(int(f))
        pbs.foreach_get("matrix", buf)
        out[i] = np.array(obj.matrix_world)[None] @ buf.reshape(-1, 4, 4).transpose(0, 2, 1)
    scene.frame_set(current)
    return out
