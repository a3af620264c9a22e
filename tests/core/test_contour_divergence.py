"""Silhouette containment, the divergence flag of contour tracking, and camera selection."""

import numpy as np
import pytest

import core.contour_track as ct
from core.contour_obs import (
    body_ellipsoids,
    containment_observations,
    contour_mask,
    contour_observations,
)
from core.contours import occluding_contours
from core.metaballs import make_metaballs
from core.model_render import render_parts
from core.skeleton import make_skeleton
from tests.core.test_contour_obs import _look_at


@pytest.fixture(scope="module")
def rig():
    skel = make_skeleton()
    balls = make_metaballs(skel)
    s = np.ones(skel.n_groups)
    target = np.array([0.0, 0.0, 1.0])
    cams = [
        _look_at(target + d, target)
        for d in (
            np.array([0.0, -4.0, 0.0]),
            np.array([4.0, 0.0, 0.0]),
            np.array([-2.8, -2.8, 0.0]),
        )
    ]
    theta = np.zeros(skel.n_dof)
    theta[skel.dof_index("l_shoulder_y")] = -0.6
    theta[skel.dof_index("r_shoulder_y")] = 0.6
    theta[skel.dof_index("l_hip_x")] = -0.3
    root = np.array([0.0, 0.0, 1.0])
    contours = []
    for cam in cams:
        c, a, r, p = body_ellipsoids(skel, theta, root, s, balls)
        contours.append(occluding_contours(render_parts(cam, c, a, r, p).mask, spacing=1.5))
    return skel, balls, s, cams, theta, root, contours


def test_contour_mask_fills_the_silhouette(rig):
    skel, balls, s, cams, theta, root, contours = rig
    c, a, r, p = body_ellipsoids(skel, theta, root, s, balls)
    truth = render_parts(cams[0], c, a, r, p).mask
    m = contour_mask(contours[0], cams[0].size)
    assert (m & truth).sum() / (m | truth).sum() > 0.9


def test_containment_jacobian_matches_finite_differences(rig):
    skel, balls, s, cams, theta, root, contours = rig
    fields = ct.frame_fields(cams, contours)
    rng = np.random.default_rng(3)
    th = theta + rng.normal(0, 0.15, theta.size)
    rt = root + np.array([0.12, 0.0, 0.0])  # body partly outside the silhouettes
    co = containment_observations(skel, th, rt, s, balls, cams, fields, tol_px=0.0)
    assert co.outside.mean() > 0.2
    # points well outside (the field is smooth there, away from the pixel grid's kinks)
    k = np.flatnonzero(co.residual > 5.0)
    assert len(k) > 20
    # the field's gradient is a central difference over ±1 px: compare with steps of
    # about a pixel (the bilinear field is piecewise linear at finer steps)
    eps = 0.02
    for j in (skel.dof_index("l_shoulder_y"), skel.dof_index("l_hip_x")):
        d = np.zeros_like(th)
        d[j] = eps
        hi = containment_observations(skel, th + d, rt, s, balls, cams, fields, tol_px=0.0)
        lo = containment_observations(skel, th - d, rt, s, balls, cams, fields, tol_px=0.0)
        fd = (hi.residual - lo.residual) / (2 * eps)
        moved = k[np.abs(co.J_theta[k, j]) > 1.0]
        assert len(moved) > 5
        # the distance transform has ridges (its gradient jumps there): most points agree
        ok = np.abs(co.J_theta[moved, j] - fd[moved]) <= 3.0 + 0.2 * np.abs(fd[moved])
        assert ok.mean() > 0.9
    d = np.array([0.003, 0.0, 0.0])
    fd = (
        containment_observations(skel, th, rt + d, s, balls, cams, fields, tol_px=0.0).residual
        - containment_observations(skel, th, rt - d, s, balls, cams, fields, tol_px=0.0).residual
    ) / (2 * d[0])
    ok = np.abs(co.J_root[k, 0] - fd[k]) <= 30.0 + 0.2 * np.abs(fd[k])
    assert ok.mean() > 0.9


def _update(rig, theta, root, recover, search=False):
    skel, balls, s, cams, _, _, contours = rig
    cfg = ct.ContourTrackSettings(recover=recover, search=search)
    ekf = ct.start_filter(skel, theta, root, cfg)
    fields = ct.frame_fields(cams, contours)
    return ct.update_with_contours(ekf, skel, s, balls, cams, contours, cfg, fields=fields)


def test_divergence_flag_quiet_on_a_good_pose(rig):
    skel, balls, s, cams, theta, root, contours = rig
    rng = np.random.default_rng(0)
    out = _update(rig, theta + rng.normal(0, 0.02, theta.size), root + 0.005, recover=False)
    assert not out.diverged
    assert out.outside_frac < 0.02 and out.unexplained_frac < 0.05


def test_divergence_flag_fires_on_a_lost_pose(rig):
    skel, balls, s, cams, theta, root, contours = rig
    lost = theta.copy()
    # both arms swung up and forward, a leg out to the side: far from the silhouettes
    for name, v in (
        ("l_shoulder_x", -1.4),
        ("r_shoulder_x", -1.4),
        ("r_hip_y", 0.9),
        ("l_shoulder_y", 0.0),
        ("r_shoulder_y", 0.0),
    ):
        lost[skel.dof_index(name)] = v
    out = _update(rig, lost, root + np.array([0.25, 0.0, 0.0]), recover=False)
    assert out.diverged
    assert out.outside_frac > 0.15 or out.unexplained_frac > 0.2
    # the limb search and the re-solve bring it back
    back = _update(rig, lost, root + np.array([0.25, 0.0, 0.0]), recover=True, search=True)
    assert back.searched
    assert back.outside_frac + back.unexplained_frac < 0.5 * (
        out.outside_frac + out.unexplained_frac
    )


def test_selection_uses_only_cameras_that_see_the_part(rig):
    skel, balls, s, cams, theta, root, contours = rig
    rate = np.zeros(skel.n_dof)
    rate[skel.dof_index("l_hip_x")] = 0.05
    rate[skel.dof_index("l_shoulder_y")] = 0.05
    obs = contour_observations(skel, theta, root, s, balls, cams, contours, theta_rate=rate)
    vis = np.nan_to_num(obs.selection.visibility, nan=0.0)
    assert (vis < 0.2).any()  # some part is hidden in some camera
    assert np.all(vis[obs.selection.use] >= 0.2)
    assert np.all(vis[obs.part, obs.camera] >= 0.2)
    # all fused uses hidden part-views too
    fused = contour_observations(skel, theta, root, s, balls, cams, contours, select=False)
    assert (vis[fused.part, fused.camera] < 0.2).any()
