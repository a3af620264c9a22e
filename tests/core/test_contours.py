import cv2
import numpy as np

from core.contours import occluding_contours


def test_circle_contour_geometry():
    h = w = 200
    r, c = 50.0, np.array([100.3, 90.7])
    yy, xx = np.mgrid[:h, :w]
    mask = (xx - c[0]) ** 2 + (yy - c[1]) ** 2 <= r**2
    (con,) = occluding_contours(mask, spacing=1.0, smooth_px=3.0)
    radius = np.linalg.norm(con.uv - c, axis=1)
    assert abs(np.mean(radius) - r) < 0.3  # edge located to a fraction of a pixel
    radial = (con.uv - c) / radius[:, None]
    assert np.min(np.sum(con.normal * radial, axis=1)) > 0.98  # normals point outwards
    assert np.max(np.abs(np.sum(con.tangent * radial, axis=1))) < 0.2
    np.testing.assert_allclose(np.median(con.curvature), 1 / r, rtol=0.1)
    assert not con.hole


def test_hole_normals_point_out_of_foreground():
    mask = np.zeros((120, 120), np.uint8)
    cv2.rectangle(mask, (10, 10), (110, 110), 1, -1)
    cv2.circle(mask, (60, 60), 20, 0, -1)
    cons = occluding_contours(mask.astype(bool), spacing=1.0)
    assert [c.hole for c in cons] == [False, True]
    hole = cons[1]
    radial = (hole.uv - 60) / np.linalg.norm(hole.uv - 60, axis=1)[:, None]
    # out of the foreground = into the hole = towards its centre
    assert np.median(np.sum(hole.normal * radial, axis=1)) < -0.95
    assert np.median(hole.curvature) < 0


def test_specks_are_dropped():
    mask = np.zeros((50, 50), bool)
    mask[10:12, 10:12] = True
    assert occluding_contours(mask) == []
