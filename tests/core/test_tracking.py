"""Tracking a moving textured plane; trajectory filters on injected false trajectories."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from core.surface import measure_surface
from core.track_diagnose import REASONS
from core.tracking import (
    PointFilter,
    TrackSettings,
    fill_gaps,
    filter_trajectories,
    predict_in_image,
    track,
)
from tests.core._planescene import cameras, render


def test_moving_plane_is_tracked_and_a_missing_image_is_survived():
    cams = cameras()
    motion = np.array([0.004, 0.0, -0.003])  # metres per frame
    frames = [[render(c, offset=k * motion) for c in cams] for k in range(5)]
    frames[2][0] = None  # cam01 lost its image in frame 2
    seeds = np.stack([c.project(np.array([[0.0, 0.0, 0.0]])) for c in cams], 1)
    surf = measure_surface(frames[0], cams, seeds, step=6)
    tr = track(lambda i: frames[i], cams, surf, 5, 25.0, regen_every=0)
    p0 = len(surf)
    through = tr.alive[:, :p0].all(axis=0)
    assert through.mean() > 0.8
    err = tr.xyz[-1, through] - (surf.xyz[through] + 4 * motion)
    assert np.median(np.linalg.norm(err, axis=1)) < 0.001
    assert np.all(np.isnan(tr.uv[2, :, 0]))  # nothing matched in the missing image
    v = tr.velocity()[2, through]
    assert np.allclose(np.median(v, axis=0), motion * 25.0, atol=0.01)


def test_filters_remove_false_trajectories(rng):
    F, P = 30, 400
    base = rng.uniform(-0.2, 0.2, (P, 3))
    t = np.arange(F)[:, None, None] / 25.0
    xyz = base[None] + t * np.array([1.0, 0.2, 0.0]) + rng.normal(0, 0.001, (F, P, 3))
    false = rng.choice(P, 20, replace=False)
    kind = np.arange(20) % 3
    for j, p in enumerate(false):
        k0 = rng.integers(3, F - 5)
        if kind[j] == 0:  # jump to a wrong match
            xyz[k0:, p] += rng.choice([-1, 1], 3) * 0.03
        elif kind[j] == 1:  # random-walk drift
            xyz[:, p] += np.cumsum(rng.normal(0, 0.01, (F, 3)), axis=0)
        else:  # stuck in space
            xyz[k0:, p] = xyz[k0, p]
    res = filter_trajectories(xyz, 25.0, radius_m=0.08)
    hit = res.removed | res.truncated
    good = np.setdiff1d(np.arange(P), false)
    assert hit[false].mean() >= 0.95
    assert hit[good].mean() < 0.05


def test_point_filter_follows_constant_velocity_and_gates_a_jump(rng):
    P = 200
    xyz0 = rng.uniform(-1, 1, (P, 3))
    rate = rng.uniform(-0.02, 0.02, (P, 3))  # m/frame
    R = np.tile(np.eye(3) * 0.001**2, (P, 1, 1))
    kf = PointFilter.start(xyz0, R, accel_sigma=0.002)
    rows = np.arange(P)
    for k in range(1, 8):
        kf.predict()
        kf.update(xyz0 + k * rate + rng.normal(0, 0.001, (P, 3)), R, rows)
    assert np.median(np.abs(kf.x[:, 3:] - rate)) < 0.001
    xyz_p, cov_p = kf.predicted()
    assert np.median(np.linalg.norm(xyz_p - (xyz0 + 8 * rate), axis=1)) < 0.004
    kf.predict()
    z = xyz0 + 8 * rate + rng.normal(0, 0.001, (P, 3))
    z[:20] += 0.05  # a 5 cm jump: a wrong match
    m2 = kf.mahalanobis2(z, R)
    assert np.all(m2[:20] > 25.0) and np.mean(m2[20:] < 25.0) > 0.98
    # Coasting widens the prediction; its projection is the camera's.
    cam = cameras()[1]
    before = predict_in_image(cam, kf.x[:, :3], kf.P[:, :3, :3])[1]
    for _ in range(3):
        kf.predict()
    uv, sig = predict_in_image(cam, kf.x[:, :3], kf.P[:, :3, :3])
    assert np.all(sig > before)
    assert np.allclose(uv, cam.project(kf.x[:, :3]))


def test_fill_gaps_bridges_short_gaps_only():
    F, P = 12, 3
    t = np.arange(F, dtype=float)[:, None, None]
    v = np.array([[0.01, -0.02, 0.005]])
    xyz = np.broadcast_to(t * v, (F, P, 3)).copy()
    rate = np.broadcast_to(v, (F, P, 3)).copy()
    xyz[4:6, 0] = np.nan  # 2-frame gap: filled (exactly, linear motion)
    xyz[3:9, 1] = np.nan  # 6-frame gap: too long
    xyz[9:, 2] = np.nan  # lost at the end: stays lost
    out = fill_gaps(xyz, rate, max_gap=3)
    assert np.allclose(out[:, 0], t[:, 0] * v)
    assert np.all(np.isnan(out[3:9, 1])) and np.all(np.isnan(out[9:, 2]))


def test_occluded_frame_is_coasted_and_reacquired():
    cams = cameras()
    motion = np.array([0.004, 0.0, -0.003])
    frames = [[render(c, offset=k * motion) for c in cams] for k in range(4)]
    frames[2][1] = frames[2][2] = None  # only one camera in frame 2: no intersection
    seeds = np.stack([c.project(np.array([[0.0, 0.0, 0.0]])) for c in cams], 1)
    surf = measure_surface(frames[0], cams, seeds, step=6)
    for pred in ("ekf", "linear"):
        log: list = []
        tr = track(
            lambda i: frames[i],
            cams,
            surf,
            4,
            25.0,
            regen_every=0,
            predict=pred,
            max_coast=2,
            log=log,
        )
        p0 = len(surf)
        assert not tr.measured[2, :p0].any()
        # the diagnosis blames the missing images, for every point measured at frame 1
        lost = tr.measured[1, :p0]
        assert np.all(np.array(REASONS)[log[1]["reason"][:p0][lost]] == "too_few_cameras")
        assert np.all(log[1]["reason"][:p0][~lost] == -1)
        assert tr.measured[[0, 1, 3], :p0].all(axis=0).mean() > 0.8
        ok = tr.measured[3, :p0]
        err = tr.xyz[2, :p0][ok] - (surf.xyz[ok] + 2 * motion)
        assert np.median(np.linalg.norm(err, axis=1)) < 0.001  # the bridged frame


def test_settings_object_and_keywords_are_the_same_options():
    cams = cameras()
    motion = np.array([0.003, 0.0, 0.002])
    frames = [[render(c, offset=k * motion) for c in cams] for k in range(3)]
    seeds = np.stack([c.project(np.array([[0.0, 0.0, 0.0]])) for c in cams], 1)
    surf = measure_surface(frames[0], cams, seeds, step=6)
    by_kw = track(
        lambda i: frames[i], cams, surf, 3, 25.0, regen_every=0, max_coast=2, predict="linear"
    )
    s = TrackSettings(regen_every=0, max_coast=2)
    by_obj = track(lambda i: frames[i], cams, surf, 3, 25.0, settings=s, predict="linear")
    for a in ("xyz", "uv", "sigma_xyz", "start", "measured"):
        assert np.array_equal(getattr(by_kw, a), getattr(by_obj, a), equal_nan=True)
    assert len(surf) > 10 and by_kw.measured[1:].all(axis=0).mean() > 0.8
    # a keyword replaces the settings' value: no intersection reprojects within 1e-6 px
    strict = track(lambda i: frames[i], cams, surf, 3, 25.0, settings=s, max_rms_px=1e-6)
    assert not strict.measured[1:].any()
    with pytest.raises(dataclasses.FrozenInstanceError):
        s.max_coast = 3


def test_unknown_option_and_bad_predict_are_refused():
    with pytest.raises(TypeError, match="depth_retry"):  # pruned: tried and left off
        TrackSettings.of(depth_retry=True)
    with pytest.raises(ValueError, match="predict must be"):
        TrackSettings(predict="kalman")
