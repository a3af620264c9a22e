"""Exact pixel-centre rasterisation of the visibility reference (bench/mesh_raster.py)."""

import numpy as np

from bench.mesh_raster import part_visibility, rasterize
from core.camera import Camera

CAM = Camera("c", (100, 80), [[100.0, 0, 50.3], [0, 100.0, 40.2], [0, 0, 1]])


def _quad(x0, x1, y0, y1, z):
    """Two triangles covering the rectangle at depth z (a plane facing the camera)."""
    v = np.array([[x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z]], float)
    return v, np.array([[0, 1, 2], [0, 2, 3]])


def test_a_rectangle_covers_exactly_the_pixel_centres_inside_it():
    v, f = _quad(-0.2, 0.2, -0.1, 0.1, 2.0)  # u in [40.3, 60.3], v in [35.2, 45.2]
    pix, depth, tri, bary = rasterize(CAM, v, f)
    cover = np.unique(pix)
    u, w = cover % 100, cover // 100
    assert len(cover) == 20 * 10
    assert u.min() == 41 and u.max() == 60 and w.min() == 36 and w.max() == 45
    np.testing.assert_allclose(depth, 2.0)
    np.testing.assert_allclose(bary.sum(axis=1), 1.0)
    assert np.all(bary >= -1e-9)


def test_depth_is_perspective_correct_on_a_tilted_plane():
    # plane z = 2 + 0.5 x: the ray through pixel u meets it at z = 2 / (1 - 0.5 (u-cx)/f)
    x = np.array([-0.3, 0.3, 0.3, -0.3])
    y = np.array([-0.2, -0.2, 0.2, 0.2])
    v = np.stack([x, y, 2 + 0.5 * x], axis=1)
    pix, depth, _, _ = rasterize(CAM, v, np.array([[0, 1, 2], [0, 2, 3]]))
    u = pix % 100
    np.testing.assert_allclose(depth, 2.0 / (1.0 - 0.5 * (u - 50.3) / 100.0), rtol=1e-12)


def test_an_occluder_in_front_hides_exactly_its_area():
    vb, fb = _quad(-0.2, 0.2, -0.1, 0.1, 2.0)  # part 0: 200 px
    vf, ff = _quad(0.0, 0.1, 0.0, 0.05, 1.0)  # part 1: u 51..60, v 41..45: 50 px
    v = np.vstack([vb, vf])
    f = np.vstack([fb, ff + 4])
    pix, depth, tri, _ = rasterize(CAM, v, f)
    part = np.array([0, 0, 1, 1])[tri]
    vi, full = part_visibility(pix, depth, part, 3)
    np.testing.assert_array_equal(full, [200, 50, 0])
    np.testing.assert_allclose(vi[:2], [150 / 200, 1.0])
    assert np.isnan(vi[2])
    # the order of the faces does not matter
    pix2, depth2, tri2, _ = rasterize(CAM, v, f[::-1])
    vi2, full2 = part_visibility(pix2, depth2, np.array([1, 1, 0, 0])[tri2], 3)
    np.testing.assert_array_equal(full2, full)


def test_triangles_behind_the_camera_or_outside_the_image_give_nothing():
    v, f = _quad(-0.2, 0.2, -0.1, 0.1, -2.0)
    assert len(rasterize(CAM, v, f)[0]) == 0
    v, f = _quad(5.0, 6.0, 5.0, 6.0, 2.0)
    assert len(rasterize(CAM, v, f)[0]) == 0
    # a large triangle clipped by the image border covers only in-image pixels
    v, f = _quad(-5.0, 5.0, -5.0, 5.0, 2.0)
    pix, *_ = rasterize(CAM, v, f)
    assert len(np.unique(pix)) == 100 * 80
