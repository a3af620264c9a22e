"""Rim points, the occluding-contour theorem, and camera selection on synthetic bodies."""

import numpy as np

from core.camera import Camera
from core.camera_selection import observability, select_cameras
from core.contour_match import match_contours
from core.contours import occluding_contours
from core.model_contours import rim_points
from core.model_render import render_parts


def _camera(yaw=0.0):
    # on a circle of radius 5 around the origin, looking at it, world Z up
    c = np.array([5 * np.sin(yaw), -5 * np.cos(yaw), 0.0])
    fwd = -c / np.linalg.norm(c)
    right = np.cross(fwd, [0, 0, 1.0])
    right /= np.linalg.norm(right)
    down = np.cross(fwd, right)
    R = np.stack([right, down, fwd])
    K = np.array([[500.0, 0, 160], [0, 500.0, 120], [0, 0, 1]])
    return Camera("c", (320, 240), K, np.zeros(5), R, -R @ c)


def _body(rng):
    centers = np.array([[0.0, 0.0, 0.0], [0.35, 0.0, 0.1]])
    axes = np.stack([np.linalg.qr(rng.normal(size=(3, 3)))[0] for _ in range(2)])
    axes *= np.sign(np.linalg.det(axes))[:, None, None]
    radii = np.array([[0.5, 0.25, 0.2], [0.3, 0.12, 0.1]])
    return centers, axes, radii, np.array([0, 1])


def test_rim_points_are_tangent_to_viewing_rays(rng):
    cam = _camera(0.3)
    centers, axes, radii, part = _body(rng)
    rim = rim_points(cam, centers, axes, radii, part)
    assert len(rim) > 40
    view = rim.xyz - cam.center
    view /= np.linalg.norm(view, axis=1, keepdims=True)
    # the surface normal is perpendicular to the viewing ray on the rim
    assert np.max(np.abs(np.sum(view * rim.normal, axis=1))) < 1e-9


def test_rim_projects_onto_rendered_silhouette_boundary(rng):
    cam = _camera(0.8)
    centers, axes, radii, part = _body(rng)
    render = render_parts(cam, centers, axes, radii, part)
    rim = rim_points(cam, centers, axes, radii, part, n_per=96, render=render)
    (outer, *_) = occluding_contours(render.mask, spacing=1.0, smooth_px=1.0)
    # every visible rim point lies on the outline of the rendered mask (within ~1 px)
    d = np.min(np.linalg.norm(rim.uv[:, None] - outer.uv[None], axis=2), axis=1)
    assert np.percentile(d, 90) < 1.0, np.percentile(d, [50, 90, 100])


def test_contour_matching_recovers_offset(rng):
    """A model shifted by a known amount: the normal residuals measure the shift."""
    cam = _camera(0.0)
    centers, axes, radii, part = _body(rng)
    observed = render_parts(cam, centers, axes, radii, part)
    contours = occluding_contours(observed.mask, spacing=1.0, smooth_px=1.5)
    medians = []
    for shift in (0.0, 0.01):  # 1 cm along world X = 1 px along u at 5 m
        moved = centers + np.array([shift, 0.0, 0.0])
        rim = rim_points(
            cam,
            moved,
            axes,
            radii,
            part,
            n_per=256,
            render=render_parts(cam, moved, axes, radii, part),
        )
        m = match_contours(cam, contours, rim, max_dist_px=5.0)
        assert len(m) > 0.7 * sum(len(c) for c in contours)
        vertical = np.abs(m.contour_normal[:, 0]) > 0.95
        medians.append(np.median(m.f_im[vertical, 0]))
        assert np.median(np.linalg.norm(m.f_3d, axis=1)) < 0.2
    # unmoved: the discretised silhouette sits within a fraction of a pixel of the rim
    assert abs(medians[0]) < 0.35
    # moved by 1 px: observed minus predicted changes by -1 px
    np.testing.assert_allclose(medians[1] - medians[0], -500 * 0.01 / 5.0, atol=0.1)


def test_camera_selection_drops_hidden_and_degenerate_views():
    vis = np.array([[0.9, 0.1, 0.8], [0.5, 0.6, np.nan]])
    # part 0 moves along camera 2's optical axis: almost no image motion there
    disp = [
        [np.full((10, 2), 0.5), np.full((10, 2), 0.5), np.full((10, 2), 0.01)],
        [np.full((10, 2), 0.2), np.full((10, 2), 0.3), np.zeros((0, 2))],
    ]
    obs = observability(disp)
    sel = select_cameras(vis, obs)
    assert sel.use.tolist() == [[True, False, False], [True, True, False]]
    assert sel.rank[0].tolist() == [0, -1, 1]
    # a still part uses every visible camera
    assert select_cameras(vis, np.zeros_like(vis)).use.tolist() == [
        [True, False, True],
        [True, True, False],
    ]
