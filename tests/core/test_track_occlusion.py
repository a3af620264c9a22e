"""Occlusion of tracked points by the cloud of the other points (core.track_occlusion)."""

import numpy as np

from core.track_occlusion import occluded
from tests.core._planescene import cameras


def _plane(y, half, step, rng, jitter=0.0):
    s = np.arange(-half, half + 1e-9, step)
    x, z = np.meshgrid(s, s)
    p = np.stack([x.ravel(), np.full(x.size, y), z.ravel()], axis=1)
    return p + rng.normal(0, jitter, p.shape)


def test_points_behind_a_patch_are_flagged_and_a_single_stray_point_hides_nothing(rng):
    cams = cameras()
    back = _plane(0.3, 0.2, 0.01, rng, jitter=0.002)  # wall behind
    front = _plane(0.0, 0.06, 0.01, rng, jitter=0.002)  # a patch 30 cm in front
    xyz = np.concatenate([back, front])
    occ = occluded(cams, xyz, margin_m=0.03)
    assert not occ[len(back) :].any()  # the patch is in front everywhere
    # Back points on a camera's line of sight through the patch's centre are hidden
    # there; points far out on the wall are seen by every camera.
    for j, cam in enumerate(cams):
        o, d = cam.rays(cam.project(np.zeros((1, 3))))
        on_ray = o + d[0] * (0.3 - o[1]) / d[0, 1]
        near = np.linalg.norm(back - on_ray, axis=1) < 0.03
        assert occ[: len(back)][near, j].all()
    far = np.max(np.abs(back[:, [0, 2]]), axis=1) > 0.17
    assert not occ[: len(back)][far].any()
    # one stray point in front of the wall does not hide the wall behind it (rank 2)
    stray = np.array([[0.15, 0.0, 0.15]])
    occ2 = occluded(cams, np.concatenate([back, stray]), margin_m=0.03)
    assert not occ2[: len(back)].any()
    assert occluded(cams, np.concatenate([back, stray]), margin_m=0.03, rank=1)[: len(back)].any()


def test_nan_points_are_ignored():
    cams = cameras()
    xyz = np.array([[0.0, 0.0, 0.0], [np.nan, np.nan, np.nan], [0.0, 0.3, 0.0]])
    occ = occluded(cams, xyz, rank=1)
    assert occ.shape == (3, 3)
    assert not occ[1].any() and not occ[0].any()
