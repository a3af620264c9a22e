import cv2
import numpy as np
import pytest

from core.camera import (
    Camera,
    matrix_to_rodrigues,
    pack_camera,
    project_params,
    rodrigues_batch,
    rodrigues_to_matrix,
    unpack_camera,
)


def _camera(rng):
    K = np.array([[800.0, 0.0, 250.0], [0.0, 790.0, 190.0], [0.0, 0.0, 1.0]])
    dist = np.array([-0.2, 0.05, 0.001, -0.002, 0.01])
    R = rodrigues_to_matrix(rng.normal(size=3) * 0.3)
    return Camera("cam01", (512, 384), K, dist, R, np.array([0.1, -0.2, 4.0]))


def test_project_matches_opencv(rng):
    cam = _camera(rng)
    xyz = rng.normal(size=(200, 3)) * 0.5
    uv_cv, _ = cv2.projectPoints(xyz, cam.rvec, cam.t, cam.K, cam.dist)
    np.testing.assert_allclose(cam.project(xyz), uv_cv[:, 0], atol=1e-9)


def test_undistort_inverts_distortion(rng):
    cam = _camera(rng)
    xyz = rng.normal(size=(100, 3)) * 0.5
    uv = cam.project(xyz)
    origin, d = cam.rays(uv)
    # every ray passes through its point
    v = xyz - origin
    cross = np.cross(v, d)
    assert np.max(np.linalg.norm(cross, axis=1)) < 1e-8


@pytest.mark.parametrize("angle", [0.0, 1e-8, 0.5, 3.0, np.pi - 1e-9])
def test_rodrigues_round_trip(angle, rng):
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    R = rodrigues_to_matrix(axis * angle)
    np.testing.assert_allclose(R, cv2.Rodrigues(axis * angle)[0], atol=1e-9)
    np.testing.assert_allclose(rodrigues_to_matrix(matrix_to_rodrigues(R)), R, atol=1e-7)


def test_pixel_aspect_is_fx_over_fy():
    cam = Camera("c", (10, 10), np.diag([800.0, 400.0, 1.0]))
    assert cam.aspect == pytest.approx(2.0)


# -- packing and analytic Jacobians ------------------------------------------------------


def _aspect_camera(rng):
    K = np.array([[800.0, 0.0, 250.0], [0.0, 400.0, 95.0], [0.0, 0.0, 1.0]])
    dist = np.array([-0.2, 0.05, 0.001, -0.002, 0.01])
    R = rodrigues_to_matrix(rng.normal(size=3) * 0.3)
    return Camera("cam01", (512, 192), K, dist, R, np.array([0.1, -0.2, 4.0]))


def test_pack_round_trip(rng):
    cam = _aspect_camera(rng)
    p = pack_camera(cam)
    assert p[7] == pytest.approx(2.0)
    back = unpack_camera(p, cam.name, cam.size)
    xyz = rng.normal(size=(50, 3)) * 0.5
    np.testing.assert_allclose(back.project(xyz), cam.project(xyz), atol=1e-9)
    np.testing.assert_allclose(project_params(p, xyz, jacobian=False), cam.project(xyz), atol=1e-9)


@pytest.mark.parametrize("scale", [0.0, 1e-12, 0.3, 2.5])
def test_rodrigues_derivative_matches_finite_differences(scale, rng):
    rvec = rng.normal(size=(4, 3)) * scale
    R, dR = rodrigues_batch(rvec)
    for i, rv in enumerate(rvec):
        np.testing.assert_allclose(R[i], cv2.Rodrigues(rv)[0], atol=1e-9)
    h = 1e-6
    for k in range(3):
        e = np.zeros(3)
        e[k] = h
        num = (rodrigues_batch(rvec + e)[0] - rodrigues_batch(rvec - e)[0]) / (2 * h)
        np.testing.assert_allclose(dR[:, k], num, atol=1e-6)
    R2, none = rodrigues_batch(rvec, derivative=False)  # the rotations alone, the same bits
    np.testing.assert_array_equal(R2, R)
    assert none is None


def test_projection_jacobians_match_finite_differences(rng):
    cam = _aspect_camera(rng)
    p = pack_camera(cam)
    xyz = rng.normal(size=(30, 3)) * 0.5
    uv, J_cam, J_xyz = project_params(p, xyz)
    steps = np.array([1e-6] * 6 + [1e-3, 1e-6, 1e-3, 1e-3] + [1e-6] * 5)
    for k in range(p.size):
        dp = np.zeros_like(p)
        dp[k] = steps[k]
        num = (project_params(p + dp, xyz, False) - project_params(p - dp, xyz, False)) / (
            2 * steps[k]
        )
        np.testing.assert_allclose(
            J_cam[:, :, k], num, rtol=1e-5, atol=1e-4, err_msg=f"parameter {k}"
        )
    for k in range(3):
        d = np.zeros(3)
        d[k] = 1e-6
        num = (project_params(p, xyz + d, False) - project_params(p, xyz - d, False)) / 2e-6
        np.testing.assert_allclose(J_xyz[:, :, k], num, rtol=1e-5, atol=1e-4)


def test_one_camera_for_all_points_equals_per_point_parameters(rng):
    """A single parameter vector computes its rotation once; per-point copies compute
    one each: the same projection and Jacobians, to the bit (the tracker's intersection
    follows these last bits).  The one-camera matrix product path agrees to rounding."""
    from core.camera import camera_project_jacobians

    cam = _aspect_camera(rng)
    p = pack_camera(cam)
    xyz = rng.normal(size=(40, 3)) * 0.5
    one = project_params(p, xyz)
    each = project_params(np.tile(p, (40, 1)), xyz)
    for a, b in zip(one, each, strict=True):
        np.testing.assert_array_equal(a, b)
    uv, J_cam, J_xyz = camera_project_jacobians(cam, xyz)
    assert J_cam is None
    np.testing.assert_allclose(uv, one[0], rtol=1e-12)
    np.testing.assert_allclose(J_xyz, one[2], rtol=1e-12)


def test_remembered_camera_projects_to_the_same_bits(rng):
    """camera_project_jacobians remembers a camera's packed vector and rotation: the
    same bits as packing it anew, and a camera changed in place is packed again."""
    from core.camera import _PACKED, _project, camera_project_jacobians

    cam = _camera(rng)
    xyz = rng.normal(size=(30, 3)) * 0.5
    fresh = _project(pack_camera(cam), xyz, True, False, one_camera=True)
    for _ in range(2):  # the second call is served from the cache
        got = camera_project_jacobians(cam, xyz)
        for a, b in zip(got, fresh, strict=True):
            np.testing.assert_array_equal(a, b)
    assert any(v[0] is not None for v in _PACKED.values())
    cam.t[2] += 0.5  # moved in place: a new entry, not the old projection
    moved = camera_project_jacobians(cam, xyz)
    np.testing.assert_array_equal(
        moved[0], _project(pack_camera(cam), xyz, True, False, one_camera=True)[0]
    )
    assert not np.allclose(moved[0], fresh[0])
