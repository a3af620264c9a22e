"""The tangent plane's affine warp between two views (core.plane_warp)."""

import numpy as np

from core.plane_warp import plane_affine
from tests.core.wand_truth import look_at


def _pair(angle_deg, dist=2.0):
    a = np.radians(angle_deg)
    tmpl = look_at("t", (0.0, -dist, 0.0), (0, 0, 0), size=(320, 240), f=400.0)
    srch = look_at(
        "s", (dist * np.sin(a), -dist * np.cos(a), 0.0), (0, 0, 0), size=(320, 240), f=400.0
    )
    return tmpl, srch


def test_a_plane_seen_obliquely_is_foreshortened_by_the_cosine():
    tmpl, srch = _pair(60.0)
    X = np.zeros((1, 3))
    A = plane_affine(tmpl, srch, tmpl.project(X), X, np.array([[0.0, -1.0, 0.0]]))
    # at the optical centres: horizontal offsets shrink by cos 60°, vertical ones keep
    assert np.allclose(A[0], [[0.5, 0.0], [0.0, 1.0]], atol=2e-3)


def test_the_warp_predicts_where_nearby_plane_points_land():
    tmpl, srch = _pair(70.0)
    rng = np.random.default_rng(0)
    X = np.column_stack([rng.uniform(-0.2, 0.2, 20), np.zeros(20), rng.uniform(-0.2, 0.2, 20)])
    n = np.tile([0.0, -1.0, 0.0], (20, 1))
    A = plane_affine(tmpl, srch, tmpl.project(X), X, n)
    off = X + [0.004, 0.0, -0.003]  # 4 mm / 3 mm along the plane: a few pixels
    du_t = tmpl.project(off) - tmpl.project(X)
    du_s = srch.project(off) - srch.project(X)
    assert np.abs(du_t).max() > 0.5
    assert np.allclose(np.einsum("nij,nj->ni", A, du_t), du_s, atol=0.02)


def test_edge_on_planes_and_missing_values_give_the_identity():
    tmpl, srch = _pair(45.0)
    X = np.array([[0.0, 0.0, 0.0], [np.nan, 0.0, 0.0]])
    n = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])  # the first seen edge-on
    A = plane_affine(tmpl, srch, np.nan_to_num(tmpl.project(np.nan_to_num(X))), X, n)
    assert np.allclose(A, np.eye(2))
    assert plane_affine(tmpl, srch, np.zeros((0, 2)), np.zeros((0, 3)), np.zeros((0, 3))).shape == (
        0,
        2,
        2,
    )
