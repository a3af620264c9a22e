"""The fitted motion smoothed over the take: noise goes, true motion and flips do not mislead it."""

import numpy as np
import pytest

from core import skeleton as sk
from core.motion_smoother import smooth_angles, smooth_joints, smooth_series


def _rms(a):
    return float(np.sqrt(np.mean(np.square(a))))


def test_noise_around_a_slow_path_is_smoothed_and_a_one_frame_flip_dropped(rng):
    f = 50
    t = np.arange(f)
    truth = np.stack([0.5 * np.sin(2 * np.pi * t / 40), 0.01 * t, np.zeros(f)], axis=1)
    z = truth + rng.normal(0.0, 0.02, truth.shape)
    z[20, 0] += 0.5  # one frame flipped
    res = smooth_series(z, np.ones(z.shape, bool))
    for k in range(3):
        assert _rms(res.x[:, k] - truth[:, k]) < 0.4 * _rms(z[:, k] - truth[:, k])
    assert abs(res.x[20, 0] - truth[20, 0]) < 0.03  # the flip is not spread
    assert res.far[20, 0] and res.far[:, 0].sum() <= 3
    # the noise the smoother estimates is the noise that was added
    assert res.noise[1] == pytest.approx(0.02, rel=0.35)


def test_a_fast_true_motion_measured_closely_is_kept(rng):
    """A 12-frame period with 1 mrad noise: the likelihood asks for little smoothing."""
    t = np.arange(50)
    truth = 0.3 * np.sin(2 * np.pi * t / 12)[:, None]
    z = truth + rng.normal(0.0, 0.001, truth.shape)
    res = smooth_series(z, np.ones(z.shape, bool))
    assert _rms(res.x - truth) < 1.2 * _rms(z - truth)
    assert res.ratio[0] > 1e-2


def test_unused_frames_keep_their_values_and_short_series_are_left(rng):
    z = np.cumsum(rng.normal(0.0, 0.01, (30, 2)), axis=0)
    use = np.ones(z.shape, bool)
    use[10:13] = False
    z[10:13] = 5.0  # a diverged stretch: its values are not data
    use[:, 1] = False
    use[:3, 1] = True  # three frames: too few to choose a smoothness
    res = smooth_series(z, use)
    assert np.array_equal(res.x[10:13, 0], z[10:13, 0])
    assert np.all(np.abs(res.x[9, 0] - z[9, 0]) < 0.05)  # not pulled towards 5
    assert np.array_equal(res.x[:, 1], z[:, 1]) and np.isnan(res.ratio[1])


def test_one_ratio_for_all_series_keeps_their_sum():
    """Two angles that trade off (one up as the other goes down) keep their sum's path
    with one common smoothness; the sum is all that places the end of the chain."""
    rng = np.random.default_rng(3)
    t = np.arange(50)
    wobble = rng.normal(0.0, 0.05, 50)
    a = 0.3 * np.sin(2 * np.pi * t / 40) + wobble
    b = -wobble  # a + b is smooth
    z = np.stack([a, b], axis=1)
    res = smooth_series(z, np.ones(z.shape, bool), common=True)
    assert res.ratio[0] == res.ratio[1]
    s_true = 0.3 * np.sin(2 * np.pi * t / 40)
    assert _rms(res.x.sum(axis=1) - s_true) < 0.01


def test_smooth_angles_unwraps_turns_keeps_limits_and_diverged_frames(rng):
    skel = sk.make_skeleton()
    f, n = 40, skel.n_dof
    t = np.arange(f)
    theta = np.zeros((f, n))
    heading = 0.25 * t - np.pi  # a turn through ±π
    theta[:, 0] = np.angle(np.exp(1j * heading))  # as a fit may write it, wrapped
    knee = skel.dof_index("l_knee_x")
    lo, hi = skel.dof_lo[knee], skel.dof_hi[knee]
    theta[:, knee] = np.clip(lo + 0.002 + rng.normal(0, 0.01, f), lo, hi)  # at its limit
    theta += rng.normal(0.0, 1e-4, theta.shape) * (np.arange(n) != knee)
    root = np.c_[0.02 * t, np.zeros(f), np.full(f, 0.9)] + rng.normal(0, 0.003, (f, 3))
    div = np.zeros(f, bool)
    div[25] = True
    th, rx, res = smooth_angles(theta, root, div, lo=skel.dof_lo, hi=skel.dof_hi)
    # the turn is one motion: each frame stays on its own branch, close to its value
    assert np.all(np.abs(th[:, 0] - theta[:, 0]) < 0.01)
    assert np.all(th[:, knee] >= np.minimum(lo, theta[:, knee]) - 1e-12)
    assert np.array_equal(th[25], theta[25]) and np.array_equal(rx[25], root[25])
    ok = ~div
    assert _rms(rx[ok, 0] - 0.02 * t[ok]) < 0.6 * _rms(root[ok, 0] - 0.02 * t[ok])
    assert np.all(np.isfinite(res.ratio)) and len(set(res.ratio)) == 1


def test_core_fit_smooth_asks_the_sequence_fit_for_it(monkeypatch):
    """``python -m core fit SCENE --smooth`` turns ``smooth_motion`` on; off without it."""
    from pathlib import Path

    import core.fit_scene
    from core.cli import main

    seen = []

    class Stop(Exception):
        pass

    def fake_run_scene(scene, settings=None, **kw):
        seen.append(settings.smooth_motion)
        raise Stop

    monkeypatch.setattr(core.fit_scene, "run_scene", fake_run_scene)
    scene = Path(__file__).resolve().parents[2] / "sample_scenes" / "walk_line3"
    for argv, want in ((["--smooth"], True), ([], False)):
        with pytest.raises(Stop):
            main(["fit", str(scene), *argv])
        assert seen[-1] is want


def test_the_joints_smoothed_where_they_are_seen_and_a_chain_kept(rng):
    """``smooth_joints``: angles with frame-to-frame noise, and the spine's links
    counter-rotating from frame to frame (their sum smooth): the joints come closer to
    the truth, the head does not wobble, a diverged frame keeps its pose."""
    skel = sk.make_skeleton()
    s = np.ones(skel.n_groups)
    f, n = 40, skel.n_dof
    t = np.arange(f)[:, None]
    truth = np.zeros((f, n))
    moving = [skel.dof_index(d) for d in ("l_hip_x", "r_hip_x", "l_knee_x", "l_shoulder_x")]
    truth[:, moving] = 0.4 * np.sin(2 * np.pi * t / 30 + np.arange(len(moving)))
    truth[:, skel.dof_index("l_knee_x")] += 0.5  # bent, within its limits
    root = np.c_[0.02 * t[:, 0], np.zeros(f), np.full(f, 0.95)]
    theta = truth + rng.normal(0.0, 0.02, truth.shape)
    wobble = rng.normal(0.0, 0.1, f)
    theta[:, skel.dof_index("lowerback_x")] += wobble
    theta[:, skel.dof_index("spine_x")] -= wobble
    div = np.zeros(f, bool)
    div[20] = True
    th, rt, res = smooth_joints(skel, s, theta, root, div)
    x_true = sk.joint_positions(skel, truth, root, s)
    x_fit = sk.joint_positions(skel, theta, root, s)
    x_sm = sk.joint_positions(skel, th, rt, s)
    ok = ~div
    err = lambda x: float(np.mean(np.linalg.norm(x[ok] - x_true[ok], axis=-1)))  # noqa: E731
    assert err(x_sm) < 0.5 * err(x_fit)
    head = skel.joint_index("head")
    acc = lambda x: np.linalg.norm(np.diff(x[:20, head], 2, axis=0), axis=-1).mean()  # noqa: E731
    assert acc(x_sm) < 0.2 * acc(x_fit)
    np.testing.assert_array_equal(th[20], theta[20])
    np.testing.assert_array_equal(rt[20], root[20])
    assert np.all((th >= np.minimum(skel.dof_lo, theta)) & (th <= np.maximum(skel.dof_hi, theta)))
    assert res.x.shape == (f, 3 * len(skel.joint_names))
