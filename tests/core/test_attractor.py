"""Attractor observations: log field, signed distance, analytic Jacobians vs finite differences."""

import numpy as np
import pytest

from core import attractor as at
from core import metaballs as mb
from core import skeleton as sk


def test_distance_of_a_lone_sphere_is_metric_inside_and_outside():
    radii = np.full((1, 3), 0.1)
    r0 = 0.1 * mb.VISIBLE
    r = np.array([0.3, 0.9, 1.0, 1.1, 3.0]) * r0
    x = np.stack([r, np.zeros(5), np.zeros(5)], axis=1)
    idx, ok = np.zeros((5, 1), int), np.ones((5, 1), bool)
    a = at.attractor(x, idx, ok, np.eye(3)[None], np.zeros((1, 3)), radii, g_min=0.0)
    np.testing.assert_allclose(a.dist, (r0**2 - r**2) / (2 * r), rtol=1e-12)
    assert abs(a.dist[2]) < 1e-15 and np.all(np.isfinite(a.dist))
    # far outside the field underflows, the log field does not
    far = at.attractor(
        np.array([[2.0, 0, 0]]), idx[:1], ok[:1], np.eye(3)[None], np.zeros((1, 3)), radii
    )
    assert np.isfinite(far.dist[0]) and far.dist[0] < -0.5


@pytest.mark.parametrize("no_numba", ["0", "1"])  # compiled, numpy
@pytest.mark.parametrize("members", ["part", "neighbours"])
def test_jacobians_match_finite_differences(rng, members, no_numba, monkeypatch):
    monkeypatch.setenv("SOMACAP_NO_NUMBA", no_numba)
    skel = sk.make_skeleton()
    balls = mb.make_metaballs(skel, "simplified")
    balls.radii *= 1 + 0.2 * rng.random(balls.radii.shape)
    balls.center0 += rng.normal(0, 0.01, balls.center0.shape)
    th = rng.normal(0, 0.3, skel.n_dof)
    rt, s = np.array([0.1, 0.0, 1.0]), 1 + 0.05 * rng.normal(size=skel.n_groups)
    pose = sk.forward(skel, th[None], rt[None], s)
    Rw, cw = mb.world_frames(skel, pose, balls, s)
    pick = rng.integers(0, len(balls), 40)
    x = cw[0, pick] + rng.normal(0, 0.05, (40, 3))
    table, valid = at.member_table(skel, balls, members)
    idx, ok = at.gather(table, valid, balls.bone[pick])
    anc = skel.ancestors()

    def L(th_=th, rt_=rt, s_=s, radii=balls.radii, c0=balls.center0):
        b = mb.Metaballs(balls.bone, c0, balls.group, balls.rot, radii)
        R, c = mb.world_frames(skel, sk.forward(skel, th_[None], rt_[None], s_), b, s_)
        return at.attractor(x, idx, ok, R[0], c[0], radii).L

    att = at.attractor(x, idx, ok, Rw[0], cw[0], balls.radii)
    Jt, Jr, Js, Jrad, Jc = at.attractor_jacobians(
        skel, pose, balls, s, x, idx, att, balls.radii, anc, shape=True
    )
    M = len(balls)
    Jrad, Jc = at.scatter(Jrad, idx, ok, M), at.scatter(Jc, idx, ok, M)
    e = 1e-6

    def num(fn, v):
        out = []
        for k in range(v.size):
            d = np.zeros(v.size)
            d[k] = e
            out.append((fn(v + d.reshape(v.shape)) - fn(v - d.reshape(v.shape))) / (2 * e))
        return np.stack(out, axis=1)

    for J, n in (
        (Jt, num(lambda v: L(th_=v), th)),
        (Jr, num(lambda v: L(rt_=v), rt)),
        (Js, num(lambda v: L(s_=v), s)),
        (Jrad, num(lambda v: L(radii=v), balls.radii)),
        (Jc, num(lambda v: L(c0=v), balls.center0)),
    ):
        assert np.abs(J - n).max() <= 1e-6 * max(np.abs(n).max(), 1.0)


def test_compiled_and_numpy_paths_agree(rng, monkeypatch):
    from core import field_kernel

    if not field_kernel.enabled():
        pytest.skip("numba not available: only the numpy path runs")
    skel = sk.make_skeleton()
    balls = mb.make_metaballs(skel, "complete")
    th, rt = rng.normal(0, 0.3, skel.n_dof), np.array([0.1, 0.0, 1.0])
    s = 1 + 0.05 * rng.normal(size=skel.n_groups)
    pose = sk.forward(skel, th[None], rt[None], s)
    Rw, cw = mb.world_frames(skel, pose, balls, s)
    pick = rng.integers(0, len(balls), 300)
    x = cw[0, pick] + rng.normal(0, 0.05, (300, 3))
    table, valid = at.member_table(skel, balls, "neighbours")
    idx, ok = at.gather(table, valid, balls.bone[pick])
    ok[::7] = False  # points without members
    out = {}
    for flag in ("0", "1"):
        monkeypatch.setenv("SOMACAP_NO_NUMBA", flag)
        att = at.attractor(x, idx, ok, Rw[0], cw[0], balls.radii)
        out[flag] = (
            att,
            at.attractor_jacobians(
                skel, pose, balls, s, x, idx, att, balls.radii, skel.ancestors(), shape=True
            ),
        )
    (a0, J0), (a1, J1) = out["0"], out["1"]
    assert np.isneginf(a0.L[::7]).all()
    for name in ("L", "grad", "p", "y", "q", "gx", "dist", "inv_g"):
        np.testing.assert_allclose(
            getattr(a0, name), getattr(a1, name), rtol=1e-12, atol=1e-12, err_msg=name
        )
    for u, v in zip(J0, J1, strict=True):
        np.testing.assert_allclose(u, v, rtol=1e-11, atol=1e-11 * np.abs(v).max())


def test_scatter_places_valid_members_and_drops_padding(rng):
    skel = sk.make_skeleton()
    balls = mb.make_metaballs(skel, "complete")
    table, valid = at.member_table(skel, balls, "part")
    idx, ok = at.gather(table, valid, rng.integers(-1, len(skel.bone_names), 50))
    J_k = rng.normal(size=idx.shape + (3,))
    want = np.zeros((50, len(balls), 3))
    np.add.at(
        want,
        (np.repeat(np.arange(50), idx.shape[1]), idx.ravel()),
        (J_k * ok[..., None]).reshape(-1, 3),
    )
    np.testing.assert_array_equal(at.scatter(J_k, idx, ok, len(balls)), want.reshape(50, -1))
