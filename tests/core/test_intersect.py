import numpy as np
import pytest

from core.camera import Camera
from core.intersect import triangulate


def _look_at(name, center, target, size=(512, 384), f=600.0, aspect=1.0, dist=None):
    z = target - center
    z = z / np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    K = np.array([[f, 0, size[0] / 2 - 0.5], [0, f / aspect, size[1] / 2 - 0.5], [0, 0, 1]])
    return Camera(name, size, K, dist if dist is not None else np.zeros(5), R, -R @ center)


def _rig():
    target = np.array([0.0, 0.0, 1.0])
    dist = np.array([-0.1, 0.02, 0.001, -0.001, 0.0])
    return [
        _look_at("cam01", np.array([-2.0, -4.0, 1.5]), target, dist=dist),
        _look_at("cam02", np.array([0.0, -4.5, 1.2]), target),
        _look_at("cam03", np.array([2.5, -3.5, 1.6]), target, aspect=2.0, size=(512, 192)),
    ]


def _project(cams, xyz):
    return np.stack([c.project(xyz) for c in cams], axis=1)


def test_exact_points_recovered_with_distortion(rng):
    cams = _rig()
    xyz = rng.uniform([-0.6, -0.6, 0.2], [0.6, 0.6, 1.8], size=(500, 3))
    res = triangulate(cams, _project(cams, xyz))
    assert res.ok.all()
    np.testing.assert_allclose(res.xyz, xyz, atol=1e-9)
    assert np.max(res.rms) < 1e-6
    assert res.cov.shape == (500, 3, 3)


def test_error_agrees_with_predicted_sigma(rng):
    cams = _rig()
    xyz = rng.uniform([-0.6, -0.6, 0.2], [0.6, 0.6, 1.8], size=(3000, 3))
    uv = _project(cams, xyz) + rng.normal(scale=0.1, size=(3000, 3, 2))
    res = triangulate(cams, uv, sigma_px=0.1)
    assert res.ok.all()
    err2 = np.sum((res.xyz - xyz) ** 2, axis=1)
    pred2 = np.trace(res.cov, axis1=1, axis2=2)
    ratio = np.sqrt(err2.mean() / pred2.mean())
    assert 0.8 <= ratio <= 1.25, ratio
    # Mahalanobis distances follow chi2(3): mean 3.
    e = res.xyz - xyz
    m = np.einsum("ni,nij,nj->n", e, np.linalg.inv(res.cov), e)
    assert 2.6 < m.mean() < 3.4


def test_missing_views_and_flags(rng):
    cams = _rig()
    xyz = rng.uniform([-0.5, -0.5, 0.5], [0.5, 0.5, 1.5], size=(6, 3))
    uv = _project(cams, xyz)
    uv[0, 0] = np.nan  # two views left
    uv[1, :2] = np.nan  # one view: not ok
    uv[2] = np.nan  # none
    res = triangulate(cams, uv)
    np.testing.assert_array_equal(res.n_views, [2, 1, 0, 3, 3, 3])
    np.testing.assert_array_equal(res.ok, [True, False, False, True, True, True])
    np.testing.assert_allclose(res.xyz[0], xyz[0], atol=1e-9)
    assert np.isnan(res.xyz[1]).all() and np.isnan(res.cov[2]).all()


def test_single_point_and_shape_check(rng):
    cams = _rig()
    p = np.array([0.1, 0.2, 1.0])
    res = triangulate(cams, _project(cams, p[None])[0])
    np.testing.assert_allclose(res.xyz, p, atol=1e-9)
    assert res.ok
    with pytest.raises(ValueError, match="shape"):
        triangulate(cams, np.zeros((4, 2, 2)))
