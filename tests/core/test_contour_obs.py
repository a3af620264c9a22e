"""Contour observations drive the body back to the pose that made the silhouettes."""

import numpy as np
import pytest

from core.camera import Camera
from core.contour_obs import body_ellipsoids, contour_observations
from core.contours import occluding_contours
from core.metaballs import make_metaballs
from core.model_render import render_parts
from core.skeleton import joint_positions, make_skeleton


def _look_at(centre, target, size=(320, 240), f=420.0):
    fwd = target - centre
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, [0.0, 0.0, 1.0])
    if np.linalg.norm(right) < 1e-6:
        right = np.array([1.0, 0.0, 0.0])
    right /= np.linalg.norm(right)
    down = np.cross(fwd, right)
    R = np.stack([right, down, fwd])
    K = np.array([[f, 0, size[0] / 2 - 0.5], [0, f, size[1] / 2 - 0.5], [0, 0, 1]])
    return Camera("c", size, K, np.zeros(5), R, -R @ centre)


@pytest.fixture(scope="module")
def body():
    skel = make_skeleton()
    balls = make_metaballs(skel)
    s = np.ones(skel.n_groups)
    rng = np.random.default_rng(7)
    theta = np.zeros(skel.n_dof)
    # arms abducted (left: negative y, right: positive), an elbow bent, legs apart
    for name, val in (
        ("l_shoulder_y", -0.8),
        ("r_shoulder_y", 0.9),
        ("l_elbow_x", -0.6),
        ("r_knee_x", 0.5),
        ("r_hip_x", -0.4),
        ("l_hip_y", -0.25),
    ):
        theta[skel.dof_index(name)] = val
    root = np.array([0.0, 0.0, 1.0])
    target = np.array([0.0, 0.0, 1.0])
    cams = [
        _look_at(target + d, target)
        for d in (
            np.array([0.0, -4.0, 0.0]),
            np.array([4.0, 0.0, 0.0]),
            np.array([-2.8, -2.8, 0.0]),
        )
    ]
    observed = []
    for cam in cams:
        c, a, r, p = body_ellipsoids(skel, theta, root, s, balls)
        observed.append(occluding_contours(render_parts(cam, c, a, r, p).mask, spacing=1.5))
    return skel, balls, s, theta, root, cams, observed, rng


def test_residuals_vanish_at_the_true_pose(body):
    skel, balls, s, theta, root, cams, observed, _ = body
    obs = contour_observations(skel, theta, root, s, balls, cams, observed)
    assert len(obs) > 300
    assert np.median(np.abs(obs.residual)) < 0.5  # pixel discretisation only


def test_gauss_newton_on_contours_recovers_the_pose(body):
    """Perturb limb angles and the root; Gauss–Newton on the contour equations alone,
    solving for those parameters, brings every joint back (the observation model and its
    Jacobian are right)."""
    skel, balls, s, theta, root, cams, observed, rng = body
    names = ("l_shoulder_y", "r_shoulder_x", "r_knee_x", "l_hip_x", "l_elbow_x")
    free = [skel.dof_index(n) for n in names]
    th = theta.copy()
    th[free] += rng.choice([-1, 1], len(free)) * 0.12
    rt = root + np.array([0.02, -0.015, 0.01])
    truth = joint_positions(skel, theta, root, s)
    err0 = np.linalg.norm(joint_positions(skel, th, rt, s) - truth, axis=1).max()
    for _ in range(6):
        obs = contour_observations(skel, th, rt, s, balls, cams, observed)
        J = np.hstack([obs.J_theta[:, free], obs.J_root])
        d = np.linalg.lstsq(J, -obs.residual, rcond=None)[0]
        th[free] += d[:-3]
        rt = rt + d[-3:]
    err = np.linalg.norm(joint_positions(skel, th, rt, s) - truth, axis=1)
    assert err0 > 0.05
    assert err.max() < 0.006, (err0, err.max())
    assert obs.rms_px < 1.0


def test_all_cameras_fused_without_selection(body):
    skel, balls, s, theta, root, cams, observed, _ = body
    sel = contour_observations(
        skel, theta, root, s, balls, cams, observed, theta_rate=np.full(skel.n_dof, 0.01)
    )
    fused = contour_observations(skel, theta, root, s, balls, cams, observed, select=False)
    assert fused.selection.use.sum() >= sel.selection.use.sum()
    # a part hidden behind the torso in one view is not used there when selecting
    hidden = (sel.selection.visibility < 0.2) & np.isfinite(sel.selection.visibility)
    assert not np.any(sel.selection.use & hidden)
