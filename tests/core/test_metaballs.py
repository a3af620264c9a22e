"""Metaballs: field, gradient, surface, and Jacobians w.r.t. radii and pose."""

import numpy as np
import pytest

from core import metaball_surface as mbs
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
    num = np.stack(
        [
            (
                mb.field(x + eps * e, Rw[0], cw[0], balls.radii)[0]
                - mb.field(x - eps * e, Rw[0], cw[0], balls.radii)[0]
            )
            / (2 * eps)
            for e in np.eye(3)
        ],
        axis=-1,
    )
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
    num = np.stack(
        [
            (F_of(theta + eps * e, root, s) - F_of(theta - eps * e, root, s)) / (2 * eps)
            for e in np.eye(skel.n_dof)
        ],
        axis=-1,
    )
    np.testing.assert_allclose(J_theta, num, atol=1e-6)
    num = np.stack(
        [
            (F_of(theta, root + eps * e, s) - F_of(theta, root - eps * e, s)) / (2 * eps)
            for e in np.eye(3)
        ],
        axis=-1,
    )
    np.testing.assert_allclose(J_root, num, atol=1e-6)
    num = np.stack(
        [
            (F_of(theta, root, s + eps * e) - F_of(theta, root, s - eps * e)) / (2 * eps)
            for e in np.eye(skel.n_groups)
        ],
        axis=-1,
    )
    np.testing.assert_allclose(J_s, num, atol=1e-6)


def test_surface_sampler_lands_on_iso_surface(setup):
    skel, theta, root, s, balls = setup
    pose = sk.forward(skel, theta, root, s)
    xyz, ok = mbs.sample_surface(skel, pose, balls, s, per_ball=20)
    assert ok.mean() > 0.95
    Rw, cw = mb.world_frames(skel, pose, balls, s)
    F, _, _, _ = mb.field(xyz[ok], Rw[0], cw[0], balls.radii)
    np.testing.assert_allclose(F, 0.5, atol=1e-8)


def test_local_coords_and_gradient_by_definition(setup, rng):
    """``local_coords`` is ``Rwᵀ (x − c)`` per metaball, and the field's gradient is
    ``−4 Σ f_m Rw_m q_m`` (the matrix-product forms against the plain sums)."""
    skel, theta, root, s, balls = setup
    Rw, cw = mb.world_frames(skel, sk.forward(skel, theta, root, s), balls, s)
    Rw, cw = Rw[0], cw[0]
    x = cw[rng.integers(0, len(balls), 30)] + rng.normal(scale=0.04, size=(30, 3))
    y = mb.local_coords(x, Rw, cw)
    ref = np.stack([[Rw[m].T @ (xi - cw[m]) for m in range(len(balls))] for xi in x])
    np.testing.assert_allclose(y, ref, atol=1e-14)
    F, grad, f, _ = mb.field(x, Rw, cw, balls.radii)
    q = ref / balls.radii[None] ** 2
    M = len(balls)
    g_ref = -4.0 * np.stack([sum(f[n, m] * Rw[m] @ q[n, m] for m in range(M)) for n in range(30)])
    np.testing.assert_allclose(grad, g_ref, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(F, f.sum(axis=1))


def test_projection_settles_each_point_on_its_own(setup):
    """Points already on the surface stay where they are; far ones walk in; the result
    does not depend on which other points are projected with them."""
    skel, theta, root, s, balls = setup
    pose = sk.forward(skel, theta, root, s)
    Rw, cw = mb.world_frames(skel, pose, balls, s)
    Rw, cw = Rw[0], cw[0]
    on, ok = mbs.sample_surface(skel, pose, balls, s, per_ball=10)
    on = on[ok]
    far = cw[:5] + np.array([0.0, 0.0, 0.3])
    xs, good = mbs.project_to_surface(np.vstack([on, far]), Rw, cw, balls.radii)
    np.testing.assert_array_equal(xs[: len(on)], on)
    assert good.all()
    F, _, _, _ = mb.field(xs, Rw, cw, balls.radii)
    np.testing.assert_allclose(F, 0.5, atol=1e-9)
    alone, _ = mbs.project_to_surface(far, Rw, cw, balls.radii)
    # to round-off: the matrix products' last bit can depend on the batch's size (BLAS
    # picks its kernels by shape; 2e-16 m apart on one of our machines)
    np.testing.assert_allclose(alone, xs[len(on) :], rtol=0, atol=1e-12)


@pytest.mark.parametrize("model", ["simplified", "complete"])
@pytest.mark.parametrize("per_part", [True, False])
def test_deflated_blend_follows_the_rendered_ellipsoids(model, per_part):
    skel = sk.make_skeleton()
    s = np.ones(skel.n_groups)
    tmpl = mb.make_metaballs(skel, model, s)
    flat = mbs.deflate(skel, tmpl, s, per_part=per_part)
    # the rendered ellipsoids (contours, selection, segmentation) are unchanged
    np.testing.assert_allclose(flat.visible, tmpl.visible, rtol=1e-12)
    q = flat.radii / tmpl.radii
    if per_part:  # within a part the metaballs only shrink
        assert np.median(q) < 0.99 and q.max() < 1.01
    else:
        assert np.median(q) < 0.9 and q.max() < 1.3
    # points on the union of the rendered ellipsoids, at a pose the fit did not see
    theta = np.zeros((1, skel.n_dof))
    theta[0, skel.dof_index("l_elbow_x")] = -0.8
    pose = sk.forward(skel, theta, np.array([[0.0, 0.0, 1.0]]), s)
    Rw, cw = mb.world_frames(skel, pose, tmpl, s)
    Rw, cw = Rw[0], cw[0]
    u = np.random.default_rng(0).normal(size=(len(tmpl), 40, 3))
    u /= np.linalg.norm(u, axis=2, keepdims=True)
    x = (cw[:, None] + np.einsum("mij,mpj->mpi", Rw, u * tmpl.visible[:, None])).reshape(-1, 3)
    y = mb.local_coords(x, Rw, cw)
    own = np.repeat(np.arange(len(tmpl)), 40)
    inside = np.sum((y / tmpl.visible[None]) ** 2, axis=-1) < 1.0 - 1e-9
    inside[np.arange(len(x)), own] = False
    x = x[~inside.any(axis=1)]
    gap = {}
    for name, b in (("template", tmpl), ("deflated", flat)):
        xs, ok = mbs.project_to_surface(x, Rw, cw, b.radii, iterations=60, tol=1e-6)
        gap[name] = np.median(np.linalg.norm(xs - x, axis=1)[ok])
    # the template's blend swells a centimetre or more off its rendered ellipsoids;
    # deflated part by part, the parts' blends still add up across the joints
    assert gap["template"] > 0.01
    assert gap["deflated"] < (0.6 if per_part else 0.3) * gap["template"]


def test_visible_scale_survives_the_state_dict():
    skel = sk.make_skeleton()
    s = np.ones(skel.n_groups)
    flat = mbs.deflate(skel, mb.make_metaballs(skel, "simplified", s), s)
    back = mb.Metaballs.from_dict(flat.to_dict(skel), skel)
    np.testing.assert_allclose(back.visible_scale, flat.visible_scale)
    np.testing.assert_allclose(back.visible, flat.visible)
    plain = mb.make_metaballs(skel, "simplified", s)
    assert mb.Metaballs.from_dict(plain.to_dict(skel), skel).visible_scale is None
    np.testing.assert_allclose(plain.visible, plain.radii * mb.VISIBLE)


def test_the_hip_girdle_follows_the_hips_when_they_sit_in_front_of_the_pelvis():
    """Hips clicked in front of the pelvis (a mocap root near the sacrum) turn the
    girdle about the lateral axis with them: it keeps its place and axes relative to
    the hips' line, as with hips straight below the pelvis."""
    lean = np.radians(40.0)
    Q = np.array(
        [[1, 0, 0], [0, np.cos(lean), np.sin(lean)], [0, -np.sin(lean), np.cos(lean)]]
    )  # turns straight down (0, 0, −1) to down and forward (0, −sin, −cos)
    below = np.array([0.09, 0.0, -0.09])
    for model in ("simplified", "complete"):
        upright = sk.make_skeleton({"l_hip": below, "r_hip": below * [-1, 1, 1]})
        leaning = sk.make_skeleton({"l_hip": Q @ below, "r_hip": Q @ (below * [-1, 1, 1])})
        a, b = mb.make_metaballs(upright, model), mb.make_metaballs(leaning, model)
        on = a.bone == upright.bone_index("pelvis")
        assert on.sum() == (1 if model == "simplified" else 3)
        np.testing.assert_allclose(b.center0[on], a.center0[on] @ Q.T, atol=1e-12)
        np.testing.assert_allclose(b.rot[on], Q @ a.rot[on], atol=1e-12)
        np.testing.assert_allclose(b.radii, a.radii)
        assert np.allclose(a.rot[on], np.eye(3))  # hips straight below: as the template


def test_world_frames_of_some_metaballs(setup):
    """world_frames(..., which=...) gives those metaballs' frames, the same bits, also
    from a pose of their bones' DOFs alone."""
    skel, theta, root, s, balls = setup
    which = np.isin(balls.bone, [skel.bone_index(b) for b in ("r_knee", "r_ankle")])
    Rw, cw = mb.world_frames(skel, sk.forward(skel, theta, root, s), balls, s)
    dofs = skel.bone_dof[balls.bone[which]]
    sub = mb.world_frames(skel, sk.forward(skel, theta, root, s, dofs=dofs), balls, s, which)
    np.testing.assert_array_equal(sub[0], Rw[:, which])
    np.testing.assert_array_equal(sub[1], cw[:, which])
