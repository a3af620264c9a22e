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
    np.testing.assert_allclose(
        out.depth[int(round(v)), int(round(u))],
        np.linalg.norm(centers[1] - cam.center) - r,
        atol=0.01,
    )


def test_rotated_ellipsoid_projects_to_its_outline():
    cam = _camera()
    ang = 0.6
    Rz = np.array([[np.cos(ang), 0, -np.sin(ang)], [0, 1, 0], [np.sin(ang), 0, np.cos(ang)]])
    out = render_parts(cam, np.zeros((1, 3)), Rz[None], np.array([[0.6, 0.1, 0.1]]), np.array([0]))
    # tip of the long axis is inside the mask, a point just beyond is not
    tip = cam.project(Rz[:, 0] * 0.58)
    beyond = cam.project(Rz[:, 0] * 0.66)
    assert out.mask[int(round(tip[1])), int(round(tip[0]))]
    assert not out.mask[int(round(beyond[1])), int(round(beyond[0]))]


def test_part_outside_image_has_nan_index():
    cam = _camera()
    out = render_parts(
        cam,
        np.array([[10.0, 0.0, 0.0]]),
        np.eye(3)[None],
        np.array([[0.1, 0.1, 0.1]]),
        np.array([0]),
    )
    assert np.isnan(out.visibility_index[0])


def test_outer_only_leaves_out_the_buried_surface():
    """A small sphere half inside a big one (a clavicle in the chest): seen side by side,
    the buried half is no skin — with ``outer_only`` its index is about 1, not ~0.6."""
    from core.model_render import neighbour_parts

    cam = _camera()
    centers = np.array([[0.0, 0.0, 0.0], [0.3, 0.0, 0.0]])
    axes = np.repeat(np.eye(3)[None], 2, axis=0)
    radii = np.array([[0.3] * 3, [0.1] * 3])
    part = np.array([0, 1])
    plain = render_parts(cam, centers, axes, radii, part)
    outer = render_parts(cam, centers, axes, radii, part, outer_only=True)
    np.testing.assert_array_equal(plain.part_id, outer.part_id)
    np.testing.assert_array_equal(plain.visible_area, outer.visible_area)
    assert plain.visibility_index[1] < 0.8
    assert outer.visibility_index[1] > 0.9
    assert outer.full_area[1] < plain.full_area[1]
    # the big sphere's surface inside the small one is buried too (a little)
    assert outer.full_area[0] <= plain.full_area[0]
    # burial restricted to "part 1 inside part 0" leaves part 0's area whole
    only = np.array([[False, False], [True, False]])
    sel = render_parts(cam, centers, axes, radii, part, outer_only=True, buried_by=only)
    assert sel.full_area[0] == plain.full_area[0]
    assert sel.full_area[1] == outer.full_area[1]
    np.testing.assert_array_equal(
        neighbour_parts(np.array([-1, 0, 1])), [[1, 1, 0], [1, 1, 1], [0, 1, 1]]
    )
