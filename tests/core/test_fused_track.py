"""Point-fit poses and contours in one EKF (core.fused_track)."""

import numpy as np
import pytest

from core.contour_track import ContourTrackSettings, track_contours
from core.fused_track import track_fused
from core.metaballs import make_metaballs
from core.skeleton import make_skeleton
from tests.core.test_contour_track import _contours, _swing


@pytest.fixture(scope="module")
def rig():
    from tests.core.test_contour_obs import _look_at

    skel = make_skeleton()
    balls = make_metaballs(skel)
    s = np.ones(skel.n_groups)
    target = np.array([0.0, 0.0, 1.0])
    cams = [
        _look_at(target + d, target)
        for d in (np.array([0.0, -4.0, 0.0]), np.array([4.0, 0.0, 0.0]))
    ]
    return skel, balls, s, cams


def test_without_points_it_is_the_contour_tracker(rig):
    skel, balls, s, cams = rig
    theta, root = _swing(skel, 3)
    obs = [_contours(skel, theta[f], root[f], s, balls, cams) for f in range(3)]
    cfg = ContourTrackSettings(iterations=2)
    nan = np.full((3, skel.n_dof + 3), np.nan)
    fused, used = track_fused(
        skel, s, balls, theta[0], root[0], cams, obs, nan, nan, cfg, silhouettes=True
    )
    plain = track_contours(skel, s, balls, theta[0], root[0], cams, obs, cfg)
    assert not used.any()
    for a, b in zip(fused, plain, strict=True):
        np.testing.assert_allclose(a.theta, b.theta, atol=1e-12)
        np.testing.assert_allclose(a.root, b.root, atol=1e-12)


def test_point_poses_carry_the_track_where_contours_fail(rig):
    skel, balls, s, cams = rig
    F = 6
    theta, root = _swing(skel, F)
    empty = [[[] for _ in cams] for _ in range(F)]  # no silhouettes at all
    q = np.hstack([theta, root])
    sig = np.full_like(q, 0.01)
    q_bad = q.copy()
    q_bad[3, skel.n_dof] += 1.0  # one root coordinate slid off by a metre in frame 3
    cfg = ContourTrackSettings()
    tr, used = track_fused(
        skel,
        s,
        balls,
        theta[0],
        root[0],
        cams,
        empty,
        q_bad,
        sig,
        cfg,
        sigma_floor_theta=0.01,
        sigma_floor_root=0.01,
    )
    est = np.array([np.concatenate([t.theta, t.root]) for t in tr])
    assert not any(t.updated for t in tr)  # the contour update had nothing to use
    np.testing.assert_array_equal(used, [q.shape[1]] * 3 + [q.shape[1] - 1] + [q.shape[1]] * 2)
    assert np.abs(est - q).max() < 0.03  # followed the points, ignored the gross one
    coast = track_contours(skel, s, balls, theta[0], root[0], cams, empty, cfg)
    assert np.abs(coast[-1].theta - theta[-1]).max() > 0.1  # without them: stuck at frame 0


def test_shapes_are_checked(rig):
    skel, balls, s, cams = rig
    theta, root = _swing(skel, 2)
    with pytest.raises(ValueError, match="must both be"):
        track_fused(
            skel,
            s,
            balls,
            theta[0],
            root[0],
            cams,
            [[[], []]] * 2,
            np.zeros((2, 3)),
            np.zeros((2, 3)),
        )
