"""Key templates: re-anchoring removes drift; distorted or far keys are not used."""

from __future__ import annotations

import numpy as np

from core.lsm import ImageStack
from core.track_anchor import KeyTemplates, distortion, reanchor
from tests.core._planescene import cameras, render


def test_distortion_of_rotations_stretches_and_singular_affines():
    th = 0.7
    rot = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    a = np.stack(
        [rot, np.diag([1.25, 1.0]), np.diag([1.0, 0.8]), np.zeros((2, 2)), np.full((2, 2), np.nan)]
    )
    d = distortion(a)
    assert np.allclose(d[:3], [0.0, np.log(1.25), np.log(1.25)], atol=1e-12)
    assert np.all(np.isinf(d[3:]))


def test_reanchor_pulls_drifted_matches_back_to_the_key(rng):
    cams = cameras()
    motion = np.array([0.012, 0.0, -0.009])  # metres: three frames of motion
    im0 = [render(c) for c in cams]
    im1 = [render(c, offset=motion) for c in cams]
    xyz = np.column_stack(
        [rng.uniform(-0.15, 0.15, 60), np.zeros(60), rng.uniform(-0.15, 0.15, 60)]
    )
    uv0 = np.stack([c.project(xyz) for c in cams], 1)  # (P, C, 2)
    uv1 = np.stack([c.project(xyz + motion) for c in cams], 1)
    keys = KeyTemplates.start(uv0, 0)
    pi, ci = np.nonzero(np.ones(uv0.shape[:2], bool))
    drift = rng.normal(0, 0.35, (len(pi), 2))  # accumulated drift
    drift[:10] = [2.5, 0.0]  # or a wrong match
    uv_t = uv1[pi, ci] + drift
    aff_t = np.broadcast_to(np.eye(2), (len(pi), 2, 2))
    uv, aff, ok = reanchor(keys, {0: ImageStack(im0)}, ImageStack(im1), pi, ci, uv_t, aff_t)
    err_before = np.linalg.norm(drift[10:], axis=1)
    err_after = np.linalg.norm(uv[10:] - uv1[pi[10:], ci[10:]], axis=1)
    assert ok[10:].mean() > 0.95
    assert np.median(err_after[ok[10:]]) < 0.05 < 0.3 < np.median(err_before)
    assert not ok[:10].any() and np.allclose(uv[:10], uv_t[:10])  # too far: kept, flagged
    # A key whose carried affine is strongly distorted is not used.
    keys.affine[:] = np.diag([1.8, 1.0])
    _, _, ok2 = reanchor(keys, {0: ImageStack(im0)}, ImageStack(im1), pi, ci, uv_t, aff_t)
    assert not ok2.any()


def test_key_reset_and_append():
    uv = np.full((3, 2, 2), np.nan)
    uv[0] = [[10.0, 11.0], [12.0, 13.0]]
    uv[1, 0] = [5.0, 6.0]
    keys = KeyTemplates.start(uv, 4)
    assert keys.f.tolist() == [[4, 4], [4, -1], [-1, -1]]
    keys.affine[0, 0] = 2 * np.eye(2)
    keys.reset(np.array([0]), np.array([0]), np.array([[1.0, 2.0]]), 7)
    assert keys.f[0, 0] == 7 and np.allclose(keys.affine[0, 0], np.eye(2))
    keys.append(KeyTemplates.start(uv[:1], 9))
    assert keys.f.shape == (4, 2) and keys.frames() == {4, 7, 9}
