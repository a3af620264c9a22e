"""The articulated skeleton: single-DOF joints, forward kinematics, analytic Jacobians.

The paper's model (D'Apuzzo et al. 1999, section 3.2): a hierarchy of degrees of
freedom, each one rotation about its own local z axis.  Multi-DOF articulations are
chains of single-DOF joints.  Each DOF ``k`` has a fixed matrix ``D_ini = [A_k | s·o_k]``
(an axis permutation ``A_k`` and the bone offset ``o_k`` scaled by the subject's scale
coefficient ``s`` of its scale group) and a motion matrix ``Rz(θ_k)``.  Here the frames
are written local-to-world, so that eq. (2)-(3) read

    F_k = F_parent(k) · D_ini_k · Rz(θ_k),      x_world = F_k · x_local

with ``F_root_parent = Translation(root_xyz)``.  A 3-DOF joint with intrinsic axes
``a1 a2 a3`` is the chain ``D_ini_1 = [P_a1 | s·o]``, ``D_ini_2 = P_a1ᵀ P_a2``,
``D_ini_3 = P_a2ᵀ P_a3`` with ``P_a`` the cyclic permutation taking z to axis ``a``; its
anatomical (bone) frame is ``F_3 · P_a3ᵀ``, which at θ = 0 is aligned with its parent's.

Frames and names
----------------
* World: Z up, metres.  At θ = 0 every anatomical frame is aligned with the world:
  +X is the subject's left, −Y forward, +Z up (the rest pose stands upright, facing −Y,
  arms hanging down, feet forward).
* **Bones** (stable names, used by the fitted state and the Blender armature):
  ``pelvis`` (the root: translation ``root_xyz`` plus rotations z, x, y), ``lowerback``,
  ``spine``, ``chest``, ``neck``, ``head``, ``l_clavicle``, ``l_shoulder`` (upper arm),
  ``l_elbow`` (forearm), ``l_wrist`` (hand), ``l_hip`` (thigh), ``l_knee`` (shin),
  ``l_ankle`` (foot), and the same with ``r_``.  A bone is named by the joint at its
  head; its tail is the joint listed in :data:`BONES`.
* **DOFs** are named ``<bone>_<axis>`` (e.g. ``l_shoulder_x``), axis in the bone's
  anatomical frame: x = flexion (about the left-right axis), y = abduction / lateral
  bend (about the front-back axis), z = twist (about the vertical / limb axis).
* **Joints**: :data:`core.landmarks.JOINTS`, each a point fixed in one bone's
  anatomical frame, scaled by one scale group.
* **Scale groups** (:data:`SCALE_GROUPS`): per-subject coefficients ``s`` shared by
  left and right.

Arrays: ``theta`` (F, n_dof) radians, ``root_xyz`` (F, 3) metres, ``s`` (G,).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import numpy as np

from .landmarks import JOINTS
from .skeleton_template import (
    ANCHOR_SIGMA,
    BONES,
    LIMITS,
    SCALE_GROUPS,
    STIFF_SIGMA,
    TEMPLATE_JOINTS,
)


def anchor_sigma(skel: Skeleton) -> np.ndarray:
    """Per-DOF σ (n,) radians of the prior towards the initial posture (inf: none)."""
    return np.array([ANCHOR_SIGMA.get(n, np.inf) for n in skel.dof_names])


def stiff_sigma(skel: Skeleton) -> np.ndarray:
    """Per-DOF prior σ ceiling (n,) radians from :data:`STIFF_SIGMA` (inf elsewhere)."""
    return np.array([STIFF_SIGMA.get(n, np.inf) for n in skel.dof_names])


def axis_permutation(axis: str) -> np.ndarray:
    """Proper rotation (3, 3) that permutes the axes cyclically so that z goes to ``axis``."""
    e = np.eye(3)
    if axis == "z":
        return e
    if axis == "x":  # new x = e_y, new y = e_z, new z = e_x
        return np.stack([e[1], e[2], e[0]], axis=1)
    if axis == "y":  # new x = e_z, new y = e_x, new z = e_y
        return np.stack([e[2], e[0], e[1]], axis=1)
    raise ValueError(f"unknown axis {axis!r}")


def rot_z(theta: np.ndarray) -> np.ndarray:
    """Rotations about z, ``(..., 3, 3)`` from angles ``(...)`` in radians."""
    theta = np.asarray(theta, dtype=float)
    c, s = np.cos(theta), np.sin(theta)
    out = np.zeros(theta.shape + (3, 3))
    out[..., 0, 0] = c
    out[..., 0, 1] = -s
    out[..., 1, 0] = s
    out[..., 1, 1] = c
    out[..., 2, 2] = 1.0
    return out


def _align_y(direction: np.ndarray) -> np.ndarray:
    """Rotation whose Y column is ``direction`` (unit), X as close to world X as possible."""
    y = direction / np.linalg.norm(direction)
    ref = np.array([1.0, 0.0, 0.0]) if abs(y[0]) < 0.9 else np.array([0.0, 0.0, 1.0])
    x = ref - y * (ref @ y)
    x /= np.linalg.norm(x)
    z = np.cross(x, y)
    return np.stack([x, y, z], axis=1)


@dataclass(frozen=True)
class Skeleton:
    """A skeleton as plain arrays (n DOFs, B bones, J joints, G scale groups).

    Attributes
    ----------
    dof_names : tuple of str, (n,)
    dof_parent : ndarray of int, (n,)
        Parent DOF, −1 for the root frame ``Translation(root_xyz)``.  Parents first.
    dof_rot : ndarray, (n, 3, 3)
        Rotation part of ``D_ini`` (an axis permutation, possibly composed with the
        parent's anatomical alignment).
    dof_offset : ndarray, (n, 3)
        Translation part of ``D_ini`` before scaling, metres, in the parent DOF frame.
    dof_group : ndarray of int, (n,)
        Scale group of the offset, −1 when the offset is zero / unscaled.
    dof_lo, dof_hi : ndarray, (n,)
        Soft joint limits, radians (±inf when unlimited).
    group_names : tuple of str, (G,)
    bone_names : tuple of str, (B,)
    bone_parent : ndarray of int, (B,)
    bone_dof : ndarray of int, (B,)
        The last DOF of each bone's chain (its frame).
    bone_post : ndarray, (B, 3, 3)
        Fixed rotation from the last DOF frame to the bone's anatomical frame.
    bone_head, bone_tail : tuple of str, (B,)
        Joint names at the head and tail of each bone.
    joint_names : tuple of str, (J,)
    joint_bone : ndarray of int, (J,)
    joint_offset : ndarray, (J, 3)
        Rest offset in the bone's anatomical frame, metres before scaling.
    joint_group : ndarray of int, (J,)
    """

    dof_names: tuple
    dof_parent: np.ndarray
    dof_rot: np.ndarray
    dof_offset: np.ndarray
    dof_group: np.ndarray
    dof_lo: np.ndarray
    dof_hi: np.ndarray
    group_names: tuple
    bone_names: tuple
    bone_parent: np.ndarray
    bone_dof: np.ndarray
    bone_post: np.ndarray
    bone_head: tuple
    bone_tail: tuple
    joint_names: tuple
    joint_bone: np.ndarray
    joint_offset: np.ndarray
    joint_group: np.ndarray

    @property
    def n_dof(self) -> int:
        return len(self.dof_names)

    @property
    def n_groups(self) -> int:
        return len(self.group_names)

    def dof_index(self, name: str) -> int:
        return self.dof_names.index(name)

    def bone_index(self, name: str) -> int:
        return self.bone_names.index(name)

    def joint_index(self, name: str) -> int:
        return self.joint_names.index(name)

    def dof_bones(self) -> np.ndarray:
        """``(n,)`` int: the bone each DOF turns (the bone named by its name's prefix)."""
        return np.array([self.bone_index(d.rsplit("_", 1)[0]) for d in self.dof_names], int)

    def ancestors(self) -> np.ndarray:
        """``(n, n)`` bool: ``[k, j]`` is True when DOF j is DOF k or one of its ancestors."""
        n = self.n_dof
        anc = np.zeros((n, n), dtype=bool)
        for k in range(n):
            anc[k, k] = True
            if self.dof_parent[k] >= 0:
                anc[k] |= anc[self.dof_parent[k]]
        return anc

    def bone_align(self) -> np.ndarray:
        """``(B, 3, 3)``: rotation from a bone's anatomical frame to its Blender-style
        frame (Y from head to tail at rest, X as close as possible to the subject's left)."""
        out = np.zeros((len(self.bone_names), 3, 3))
        for b, tail in enumerate(self.bone_tail):
            j = self.joint_index(tail)
            off = self.joint_offset[j].copy()
            if self.joint_bone[j] != b:  # tail carried by another bone (lowerback/pelvis)
                off = np.array([0.0, 0.0, 1.0])
            if np.linalg.norm(off) < 1e-9:
                off = np.array([0.0, 0.0, 1.0])
            out[b] = _align_y(off)
        return out

    # -- (de)serialisation ------------------------------------------------------------
    def to_dict(self) -> dict:
        """Plain JSON-able description (see :mod:`core.state`)."""
        return {
            "scale_groups": list(self.group_names),
            "dofs": [
                {
                    "name": n,
                    "parent": int(self.dof_parent[k]),
                    "d_ini_rot": self.dof_rot[k].round(15).tolist(),
                    "d_ini_offset": self.dof_offset[k].tolist(),
                    "scale_group": int(self.dof_group[k]),
                    "limits": [_inf_none(self.dof_lo[k]), _inf_none(self.dof_hi[k])],
                }
                for k, n in enumerate(self.dof_names)
            ],
            "bones": [
                {
                    "name": n,
                    "parent": int(self.bone_parent[b]),
                    "dof": int(self.bone_dof[b]),
                    "post_rot": self.bone_post[b].round(15).tolist(),
                    "head": self.bone_head[b],
                    "tail": self.bone_tail[b],
                }
                for b, n in enumerate(self.bone_names)
            ],
            "joints": [
                {
                    "name": n,
                    "bone": int(self.joint_bone[j]),
                    "offset": self.joint_offset[j].tolist(),
                    "scale_group": int(self.joint_group[j]),
                }
                for j, n in enumerate(self.joint_names)
            ],
        }

    @classmethod
    def from_dict(cls, d: dict) -> Skeleton:
        """Inverse of :meth:`to_dict` (raises KeyError/ValueError on malformed input;
        :mod:`core.state` turns those into InputError)."""
        dofs, bones, joints = d["dofs"], d["bones"], d["joints"]
        lim = np.array(
            [
                [
                    (-np.inf if v["limits"][0] is None else v["limits"][0]),
                    (np.inf if v["limits"][1] is None else v["limits"][1]),
                ]
                for v in dofs
            ],
            dtype=float,
        ).reshape(-1, 2)
        return cls(
            dof_names=tuple(str(v["name"]) for v in dofs),
            dof_parent=np.array([int(v["parent"]) for v in dofs], dtype=int),
            dof_rot=np.array([v["d_ini_rot"] for v in dofs], dtype=float).reshape(-1, 3, 3),
            dof_offset=np.array([v["d_ini_offset"] for v in dofs], dtype=float).reshape(-1, 3),
            dof_group=np.array([int(v["scale_group"]) for v in dofs], dtype=int),
            dof_lo=lim[:, 0],
            dof_hi=lim[:, 1],
            group_names=tuple(str(g) for g in d["scale_groups"]),
            bone_names=tuple(str(v["name"]) for v in bones),
            bone_parent=np.array([int(v["parent"]) for v in bones], dtype=int),
            bone_dof=np.array([int(v["dof"]) for v in bones], dtype=int),
            bone_post=np.array([v["post_rot"] for v in bones], dtype=float).reshape(-1, 3, 3),
            bone_head=tuple(str(v["head"]) for v in bones),
            bone_tail=tuple(str(v["tail"]) for v in bones),
            joint_names=tuple(str(v["name"]) for v in joints),
            joint_bone=np.array([int(v["bone"]) for v in joints], dtype=int),
            joint_offset=np.array([v["offset"] for v in joints], dtype=float).reshape(-1, 3),
            joint_group=np.array([int(v["scale_group"]) for v in joints], dtype=int),
        )

    def validate(self) -> str | None:
        """Return a description of the first structural inconsistency, or None."""
        n, nb, g = self.n_dof, len(self.bone_names), self.n_groups
        if any(p >= k for k, p in enumerate(self.dof_parent)) or np.any(self.dof_parent < -1):
            return "every DOF parent must come before the DOF (or be -1)"
        if np.any(self.dof_group >= g) or np.any(self.joint_group >= g):
            return "a scale group index is out of range"
        if np.any((self.bone_dof < 0) | (self.bone_dof >= n)):
            return "a bone names a DOF out of range"
        if np.any((self.joint_bone < 0) | (self.joint_bone >= nb)):
            return "a joint names a bone out of range"
        for arr in (self.dof_rot, self.bone_post):
            if not np.allclose(arr @ np.swapaxes(arr, -1, -2), np.eye(3), atol=1e-9):
                return "a D_ini or bone rotation is not orthonormal"
        if not (np.all(np.isfinite(self.dof_offset)) and np.all(np.isfinite(self.joint_offset))):
            return "an offset is not finite"
        return None


def _inf_none(v: float):
    return None if not np.isfinite(v) else float(v)


def make_skeleton(rest_offsets: dict | None = None, bones: dict | None = None) -> Skeleton:
    """Build the full-body skeleton.

    Parameters
    ----------
    rest_offsets : dict, optional
        ``joint -> (3,)`` rest offsets (metres, in the carrying bone's anatomical frame)
        replacing those of :data:`TEMPLATE_JOINTS` (e.g. measured on one subject).
    bones : dict, optional
        Replaces :data:`BONES` (same layout), e.g. with other DOF axes.

    Returns
    -------
    Skeleton
    """
    bones = BONES if bones is None else bones
    rest_offsets = rest_offsets or {}
    groups = SCALE_GROUPS
    bone_names = tuple(bones)
    joint_info = {}
    for j in JOINTS:
        bone, group, off = TEMPLATE_JOINTS[j]
        off = np.asarray(rest_offsets.get(j, off), dtype=float)
        joint_info[j] = (bone_names.index(bone), -1 if group is None else groups.index(group), off)

    names, parent, rot, offset, dgroup, lo, hi = [], [], [], [], [], [], []
    b_parent, b_dof, b_post, b_head, b_tail = [], [], [], [], []
    for bname, (pname, tail, axes) in bones.items():
        pb = -1 if pname is None else bone_names.index(pname)
        head = "pelvis" if bname in ("pelvis", "lowerback") else bname
        if pb < 0:
            par_dof, par_post, head_off, head_group = -1, np.eye(3), np.zeros(3), -1
        else:
            par_dof, par_post = b_dof[pb], b_post[pb]
            hb, hg, hoff = joint_info[head]
            if hb != pb:
                raise ValueError(f"joint {head} must be carried by bone {pname}")
            head_off, head_group = hoff, hg
        prev = None
        for i, a in enumerate(axes):
            P = axis_permutation(a)
            if i == 0:
                rot.append(par_post @ P)
                offset.append(par_post @ head_off)
                dgroup.append(head_group)
                parent.append(par_dof)
            else:
                rot.append(prev.T @ P)
                offset.append(np.zeros(3))
                dgroup.append(-1)
                parent.append(len(names) - 1)
            dname = f"{bname}_{a}"
            names.append(dname)
            lim = LIMITS.get(dname)
            lo.append(-np.inf if lim is None else np.deg2rad(lim[0]))
            hi.append(np.inf if lim is None else np.deg2rad(lim[1]))
            prev = P
        b_parent.append(pb)
        b_dof.append(len(names) - 1)
        b_post.append(prev.T)
        b_head.append(head)
        b_tail.append(tail)
    return Skeleton(
        dof_names=tuple(names),
        dof_parent=np.array(parent, dtype=int),
        dof_rot=np.array(rot),
        dof_offset=np.array(offset),
        dof_group=np.array(dgroup, dtype=int),
        dof_lo=np.array(lo),
        dof_hi=np.array(hi),
        group_names=tuple(groups),
        bone_names=bone_names,
        bone_parent=np.array(b_parent, dtype=int),
        bone_dof=np.array(b_dof, dtype=int),
        bone_post=np.array(b_post),
        bone_head=tuple(b_head),
        bone_tail=tuple(b_tail),
        joint_names=tuple(JOINTS),
        joint_bone=np.array([joint_info[j][0] for j in JOINTS], dtype=int),
        joint_offset=np.array([joint_info[j][2] for j in JOINTS]),
        joint_group=np.array([joint_info[j][1] for j in JOINTS], dtype=int),
    )


@dataclass
class Pose:
    """Forward kinematics of F frames.

    Attributes
    ----------
    R : ndarray, (F, n, 3, 3)
        World rotation of every DOF frame ``F_k``.
    p : ndarray, (F, n, 3)
        World origin of every DOF frame, metres.
    R_parent : ndarray, (F, n, 3, 3)
        World rotation of each DOF's parent frame (identity for the root chain).
    """

    R: np.ndarray
    p: np.ndarray
    R_parent: np.ndarray

    @property
    def axes(self) -> np.ndarray:
        """World rotation axes ``ω_k`` (F, n, 3) — the z column of each DOF frame."""
        return self.R[..., :, 2]


def _as_frames(theta, root_xyz):
    theta = np.asarray(theta, dtype=float)
    root_xyz = np.asarray(root_xyz, dtype=float)
    single = theta.ndim == 1
    return np.atleast_2d(theta), root_xyz.reshape(-1, 3), single


def forward(
    skel: Skeleton,
    theta: np.ndarray,
    root_xyz: np.ndarray,
    s: np.ndarray,
    dofs: np.ndarray | None = None,
) -> Pose:
    """Forward kinematics, eq. (2)-(3), batched over frames.

    Parameters
    ----------
    theta : (F, n) or (n,) radians
    root_xyz : (F, 3) or (3,) metres, world position of the root DOF frame origin
    s : (G,) scale coefficients
    dofs : indices of the DOFs whose frames are wanted, optional; with their ancestors
        (:func:`dof_chains`), those alone are computed (the same bits), the others NaN —
        for a search that poses one limb many times

    Returns
    -------
    Pose
    """
    theta, root_xyz, _ = _as_frames(theta, root_xyz)
    s = np.asarray(s, dtype=float)
    nf, n = theta.shape[0], skel.n_dof
    scale = np.where(skel.dof_group >= 0, s[np.maximum(skel.dof_group, 0)], 1.0)
    local_off = skel.dof_offset * scale[:, None]
    if dofs is None:
        order, make = range(n), np.empty
        DR = skel.dof_rot[None] @ rot_z(theta)  # (F, n, 3, 3) = A_k Rz(θ_k)
    else:
        order, make = dof_chains(skel, dofs), partial(np.full, fill_value=np.nan)
        DR = make((nf, n, 3, 3))
        DR[:, order] = skel.dof_rot[None, order] @ rot_z(theta[:, order])
    R = make((nf, n, 3, 3))
    p = make((nf, n, 3))
    Rp = make((nf, n, 3, 3))
    eye = np.broadcast_to(np.eye(3), (nf, 3, 3))
    for k in order:
        par = skel.dof_parent[k]
        if par < 0:
            Rpar, ppar = eye, root_xyz
        else:
            Rpar, ppar = R[:, par], p[:, par]
        Rp[:, k] = Rpar
        R[:, k] = Rpar @ DR[:, k]
        p[:, k] = ppar + Rpar @ local_off[k]
    return Pose(R=R, p=p, R_parent=Rp)


def dof_chains(skel: Skeleton, dofs) -> np.ndarray:
    """The DOFs ``dofs`` and all their ancestors, ascending (parents before children)."""
    need = set()
    for k in np.asarray(dofs, int).ravel():
        while k >= 0 and k not in need:
            need.add(int(k))
            k = skel.dof_parent[k]
    return np.array(sorted(need), int)


def bone_frames(skel: Skeleton, pose: Pose) -> tuple[np.ndarray, np.ndarray]:
    """Anatomical bone frames: rotations (F, B, 3, 3) and origins (F, B, 3)."""
    R = pose.R[:, skel.bone_dof] @ skel.bone_post[None]
    return R, pose.p[:, skel.bone_dof]


def points_world(
    skel: Skeleton, pose: Pose, bone: np.ndarray, q0: np.ndarray, group: np.ndarray, s: np.ndarray
) -> np.ndarray:
    """World positions (F, N, 3) of points fixed in bone frames.

    Parameters
    ----------
    bone : (N,) int — carrying bone of each point
    q0 : (N, 3) — position in the bone's anatomical frame, metres before scaling
    group : (N,) int — scale group multiplying ``q0`` (−1: unscaled)
    """
    Rb, pb = bone_frames(skel, pose)
    q = _scaled(q0, group, s)
    return np.einsum("fnij,nj->fni", Rb[:, bone], q) + pb[:, bone]


def _scaled(q0, group, s):
    group = np.asarray(group, dtype=int)
    s = np.asarray(s, dtype=float)
    scale = np.where(group >= 0, s[np.maximum(group, 0)], 1.0)
    return np.asarray(q0, dtype=float) * scale[:, None]


def point_jacobians(
    skel: Skeleton,
    pose: Pose,
    bone: np.ndarray,
    q0: np.ndarray,
    group: np.ndarray,
    s: np.ndarray,
    anc: np.ndarray | None = None,
    scales: bool = True,
):
    """Analytic Jacobians of bone-fixed points (see :func:`points_world`).

    Returns
    -------
    x : (F, N, 3) world positions
    J_theta : (F, N, 3, n) — ``∂x/∂θ_k = ω_k × (x − p_k)`` for DOFs k above the point
    J_s : (F, N, 3, G) — derivative w.r.t. the scale coefficients; None unless ``scales``
    (the derivative w.r.t. ``root_xyz`` is the identity.)
    """
    bone = np.asarray(bone, dtype=int)
    group = np.asarray(group, dtype=int)
    anc = skel.ancestors() if anc is None else anc
    x = points_world(skel, pose, bone, q0, group, s)
    dof_of = skel.bone_dof[bone]  # (N,)
    mask = anc[dof_of]  # (N, n)
    F, N = x.shape[:2]
    # ω_k × (x − p_k) one component at a time, with np.cross's arithmetic (the same
    # bits) but without its (F, N, n, 3) difference array and axis moves
    d = [x[:, :, None, i] - pose.p[:, None, :, i] for i in range(3)]  # 3 × (F, N, n)
    w = [pose.axes[:, None, :, i] for i in range(3)]  # 3 × (F, 1, n)
    J = np.empty((F, N, skel.n_dof, 3))
    for c, (a, b) in enumerate(((1, 2), (2, 0), (0, 1))):
        np.subtract(w[a] * d[b], w[b] * d[a], out=J[..., c])
    J *= mask[None, :, :, None]
    J_theta = np.swapaxes(J, 2, 3)  # (F, N, 3, n)
    if not scales:
        return x, J_theta, None
    # scale: each DOF offset term R_parent(k) o_k s_g, plus the point's own q0 s_g
    G = skel.n_groups
    off_world = np.einsum("fkij,kj->fki", pose.R_parent, skel.dof_offset)  # (F, n, 3)
    onehot = np.zeros((skel.n_dof, G))
    has = skel.dof_group >= 0
    onehot[np.nonzero(has)[0], skel.dof_group[has]] = 1.0
    per_dof = (off_world[..., None] * onehot[None, :, None, :]).reshape(F, skel.n_dof, 3 * G)
    J_s = (mask.astype(float)[None] @ per_dof).reshape(F, N, 3, G)
    Rb, _ = bone_frames(skel, pose)
    own = np.einsum("fnij,nj->fni", Rb[:, bone], np.asarray(q0, dtype=float))
    sel = np.nonzero(group >= 0)[0]
    J_s[:, sel, :, group[sel]] += np.swapaxes(own[:, sel, :], 0, 1)
    return x, J_theta, J_s


def joint_positions(skel: Skeleton, theta, root_xyz, s) -> np.ndarray:
    """World positions (F, J, 3) of :attr:`Skeleton.joint_names` (F omitted for 1-D theta)."""
    theta_, root_, single = _as_frames(theta, root_xyz)
    pose = forward(skel, theta_, root_, s)
    x = points_world(skel, pose, skel.joint_bone, skel.joint_offset, skel.joint_group, s)
    return x[0] if single else x


def joint_jacobians(skel: Skeleton, theta, root_xyz, s):
    """Joints and their Jacobians: ``x (F, J, 3)``, ``J_theta (F, J, 3, n)``,
    ``J_s (F, J, 3, G)``."""
    theta_, root_, _ = _as_frames(theta, root_xyz)
    pose = forward(skel, theta_, root_, s)
    return point_jacobians(skel, pose, skel.joint_bone, skel.joint_offset, skel.joint_group, s)


def bone_matrices(skel: Skeleton, theta, root_xyz, s) -> np.ndarray:
    """Per-frame bone world matrices (F, B, 4, 4) for an armature.

    Column convention: ``M @ [x, y, z, 1]`` maps bone-local to world.  The origin is the
    bone's head joint, the Y axis points from head to tail as in the rest pose (Blender
    bones: Y along the bone), X as close as possible to the subject's left.  Bone names
    and order: :attr:`Skeleton.bone_names`.
    """
    theta_, root_, _ = _as_frames(theta, root_xyz)
    pose = forward(skel, theta_, root_, s)
    Rb, pb = bone_frames(skel, pose)
    M = np.zeros(Rb.shape[:2] + (4, 4))
    M[..., :3, :3] = Rb @ skel.bone_align()[None]
    M[..., :3, 3] = pb
    M[..., 3, 3] = 1.0
    return M


def limit_residuals(skel: Skeleton, theta: np.ndarray, sigma: float = 0.05):
    """Soft joint limits as residuals ``(θ − hi)/σ`` above, ``(lo − θ)/σ`` below, else 0.

    Returns
    -------
    r : (F, n) residuals; J : (F, n) diagonal of ``∂r/∂θ``.
    """
    theta = np.atleast_2d(np.asarray(theta, dtype=float))
    above = theta > skel.dof_hi
    below = theta < skel.dof_lo
    r = np.where(above, theta - skel.dof_hi, 0.0) + np.where(below, skel.dof_lo - theta, 0.0)
    J = above.astype(float) - below.astype(float)
    return r / sigma, J / sigma
