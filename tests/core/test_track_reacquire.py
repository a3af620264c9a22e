"""Re-acquisition of lost points: rigid neighbour motion, gap bridging, and occlusion."""

from __future__ import annotations

import numpy as np

from core.camera import rodrigues_to_matrix
from core.surface import measure_surface
from core.track_reacquire import neighbour_motion, predict_unmeasured, rigid_fit
from core.track_trajectories import bridge_gaps
from core.tracking import track
from tests.core._planescene import cameras, render


def test_rigid_fit_recovers_the_motion_and_ignores_zero_weights(rng):
    Q, K = 50, 8
    R = np.stack([rodrigues_to_matrix(r) for r in rng.normal(0, 0.3, (Q, 3))])
    t = rng.normal(0, 0.1, (Q, 3))
    src = rng.normal(0, 0.05, (Q, K, 3))
    dst = np.einsum("qij,qkj->qki", R, src) + t[:, None]
    w = np.ones((Q, K))
    w[:, -2:] = 0.0
    dst[:, -2:] += 1.0  # garbage where the weight is 0
    R_est, t_est = rigid_fit(src, dst, w)
    assert np.allclose(R_est, R, atol=1e-9) and np.allclose(t_est, t, atol=1e-9)
    assert np.allclose(np.linalg.det(R_est), 1.0)


def test_neighbour_motion_predicts_points_of_a_rigid_patch(rng):
    M = 400
    then = rng.uniform(-0.2, 0.2, (M, 3))
    R, t = rodrigues_to_matrix([0.05, -0.1, 0.08]), np.array([0.03, -0.01, 0.02])
    now = then @ R.T + t + rng.normal(0, 0.0005, (M, 3))
    now[:5] = np.nan  # not measured now: not used
    query = np.vstack([rng.uniform(-0.15, 0.15, (30, 3)), [[5.0, 5.0, 5.0]]])
    xyz, rms, ok = neighbour_motion(then, now, query, k=10, radius_m=0.1)
    assert ok[:30].all() and not ok[30] and np.isnan(xyz[30]).all()
    err = np.linalg.norm(xyz[:30] - (query[:30] @ R.T + t), axis=1)
    assert np.median(err) < 0.001
    assert np.all((rms[:30] > 0.0003) & (rms[:30] < 0.0015))  # ~ the 0.87 mm 3-D noise


def test_bridge_gaps_follows_the_prediction_and_closes_on_the_measurement():
    F, P = 10, 3
    truth = np.cumsum(np.full((F, P, 3), 0.01), axis=0)
    xyz = truth.copy()
    pred = np.full((F, P, 3), np.nan)
    xyz[3:7] = np.nan  # gap 3..6, re-acquired at 7
    pred[3:8] = truth[3:8] + 0.001 * np.arange(1, 6)[:, None, None]  # error grows from 0
    pred[5, 2] = np.nan  # a frame without prediction
    xyz[8:, 1] = np.nan  # point 1 never comes back
    pred[8:, 1] = truth[8:, 1]
    out = bridge_gaps(xyz, pred)
    assert np.allclose(out[:, 0], truth[:, 0])  # ramp removes the linear error
    assert np.all(np.isnan(out[8:, 1]))
    assert np.all(np.isnan(out[3:7, 2])) and np.allclose(out[7:, 2], truth[7:, 2])


def _band_occluded(cam, offset, band=(0.0, 0.08)):
    """The plane of :func:`render` with a flat grey occluder over a band of it."""
    img = render(cam, offset)
    w, h = cam.size
    u, v = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    o, d = cam.rays(np.stack([u, v], -1))
    s = o[0] + (offset[1] - o[1]) / d[..., 1] * d[..., 0] - offset[0]
    img[(s > band[0]) & (s < band[1])] = 90
    return img


def test_occluded_points_are_reacquired_with_the_same_index():
    cams = cameras()
    motion = np.array([0.004, 0.0, -0.003])
    F = 5
    frames = [
        [(_band_occluded(c, k * motion) if k in (2, 3) else render(c, k * motion)) for c in cams]
        for k in range(F)
    ]
    seeds = np.stack([c.project(np.array([[0.0, 0.0, 0.0]])) for c in cams], 1)
    surf = measure_surface(frames[0], cams, seeds, step=4)
    p0 = len(surf)
    truth = surf.xyz[None] + np.arange(F)[:, None, None] * motion
    band = (surf.xyz[:, 0] > 0.005) & (surf.xyz[:, 0] < 0.075)
    lost = track(
        lambda i: frames[i], cams, surf, F, 25.0, regen_every=0, max_dormant=0, max_coast=0
    )
    tr = track(lambda i: frames[i], cams, surf, F, 25.0, regen_every=0, max_dormant=3, max_coast=0)
    assert not lost.alive[4, :p0][band].any()  # without: lost for good
    # hidden in both occluded frames, measured again after them (a point that only the
    # depth test dropped in frame 2 may be re-acquired in frame 3 already)
    back = tr.measured[4, :p0] & ~tr.measured[2:4, :p0].any(axis=0)
    assert back[band].mean() > 0.5  # re-acquired, same trajectory
    bridged = tr.alive[2:4, :p0][:, back].all(axis=0)
    assert bridged.mean() > 0.9  # and bridged through the gap
    assert not tr.measured[2:4, :p0][:, back].any()  # flagged as not measured there
    err = np.linalg.norm(tr.xyz[:, :p0][:, back] - truth[:, back], axis=2)
    assert np.median(err[4]) < 0.001 and np.median(err[2:4, bridged]) < 0.002


def test_neighbour_motion_follows_the_neighbours_that_moved_with_the_point(rng):
    M = 600  # two parts passing each other (two legs)
    then = rng.uniform(-0.05, 0.05, (M, 3))
    part = rng.random(M) < 0.5
    step = np.where(part[:, None], [0.02, 0.0, 0.0], [0.0, -0.03, 0.01])  # m/frame
    now = then + step
    query = rng.uniform(-0.03, 0.03, (20, 3))
    q_rate = np.tile([0.02, 0.0, 0.0], (20, 1)) + rng.normal(0, 0.002, (20, 3))
    xyz, _, ok = neighbour_motion(then, now, query, rate_then=step, query_rate=q_rate)
    assert ok.all()
    assert np.allclose(xyz, query + [0.02, 0.0, 0.0], atol=1e-6)
    mixed, _, _ = neighbour_motion(then, now, query)  # without rates: either part
    assert np.mean(np.linalg.norm(mixed - (query + [0.02, 0.0, 0.0]), axis=1) > 0.005) > 0.2


def test_unmeasured_points_are_carried_by_their_neighbours_over_two_frames(rng):
    # a rigid patch (points 1 cm apart) turning and sliding; 40 points unmeasured in
    # frames 1 and 2 are carried from frame 0 through frame 1's prediction to frame 2
    s = np.arange(-0.1, 0.1001, 0.01)
    x, z = np.meshgrid(s, s)
    p0 = np.stack([x.ravel(), 0.02 * np.sin(8 * x.ravel()), z.ravel()], axis=1)
    R, t = rodrigues_to_matrix([0.02, -0.03, 0.04]), np.array([0.01, -0.004, 0.006])
    truth = [p0, p0 @ R.T + t, (p0 @ R.T + t) @ R.T + t]
    hide = np.zeros(len(p0), bool)
    hide[rng.choice(len(p0), 40, replace=False)] = True
    rate0 = truth[1] - truth[0]
    xyz_hist = [truth[0].copy()]
    pred_hist = [np.full_like(p0, np.nan)]
    for f in (1, 2):
        meas = np.where(hide[:, None], np.nan, truth[f] + rng.normal(0, 2e-4, p0.shape))
        rate = rate0 if f == 1 else np.where(hide[:, None], np.nan, rate0)
        pred = predict_unmeasured(hide, xyz_hist, pred_hist, rate, meas, ~hide)
        assert np.all(np.isnan(pred[~hide]))
        assert np.max(np.linalg.norm(pred[hide] - truth[f][hide], axis=1)) < 0.002
        xyz_hist.append(meas)
        pred_hist.append(pred)


def test_a_point_hidden_for_a_frame_coasts_on_its_neighbours_and_continues():
    # the plane changes velocity at frame 2, where a band of it is hidden: the hidden
    # points coast on their neighbours' motion (not on their own old velocity), are
    # measured again at frame 3 and their frame 2 is bridged from that prediction
    cams = cameras()
    m1, m2 = np.array([0.004, 0.0, -0.003]), np.array([-0.002, 0.0, 0.004])
    offs = [np.zeros(3), m1, m1 + m2, m1 + 2 * m2]
    frames = [
        [(_band_occluded(c, o, (0.0, 0.05)) if k == 2 else render(c, o)) for c in cams]
        for k, o in enumerate(offs)
    ]
    seeds = np.stack([c.project(np.array([[0.0, 0.0, 0.0]])) for c in cams], 1)
    surf = measure_surface(frames[0], cams, seeds, step=6)
    p0 = len(surf)
    truth = surf.xyz[None] + np.array(offs)[:, None]
    log: list = []
    tr = track(lambda i: frames[i], cams, surf, 4, 25.0, regen_every=0, max_coast=2, log=log)
    hidden = tr.measured[[0, 1, 3], :p0].all(axis=0) & ~tr.measured[2, :p0]
    band = (surf.xyz[:, 0] > 0.005) & (surf.xyz[:, 0] < 0.045)
    assert hidden[band].mean() > 0.8  # the same trajectories go on
    assert log[1]["coast_predicted"] >= 0.8 * hidden.sum()
    err = np.linalg.norm(tr.xyz[2, :p0][hidden] - truth[2, hidden], axis=1)
    assert np.median(err) < 0.001  # their own velocity: 6 mm off
    err3 = np.linalg.norm(tr.xyz[3, :p0][hidden] - truth[3, hidden], axis=1)
    assert np.median(err3) < 0.001
