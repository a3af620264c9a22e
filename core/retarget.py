"""Retargeting maths in world space (no bpy): rotations, root path, target pose matrices.

For every canonical bone both rigs have (see :mod:`core.bone_mapping`), the target
bone's world rotation follows the source bone's rotation *change from its rest pose*,
after a fixed rest alignment that turns the target's rest direction onto the source's:

    A_b      = swing(d_target_rest → d_source_rest)            (minimal rotation)
    R_t(f)   = [R_s(f) · R_s_restᵀ] · A_b · R_t_rest

so the target bone points exactly where the source bone points on every frame
(``R_t(f) y = R_s(f) R_s_restᵀ d_s_rest = d_s(f)``), whatever the rest poses (T-pose
vs A-pose) and bone rolls of the two rigs; twist about the bone follows the source's
twist.  Retargeting A→B→A returns A's rotations (the two swings are inverse).

Root motion: the target's hips follow the source's hips path scaled by the ratio of leg
lengths (hip→knee→ankle, rest pose), about each rig's floor origin:

    p_t(f) = o_t + k · (p_s(f) − o_s),   k = leg_t / leg_s

Matrices are 4×4 (or 3×3 rotations), column convention, world = Z up, metres.
"""

from __future__ import annotations

import numpy as np


def swing(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Minimal rotations (..., 3, 3) turning unit vectors ``a`` onto ``b`` (..., 3).

    Anti-parallel pairs turn by π about an axis perpendicular to ``a``.
    """
    a = np.asarray(a, float) / np.linalg.norm(a, axis=-1, keepdims=True)
    b = np.asarray(b, float) / np.linalg.norm(b, axis=-1, keepdims=True)
    v = np.cross(a, b)
    c = np.sum(a * b, axis=-1)
    anti = c < -1.0 + 1e-9
    if np.any(anti):  # pick a perpendicular axis; rotation by π about it
        ref = np.where(np.abs(a[..., :1]) < 0.9, [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
        perp = np.cross(a, ref)
        perp /= np.linalg.norm(perp, axis=-1, keepdims=True)
        v = np.where(anti[..., None], perp, v)
    K = np.zeros(v.shape[:-1] + (3, 3))
    K[..., 0, 1], K[..., 0, 2] = -v[..., 2], v[..., 1]
    K[..., 1, 0], K[..., 1, 2] = v[..., 2], -v[..., 0]
    K[..., 2, 0], K[..., 2, 1] = -v[..., 1], v[..., 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        f = np.where(anti, 0.0, 1.0 / (1.0 + c))
    R = np.eye(3) + K + (K @ K) * f[..., None, None]
    # anti-parallel: R = 2 p pᵀ − I (rotation by π about the unit axis p)
    pp = 2.0 * v[..., :, None] * v[..., None, :] - np.eye(3)
    return np.where(anti[..., None, None], pp, R)


def transfer_rotations(
    src_rest: np.ndarray, src_pose: np.ndarray, tgt_rest: np.ndarray, axis: int = 1
) -> np.ndarray:
    """Target world rotations (F, P, 3, 3) for P paired bones.

    Parameters
    ----------
    src_rest : (P, 3, 3) source bones' rest world rotations.
    src_pose : (F, P, 3, 3) source bones' world rotations per frame.
    tgt_rest : (P, 3, 3) target bones' rest world rotations.
    axis : the bone axis (column) that points head → tail (1: Blender's Y).
    """
    A = swing(tgt_rest[..., :, axis], src_rest[..., :, axis])
    delta = src_pose @ np.swapaxes(src_rest, -1, -2)[None]
    return delta @ (A @ tgt_rest)[None]


def leg_length(heads: dict) -> float:
    """Mean leg length (m) from rest head positions of canonical bones
    (``l_thigh``, ``l_shin``, ``l_foot`` and the ``r_`` ones; missing sides skipped)."""
    out = []
    for s in ("l", "r"):
        try:
            hip, knee, ankle = (
                np.asarray(heads[f"{s}_{b}"], float) for b in ("thigh", "shin", "foot")
            )
        except KeyError:
            continue
        out.append(np.linalg.norm(knee - hip) + np.linalg.norm(ankle - knee))
    if not out:
        raise ValueError("no leg (thigh, shin and foot) to measure")
    return float(np.mean(out))


def scale_root_path(
    src_xyz: np.ndarray, k: float, src_origin: np.ndarray, tgt_origin: np.ndarray
) -> np.ndarray:
    """``o_t + k (p_s − o_s)`` for a path (F, 3)."""
    return np.asarray(tgt_origin, float) + k * (np.asarray(src_xyz, float) - src_origin)


def pose_matrices(
    rest: np.ndarray,
    parent: np.ndarray,
    rot: dict,
    root_xyz: dict,
    n_frames: int,
    basis: np.ndarray | None = None,
) -> np.ndarray:
    """Armature-space pose matrices (F, B, 4, 4) of a target rig.

    Parameters
    ----------
    rest : (B, 4, 4) rest matrices, parents before children.
    parent : (B,) parent index, −1 for roots.
    rot : bone index -> (F, 3, 3) wanted rotation; other bones keep their rest
        orientation relative to their parent.
    root_xyz : bone index -> (F, 3) wanted head position; other bones' heads follow
        their parent (rigidly, as at rest).
    basis : (B, 4, 4), optional
        The static local pose (``matrix_basis``) that bones without keys keep
        (default: identity, the rest pose).
    """
    B = len(rest)
    pose = np.zeros((n_frames, B, 4, 4))
    inv_rest = np.linalg.inv(rest)
    basis = np.tile(np.eye(4), (B, 1, 1)) if basis is None else np.asarray(basis, float)
    for b in range(B):
        p = parent[b]
        if p < 0:
            M = np.broadcast_to(rest[b] @ basis[b], (n_frames, 4, 4)).copy()
        else:
            M = pose[:, p] @ (inv_rest[p] @ rest[b] @ basis[b])[None]
        if b in rot:
            M[:, :3, :3] = rot[b]
        if b in root_xyz:
            M[:, :3, 3] = root_xyz[b]
        pose[:, b] = M
    return pose


def angle_between(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Angles (radians) between vectors (..., 3), robust near 0 and π."""
    u = np.asarray(u, float)
    v = np.asarray(v, float)
    return np.arctan2(np.linalg.norm(np.cross(u, v), axis=-1), np.sum(u * v, axis=-1))
