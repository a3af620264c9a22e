"""Foot locking maths (no bpy): contact detection, pinned targets, 2-bone analytic IK, skate.

A foot is *in contact* on frames where its ankle is low (within ``max_height`` of the
clip's lowest ankle height) and slow (horizontal speed below ``max_speed``), for at
least ``min_frames`` consecutive frames.  During a contact the ankle is pinned to its
horizontal position at the contact's first frame (height kept), and the leg reaches it
by the analytic two-bone IK below (thigh and shin lengths kept, the knee kept on the
side of the original knee).  World: Z up, metres.

:func:`lock_leg` applies all of it to a leg's world bone rotations; the Blender retarget
uses it with ``foot_lock=True`` (``addon/retarget.py``).
"""

from __future__ import annotations

import numpy as np


def contact_mask(
    xyz: np.ndarray,
    fps: float,
    max_height: float = 0.05,
    max_speed: float = 0.25,
    min_frames: int = 3,
) -> np.ndarray:
    """Frames (F,) bool on which a foot (ankle path ``xyz`` (F, 3), m) is in contact.

    Height is measured above the clip's lowest point; speed (m/s) is horizontal.
    """
    xyz = np.asarray(xyz, float)
    h = xyz[:, 2] - np.nanmin(xyz[:, 2])
    v = np.linalg.norm(np.gradient(xyz[:, :2], axis=0), axis=1) * fps
    c = (h < max_height) & (v < max_speed)
    return _drop_short_runs(c, min_frames)


def _runs(c: np.ndarray) -> list[tuple[int, int]]:
    """(start, stop) of the True runs of a bool array (stop exclusive)."""
    d = np.diff(np.concatenate([[0], c.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1), strict=True))


def _drop_short_runs(c: np.ndarray, min_frames: int) -> np.ndarray:
    out = np.zeros_like(c, dtype=bool)
    for a, b in _runs(c):
        if b - a >= min_frames:
            out[a:b] = True
    return out


def pinned_targets(xyz: np.ndarray, contact: np.ndarray) -> np.ndarray:
    """Ankle targets (F, 3): during each contact the horizontal position of its first
    frame (height as in ``xyz``); elsewhere ``xyz`` unchanged."""
    out = np.array(xyz, float)
    for a, b in _runs(np.asarray(contact, bool)):
        out[a:b, :2] = out[a, :2]
    return out


def two_bone_ik(
    hip: np.ndarray, knee: np.ndarray, ankle: np.ndarray, target: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """New knee and ankle positions (F, 3) reaching ``target`` with the hip fixed.

    Bone lengths |knee − hip| and |ankle − knee| are kept; the knee stays in the plane
    of hip, target and the original knee, on the original knee's side.  A target out of
    reach is approached along the hip→target line (leg straight).  All (F, 3), metres.
    """
    hip, knee, ankle, target = (np.asarray(a, float) for a in (hip, knee, ankle, target))
    l1 = np.linalg.norm(knee - hip, axis=-1)
    l2 = np.linalg.norm(ankle - knee, axis=-1)
    d_vec = target - hip
    d = np.linalg.norm(d_vec, axis=-1)
    d = np.clip(d, np.abs(l1 - l2) + 1e-9, l1 + l2 - 1e-9)
    u = d_vec / np.linalg.norm(d_vec, axis=-1, keepdims=True)
    # pole: the original knee's offset from the hip→target line
    k = knee - hip
    pole = k - np.sum(k * u, axis=-1, keepdims=True) * u
    pole /= np.linalg.norm(pole, axis=-1, keepdims=True)
    a = (l1**2 - l2**2 + d**2) / (2 * d)  # law of cosines: distance along u to the knee
    r = np.sqrt(np.maximum(l1**2 - a**2, 0.0))
    new_knee = hip + a[..., None] * u + r[..., None] * pole
    new_ankle = hip + d[..., None] * u
    return new_knee, new_ankle


def skate_mm(xyz: np.ndarray, contact: np.ndarray) -> float:
    """Foot skate: horizontal path length (mm) of ``xyz`` (F, 3) summed over the
    consecutive frame pairs that are both in contact."""
    xyz = np.asarray(xyz, float)
    c = np.asarray(contact, bool)
    both = c[1:] & c[:-1]
    step = np.linalg.norm(np.diff(xyz[:, :2], axis=0), axis=1)
    return float(step[both].sum() * 1000.0)


def lock_leg(
    hip: np.ndarray,
    R_thigh: np.ndarray,
    R_shin: np.ndarray,
    thigh_len: float,
    shin_len: float,
    fps: float,
    axis: int = 1,
    **contact_kw,
):
    """Lock one foot: new world rotations of thigh and shin so the ankle stays put in contact.

    Parameters
    ----------
    hip : (F, 3)
        Thigh head (hip joint) world positions, metres.
    R_thigh, R_shin : (F, 3, 3)
        World rotations of the thigh and shin bones; column ``axis`` points head → tail.
    thigh_len, shin_len : float
        Bone lengths, metres (knee = hip + thigh_len · thigh axis, ankle likewise).
    fps : float
        Frame rate (contact speed threshold is in m/s).
    contact_kw
        Passed to :func:`contact_mask`.

    Returns
    -------
    R_thigh, R_shin : (F, 3, 3)
        Locked rotations (each bone turned by the minimal rotation onto its new direction,
        so twist is kept).
    contact : (F,) bool
    ankle : (F, 3)
        Ankle positions before locking (for measuring skate).
    ankle_locked : (F, 3)
    """
    from .retarget import swing

    hip = np.asarray(hip, float)
    knee = hip + thigh_len * R_thigh[:, :, axis]
    ankle = knee + shin_len * R_shin[:, :, axis]
    contact = contact_mask(ankle, fps, **contact_kw)
    target = pinned_targets(ankle, contact)
    new_knee, new_ankle = two_bone_ik(hip, knee, ankle, target)
    Rt = swing(R_thigh[:, :, axis], new_knee - hip) @ R_thigh
    Rs = swing(R_shin[:, :, axis], new_ankle - new_knee) @ R_shin
    keep = ~contact
    Rt[keep], Rs[keep] = R_thigh[keep], R_shin[keep]
    return Rt, Rs, contact, ankle, np.where(contact[:, None], new_ankle, ankle)
