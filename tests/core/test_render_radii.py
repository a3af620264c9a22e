"""core.metaball_surface.render_radii: ellipsoids whose union approximates the blended surface."""

from __future__ import annotations

import numpy as np

from core import metaball_surface as mbs
from core import metaballs as mb
from core import skeleton as sk


def _body():
    skel = sk.make_skeleton()
    s = np.ones(skel.n_groups)
    balls = mb.make_metaballs(skel, "simplified", s)
    pose = sk.forward(skel, np.zeros(skel.n_dof)[None], np.array([[0.0, 0.0, 1.0]]), s)
    return skel, s, balls, pose


def _iso_distance(balls, Rw, cw, x):
    xs, ok = mbs.project_to_surface(x, Rw, cw, balls.radii)
    return np.linalg.norm(xs - x, axis=1)[ok]


def test_a_lone_metaball_keeps_its_visible_ellipsoid():
    skel, s, balls, pose = _body()
    one = mb.Metaballs(
        balls.bone[:1],
        balls.center0[:1],
        balls.group[:1],
        balls.rot[:1],
        np.array([[0.2, 0.12, 0.08]]),
    )
    a = mbs.render_radii(skel, pose, one, s)
    np.testing.assert_allclose(a, one.radii * mb.VISIBLE, rtol=1e-6)


def test_render_ellipsoids_follow_the_blended_surface_better_than_lone_ones():
    skel, s, balls, pose = _body()
    Rw, cw = mb.world_frames(skel, pose, balls, s)
    Rw, cw = Rw[0], cw[0]
    a = mbs.render_radii(skel, pose, balls, s, per_ball=24)
    lone = balls.radii * mb.VISIBLE
    assert np.all(a >= lone - 1e-12) and np.all(a <= 2 * lone + 1e-12)
    assert (a > 1.05 * lone).any()  # overlapping metaballs blend into a larger surface
    rng = np.random.default_rng(3)
    u = rng.normal(size=(len(balls), 12, 3))
    u /= np.linalg.norm(u, axis=-1, keepdims=True)

    def outer_points(axes):
        x = (np.einsum("mij,mpj->mpi", Rw, u * axes[:, None, :]) + cw[:, None, :]).reshape(-1, 3)
        # keep the points on the union's outside (not inside another ellipsoid)
        y = np.einsum("mji,nmj->nmi", Rw, x[:, None, :] - cw[None])
        inside = np.sum((y / axes[None]) ** 2, axis=-1) < 1.0 - 1e-9
        return x[~inside.any(axis=1)]

    d_render = _iso_distance(balls, Rw, cw, outer_points(a))
    d_lone = _iso_distance(balls, Rw, cw, outer_points(lone))
    assert np.mean(d_render) < 0.6 * np.mean(d_lone)
