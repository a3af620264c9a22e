"""Metaballs: field, gradient, surface, and Jacobians w.r.t. radii and pose."""

import numpy as np
import pytest

from core import metaballs as mb
from core import skeleton as sk


@pytest.fixture
def setup(rng):
    skel = sk.make_skeleton()
    theta = rng.normal(0.0, 0.3, (1, skel.n_dof))
    root = np.array([[0.2, -0.1, 0.95]])
    s = 1.0 + 0.05 * rng.normal(size=skel.n_groups)
    balls = mb.make_metaballs(skel, "simplified", s)
    balls.radii *= 1.0 + 0.1 * rng.random(balls.radii.shape)
    return skel, theta, root, s, balls


def test_models_counts():
    skel = sk.make_skeleton()
    simple = mb.make_metaballs(skel, "simplified")
    full = mb.make_metaballs(skel, "complete")
    upper = skel.bone_index("l_shoulder")
    assert np.count_nonzero(simple.bone == upper) == 3
    assert np.count_nonzero(full.bone == upper) == 6
    assert len(full) > len(simple)


def test_lone_metaball_surface_is_the_scaled_ellipsoid():
    radii = np.array([[0.1, 0.2, 0.3]])
    Rw, cw = np.eye(3)[None], np.zeros((1, 3))
    x = np.diag(radii[0] * mb.VISIBLE)
    F, grad, _, _ = mb.field(x, Rw, cw, radii)
    np.testing.assert_allclose(F, 0.5)
    n = mb.normals(grad)
    np.testing.assert_allclose(n, np.eye(3), atol=1e-12)


def test_gradient_and_radius_jacobian(setup, rng):
    skel, theta, root, s, balls = setup
    pose = sk.forward(skel, theta, root, s)
    Rw, cw = mb.world_frames(skel, pose, balls, s)
    x = cw[0, rng.integers(0, len(balls), 30)] + rng.normal(0, 0.05, (30, 3))
    F, grad, f, y = mb.field(x, Rw[0], cw[0], balls.radii)
    eps = 1e-6
    num = np.stack([(mb.field(x + eps * e, Rw[0], cw[0], balls.radii)[0]
                     - mb.field(x - eps * e, Rw[0], cw[0], balls.radii)[0]) / (2 * eps)
                    for e in np.eye(3)], axis=-1)
    np.testing.assert_allclose(grad, num, atol=1e-6)
    Jr = mb.radius_jacobian(f, y, balls.radii)
    m, a = 5, 1
    r2 = balls.radii.copy()
    r2[m, a] += eps
    r1 = balls.radii.copy()
    r1[m, a] -= eps
    num = (mb.field(x, Rw[0], cw[0], r2)[0] - mb.field(x, Rw[0], cw[0], r1)[0]) / (2 * eps)
    np.testing.assert_allclose(Jr[:, m, a], num, atol=1e-6)


def test_pose_and_scale_jacobians(setup, rng):
    skel, theta, root, s, balls = setup
    pose = sk.forward(skel, theta, root, s)
    Rw, cw = mb.world_frames(skel, pose, balls, s)
    x = cw[0, rng.integers(0, len(balls), 25)] + rng.normal(0, 0.05, (25, 3))
    member = rng.random((25, len(balls))) < 0.5

    def F_of(th, rt, ss):
        p = sk.forward(skel, th, rt, ss)
        R, c = mb.world_frames(skel, p, balls, ss)
        return mb.field(x, R[0], c[0], balls.radii, member)[0]

    _, _, f, y = mb.field(x, Rw[0], cw[0], balls.radii, member)
    J_theta, J_root, J_s = mb.pose_jacobian(skel, pose, balls, s, x, f, y, balls.radii)
    eps = 1e-6
    num = np.stack([(F_of(theta + eps * e, root, s) - F_of(theta - eps * e, root, s)) / (2 * eps)
                    for e in np.eye(skel.n_dof)], axis=-1)
    np.testing.assert_allclose(J_theta, num, atol=1e-6)
    num = np.stack([(F_of(theta, root + eps * e, s) - F_of(theta, root - eps * e, s)) / (2 * eps)
                    for e in np.eye(3)], axis=-1)
    np.testing.assert_allclose(J_root, num, atol=1e-6)
    num = np.stack([(F_of(theta, root, s + eps * e) - F_of(theta, root, s - eps * e)) / (2 * eps)
                    for e in np.eye(skel.n_groups)], axis=-1)
    np.testing.assert_allclose(J_s, num, atol=1e-6)


def test_surface_sampler_lands_on_iso_surface(setup):
    skel, theta, root, s, balls = setup
    pose = sk.forward(skel, theta, root, s)
    xyz, ok = mb.sample_surface(skel, pose, balls, s, per_ball=20)
    assert ok.mean() > 0.95
    Rw, cw = mb.world_frames(skel, pose, balls, s)
    F, _, _, _ = mb.field(xyz[ok], Rw[0], cw[0], balls.radii)
    np.testing.assert_allclose(F, 0.5, atol=1e-8)
