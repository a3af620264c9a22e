"""Held-out-camera silhouette check: body masks of a posed model and their IoU."""

import numpy as np
import pytest

from core import metaballs as mb
from core import skeleton as sk
from core.silhouette_check import body_masks, mask_iou, shift_iou
from tests.core._bodyscene import look_at


def _body():
    skel = sk.make_skeleton()
    s = np.ones(skel.n_groups)
    return skel, s, mb.make_metaballs(skel, "simplified", s)


def test_mask_iou_of_known_rectangles():
    a = np.zeros((2, 20, 30), bool)
    b = np.zeros((2, 20, 30), bool)
    a[0, 2:12, 3:13] = True  # 100 px
    b[0, 7:17, 3:13] = True  # 100 px, 50 shared
    a[1, 0:4, 0:5] = True
    iou = mask_iou(a, b)
    np.testing.assert_allclose(iou, [50 / 150, 0.0])
    assert np.isnan(mask_iou(np.zeros((5, 5), bool), np.zeros((5, 5), bool)))
    with pytest.raises(ValueError, match="cannot be compared"):
        mask_iou(a, b[:, :10])


def test_body_masks_follow_the_pose():
    skel, s, balls = _body()
    cam = look_at("c", (0.0, -4.0, 1.0), target=(0.0, 0.0, 1.0))
    n = skel.n_dof
    theta = np.zeros((4, n))
    root = np.array([[0.0, 0.0, 1.0], [0.1, 0.0, 1.0], [0.3, 0.0, 1.0], [np.nan, 0.0, 1.0]])
    m = body_masks(skel, s, balls, theta, root, cam)
    assert m.shape == (4, 384, 512)
    assert m[0].sum() > 1000 and not m[3].any()  # a non-finite pose renders nothing
    # the silhouette spans the body: from above the head joint to below the ankles
    j = sk.joint_positions(skel, theta[0], root[0], s)
    uv = cam.project(j)
    rows = np.flatnonzero(m[0].any(axis=1))
    assert rows[0] < uv[skel.joint_index("head_top"), 1] + 3
    assert rows[-1] > uv[skel.joint_index("l_ankle"), 1]
    # a sideways shift moves the silhouette by f * dx / depth pixels
    cols = [np.nonzero(m[k])[1].mean() for k in range(3)]
    np.testing.assert_allclose(np.diff(cols), [600 * 0.1 / 4.0, 600 * 0.2 / 4.0], rtol=0.1)
    iou = mask_iou(m[:3], np.repeat(m[:1], 3, axis=0))
    assert iou[0] == 1.0 and 1.0 > iou[1] > iou[2]


def test_shift_iou_recovers_a_constant_offset(rng):
    h, w = 60, 80
    image = np.zeros((5, h, w), bool)
    for f in range(5):  # blobs of varying position and size, like a moving person
        v, u = rng.integers(15, 40), rng.integers(15, 55)
        image[f, v : v + rng.integers(8, 18), u : u + rng.integers(5, 12)] = True
    model = np.zeros_like(image)
    model[:, : h - 2, : w - 3] = image[:, 2:, 3:]  # the model drawn 3 px left, 2 px up
    shift, iou = shift_iou(model, image, max_shift_px=6)
    np.testing.assert_array_equal(shift, [3, 2])
    np.testing.assert_allclose(iou, 1.0)
    assert np.all(mask_iou(model, image) < 0.8)
