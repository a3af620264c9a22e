import cv2
import numpy as np
import pytest

from core.camera import Camera, matrix_to_rodrigues, rodrigues_to_matrix


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
