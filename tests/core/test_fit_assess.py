"""Judging one fitted frame (core.fit_assess)."""

import numpy as np

from core import metaball_surface as mbs
from core import metaballs as mb
from core import skeleton as sk
from core.fit_assess import assess_frame
from core.fit_search import explain_distance
from core.fit_types import SequenceSettings
from core.fitting import FitResult
from core.segment import segment_points


def _frame():
    """The template body standing at (0, 0, 1), points on its whole-body surface and
    their parts as the sequence fit segments them (−1 ambiguous)."""
    skel = sk.make_skeleton()
    s = np.ones(skel.n_groups)
    balls = mb.make_metaballs(skel, "simplified", s)
    theta, root = np.zeros(skel.n_dof), np.array([0.0, 0.0, 1.0])
    xyz, ok = mbs.sample_surface(
        skel, sk.forward(skel, theta[None], root[None], s), balls, s, per_ball=20
    )
    xyz = xyz[ok]
    cfg = SequenceSettings()
    part, _ = segment_points(
        xyz, skel, balls, theta, root, s, None, cfg.segment_max_dist, cfg.segment_margin
    )
    return skel, s, balls, theta, root, xyz, part, cfg


def _res(skel, theta, root, s, part):
    """A converged pose solve's result tuple at (theta, root) with the points' parts."""
    r = FitResult(
        theta=theta,
        root_xyz=root,
        s=s,
        radii=np.zeros((0, 3)),
        centers=np.zeros((0, 3)),
        rmse_field=0.0,
        rmse_m=0.0,
        theta_sigma=np.full(skel.n_dof, 0.01),
        converged=True,
        diverged=False,
    )
    return (np.concatenate([theta, root]), r, True, part, None)


def test_points_on_the_body_are_accepted_and_far_points_are_named():
    skel, s, balls, theta, root, xyz, part, cfg = _frame()
    assert np.abs(explain_distance(xyz, skel, balls, s, balls.radii, theta, root)).max() < 1e-9
    ok, why, st = assess_frame(
        _res(skel, theta, root, s, part), skel, balls, balls.radii, s, xyz, None, lambda: None, cfg
    )
    assert ok and why == "", why
    assert st["n"] == (part >= 0).sum() > 300
    assert st["inl"] == 1.0 and st["rmse"] < 0.01 and st["unexplained"] == 0.0
    assert st["cost"] < 1e-12 and st["contour"] is None and st["conv"]
    # the same points and parts, the body 0.3 m aside: every check on the points fails
    ok, why, st = assess_frame(
        _res(skel, theta, root + [0.3, 0.0, 0.0], s, part),
        skel,
        balls,
        balls.radii,
        s,
        xyz,
        None,
        lambda: None,
        cfg,
    )
    assert not ok
    assert "inlier points" in why and "far from the body" in why, why
    assert st["unexplained"] > 0.8 and st["cost"] > 0.8 * len(xyz) * cfg.search_tau**2


def test_a_failed_solve_passes_its_message_on_without_statistics():
    skel, s, balls, theta, root, xyz, _, cfg = _frame()
    res = (None, None, False, "frame 3: only 12 usable points", None)
    calls = []
    ok, why, st = assess_frame(
        res, skel, balls, balls.radii, s, xyz, None, lambda: calls.append(1), cfg
    )
    assert (ok, why, st) == (False, "frame 3: only 12 usable points", None)
    assert not calls  # the free-space probes are not even built
