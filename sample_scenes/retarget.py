"""World-space retargeting of a BVH clip onto a character armature (numpy, no bpy).

The CMU skeleton rests in a T-pose with splayed thighs, the MakeHuman character in an
A-pose; copying local rotations would twist and cross the legs.  Instead, per bone:

1. ``Q_b`` = the smallest rotation taking the character's rest bone direction onto the
   BVH bone's rest direction (both world).  Bones whose BVH segment has no length
   (CMU ``Spine1``, ``LeftHand``, ... whose children start at the same point) inherit
   their parent's ``Q``; the root gets the identity (both skeletons rest upright, facing -Y).
2. At frame ``f`` the bone's world orientation is ``R_b(f) = G_j(f) · Q_b · A_b``, with
   ``G_j(f)`` the BVH joint's world rotation (identity at the BVH rest) and ``A_b`` the
   character's rest orientation.  So the bone points where the BVH bone points and
   carries the BVH's twist about it.
3. The root position is the BVH root scaled by the leg-length ratio (character / BVH),
   recentred horizontally on the take.

Everything is in the armature's space (taken as the world; Z up, metres).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from core.errors import InputError

from .bvh import Bvh

#: Character bone names that differ from the CMU MotionBuilder-friendly BVH names.
NAME_MAP = {"LeftHandFinger1": "LeftHandIndex1", "RightHandFinger1": "RightHandIndex1"}

LEG_CHAIN = ("LeftUpLeg", "LeftLeg", "LeftFoot")


@dataclass
class Rig:
    """A character armature at rest (armature space, metres).

    Attributes
    ----------
    names : list of str
        Bone names, parents before children.
    parents : ndarray (B,) int
    matrix_local : ndarray (B, 4, 4)
        Rest matrices (Blender ``Bone.matrix_local``: head at the origin, Y along the bone).
    tails : ndarray (B, 3)
        Rest tail positions.
    """

    names: list
    parents: np.ndarray
    matrix_local: np.ndarray
    tails: np.ndarray

    @property
    def heads(self) -> np.ndarray:
        return self.matrix_local[:, :3, 3]


@dataclass
class Retarget:
    """Result of :func:`retarget`, for T sample times and B character bones.

    Attributes
    ----------
    basis : ndarray (T, B, 4, 4)
        ``PoseBone.matrix_basis`` per bone and time.
    matrices : ndarray (T, B, 4, 4)
        Posed bone matrices in armature space (``PoseBone.matrix``).
    scale : float
        Character leg length over BVH leg length.
    offset : ndarray (3,)
        Horizontal recentring added after scaling, metres.
    bvh_xyz : ndarray (T, J, 3)
        The BVH joints, scaled and recentred the same way (the reference for tests).
    mapped : dict
        Character bone name -> BVH joint name.
    """

    basis: np.ndarray
    matrices: np.ndarray
    scale: float
    offset: np.ndarray
    bvh_xyz: np.ndarray
    mapped: dict


def _min_rotation(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Smallest rotation (3, 3) taking unit vector ``a`` onto unit vector ``b``."""
    v = np.cross(a, b)
    c = float(np.dot(a, b))
    if c < -1 + 1e-9:  # opposite: rotate by pi about any axis normal to a
        axis = np.cross(a, [1.0, 0, 0])
        if np.linalg.norm(axis) < 1e-6:
            axis = np.cross(a, [0, 1.0, 0])
        axis /= np.linalg.norm(axis)
        return 2 * np.outer(axis, axis) - np.eye(3)
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx / (1 + c)


def leg_length(xyz: dict) -> float:
    """Hip-to-ankle length through the knee from joint positions ``{name: (3,)}``."""
    h, k, a = (np.asarray(xyz[n]) for n in LEG_CHAIN)
    return float(np.linalg.norm(k - h) + np.linalg.norm(a - k))


def retarget(
    rig: Rig, bvh: Bvh, times: np.ndarray, unit_scale: float, center_on: np.ndarray | None = None
) -> Retarget:
    """Pose ``rig`` like ``bvh`` at ``times`` (seconds from the BVH's first frame).

    Parameters
    ----------
    rig : Rig
    bvh : Bvh
    times : ndarray (T,)
        Sample times, seconds.
    unit_scale : float
        BVH units -> metres (0.056444 for CMU).
    center_on : ndarray (T2,), optional
        Times over which the horizontal root mean is taken for recentring
        (default ``times``).
    """
    mapped = {}
    for b in rig.names:
        j = NAME_MAP.get(b, b)
        if j in bvh.names:
            mapped[b] = j
    missing = [n for n in LEG_CHAIN + ("Hips",) if n not in mapped]
    if missing:
        raise InputError(f"{bvh.path}: lacks the joints {missing} that the character needs")

    rest_bvh = _rest_positions(bvh, unit_scale)
    char_heads = {n: rig.heads[i] for i, n in enumerate(rig.names)}
    bvh_heads = {n: rest_bvh[bvh.index(mapped.get(n, n))] for n in LEG_CHAIN}
    scale = leg_length(char_heads) / leg_length(bvh_heads)

    G, xyz = bvh.sample(times, unit_scale)
    center_times = times if center_on is None else center_on
    _, xyz_c = bvh.sample(np.asarray(center_times, dtype=float), unit_scale)
    offset = np.zeros(3)
    offset[:2] = -scale * xyz_c[:, bvh.index(mapped["Hips"]), :2].mean(axis=0)
    bvh_xyz = scale * xyz + offset

    nb = len(rig.names)
    A = rig.matrix_local
    Q = np.broadcast_to(np.eye(3), (nb, 3, 3)).copy()
    for i in range(nb):
        p = rig.parents[i]
        q_parent = Q[p] if p >= 0 else np.eye(3)
        d_bvh = _bvh_direction(rig, bvh, i, mapped, unit_scale)
        d_char = rig.tails[i] - rig.heads[i]
        if d_bvh is None or p < 0 or np.linalg.norm(d_char) < 1e-9:
            Q[i] = q_parent
        else:
            Q[i] = _min_rotation(d_char / np.linalg.norm(d_char), d_bvh)

    t = len(times)
    M = np.zeros((t, nb, 4, 4))
    basis = np.zeros((t, nb, 4, 4))
    for i, b in enumerate(rig.names):
        p = rig.parents[i]
        if b in mapped:
            R = G[:, bvh.index(mapped[b])] @ Q[i] @ A[i, :3, :3]
        else:
            R = None
        if p < 0:
            Mi = np.broadcast_to(np.eye(4), (t, 4, 4)).copy()
            Mi[:, :3, :3] = R if R is not None else A[i, :3, :3]
            Mi[:, :3, 3] = bvh_xyz[:, bvh.index(mapped[b])] if b in mapped else A[i, :3, 3]
            Bi = np.linalg.inv(A[i]) @ Mi
        else:
            L = np.linalg.inv(A[p]) @ A[i]
            Bi = np.broadcast_to(np.eye(4), (t, 4, 4)).copy()
            if R is not None:
                Bi[:, :3, :3] = L[:3, :3].T @ np.swapaxes(M[:, p, :3, :3], -1, -2) @ R
            Mi = M[:, p] @ L @ Bi
        M[:, i] = Mi
        basis[:, i] = Bi
    return Retarget(
        basis=basis, matrices=M, scale=scale, offset=offset, bvh_xyz=bvh_xyz, mapped=mapped
    )


def _rest_positions(bvh: Bvh, unit_scale: float) -> np.ndarray:
    xyz = np.zeros((len(bvh.names), 3))
    for j, p in enumerate(bvh.parents):
        xyz[j] = (xyz[p] if p >= 0 else 0.0) + bvh.offsets[j] * unit_scale
    return xyz


def _bvh_direction(rig: Rig, bvh: Bvh, i: int, mapped: dict, unit_scale: float):
    """Unit rest direction (3,) of the BVH segment matching character bone ``i``, or None."""
    b = rig.names[i]
    if b not in mapped:
        return None
    j = bvh.index(mapped[b])
    d = None
    # The character child whose head sits at this bone's tail names the BVH child to aim at.
    for c in np.flatnonzero(rig.parents == i):
        cname = rig.names[c]
        if np.linalg.norm(rig.heads[c] - rig.tails[i]) < 1e-3 and cname in mapped:
            jc = bvh.index(mapped[cname])
            if bvh.parents[jc] == j:
                d = bvh.offsets[jc]
                break
    if d is None:
        d = bvh.ends[j]
    n = np.linalg.norm(d) * unit_scale
    if n < 1e-6:
        return None
    return d / np.linalg.norm(d)
