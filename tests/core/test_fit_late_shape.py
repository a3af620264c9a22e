"""The late shape (``SequenceSettings.late_shape_points``, :mod:`core.fit_late_shape`).

A forearm that the shape frames did not see keeps the template's radii; when its points
arrive they cover only the side the cameras face, and a forearm fatter than the real one
is pushed off them.  The late shape re-solves that bone over the fitted take and the
second pass tracks with it.
"""

from dataclasses import replace

import numpy as np
import pytest

from core import metaball_surface as mbs
from core import metaballs as mb
from core import skeleton as sk
from core.fit import FramePoints, SequenceSettings, fit_sequence
from core.fit_frame import FrameFitter
from core.fit_init import initialise
from core.fit_late_shape import late_shape
from core.landmarks import CLICK_JOINTS
from tests.core._bodyscene import cameras, clicks_of, model_points

NF = 8
HIDDEN_UNTIL = 2  # the forearm has no points in frames 0-1 (the shape frames)
OTHER_MAX = 0.45  # a point deeper in another part's field is inside the body


@pytest.fixture(scope="module")
def thin_forearm():
    """A left elbow bending over 8 frames; the true forearm 40 % thinner across than
    the template's; its points only on the camera side (−Y) and none in frames 0–1."""
    rng = np.random.default_rng(11)
    skel = sk.make_skeleton()
    s = np.ones(skel.n_groups)
    balls = mb.make_metaballs(skel, "complete", s)
    true = balls.copy()
    fore = true.bone == skel.bone_index("l_elbow")
    true.radii[fore] *= np.array([0.6, 0.6, 1.0])  # the metaballs' long axis is z
    theta = np.zeros((NF, skel.n_dof))
    theta[:, skel.dof_index("l_shoulder_x")] = 0.1
    theta[:, skel.dof_index("l_elbow_x")] = -0.3 - 0.1 * np.arange(NF)
    root = np.array([[0.0, -0.01 * f, 1.0] for f in range(NF)])
    b = skel.bone_index("l_elbow")
    frames = []
    for f in range(NF):
        xyz, part = model_points(skel, true, theta[f], root[f], s, rng, per_bone=60)
        pose = sk.forward(skel, theta[f][None], root[f][None], s)
        centre = sk.bone_frames(skel, pose)[1][0, b]
        front = xyz[:, 1] < centre[1] - 0.005  # the side the cameras face
        Rw, cw = mb.world_frames(skel, pose, true, s)
        outer = np.ones(len(xyz), bool)  # not inside another part
        for p in np.unique(part):
            on, other = part == p, true.bone != p
            f_other = mb.field(xyz[on], Rw[0, other], cw[0, other], true.radii[other])[0]
            outer[on] = f_other < OTHER_MAX
        keep = outer & ((part != b) | (front & (f >= HIDDEN_UNTIL)))
        frames.append(FramePoints(xyz[keep] + rng.normal(0, 0.001, (keep.sum(), 3)), 0.001))
    init = initialise(
        clicks_of(skel, theta[0], root[0], s, cameras(), CLICK_JOINTS), cameras(), model="complete"
    )
    return skel, s, theta, root, frames, init, true


def _forearm_surface_mm(skel, s, true, theta, root, radii, centers, f, rng):
    """Mean distance (mm) of the true forearm and hand surface, the cameras' side and
    the far side, to the same bones' metaballs with ``radii`` and ``centers``, at the
    true pose of frame f."""
    b = skel.bone_index("l_elbow")
    xyz, part = model_points(skel, true, theta[f], root[f], s, rng, per_bone=300)
    x = xyz[part == b]
    pose = sk.forward(skel, theta[f][None], root[f][None], s)
    front = x[:, 1] < sk.bone_frames(skel, pose)[1][0, b, 1] - 0.005
    arm = np.isin(true.bone, [b, skel.bone_index("l_wrist")])
    Rw, cw = mb.world_frames(skel, pose, true.with_parts(centers, radii), s)
    p, ok = mbs.project_to_surface(x, Rw[0, arm], cw[0, arm], radii[arm])
    d = 1000 * np.linalg.norm(p - x, axis=1)
    return d[ok & front].mean(), d[ok & ~front].mean()


@pytest.mark.slow
def test_a_forearm_the_shape_frames_missed_is_shaped_from_the_take(thin_forearm):
    skel, s, theta, root, frames, init, true = thin_forearm
    fx = FrameFitter(frames, init, SequenceSettings())
    fx.theta[:], fx.root[:], fx.s = theta, root, s.copy()  # the take fitted exactly
    fx.n_pts[:] = [len(p.xyz) for p in frames]
    fx.unexpl[:] = 0.0
    late = late_shape(fx, [0, 1], init.metaballs, step=1, min_points=40, missed_points=10)
    assert late is not None and set(late.bones) == {"l_elbow", "l_wrist"}, late and late.bones
    grown = np.isin(skel.bone_names, late.bones)
    assert np.all(late.shape_points[grown] < 10) and np.all(late.take_points[grown] >= 40)
    kept = ~grown[fx.balls.bone]  # every other bone keeps the shape frames' shape
    assert np.array_equal(late.radii[kept], fx.radii[kept])
    assert np.array_equal(late.centers[kept], fx.balls.center0[kept])
    rng = np.random.default_rng(3)
    for f in (3, 6):
        was = _forearm_surface_mm(skel, s, true, theta, root, fx.radii, fx.balls.center0, f, rng)
        now = _forearm_surface_mm(skel, s, true, theta, root, late.radii, late.centers, f, rng)
        # the template's forearm is 40 % too thick: ~20 mm off on the cameras' side
        assert was[0] > 15.0 and now[0] < 0.5 * was[0] and now[1] < was[1], (f, was, now)
    assert "l_elbow, l_wrist re-shaped over frames 0, 1, 2" in late.message()
    fx.unexpl[:] = 0.3  # a take whose fit leaves its points unexplained: not re-shaped
    assert late_shape(fx, [0, 1], init.metaballs, step=1, min_points=40, missed_points=10) is None

    # the second pass starts from it: the shape frames (no forearm points) keep it
    cfg = SequenceSettings(shape="template", late_shape_points=40, late_shape_missed=10)
    second = fit_sequence(frames[:2], init, cfg, shape0=late)
    assert second.late_shape is None  # one late shape per take
    st = second.state.metaballs
    now = _forearm_surface_mm(skel, s, true, theta, root, st.radii, st.center0, 0, rng)
    was = _forearm_surface_mm(skel, s, true, theta, root, fx.radii, fx.balls.center0, 0, rng)
    assert now[0] < 0.5 * was[0], (was, now)


def test_cli_one_pass_turns_the_late_shape_off(monkeypatch):
    """``python -m core fit SCENE --one-pass`` asks for no late shape; by default the
    fit has it."""
    from pathlib import Path

    import core.fit_scene
    from core.cli import main

    seen = []

    class Stop(Exception):
        pass

    def fake_run_scene(scene, settings=None, **kw):
        seen.append(settings.late_shape_points)
        raise Stop

    monkeypatch.setattr(core.fit_scene, "run_scene", fake_run_scene)
    scene = Path(__file__).resolve().parents[2] / "sample_scenes" / "walk_line3"
    for argv, want in ((["--one-pass"], None), ([], SequenceSettings().late_shape_points)):
        with pytest.raises(Stop):
            main(["fit", str(scene), *argv])
        assert seen[-1] == want
    assert seen[-1] == 100


@pytest.mark.slow
def test_the_first_pass_leaves_the_written_shape_to_the_second(thin_forearm):
    """``defer_shape``: where the late shape qualifies, the first pass does not fit the
    whole-body shape its state would carry (the second pass writes its own); the motion
    and the late shape are the same to the last bit, and without a qualifying late shape
    the written shape is fitted as before."""
    frames, init = thin_forearm[4][:6], thin_forearm[5]  # the forearm seen in frames 2-5
    cfg = SequenceSettings(late_shape_points=40, late_shape_missed=10, late_shape_step=1)
    kept = fit_sequence(frames, init, cfg)
    left = fit_sequence(frames, init, cfg, defer_shape=True)
    assert kept.late_shape is not None and left.late_shape is not None
    assert kept.shape is not None and left.shape is None
    assert "whole-body shape: left to the second pass (late shape)" in left.messages
    assert np.array_equal(kept.state.theta, left.state.theta)
    assert np.array_equal(kept.state.root_xyz, left.state.root_xyz)
    assert np.array_equal(kept.late_shape.radii, left.late_shape.radii)
    assert np.array_equal(kept.late_shape.centers, left.late_shape.centers)
    # nothing qualifies: the written shape is fitted whatever the caller asked
    none = fit_sequence(frames, init, replace(cfg, late_shape_points=10**6), defer_shape=True)
    assert none.late_shape is None and none.shape is not None
    assert np.array_equal(none.state.metaballs.radii, kept.state.metaballs.radii)
