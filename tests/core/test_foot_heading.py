"""The feet's turn at the clicked frame from the points round each foot."""

from dataclasses import replace

import numpy as np
import pytest

from core import skeleton as sk
from core.fit_init import initialise
from core.foot_heading import FootHeadingSettings, feet_from_points
from core.landmarks import CLICK_JOINTS
from tests.core._bodyscene import cameras, clicks_of


@pytest.fixture
def subject(rng):
    skel = sk.make_skeleton()
    theta = rng.normal(0, 0.1, skel.n_dof)
    theta[skel.dof_index("pelvis_z")] = 0.6
    theta[skel.dof_index("l_knee_x")] = 0.4
    theta[skel.dof_index("r_ankle_z")] += 0.3  # the right foot turned 17° out
    s = 1 + 0.05 * rng.normal(size=skel.n_groups)
    return skel, theta, np.array([0.1, 0.2, 1.0]), s


def test_feet_side_by_side_share_their_points_right(rng):
    """Standing, the feet turned 20° in towards each other (toes 8 cm apart): each foot's
    points are told from the other's by the feet's heel–toe lines, refined with the
    headings found."""
    skel = sk.make_skeleton()
    theta = np.zeros(skel.n_dof)
    theta[skel.dof_index("l_ankle_z")] = -0.35
    theta[skel.dof_index("r_ankle_z")] = 0.35
    root, s = np.array([0.0, 0.0, 1.0]), np.ones(skel.n_groups)
    pts = _foot_points(skel, theta, root, s, rng)
    th, found = feet_from_points(skel, np.zeros(skel.n_dof), root, s, pts)
    for k in "lr":
        err = _heading(skel, theta, root, s, k) - _heading(skel, th, root, s, k)
        assert abs(err) < 2.0, (k, err)
    assert all(abs(f.n_points - 400) < 20 for f in found)


def _heading(skel, theta, root, s, side):
    x = sk.joint_positions(skel, theta, root, s)
    d = x[skel.joint_index(side + "_toe")] - x[skel.joint_index(side + "_ankle")]
    return np.degrees(np.arctan2(d[1], d[0]))


def _foot_points(skel, theta, root, s, rng, n_foot=400, n_shin=100):
    """A shoe-like box of points under each ankle, long along the foot, and points of
    the lower shin above it (which must not count)."""
    x = sk.joint_positions(skel, theta, root, s)
    pts = []
    for side in ("l", "r"):
        a, t = x[skel.joint_index(side + "_ankle")], x[skel.joint_index(side + "_toe")]
        u = (t - a)[:2] / np.linalg.norm((t - a)[:2])
        v = np.array([-u[1], u[0]])
        along = rng.uniform(-0.06, 0.22, n_foot)
        side_ = rng.uniform(-0.045, 0.045, n_foot)
        xy = a[:2] + along[:, None] * u + side_[:, None] * v
        z = rng.uniform(a[2] - 0.09, a[2] - 0.025, n_foot)
        pts.append(np.column_stack([xy, z]))
        ang = rng.uniform(0, 2 * np.pi, n_shin)
        h = rng.uniform(0.0, 0.3, n_shin)
        shin = a + np.column_stack([0.05 * np.cos(ang), 0.05 * np.sin(ang), h])
        pts.append(shin)
    return np.concatenate(pts) + rng.normal(0, 0.002, (2 * (n_foot + n_shin), 3))


def test_points_turn_the_feet_the_clicks_leave_at_the_template(subject, rng):
    skel, theta, root, s = subject
    cams = cameras()
    ini = initialise(clicks_of(skel, theta, root, s, cams, CLICK_JOINTS), cams)
    pts = _foot_points(skel, theta, root, s, rng)
    before = [
        _heading(skel, theta, root, s, k)
        - _heading(ini.skeleton, ini.theta, ini.root_xyz, ini.s, k)
        for k in "lr"
    ]
    assert abs(before[1]) > 10.0  # the clicks leave the turned foot at the template's
    th, found = feet_from_points(
        ini.skeleton, ini.theta, ini.root_xyz, ini.s, pts, ini.clicks.names
    )
    for k in "lr":
        err = _heading(skel, theta, root, s, k) - _heading(ini.skeleton, th, ini.root_xyz, ini.s, k)
        assert abs((err + 180) % 360 - 180) < 2.0, (k, err)
    assert [f.side for f in found] == ["l", "r"]
    assert all(f.heading_deg is not None and f.n_points >= 300 for f in found)
    # only the feet's turns move
    moved = np.flatnonzero(th != ini.theta)
    assert set(skel.dof_names[i] for i in moved) <= {"l_ankle_z", "r_ankle_z"}
    assert "r_ankle_z: the foot turned" in found[1].message()


def test_a_clicked_toe_or_too_few_points_keep_the_turn(subject, rng):
    skel, theta, root, s = subject
    pts = _foot_points(skel, theta, root, s, rng)
    th0 = np.zeros(skel.n_dof)
    th, found = feet_from_points(skel, th0, root, s, pts, clicked=("l_toe", "r_toe"))
    assert found == [] and np.array_equal(th, th0)
    few = _foot_points(skel, theta, root, s, rng, n_foot=10, n_shin=200)
    th, found = feet_from_points(skel, th0, root, s, few)
    assert np.array_equal(th, th0)
    assert all(f.heading_deg is None and "kept" in f.message() for f in found)
    th, found = feet_from_points(skel, th0, root, s, np.empty((0, 3)))
    assert np.array_equal(th, th0) and all(f.n_points == 0 for f in found)


def test_a_turn_beyond_the_joint_limit_stops_there(subject, rng):
    skel, theta, root, s = subject
    theta = theta.copy()
    k = skel.dof_index("l_ankle_z")
    theta[k] = np.radians(70.0)
    pts = _foot_points(skel, theta, root, s, rng)
    th0 = theta.copy()
    th0[k] = 0.0
    th, found = feet_from_points(skel, th0, root, s, pts, settings=FootHeadingSettings())
    assert np.isclose(th[k], np.radians(40.0))
    assert found[0].clamped and "limit" in found[0].message()


def test_the_sequence_fit_turns_the_feet_when_asked(subject, rng):
    """``SequenceSettings.foot_heading`` (off by default) turns the clicked frame's feet
    before the shape is solved there, and says so."""
    from core import metaballs as mb
    from core.fit import FramePoints, SequenceSettings, fit_sequence
    from core.fitting import FitSettings
    from tests.core._bodyscene import model_points

    skel, theta, root, s = subject
    balls = mb.make_metaballs(skel, "simplified", s)
    body, _ = model_points(skel, balls, theta, root, s, rng, per_bone=30)
    pts = np.concatenate([body, _foot_points(skel, theta, root, s, rng)])
    cams = cameras()
    init = initialise(clicks_of(skel, theta, root, s, cams, CLICK_JOINTS), cams)
    cfg = SequenceSettings(
        max_nfev=10, max_nfev_shape=10, shape="template", fit=FitSettings(members="part")
    )
    frames = [FramePoints(xyz=pts, sigma=0.002)]
    off = fit_sequence(frames, init, cfg)
    on = fit_sequence(frames, init, replace(cfg, foot_heading=True))
    assert not any("ankle_z" in m for m in off.messages)
    assert any("r_ankle_z: the foot turned" in m for m in on.messages)

    def err(res):
        st = res.state
        e = _heading(skel, theta, root, s, "r") - _heading(
            st.skeleton, st.theta[0], st.root_xyz[0], st.s, "r"
        )
        return abs((e + 180) % 360 - 180)

    assert err(on) < 3.0 < 10.0 < err(off)


def test_core_fit_passes_feet_from_points_to_the_sequence_fit(monkeypatch):
    """``python -m core fit SCENE --feet-from-points`` asks the sequence fit for it; off
    without the flag."""
    from pathlib import Path

    import core.fit_scene
    from core.cli import main

    seen = []

    class Stop(Exception):
        pass

    def fake_run_scene(scene, settings=None, **kw):
        seen.append(settings.foot_heading)
        raise Stop

    monkeypatch.setattr(core.fit_scene, "run_scene", fake_run_scene)
    scene = Path(__file__).resolve().parents[2] / "sample_scenes" / "walk_line3"
    for argv, want in ((["--feet-from-points"], True), ([], False)):
        with pytest.raises(Stop):
            main(["fit", str(scene), *argv])
        assert seen[-1] is want
