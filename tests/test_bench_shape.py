"""bench.shape surface distances and bench.visibility's model part labels."""

from __future__ import annotations

import numpy as np
import pytest

from bench.shape import surface_distances
from bench.visibility import compare, model_vertex_parts
from core import metaballs as mb
from core import skeleton as sk


def _sphere_mesh(center, radius, n=40):
    """A UV sphere: vertices (V, 3) and faces (T, 3)."""
    th = np.linspace(0, np.pi, n)[1:-1]
    ph = np.linspace(0, 2 * np.pi, 2 * n, endpoint=False)
    t, p = np.meshgrid(th, ph, indexing="ij")
    v = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1).reshape(-1, 3)
    v = np.vstack([v, [[0, 0, 1]], [[0, 0, -1]]])
    nr, nc = len(th), len(ph)
    idx = np.arange(nr * nc).reshape(nr, nc)
    a, b = idx[:-1], np.roll(idx[:-1], -1, axis=1)
    c, d = idx[1:], np.roll(idx[1:], -1, axis=1)
    faces = np.concatenate(
        [
            np.stack([a, c, b], -1).reshape(-1, 3),
            np.stack([b, c, d], -1).reshape(-1, 3),
            np.stack([np.full(nc, nr * nc), idx[0], np.roll(idx[0], -1)], -1),
            np.stack([np.full(nc, nr * nc + 1), np.roll(idx[-1], -1), idx[-1]], -1),
        ]
    )
    return np.asarray(center) + radius * v, faces


@pytest.mark.parametrize("grow", [0.0, 0.01])
def test_surface_distances_of_a_metaball_and_a_sphere_mesh(grow):
    skel = sk.make_skeleton()
    s = np.ones(skel.n_groups)
    theta, root = np.zeros(skel.n_dof), np.array([0.0, 0.0, 1.0])
    r = 0.1
    balls = mb.Metaballs(
        np.array([skel.bone_index("head")]),
        np.zeros((1, 3)),
        np.array([-1]),
        np.eye(3)[None],
        np.full((1, 3), r / mb.VISIBLE),
    )
    pose = sk.forward(skel, theta[None], root[None], s)
    _, cw = mb.world_frames(skel, pose, balls, s)
    v, f = _sphere_mesh(cw[0, 0], r + grow, n=60)
    d = surface_distances(skel, theta, root, s, balls, v, f, per_ball=200, vertex_step=3)
    # the flat triangles lie inside the round surface by at most the sagitta (~0.1 mm)
    assert abs(d["ball_to_mesh"].mean() - grow) < 3e-4
    assert abs(d["mesh_to_ball"].mean() - grow) < 3e-4
    assert len(d["vertex_idx"]) == len(range(0, len(v), 3))


def test_model_vertex_parts_follow_the_nearest_rendered_ellipsoid():
    centers = np.array([[0.0, 0.0, 1.0], [0.3, 0.0, 1.0]])
    axes = np.stack([np.eye(3), np.eye(3)])
    radii = np.array([[0.1, 0.1, 0.1], [0.2, 0.05, 0.05]])
    bone = np.array([4, 7])
    x = np.array(
        [[-0.11, 0, 1.0], [0.0, 0.11, 1.0], [0.52, 0.0, 1.0], [0.3, 0.06, 1.0], [0.12, 0.0, 1.0]]
    )
    np.testing.assert_array_equal(
        model_vertex_parts(x, centers, axes, radii, bone), [4, 4, 7, 7, 7]
    )


def test_compare_rejects_unknown_labels():
    with pytest.raises(ValueError, match="unknown part labels"):
        compare(None, {}, [], [], labels="bones")


def test_capacity_fit_takes_the_whole_mesh_as_data():
    """The capacity row's settings: a metaball started 2 cm too small, fitted to area
    samples of a whole sphere mesh, takes the sphere's size — model points on every
    side, seen by the one camera or not."""
    from bench.shape import _capacity_settings
    from core.evaluate import sample_mesh_surface
    from core.shape_fit import fit_shape
    from tests.core._bodyscene import look_at

    skel = sk.make_skeleton()
    s = np.ones(skel.n_groups)
    theta, root = np.zeros(skel.n_dof), np.array([0.0, 0.0, 1.0])
    balls = mb.Metaballs(
        np.array([skel.bone_index("head")]),
        np.zeros((1, 3)),
        np.array([-1]),
        np.eye(3)[None],
        np.full((1, 3), 0.10 / mb.VISIBLE),
    )
    pose = sk.forward(skel, theta[None], root[None], s)
    _, cw = mb.world_frames(skel, pose, balls, s)
    v, f = _sphere_mesh(cw[0, 0], 0.12, n=60)
    pts = sample_mesh_surface(v, f, 3000, np.random.default_rng(0))
    cam = look_at("cam01", (0.0, -3.0, 1.6), tuple(cw[0, 0]), f=700.0)
    fit = fit_shape(
        skel, balls, s, theta[None], root[None], [pts], [cam], settings=_capacity_settings()
    )
    d = surface_distances(skel, theta, root, s, fit.metaballs, v, f, per_ball=200)
    assert d["mesh_to_ball"].mean() < 1e-3 and d["ball_to_mesh"].mean() < 1e-3
