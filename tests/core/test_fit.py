"""Fitting across frames: prediction, per-frame quality, diverged frames marked."""

import numpy as np
import pytest

from core import metaballs as mb
from core import skeleton as sk
from core.fit import FramePoints, SequenceSettings, fit_sequence
from core.fit_init import initialise
from core.fitting import FitSettings
from core.landmarks import CLICK_JOINTS, METRIC_JOINTS
from tests.core._bodyscene import cameras, clicks_of, model_points


@pytest.mark.slow
def test_sequence_follows_the_motion_and_marks_a_frame_without_points(rng):
    skel = sk.make_skeleton()
    s = np.ones(skel.n_groups)
    balls = mb.make_metaballs(skel, "simplified", s)
    nf = 4
    theta = np.zeros((nf, skel.n_dof))
    for k, name in enumerate(("l_shoulder_y", "r_elbow_x", "l_knee_x")):
        theta[:, skel.dof_index(name)] = np.linspace(0.1, 0.4, nf) * (-1 if k == 1 else 1)
    root = np.array([[0.0, 0.03 * f, 1.0] for f in range(nf)])
    frames = []
    for f in range(nf):
        xyz, _ = model_points(skel, balls, theta[f], root[f], s, rng, per_bone=40)
        pose = sk.forward(skel, theta[f][None], root[f][None], s)
        Rw, cw = mb.world_frames(skel, pose, balls, s)
        xyz = xyz[mb.field(xyz, Rw[0], cw[0], balls.radii)[0] < 0.7]  # the outer surface
        xyz = xyz + rng.normal(0, 0.001, xyz.shape)
        frames.append(FramePoints(xyz=xyz, sigma=0.001))
    frames[2] = FramePoints(xyz=frames[2].xyz[:5], sigma=0.001)  # almost nothing seen
    cams = cameras()
    init = initialise(clicks_of(skel, theta[0], root[0], s, cams, CLICK_JOINTS), cams,
                      model="simplified")
    cfg = SequenceSettings(max_nfev=15, max_nfev_shape=15,
                           fit=FitSettings(members="part"))
    res = fit_sequence(frames, init, cfg)
    st = res.state
    q = st.quality
    assert q.diverged.tolist() == [False, False, True, False]
    assert any("frame 2" in m for m in res.messages)
    for arr in (st.theta, st.root_xyz, st.s, st.metaballs.radii):
        assert np.all(np.isfinite(arr))
    idx = [st.skeleton.joint_index(j) for j in METRIC_JOINTS]
    fit_x = st.joints_xyz()[:, idx]
    true_x = sk.joint_positions(skel, theta, root, s)[:, idx]
    err = np.linalg.norm(fit_x - true_x, axis=-1)
    assert err[[0, 1, 3]].mean() < 0.02, err.mean(axis=1)
    assert np.all(np.isfinite(q.rmse_m[[0, 1, 3]])) and np.isnan(q.rmse_m[2])
    assert np.all(np.isfinite(q.theta_sigma[[0, 1, 3]]))
