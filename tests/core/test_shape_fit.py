"""Shape fit (core.shape_fit): Jacobians, symmetry, the model-point penalty, recovery."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy import sparse

from core import metaball_surface as mbs
from core import metaballs as mb
from core import skeleton as sk
from core.shape_fit import (
    ShapeProblem,
    ShapeSettings,
    fit_shape,
    mirror_pairs,
    model_offsets,
    nearest_members,
    seen_by,
)
from core.shape_priors import one_sided, symmetry_rows

from ._bodyscene import cameras


def _body(rng, scale_sd=0.12):
    """Template skeleton and metaballs, and a left/right-symmetric 'true' shape."""
    skel = sk.make_skeleton()
    s = np.ones(skel.n_groups)
    balls = mb.make_metaballs(skel, "simplified", s)
    sym = mirror_pairs(skel, balls, s)
    factor = np.exp(rng.normal(0.0, scale_sd, balls.radii.shape))
    factor[sym.right[:, None], sym.axis_map] = factor[sym.left]
    return skel, s, balls, balls.copy(radii=balls.radii * factor)


def _surface(skel, s, balls, theta, root, per_ball, seed):
    pose = sk.forward(skel, theta[None], root[None], s)
    x, ok = mbs.sample_surface(skel, pose, balls, s, per_ball=per_ball, seed=seed)
    return x[ok]


def _distance(skel, s, balls, theta, root, x):
    """Unsigned distance of points x to the whole-body iso-surface (Newton projection)."""
    pose = sk.forward(skel, theta[None], root[None], s)
    Rw, cw = mb.world_frames(skel, pose, balls, s)
    xs, ok = mbs.project_to_surface(x, Rw[0], cw[0], balls.radii)
    assert ok.mean() > 0.95
    return np.linalg.norm(xs - x, axis=1)[ok]


def test_nearest_members_are_the_strongest_fields(rng):
    skel, s, balls, _ = _body(rng)
    pose = sk.forward(skel, np.zeros(skel.n_dof)[None], np.array([[0.0, 0.0, 1.0]]), s)
    Rw, cw = mb.world_frames(skel, pose, balls, s)
    x = rng.normal([0, 0, 1.0], 0.4, (50, 3))
    idx, valid = nearest_members(x, Rw[0], cw[0], balls.radii, 5)
    _, _, f, _ = mb.field(x, Rw[0], cw[0], balls.radii)
    best = np.sort(np.argsort(-f, axis=1)[:, :5], axis=1)
    strong = f.max(axis=1) > 1e-200  # beyond that every field underflows to zero
    assert valid.all()
    np.testing.assert_array_equal(np.sort(idx, axis=1)[strong], best[strong])


def test_symmetry_rows_vanish_for_a_mirrored_shape_and_are_linear(rng):
    skel, s, balls, truth = _body(rng)
    sym = mirror_pairs(skel, balls, s)
    assert len(sym.left) == len(sym.right) > 10 and len(sym.centre) > 5
    M = len(balls)
    r, J = symmetry_rows(sym, M, 3 * M, 1.0, truth.radii, balls.center0)
    assert np.abs(r).max() < 1e-9  # template centres are mirror images, radii mirrored
    bumped = truth.radii.copy()
    bumped[sym.left[0], 0] += 0.01
    r2, _ = symmetry_rows(sym, M, 3 * M, 1.0, bumped, balls.center0)
    assert np.abs(r2).max() == pytest.approx(0.01)
    dx = rng.normal(0.0, 0.01, 6 * M)
    x = np.concatenate([truth.radii.ravel(), balls.center0.ravel()])
    x2 = x + dx
    r3, _ = symmetry_rows(sym, M, 3 * M, 1.0, x2[: 3 * M].reshape(M, 3), x2[3 * M :].reshape(M, 3))
    np.testing.assert_allclose(r3, r + J @ dx, atol=1e-12)


def test_mirror_pairs_of_the_complete_model_pair_the_hip_girdle_sides():
    skel = sk.make_skeleton()
    s = np.ones(skel.n_groups)
    balls = mb.make_metaballs(skel, "complete", s)
    sym = mirror_pairs(skel, balls, s)
    assert 2 * len(sym.left) + len(sym.centre) == len(balls)
    assert len(set(sym.left) | set(sym.right) | set(sym.centre)) == len(balls)
    pel = skel.bone_index("pelvis")
    side = [(a, b) for a, b in zip(sym.left, sym.right, strict=True) if balls.bone[a] == pel]
    assert len(side) == 1 and balls.bone[side[0][1]] == pel
    x = np.einsum("mij,mj->mi", sym.A, balls.center0) @ sym.lateral
    assert x[side[0][0]] == pytest.approx(-x[side[0][1]]) and x[side[0][0]] > 0.01


def test_model_offsets_measure_how_far_the_surface_lies_outside_the_data(rng):
    # a plane of data at z = 0, model points above and below it, normals +z
    data = np.column_stack([rng.uniform(-1, 1, (2000, 2)), np.zeros(2000)])
    xs = np.column_stack([rng.uniform(-0.5, 0.5, (20, 2)), rng.uniform(-0.03, 0.03, 20)])
    off = model_offsets(xs, np.tile([0.0, 0.0, 2.0], (20, 1)), data, 5, 0.02)
    np.testing.assert_allclose(off, np.clip(xs[:, 2], -0.02, 0.02), atol=1e-12)


def test_seen_by_hides_the_far_side_of_the_body(rng):
    skel, s, balls, _ = _body(rng)
    theta, root = np.zeros(skel.n_dof), np.array([0.0, 0.0, 1.0])
    pose = sk.forward(skel, theta[None], root[None], s)
    Rw, cw = mb.world_frames(skel, pose, balls, s)
    x = _surface(skel, s, balls, theta, root, 20, 1)
    n = seen_by(cameras(), x, Rw[0], cw[0], balls.visible, balls.bone, 0.02)
    c = cw[0, np.flatnonzero(balls.bone == skel.bone_index("chest"))[0]]
    chest = (np.abs(x[:, 0] - c[0]) < 0.08) & (np.abs(x[:, 2] - c[2]) < 0.06)
    front = chest & (x[:, 1] < c[1] - 0.05)  # the cameras stand at y = −4
    back = chest & (x[:, 1] > c[1] + 0.05)
    assert front.sum() > 5 and back.sum() > 5
    assert (n[front] == 3).mean() > 0.9
    # the lone ellipsoids rendered as occluders leave small gaps where the blended
    # surface is closed (e.g. between the chest and the clavicles): rarely one view
    assert (n[back] == 0).mean() > 0.8 and (n[back] < 2).all()


def test_system_jacobian_matches_finite_differences(rng):
    skel, s, balls, truth = _body(rng)
    theta = rng.normal(0.0, 0.1, skel.n_dof)
    root = np.array([0.0, 0.0, 1.0])
    pose = sk.forward(skel, theta[None], root[None], s)
    x_obs = _surface(skel, s, truth, theta, root, 4, 2) + rng.normal(0, 0.002, (1, 3))
    cfg = ShapeSettings(samples_per_ball=3)
    prob = ShapeProblem(
        skel, balls, s, [pose], [x_obs], [np.full(len(x_obs), 0.003)], cameras(), cfg
    )
    x = prob.pack(balls.radii * 1.05, balls.center0 + rng.normal(0, 0.003, balls.center0.shape))
    prob.freeze(x)
    assert prob.frames[0].xs is not None and len(prob.frames[0].xs) > 20
    r, J = prob.system(x)
    assert sparse.issparse(J) and J.nnz < 0.5 * np.prod(J.shape)  # members only
    J = J.toarray()
    cols = rng.choice(len(x), 40, replace=False)
    h = 1e-6
    for c in cols:
        e = np.zeros(len(x))
        e[c] = h
        fd = (prob.system(x + e)[0] - prob.system(x - e)[0]) / (2 * h)
        np.testing.assert_allclose(J[:, c], fd, rtol=1e-4, atol=1e-3 * np.abs(J).max())


@pytest.mark.slow
def test_fit_recovers_a_synthetic_shape_from_its_surface_points(rng):
    """Noise-free points all round the true shape in two poses: the fitted surface lies
    on held-out true surface points to well under a millimetre; the template does not."""
    skel, s, balls, truth = _body(rng)
    root = np.array([0.0, 0.0, 1.0])
    thetas = [np.zeros(skel.n_dof), rng.normal(0.0, 0.15, skel.n_dof)]
    pts = [_surface(skel, s, truth, th, root, 25, k) for k, th in enumerate(thetas)]
    cfg = ShapeSettings(
        sigma_radius=0.3,
        sigma_center=0.1,
        free_centers=False,
        rounds=8,
        max_nfev=30,
        robust_scale=20.0,
    )
    out = fit_shape(
        skel, balls, s, np.array(thetas), np.array([root, root]), pts, None, settings=cfg
    )
    assert out.frame_ok.all()
    held = _surface(skel, s, truth, thetas[1], root, 15, 7)
    d_fit = _distance(skel, s, out.metaballs, thetas[1], root, held)
    d_tmp = _distance(skel, s, balls, thetas[1], root, held)
    assert d_tmp.mean() > 0.005
    assert d_fit.mean() < 0.1 * d_tmp.mean() and d_fit.mean() < 0.0008
    assert np.all(out.rms_m < 0.001)


def test_a_gap_in_the_points_is_not_taken_for_a_bulge(rng):
    """The true shape as start, its surface as data but for a hole in the chest's front
    (tracks lost there), and its silhouettes: fully weighted, the seen model points in
    the hole pull the surface in across it; Cauchy-weighted (``model_robust_scale``),
    less.  With points alone the model points keep their full weight."""
    skel, s, _, truth = _body(rng)
    theta, root = np.zeros(skel.n_dof), np.array([0.0, 0.0, 1.0])
    pose = sk.forward(skel, theta[None], root[None], s)
    _, cw = mb.world_frames(skel, pose, truth, s)
    c = cw[0, truth.bone == skel.bone_index("chest")].mean(axis=0)
    x = _surface(skel, s, truth, theta, root, 120, 3)
    hole = (np.linalg.norm(x - c, axis=1) < 0.22) & (x[:, 1] < c[1] + 0.02)
    hole &= np.abs(x[:, 2] - c[2]) < 0.14  # the cameras stand at y = −4
    assert hole.sum() > 300
    cams = cameras()
    sil = [_blend_contours(skel, s, truth, theta, root, cams)]
    inside = {}
    for knee in (0.0, 3.0):
        for outline in (True, False):
            out = fit_shape(
                skel,
                truth,
                s,
                theta[None],
                root[None],
                [x[~hole]],
                cams,
                settings=ShapeSettings(rounds=4, model_robust_scale=knee),
                contours=sil if outline else None,
            )
            inside[knee, outline] = _distance(skel, s, out.metaballs, theta, root, x[hole])
    # seeded: 13.0 mm into the hole fully weighted, 7.0 Cauchy-weighted (11.4 points alone)
    assert inside[0.0, True].mean() > 0.005  # the hole pulled in
    assert inside[3.0, True].mean() < 0.7 * inside[0.0, True].mean()
    assert np.array_equal(inside[3.0, False], inside[0.0, False])


def test_fit_flags_a_frame_with_too_few_points(rng):
    skel, s, balls, truth = _body(rng)
    root = np.array([0.0, 0.0, 1.0])
    theta = np.zeros(skel.n_dof)
    pts = [_surface(skel, s, truth, theta, root, 6, 0), np.full((5, 3), np.nan)]
    out = fit_shape(
        skel,
        balls,
        s,
        np.array([theta, theta]),
        np.array([root, root]),
        pts,
        settings=ShapeSettings(rounds=1, max_nfev=3),
    )
    assert out.frame_ok.tolist() == [True, False]
    assert np.isnan(out.rms_m[1]) and np.isfinite(out.rms_m[0])
    assert "left out" in out.message
    with pytest.raises(ValueError, match="frames of points need theta"):
        fit_shape(skel, balls, s, theta[None], root[None], pts)
    empty = fit_shape(skel, balls, s, theta[None], root[None], [np.zeros((0, 3))])
    assert not empty.frame_ok.any() and np.array_equal(empty.metaballs.radii, balls.radii)


def _blend_contours(skel, s, balls, theta, root, cams):
    """Occluding contours (per camera) of the blended surface Σ f = 0.5 as the
    renderer draws it: the ellipsoids that follow the blend (render_radii)."""
    from core.contour_obs import body_ellipsoids
    from core.contours import occluding_contours
    from core.model_render import render_parts

    c, a, _, p = body_ellipsoids(skel, theta, root, s, balls)
    r = mbs.render_radii(skel, sk.forward(skel, theta[None], root[None], s), balls, s)
    return [occluding_contours(render_parts(cam, c, a, r, p).mask, spacing=1.5) for cam in cams]


@pytest.mark.slow
def test_silhouettes_shape_the_side_no_point_sees(rng):
    """Points on the front half only (what cameras on one side triangulate) leave the
    back to the prior; the silhouettes of three frames in three cameras, front and
    sides, bring the whole surface to the truth's, points or not."""
    from ._bodyscene import look_at

    skel, s, balls, truth = _body(rng)
    # the flesh off the bones' axes, front to back (the body's y), as a real trunk's is
    A = mirror_pairs(skel, balls, s).A
    back = np.einsum("mji,j->mi", A, [0.0, 0.03, 0.0]) / np.einsum("mji,mji->mi", A, A)
    truth = truth.with_parts(
        balls.center0 + back * rng.uniform(0.3, 1.0, (len(balls), 1)), truth.radii
    )
    root = np.array([0.0, 0.0, 1.0])
    thetas = [np.zeros(skel.n_dof)] + [rng.normal(0.0, 0.12, skel.n_dof) for _ in range(2)]
    cams = [
        look_at("front", (0.0, -4.0, 1.0)),
        look_at("left", (4.0, -0.5, 1.0)),
        look_at("right", (-4.0, -0.5, 1.0)),
    ]
    front = [
        p[p[:, 1] < np.median(p[:, 1])]
        for p in (_surface(skel, s, truth, th, root, 25, k) for k, th in enumerate(thetas))
    ]
    sil = [_blend_contours(skel, s, truth, th, root, cams) for th in thetas]
    cfg = ShapeSettings(
        sigma_radius=0.3,
        sigma_center=0.1,
        sigma_symmetry=0.0,
        model_points=False,
        rounds=6,
        max_nfev=20,
        sigma_silhouette_px=1.0,
    )
    args = (skel, balls, s, np.array(thetas), np.array([root] * 3))
    pts_only = fit_shape(
        *args, front, cams, settings=replace(cfg, sigma_silhouette_px=0.0), contours=sil
    )
    both = fit_shape(*args, front, cams, settings=cfg, contours=sil)
    sil_only = fit_shape(*args, [np.zeros((0, 3))] * 3, cams, settings=cfg, contours=sil)
    assert both.frame_ok.all() and sil_only.frame_ok.all()
    assert np.all(both.silhouette_rms_px < 1.5) and np.isnan(pts_only.silhouette_rms_px).all()
    held = _surface(skel, s, truth, thetas[1], root, 15, 7)
    held = held[held[:, 1] > np.median(held[:, 1])]  # the back half
    d = {
        k: _distance(skel, s, b.metaballs if k != "template" else b, thetas[1], root, held)
        for k, b in (
            ("template", balls),
            ("points", pts_only),
            ("both", both),
            ("silhouettes", sil_only),
        )
    }
    # seeded: template 21.5, points 6.6, both 3.0, silhouettes 4.7 mm on the back half
    assert d["points"].mean() < 0.5 * d["template"].mean()
    assert d["both"].mean() < 0.6 * d["points"].mean()
    assert d["silhouettes"].mean() < 0.3 * d["template"].mean()


def test_one_sided_finds_the_pairs_and_mid_plane_metaballs_seen_from_one_side(rng):
    skel, s, balls, _ = _body(rng)
    sym = mirror_pairs(skel, balls, s)
    theta, root = np.zeros(skel.n_dof), np.array([0.0, 0.0, 1.0])
    pose = sk.forward(skel, theta[None], root[None], s)
    x = _surface(skel, s, balls, theta, root, 100, 0)
    left = x[x @ sym.lateral > root @ sym.lateral]
    pairs, centres = one_sided(sym, skel, balls, s, [pose], [x], 0.25)
    assert not pairs.any() and not centres.any()  # seen all round
    pairs, centres = one_sided(sym, skel, balls, s, [pose], [left], 0.25)
    # every trunk and head metaball's right half has no point; the neck's lone metaball
    # lies inside the chest's and head's fields and gets none at all
    empty = [skel.bone_names[balls.bone[m]] for m in sym.centre[~centres]]
    assert empty == ["neck"]
    arm = [skel.bone_names[balls.bone[m]] for m in sym.left[pairs]]
    assert {"l_clavicle", "l_shoulder", "l_hip", "l_knee", "l_ankle"} <= set(arm)
    none = one_sided(sym, skel, balls, s, [pose], [np.zeros((0, 3))], 0.25)
    assert not none[0].any() and not none[1].any()  # no point: nothing to say


def test_the_symmetry_gives_the_side_no_point_sees_the_seen_side_s_shape(rng):
    """Points on the body's left half only (line3's cameras see a walker's or a jumper's
    left side in every frame), from the template: the symmetry prior carries the seen
    side's shape to the right side.  At ``sigma_symmetry`` alone a mid-plane (trunk)
    metaball drifts towards the seen side and thins the far side (the jumps' trunk was
    17-20 mm inside the true mesh there); held tighter where its points are one-sided
    (``sigma_one_sided``, opt-in), the held-out right half lies closer."""
    skel, s, balls, truth = _body(rng)
    lateral = mirror_pairs(skel, balls, s).lateral
    root = np.array([0.0, 0.0, 1.0])
    thetas = [np.zeros(skel.n_dof), rng.normal(0.0, 0.12, skel.n_dof)]
    left = [
        p[p @ lateral > root @ lateral]
        for p in (_surface(skel, s, truth, th, root, 25, k) for k, th in enumerate(thetas))
    ]
    held = _surface(skel, s, truth, thetas[1], root, 15, 7)
    held = held[held @ lateral < root @ lateral - 0.03]  # the right half, off the plane
    base = ShapeSettings(model_points=False, rounds=6, max_nfev=20)
    assert base.sigma_one_sided == 0.0  # opt-in
    far = {}
    for name, cfg in (
        ("none", replace(base, sigma_symmetry=0.0)),
        ("even", base),
        ("one-sided", replace(base, sigma_one_sided=0.0005)),
    ):
        out = fit_shape(skel, balls, s, np.array(thetas), np.array([root] * 2), left, settings=cfg)
        far[name] = _distance(skel, s, out.metaballs, thetas[1], root, held).mean()
    # seeded: no symmetry 7.0, σ 3 mm throughout 1.5, 0.5 mm where one-sided 0.8 mm
    assert far["one-sided"] < 0.3 * far["none"]
    assert far["one-sided"] < 0.85 * far["even"]


def test_member_rows_is_the_sparse_form_of_the_scattered_blocks(rng):
    """Each point's K member blocks land in its members' columns, radii then centres."""
    from core.attractor import scatter
    from core.shape_problem import member_rows

    N, K, M = 50, 4, 9
    idx = np.array([rng.choice(M, K, replace=False) for _ in range(N)])
    valid = rng.random((N, K)) > 0.3
    b1, b2 = rng.normal(size=(N, K, 3)), rng.normal(size=(N, K, 3))
    scale = rng.random(N)
    J = member_rows([b1, b2], idx, valid, scale, M)
    dense = np.hstack([scatter(b, idx, valid, M) * scale[:, None] for b in (b1, b2)])
    assert J.shape == (N, 6 * M) and J.nnz == 6 * valid.sum()
    np.testing.assert_array_equal(J.toarray(), dense)
