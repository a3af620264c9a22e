"""A hidden limb following the opposite thigh (core.fit_coupling)."""

import numpy as np

from core import skeleton as sk
from core.fit_bridge import bridge_hidden
from core.fit_coupling import couple_hidden, coupling_lines, fill_runs, limb_dofs, segment_swing

NF = 60


def _gait(rng, arm_follows=True):
    """A walk-like sequence: the left thigh swings at 1 Hz (25 fps), the right arm swings
    against it (or, ``arm_follows=False``, at an unrelated 0.37 Hz), angles noisy 0.5°."""
    skel = sk.make_skeleton()
    s = np.ones(skel.n_groups)
    t = np.arange(NF) / 25.0
    phase = 2 * np.pi * 1.0 * t
    theta = np.zeros((NF, skel.n_dof))
    theta[:, skel.dof_index("l_hip_x")] = 0.4 * np.sin(phase)
    theta[:, skel.dof_index("r_hip_x")] = -0.4 * np.sin(phase)
    arm = np.sin(phase - 0.15) if arm_follows else np.sin(2 * np.pi * 0.37 * t + 1.0)
    theta[:, skel.dof_index("r_shoulder_x")] = -0.35 * arm
    theta[:, skel.dof_index("r_elbow_x")] = -0.3 - 0.15 * arm
    theta += rng.normal(0, np.radians(0.5), theta.shape)
    root = np.column_stack([np.zeros(NF), 1.2 * t, np.full(NF, 1.0)])
    return skel, s, theta, root


def _hide_right_arm(skel, theta, a, b):
    """The fit's view: the arm unobserved in frames a..b-1, held at frame a-1."""
    unobs = np.zeros(theta.shape, bool)
    arm = limb_dofs(skel, "r", "arm")
    unobs[a:b, arm] = True
    held = theta.copy()
    held[a:b, arm] = theta[a - 1, arm]
    return held, unobs


def test_a_hidden_arm_swing_is_recovered_from_the_opposite_thigh(rng):
    skel, s, truth, root = _gait(rng)
    a, b = 24, 40  # 16 frames about the arm's back swing, never seen (as in make demo)
    held, unobs = _hide_right_arm(skel, truth, a, b)
    coupled_theta, coupled, report = couple_hidden(skel, held, root, s, unobs)
    bridged_theta, _ = bridge_hidden(held, unobs)
    k = [skel.dof_index("r_shoulder_x"), skel.dof_index("r_elbow_x")]
    err = np.abs(coupled_theta[a:b, k] - truth[a:b, k]).max()
    err_bridge = np.abs(bridged_theta[a:b, k] - truth[a:b, k]).max()
    assert coupled[a:b, k].all() and not coupled[:a].any() and not coupled[b:].any()
    # noise 0.5°, the arm lags the thigh by 0.15 rad (3° the line cannot follow): within
    # 5° where the bridge, flat between two similar ends, is 20° off
    assert err < np.radians(5.0) and err_bridge > 4 * err, (err, err_bridge)
    r_arm = [c for c in report if c.limb == "r_arm"][0]
    assert r_arm.frames == b - a and r_arm.r2 > 0.9
    # angles without a slope (the clavicle, the wrist: noise only) are left to the bridge
    assert not coupled[:, skel.dof_index("r_wrist_x")].any()
    # the observed frames are untouched
    assert np.array_equal(coupled_theta[~unobs], held[~unobs])


def test_an_arm_that_does_not_follow_the_thigh_is_left_alone(rng):
    skel, s, truth, root = _gait(rng, arm_follows=False)
    held, unobs = _hide_right_arm(skel, truth, 18, 34)
    out, coupled, report = couple_hidden(skel, held, root, s, unobs)
    assert not coupled.any() and np.array_equal(out, held)
    assert [c.frames for c in report] == [0]


def test_runs_at_the_ends_are_left_unless_asked(rng):
    skel, s, truth, root = _gait(rng)
    held, unobs = _hide_right_arm(skel, truth, 3, 20)  # seen in 3 frames before it only
    _, coupled, _ = couple_hidden(skel, held, root, s, unobs)
    assert not coupled.any()  # the coupling must be seen on both sides (4 frames each)
    held, unobs = _hide_right_arm(skel, truth, 45, NF)
    _, coupled, _ = couple_hidden(skel, held, root, s, unobs)
    assert not coupled.any()
    out, coupled, _ = couple_hidden(skel, held, root, s, unobs, ends=True)
    k = skel.dof_index("r_shoulder_x")
    assert coupled[45:, k].all()
    assert np.abs(out[45:, k] - truth[45:, k]).max() < np.abs(held[45:, k] - truth[45:, k]).max()


def test_a_diverged_frame_or_a_hidden_driver_stops_a_run(rng):
    skel, s, truth, root = _gait(rng)
    held, unobs = _hide_right_arm(skel, truth, 18, 34)
    div = np.zeros(NF, bool)
    div[25] = True  # the run 18-33 splits: 18-24 ends at a diverged frame
    _, coupled, _ = couple_hidden(skel, held, root, s, unobs, div)
    assert not coupled.any()
    unobs2 = unobs.copy()
    unobs2[30, limb_dofs(skel, "l", "leg")] = True  # the driver itself unobserved once
    _, coupled, _ = couple_hidden(skel, held, root, s, unobs2)
    assert not coupled[:, limb_dofs(skel, "r", "arm")].any()
    unobs3 = unobs.copy()
    unobs3[30, limb_dofs(skel, "l", "leg")[-2:]] = True  # only the foot: the thigh drives
    _, coupled, _ = couple_hidden(skel, held, root, s, unobs3)
    assert coupled[18:34, skel.dof_index("r_shoulder_x")].all()


def test_segment_swing_is_the_thighs_flexion(rng):
    skel, s, truth, root = _gait(rng)
    d = segment_swing(skel, truth, root, s, "l_hip", "l_knee", np.ones(NF, bool))
    flex = truth[:, skel.dof_index("l_hip_x")]
    assert abs(np.corrcoef(d, flex)[0, 1]) > 0.99


def test_lines_and_runs():
    d = np.linspace(-1, 1, 20)
    y = np.column_stack([2 * d + 1, np.cos(7 * d) * 1e-3, np.zeros(20)])
    coef, keep, r2 = coupling_lines(d, y, 0.5)
    assert np.allclose(coef[:, 0], [1, 2]) and keep.tolist() == [True, False, False]
    assert r2 > 0.999
    y = np.arange(10.0)
    hidden = np.zeros(10, bool)
    hidden[3:6] = True
    done = fill_runs(y, np.arange(10.0) + 5.0, hidden, ~hidden, ends=False)
    # the prediction is 5 too high at both ends: the residual brings it back
    assert done.tolist() == hidden.tolist() and np.allclose(y, np.arange(10.0))


def test_a_line_seen_on_one_half_of_the_swing_is_not_extrapolated(rng):
    """The arm hidden whenever the thigh swings forward (as make demo's right arm is in
    its back swing): the line is fitted on the other half only, and the hidden
    stretch's driver reaches far past that range — it is left to the bridge and the
    gait swing, and reported.  Without the limit it is coupled."""
    skel, s, truth, root = _gait(rng)
    t = np.arange(NF) / 25.0
    forward = np.sin(2 * np.pi * t) > 0.0
    unobs = np.zeros(truth.shape, bool)
    arm = limb_dofs(skel, "r", "arm")
    unobs[np.ix_(forward, arm)] = True
    held = truth.copy()
    _, coupled, report = couple_hidden(skel, held, root, s, unobs)
    assert not coupled.any()
    r_arm = [c for c in report if c.limb == "r_arm"][0]
    assert r_arm.frames == 0 and r_arm.beyond == 1  # the middle stretch (the ends: too few)
    _, coupled, report = couple_hidden(skel, held, root, s, unobs, reach=None)
    mid = np.flatnonzero(forward & (t > 0.9) & (t < 1.6))
    assert coupled[mid][:, skel.dof_index("r_shoulder_x")].all()
