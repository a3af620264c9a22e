"""A hidden arm mirrored from the other arm while the legs move alike (core.fit_mirror)."""

import numpy as np

from core import skeleton as sk
from core.fit_coupling import fill_unobserved, limb_dofs
from core.fit_mirror import legs_mirror_r2, mirror_hidden, mirror_pairs

NF = 50


def _jumps(rng, legs="mirrored"):
    """A jump-like sequence at 25 fps: both legs flex together (``legs="mirrored"``),
    against each other (``"gait"``) or stand still (``"still"``); both arms swing
    together, the right the mirror image of the left; angles noisy 0.3°."""
    skel = sk.make_skeleton()
    s = np.ones(skel.n_groups)
    left, right, sign = mirror_pairs(skel, s)
    t = np.arange(NF) / 25.0
    phase = 2 * np.pi * 0.8 * t
    theta = np.zeros((NF, skel.n_dof))
    if legs != "still":
        theta[:, skel.dof_index("l_hip_x")] = 0.5 * np.sin(phase)
        theta[:, skel.dof_index("l_knee_x")] = -0.6 - 0.5 * np.sin(phase)
    for k, v in (
        ("l_shoulder_x", 0.6 * np.sin(phase - 0.3)),
        ("l_shoulder_z", 0.2 + 0.1 * t),
        ("l_elbow_x", -0.5 - 0.3 * np.cos(phase)),
    ):
        theta[:, skel.dof_index(k)] = v
    mirror = np.isin(
        left,
        [
            skel.dof_index(n)
            for n in ("l_hip_x", "l_knee_x", "l_shoulder_x", "l_shoulder_z", "l_elbow_x")
        ],
    )
    theta[:, right[mirror]] = theta[:, left[mirror]] * sign[mirror]
    if legs == "gait":  # the right leg half a period behind
        for k in ("r_hip_x", "r_knee_x"):
            j = skel.dof_index(k)
            theta[:, j] = np.roll(theta[:, j], 16)
    theta += rng.normal(0, np.radians(0.3), theta.shape)
    root = np.column_stack([np.zeros(NF), 0.8 * t, np.full(NF, 1.0)])
    return skel, s, theta, root


def _hide_right_arm(skel, theta, seen_hand=()):
    """The fit's view: the right arm hidden from frame 1 (frame 0 clicked), held there;
    its hand seen (and fitted right) in ``seen_hand`` frames."""
    arm = limb_dofs(skel, "r", "arm")
    hidden = np.zeros(theta.shape, bool)
    hidden[1:, arm] = True
    held = theta.copy()
    held[1:, arm] = theta[0, arm]
    hand = [skel.dof_index("r_wrist_x"), skel.dof_index("r_wrist_y")]
    for f in seen_hand:
        hidden[f, hand] = False
        held[f, hand] = theta[f, hand]
    return held, hidden


def test_mirrored_angles_put_the_right_arm_where_the_left_one_is_reflected(rng):
    skel = sk.make_skeleton()
    s = 1.0 + 0.05 * rng.standard_normal(skel.n_groups)
    left, right, sign = mirror_pairs(skel, s)
    assert len(left) == 15 and set(np.abs(sign)) == {1.0}
    theta = np.zeros(skel.n_dof)
    arm_l, leg_l = limb_dofs(skel, "l", "arm"), limb_dofs(skel, "l", "leg")
    theta[arm_l] = rng.uniform(-0.6, 0.6, len(arm_l))
    theta[leg_l] = rng.uniform(-0.6, 0.6, len(leg_l))
    theta[right] = sign * theta[left]
    xyz = sk.joint_positions(skel, theta, np.zeros(3), s).reshape(-1, 3)
    names = skel.joint_names
    lat = xyz[names.index("l_hip")] - xyz[names.index("r_hip")]
    lat /= np.linalg.norm(lat)
    mid = 0.5 * (xyz[names.index("l_hip")] + xyz[names.index("r_hip")])
    for part in ("shoulder", "elbow", "wrist", "hand", "knee", "ankle", "toe"):
        p_l, p_r = xyz[names.index("l_" + part)], xyz[names.index("r_" + part)]
        reflected = p_l - 2.0 * np.dot(p_l - mid, lat) * lat
        assert np.linalg.norm(reflected - p_r) < 1e-9, part
        assert np.linalg.norm(p_l - p_r) > 0.05, part  # not trivially on the mid-plane


def test_a_hidden_arm_in_a_jump_follows_the_other_arm_mirrored(rng):
    skel, s, truth, root = _jumps(rng)
    seen = range(30, 36)
    held, hidden = _hide_right_arm(skel, truth, seen)
    out, mirrored, report = mirror_hidden(skel, held, s, hidden, anchors=(0,))
    arm = limb_dofs(skel, "r", "arm")
    moving = [skel.dof_index(k) for k in ("r_shoulder_x", "r_shoulder_z", "r_elbow_x")]
    err = np.abs(out[1:, moving] - truth[1:, moving]).max()
    err_held = np.abs(held[1:, moving] - truth[1:, moving]).max()
    # noise 0.3° on both arms: within 2.5°, where holding the clicked pose is 40° off
    assert err < np.radians(2.5) and err_held > np.radians(40), (err, err_held)
    assert [(m.limb, m.mirrored) for m in report] == [("r_arm", True)] and report[0].r2 > 0.95
    # the clicked frame, the left arm and the seen hand keep their own angles
    assert np.array_equal(out[0], held[0]) and not mirrored[0].any()
    assert np.array_equal(out[:, limb_dofs(skel, "l", "arm")], held[:, limb_dofs(skel, "l", "arm")])
    hand = skel.dof_index("r_wrist_x")
    assert np.array_equal(out[list(seen), hand], held[list(seen), hand])
    # every clavicle, shoulder, elbow and wrist angle is mirrored
    assert mirrored[1:, arm].any(axis=0).all()
    # the seen hand's offset from the mirror image fades in and out: no jump at its ends
    steps = np.abs(np.diff(out[:, hand]))
    assert steps.max() < np.radians(3.0), np.degrees(steps.max())


def test_an_arm_is_not_mirrored_when_the_legs_do_not_move_alike(rng):
    for legs in ("gait", "still"):
        skel, s, truth, root = _jumps(rng, legs)
        held, hidden = _hide_right_arm(skel, truth)
        out, mirrored, report = mirror_hidden(skel, held, s, hidden, anchors=(0,))
        assert not mirrored.any() and np.array_equal(out, held), legs
        assert [m.mirrored for m in report] == [False]
        pairs = mirror_pairs(skel, s)
        r2 = legs_mirror_r2(skel, truth, pairs, np.arange(NF), 0.05)
        assert (r2 < 0) if legs == "gait" else (r2 == -np.inf), (legs, r2)


def test_the_fit_s_last_step_mirrors_before_it_bridges(rng):
    skel, s, truth, root = _jumps(rng)
    held, hidden = _hide_right_arm(skel, truth)
    hidden[-1] = False  # the arm seen again at the end: bridging alone would interpolate
    held[-1] = truth[-1]
    div = np.zeros(NF, bool)
    k = skel.dof_index("r_shoulder_x")
    on, msgs = fill_unobserved(skel, held, root, s, hidden, div, hidden=hidden, anchors=(0,))
    off, _ = fill_unobserved(
        skel, held, root, s, hidden, div, hidden=hidden, anchors=(0,), mirror=False
    )
    err_on = np.abs(on[:, k] - truth[:, k]).max()
    err_off = np.abs(off[:, k] - truth[:, k]).max()
    assert err_on < np.radians(2.5) and err_off > 10 * err_on, (err_on, err_off)
    assert any("mirrored from the other arm" in m for m in msgs)


def test_a_hidden_clavicle_keeps_its_own_angles_while_the_arm_is_mirrored(rng):
    """The left clavicle rises and falls with its arm's swing; the right one, hidden,
    stays where it was clicked (a shoulder girdle that hardly moves, as on the jumps'
    truth): it is held there, not given the left one's motion; seen again at the last
    frame, it moves linearly towards that angle."""
    skel, s, truth, root = _jumps(rng)
    lk, rk = skel.dof_index("l_clavicle_y"), skel.dof_index("r_clavicle_y")
    truth[:, lk] = 0.15 * np.sin(2 * np.pi * 0.8 * np.arange(NF) / 25.0)
    truth[:, rk] = np.radians(4.0)
    truth[-1, rk] = np.radians(8.0)
    held, hidden = _hide_right_arm(skel, truth)
    hidden[-1, rk] = False
    held[-1, rk] = truth[-1, rk]
    out, mirrored, _ = mirror_hidden(skel, held, s, hidden, anchors=(0,))
    assert mirrored[1:-1, rk].all() and not mirrored[[0, -1], rk].any()
    expect = np.radians(4.0 + 4.0 * np.arange(NF) / (NF - 1))
    np.testing.assert_allclose(out[:, rk], expect, atol=1e-12)
    left, right, sign = mirror_pairs(skel, s)
    g = sign[list(left).index(lk)]
    assert np.abs(g * held[:, lk] - expect).max() > np.radians(6.0)  # the mirror image
