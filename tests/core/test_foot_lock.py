"""Foot locking maths on a seeded synthetic stride (no Blender)."""

from __future__ import annotations

import numpy as np

from core.foot_lock import contact_mask, pinned_targets, skate_mm, two_bone_ik


def _stride(rng, fps=30.0):
    """An ankle path: planted (sliding 2 mm/frame) frames 10-29, swinging otherwise."""
    F = 50
    t = np.arange(F)
    xyz = np.zeros((F, 3))
    xyz[:, 0] = 0.04 * t
    xyz[:, 2] = 0.08 + 0.15 * np.abs(np.sin(np.pi * t / 20.0))
    plant = (t >= 10) & (t < 30)
    xyz[plant, 0] = 0.4 + 0.002 * (t[plant] - 10)
    xyz[plant, 2] = 0.08 + rng.normal(0, 0.002, plant.sum())
    return xyz, plant, fps


def test_contact_found_and_pinning_removes_skate(rng):
    xyz, plant, fps = _stride(rng)
    c = contact_mask(xyz, fps)
    assert c[12:28].all() and not c[:8].any() and not c[32:].any()
    before = skate_mm(xyz, c)
    assert 25.0 < before < 45.0  # about 2 mm per frame
    pinned = pinned_targets(xyz, c)
    assert skate_mm(pinned, c) < 1e-9
    np.testing.assert_array_equal(pinned[~c], xyz[~c])
    np.testing.assert_array_equal(pinned[:, 2], xyz[:, 2])


def test_two_bone_ik_keeps_lengths_and_knee_side(rng):
    F = 20
    hip = np.tile([0.0, 0.0, 0.9], (F, 1)) + rng.normal(0, 0.02, (F, 3))
    knee = hip + np.array([0.05, 0.0, -0.42]) + rng.normal(0, 0.01, (F, 3))
    ankle = knee + np.array([-0.03, 0.0, -0.41]) + rng.normal(0, 0.01, (F, 3))
    target = ankle + np.array([0.0, 0.0, 0.08]) + rng.normal(0, 0.02, (F, 3))  # in reach
    k2, a2 = two_bone_ik(hip, knee, ankle, target)
    np.testing.assert_allclose(a2, target, atol=1e-9)
    np.testing.assert_allclose(
        np.linalg.norm(k2 - hip, axis=1), np.linalg.norm(knee - hip, axis=1), atol=1e-9
    )
    np.testing.assert_allclose(
        np.linalg.norm(a2 - k2, axis=1), np.linalg.norm(ankle - knee, axis=1), atol=1e-9
    )
    assert np.all(k2[:, 0] > hip[:, 0] - 0.05)  # the knee stays forward (+x)
    # out of reach: the leg straightens towards the target
    far = hip + np.array([0.0, 0.0, -2.0])
    k3, a3 = two_bone_ik(hip, knee, ankle, far)
    reach = np.linalg.norm(knee - hip, axis=1) + np.linalg.norm(ankle - knee, axis=1)
    np.testing.assert_allclose(np.linalg.norm(a3 - hip, axis=1), reach, atol=1e-6)


def test_lock_leg_pins_the_ankle_and_keeps_bone_lengths():
    """A leg whose foot slides during a stance: after locking, the ankle stays put in
    contact, swings freely otherwise, and the thigh keeps its twist."""
    from core.foot_lock import lock_leg
    from core.retarget import swing

    F, fps = 30, 30.0
    t = np.arange(F)
    hip = np.stack([0.01 * t, np.zeros(F), np.full(F, 0.9)], axis=1)
    # the foot slides 5 mm/frame (0.15 m/s) during frames 5..20, lifted outside them
    down = np.array([0.0, 0.0, -1.0])
    lift = np.where((t >= 5) & (t <= 20), 0.0, 0.08)
    ankle = np.stack([0.005 * t - 0.1, np.zeros(F), 0.02 + lift], axis=1)
    l1 = l2 = 0.46
    d = ankle - hip
    dist = np.linalg.norm(d, axis=1, keepdims=True)
    u = d / dist
    pole = np.array([1.0, 0.0, 0.0]) - u[:, :1] * u
    pole /= np.linalg.norm(pole, axis=1, keepdims=True)
    knee = hip + 0.5 * d + np.sqrt(l1**2 - (dist / 2) ** 2) * pole  # knee bent forward
    # bone rotations whose Y axis points along each bone, with some twist
    twist = np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]])
    R_thigh = swing(np.broadcast_to(down, (F, 3)), knee - hip) @ twist
    R_shin = swing(np.broadcast_to(down, (F, 3)), ankle - knee) @ twist
    Rt, Rs, contact, before, after = lock_leg(hip, R_thigh, R_shin, l1, l2, fps)
    assert contact[8:18].all() and not contact[:3].any()
    assert skate_mm(before, contact) > 50.0
    assert skate_mm(after, contact) < 1.0
    new_ankle = hip + l1 * Rt[:, :, 1] + l2 * Rs[:, :, 1]
    np.testing.assert_allclose(new_ankle, after, atol=1e-9)
    np.testing.assert_allclose(Rt[~contact], R_thigh[~contact])
    for R in (Rt, Rs):
        np.testing.assert_allclose(
            R @ np.swapaxes(R, 1, 2), np.broadcast_to(np.eye(3), R.shape), atol=1e-9
        )
