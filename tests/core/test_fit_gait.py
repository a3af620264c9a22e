"""A hidden arm swinging with the opposite thigh in a walk (core.fit_gait)."""

import numpy as np
import pytest

from core import skeleton as sk
from core.fit_coupling import fill_unobserved, limb_dofs
from core.fit_gait import (
    _rotation,
    body_axes,
    gait_swing_arms,
    sagittal_swings,
    swing_deg,
    turn_bone,
)

NF = 50
RATIO = 0.7
SHOULDER = ["r_shoulder_x", "r_shoulder_y", "r_shoulder_z"]


def _walk(legs_sign=-1.0, left_arm_ratio=0.4):
    """Legs swinging at 1 Hz (25 fps) against each other (``legs_sign=-1``) or alike
    (+1); the right upper arm's sagittal swing exactly ``RATIO`` times the left thigh's
    plus 3°, the left upper arm's ``left_arm_ratio`` times the right thigh's, both set
    through :func:`turn_bone`."""
    skel = sk.make_skeleton()
    s = np.ones(skel.n_groups)
    t = np.arange(NF) / 25.0
    phase = 2 * np.pi * t
    theta = np.zeros((NF, skel.n_dof))
    theta[:, skel.dof_index("l_hip_x")] = 0.4 * np.sin(phase)
    theta[:, skel.dof_index("r_hip_x")] = legs_sign * 0.4 * np.sin(phase)
    theta[:, skel.dof_index("r_elbow_x")] = -0.4
    theta[:, skel.dof_index("pelvis_z")] = 0.1 * np.sin(phase)  # the body turns a little
    root = np.column_stack([np.zeros(NF), 1.2 * t, np.full(NF, 1.0)])
    x = sk.joint_positions(skel, theta, root, s)
    sw = sagittal_swings(x, skel.joint_names)
    right = -body_axes(x, skel.joint_names)["trunk"][0]
    for side, other, ratio in (("r", "l", RATIO), ("l", "r", left_arm_ratio)):
        dofs = np.array([skel.dof_index(f"{side}_shoulder_{a}") for a in "xyz"])
        for f in range(NF):
            turn = _rotation(right[f], ratio * sw[f"{other}_thigh"][f] + 3.0 - sw[f"{side}_arm"][f])
            theta[f, dofs] = turn_bone(skel, theta[f], root[f], s, f"{side}_shoulder", dofs, turn)
    return skel, s, theta, root


def _hide_right_arm(skel, theta, a, b):
    """The fit's view: the right arm unobserved in frames a..b-1, held at frame a-1
    (or at b where the stretch starts the take)."""
    unobs = np.zeros(theta.shape, bool)
    arm = limb_dofs(skel, "r", "arm")
    unobs[a:b, arm] = True
    held = theta.copy()
    held[a:b, arm] = theta[a - 1 if a > 0 else b, arm]
    return held, unobs


def test_swing_is_the_forward_angle_from_straight_down():
    up, fwd = np.array([[0.0, 0, 1]]), np.array([[0.0, 1, 0]])
    v = np.array([[0.0, np.sin(0.3), -np.cos(0.3)]])
    assert swing_deg(v, up, fwd)[0] == pytest.approx(np.degrees(0.3))
    back = np.array([[0.0, -np.sin(0.3), -np.cos(0.3)]])
    assert swing_deg(back, up, fwd)[0] == pytest.approx(-np.degrees(0.3))


def test_forward_is_the_way_the_body_faces_and_a_forward_arm_swings_positive():
    skel = sk.make_skeleton()
    s = np.ones(skel.n_groups)
    theta = np.zeros(skel.n_dof)
    root = np.array([[0.0, 0.0, 1.0]])
    x = sk.joint_positions(skel, theta[None], root, s)
    names = skel.joint_names
    toes = x[0, names.index("l_toe")] - x[0, names.index("l_ankle")]  # the feet point forwards
    for _lat, up, fwd in body_axes(x, names).values():
        assert fwd[0] @ toes > 0 and abs(fwd[0] @ up[0]) < 1e-12
    # the left arm turned forwards about the trunk's right-pointing axis swings positive
    right = -body_axes(x, names)["trunk"][0][0]
    dofs = np.array([skel.dof_index(f"l_shoulder_{a}") for a in "xyz"])
    before = sagittal_swings(x, names)["l_arm"][0]
    theta[dofs] = turn_bone(skel, theta, root[0], s, "l_shoulder", dofs, _rotation(right, 20.0))
    after = sagittal_swings(sk.joint_positions(skel, theta[None], root, s), names)["l_arm"][0]
    assert after - before == pytest.approx(20.0, abs=1e-4)


def test_turn_bone_turns_the_bone_and_nothing_else(rng):
    skel = sk.make_skeleton()
    s = np.ones(skel.n_groups)
    theta = rng.normal(0, 0.2, skel.n_dof)
    root = np.array([0.0, 0.0, 1.0])
    dofs = np.array([skel.dof_index(n) for n in SHOULDER])
    axis = np.array([0.6, 0.0, 0.8])
    turn = _rotation(axis, 20.0)
    R0, _ = sk.bone_frames(skel, sk.forward(skel, theta, root, s))
    new = theta.copy()
    new[dofs] = turn_bone(skel, theta, root, s, "r_shoulder", dofs, turn)
    R1, _ = sk.bone_frames(skel, sk.forward(skel, new, root, s))
    b = skel.bone_index("r_shoulder")
    assert np.abs(R1[0, b] - turn @ R0[0, b]).max() < 1e-8
    assert np.allclose(R1[0, skel.bone_index("l_shoulder")], R0[0, skel.bone_index("l_shoulder")])


def test_a_hidden_arm_swings_back_with_the_opposite_thigh():
    skel, s, truth, root = _walk()
    a, b = 14, 30  # the back swing, never seen (as in make demo's frames 8-23)
    held, unobs = _hide_right_arm(skel, truth, a, b)
    out, swung, report = gait_swing_arms(skel, held, root, s, unobs, unobs)
    names = skel.joint_names
    j = [names.index("r_elbow"), names.index("r_wrist")]
    err = np.linalg.norm(
        sk.joint_positions(skel, out, root, s)[a:b, j]
        - sk.joint_positions(skel, truth, root, s)[a:b, j],
        axis=-1,
    ).max()
    err_held = np.linalg.norm(
        sk.joint_positions(skel, held, root, s)[a:b, j]
        - sk.joint_positions(skel, truth, root, s)[a:b, j],
        axis=-1,
    ).max()
    # the model is exact here: only the shoulder's twist, which the swing does not
    # fix, may differ from the truth's, by the solver's tolerance
    assert err < 1e-3 and err_held > 0.1, (err, err_held)
    dofs = [skel.dof_index(n) for n in SHOULDER]
    assert swung[a:b][:, dofs].all() and swung.sum() == 3 * (b - a)
    assert np.array_equal(out[~swung], held[~swung])
    (r_arm,) = report
    assert r_arm.limb == "r_arm" and r_arm.frames == b - a and r_arm.legs_r < -0.9
    assert r_arm.other_ratio == pytest.approx(0.4, abs=0.05)


def test_a_stretch_to_the_last_frame_keeps_its_observed_end():
    skel, s, truth, root = _walk()
    a = 38
    held, unobs = _hide_right_arm(skel, truth, a, NF)
    out, swung, _ = gait_swing_arms(skel, held, root, s, unobs, unobs)
    sw_out = sagittal_swings(sk.joint_positions(skel, out, root, s), skel.joint_names)
    sw_true = sagittal_swings(sk.joint_positions(skel, truth, root, s), skel.joint_names)
    assert swung[a:].any(axis=1).all()
    assert np.abs(sw_out["r_arm"][a:] - sw_true["r_arm"][a:]).max() < 1e-3


def test_legs_moving_alike_are_not_gait():
    skel, s, truth, root = _walk(legs_sign=+1.0)
    held, unobs = _hide_right_arm(skel, truth, 14, 30)
    out, swung, report = gait_swing_arms(skel, held, root, s, unobs, unobs)
    assert not swung.any() and np.array_equal(out, held)
    assert report[0].frames == 0 and report[0].legs_r > 0.9


def test_arms_that_do_not_swing_are_not_gait():
    """Pedalling: the legs move against each other, the seen left hand stays put."""
    skel, s, truth, root = _walk(left_arm_ratio=0.0)
    held, unobs = _hide_right_arm(skel, truth, 14, 30)
    out, swung, report = gait_swing_arms(skel, held, root, s, unobs, unobs)
    assert not swung.any() and np.array_equal(out, held)
    assert report[0].frames == 0 and abs(report[0].other_ratio) < 0.05


def test_angles_placed_earlier_are_not_replaced():
    skel, s, truth, root = _walk()
    held, unobs = _hide_right_arm(skel, truth, 14, 30)
    out, swung, report = gait_swing_arms(skel, held, root, s, unobs, np.zeros_like(unobs))
    assert not swung.any() and np.array_equal(out, held) and report == []


def test_the_fill_step_swings_the_arm_after_the_bridge():
    skel, s, truth, root = _walk()
    a, b = 14, 30
    held, unobs = _hide_right_arm(skel, truth, a, b)
    diverged = np.zeros(NF, bool)
    off, _ = fill_unobserved(skel, held, root, s, unobs, diverged, couple=False, gait=False)
    on, msgs = fill_unobserved(skel, held, root, s, unobs, diverged, couple=False)
    j = skel.joint_names.index("r_wrist")
    x_true = sk.joint_positions(skel, truth, root, s)[a:b, j]
    e_off = np.linalg.norm(sk.joint_positions(skel, off, root, s)[a:b, j] - x_true, axis=-1)
    e_on = np.linalg.norm(sk.joint_positions(skel, on, root, s)[a:b, j] - x_true, axis=-1)
    assert e_on.mean() < 0.25 * e_off.mean(), (e_on.mean(), e_off.mean())
    assert any("swung with the opposite thigh" in m for m in msgs)
