"""Two fits of one take, kept by the foregrounds (core/fit_choice.py)."""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from core import metaballs as mb
from core import skeleton as sk
from core.contour_obs import body_ellipsoids
from core.fit_choice import choose, foreground_disagreement
from core.model_render import render_parts
from core.silhouette_search import mask_grid
from core.state import FitState, Quality
from tests.core._bodyscene import cameras


class _Frame:
    """The part of a contour frame the choice reads: the foregrounds' grids."""

    def __init__(self, masks):
        self._grids = [mask_grid(m) for m in masks]

    def grids(self):
        return self._grids


@pytest.fixture
def take():
    """Three frames of a walking step (the left knee bending) seen by three cameras, the
    foregrounds rendered exactly from the true pose."""
    skel = sk.make_skeleton()
    s = np.ones(skel.n_groups)
    balls = mb.make_metaballs(skel, "simplified", s)
    theta = np.zeros((3, skel.n_dof))
    theta[:, skel.dof_index("l_knee_x")] = [0.2, 0.5, 0.8]
    theta[:, skel.dof_index("r_shoulder_x")] = [-0.3, -0.2, -0.1]
    root = np.tile([0.0, 0.0, 1.0], (3, 1))
    cams = cameras()
    frames = []
    for f in range(3):
        c, a, r, p = body_ellipsoids(skel, theta[f], root[f], s, balls)
        frames.append(_Frame([render_parts(cam, c, a, r, p).mask for cam in cams]))
    state = FitState(skel, s, balls, root, theta, Quality.empty(3, skel.n_dof))
    return state, cams, frames


def test_the_true_take_disagrees_nowhere_and_a_lost_shin_everywhere_it_is_seen(take):
    state, cams, frames = take
    truth = foreground_disagreement(state, cams, frames)
    assert truth.shape == (3,)
    fg = np.array([sum(g.fg.sum() * g.step**2 for g in f.grids()) for f in frames])
    assert np.all(truth < 0.01 * fg), (truth, fg)  # edge pixels of the 2 px grid only
    lost = state.theta.copy()
    lost[1:, state.skeleton.dof_index("l_knee_x")] = 2.6  # the heel at the buttock
    folded = foreground_disagreement(replace(state, theta=lost), cams, frames)
    assert folded[0] == truth[0]
    assert np.all(folded[1:] > truth[1:] + 1500), folded


def test_the_fit_that_keeps_its_limbs_is_chosen(take):
    state, cams, frames = take
    lost = state.theta.copy()
    lost[1:, state.skeleton.dof_index("l_knee_x")] = 2.6
    folded = replace(state, theta=lost)
    best, totals = choose([folded, state], cams, frames)
    assert best == 1 and totals[0] > totals[1]
    assert choose([state, folded], cams, frames)[0] == 0


def test_a_frame_without_a_pose_counts_all_its_foreground_and_fewer_diverged_frames_win(take):
    state, cams, frames = take
    theta = state.theta.copy()
    theta[2] = np.nan
    blank = replace(state, theta=theta)
    d = foreground_disagreement(blank, cams, frames)
    fg = sum(g.fg.sum() * g.step**2 for g in frames[2].grids())
    assert d[2] == fg and np.isfinite(d).all()
    diverged = replace(state, quality=Quality.empty(3, state.skeleton.n_dof))
    diverged.quality.diverged[1] = True
    lost = state.theta.copy()
    lost[1:, state.skeleton.dof_index("r_elbow_x")] = -2.4
    worse = replace(state, theta=lost)
    # the folded arm disagrees more, but the other fit gave up on a frame
    best, totals = choose([diverged, worse], cams, frames)
    assert totals[1] > totals[0] and best == 1
    with pytest.raises(ValueError):
        choose([], cams, frames)


@pytest.fixture
def fake_passes(monkeypatch):
    """core.fit_passes's passes replaced: each call records whether its flow corners are
    refined and returns the clicked posture held over the take, the left knee folded
    from frame 1 on in the fit with Lucas–Kanade's corners."""
    import core.fit_passes as fp
    from core.fit_types import SequenceResult

    calls = []

    def passes(cframes, anchors, kw, timings, t_start, *, obs, init, **_):
        refined = anchors.cfg.refine_lsm
        calls.append(refined)
        nf = len(obs)
        theta = np.tile(init.theta, (nf, 1))
        if not refined:
            theta[1:, init.skeleton.dof_index("l_knee_x")] = 2.6
        root = np.tile(init.root_xyz, (nf, 1))
        st = FitState(
            init.skeleton, init.s, init.metaballs, root, theta, Quality.empty(nf, len(init.theta))
        )
        z = np.zeros(nf)
        return SequenceResult(st, z, z, z, np.zeros(nf, bool), [f"fit {len(calls)}"], 0.0)

    monkeypatch.setattr(fp, "run_passes", passes)
    return calls


def test_a_take_the_silhouettes_shaped_is_fitted_twice_and_the_better_fit_kept(fake_passes):
    from core.fit_flow import FlowSettings
    from core.fit_passes import choose_refined
    from core.fit_scene import run_scene
    from core.fit_types import SequenceSettings
    from core.scene import load_scene

    scene = load_scene(Path(__file__).resolve().parents[2] / "sample_scenes" / "walk_line3")
    res = run_scene(scene, frames=3, cues="contours", flow=FlowSettings())
    assert fake_passes == [False, True]
    assert res.messages[-2] == "fit 2"  # the refined fit's own messages, then the choice
    assert "the fit with LSM-refined corners kept" in res.messages[-1]
    knee = res.state.skeleton.dof_index("l_knee_x")
    assert np.all(res.state.theta[:, knee] < 2.0)
    assert "refined_alternative" in res.timings

    # one fit where the choice is off, or where the corners are refined anyway
    on, off = SequenceSettings(), SequenceSettings(flow_choice=False)
    assert choose_refined(on, FlowSettings())
    assert not choose_refined(off, FlowSettings())
    assert not choose_refined(on, FlowSettings(refine_lsm=True))


def test_cli_one_flow_fits_once(monkeypatch):
    """``python -m core fit SCENE --one-flow`` asks for one fit; by default the fit
    chooses."""
    import core.fit_scene
    from core.cli import main

    seen = []

    class Stop(Exception):
        pass

    def fake_run_scene(scene, settings=None, **kw):
        seen.append(settings.flow_choice)
        raise Stop

    monkeypatch.setattr(core.fit_scene, "run_scene", fake_run_scene)
    scene = str(Path(__file__).resolve().parents[2] / "sample_scenes" / "walk_line3")
    for argv in (["--cues", "both", "--one-flow"], ["--cues", "both"]):
        with pytest.raises(Stop):
            main(["fit", scene, *argv])
    assert seen == [False, True]
