import numpy as np

from core.camera import Camera
from core.model_render import render_parts


def _camera():
    # looking along world +Y from y = -5 (OpenCV axes: x right = world X, y down = -Z)
    R = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])
    t = -R @ np.array([0.0, -5.0, 0.0])
    K = np.array([[400.0, 0, 160], [0, 400.0, 120], [0, 0, 1]])
    return Camera("c", (320, 240), K, np.zeros(5), R, t)


def test_sphere_area_and_occlusion():
    cam = _camera()
    r = 0.25
    centers = np.array([[0.0, 0.0, 0.0], [0.2, -1.0, 0.0]])  # part 1 in front, offset
    axes = np.repeat(np.eye(3)[None], 2, axis=0)
    radii = np.array([[r, r, r], [r, r, r]])
    out = render_parts(cam, centers, axes, radii, part=np.array([0, 1]))
    # projected disc area of a sphere at distance D: pi (f r / sqrt(D^2 - r^2))^2
    for p, dist in ((0, 5.0), (1, np.hypot(4.0, 0.2))):
        rho = 400 * r / np.sqrt(dist**2 - r**2)
        np.testing.assert_allclose(out.full_area[p], np.pi * rho**2, rtol=0.03)
    assert out.visibility_index[1] == 1.0
    # the back sphere is partly hidden: lens-shaped overlap of two discs
    assert 0.35 < out.visibility_index[0] < 0.9
    assert out.visible_area.sum() == out.mask.sum()
    # depth of the front sphere's centre pixel
    u, v = cam.project(centers[1])
    np.testing.assert_allclose(out.depth[int(round(v)), int(round(u))],
                               np.linalg.norm(centers[1] - cam.center) - r, atol=0.01)


def test_rotated_ellipsoid_projects_to_its_outline():
    cam = _camera()
    ang = 0.6
    Rz = np.array([[np.cos(ang), 0, -np.sin(ang)], [0, 1, 0], [np.sin(ang), 0, np.cos(ang)]])
    out = render_parts(cam, np.zeros((1, 3)), Rz[None], np.array([[0.6, 0.1, 0.1]]),
                       np.array([0]))
    # tip of the long axis is inside the mask, a point just beyond is not
    tip = cam.project(Rz[:, 0] * 0.58)
    beyond = cam.project(Rz[:, 0] * 0.66)
    assert out.mask[int(round(tip[1])), int(round(tip[0]))]
    assert not out.mask[int(round(beyond[1])), int(round(beyond[0]))]


def test_part_outside_image_has_nan_index():
    cam = _camera()
    out = render_parts(cam, np.array([[10.0, 0.0, 0.0]]), np.eye(3)[None],
                       np.array([[0.1, 0.1, 0.1]]), np.array([0]))
    assert np.isnan(out.visibility_index[0])
