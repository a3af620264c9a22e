"""The metaball radii from several frames' silhouettes, on the model's own renders."""

from pathlib import Path

import numpy as np
import pytest

from core.contour_obs import body_ellipsoids
from core.contour_shape_frames import fit_shape_to_frames
from core.contour_track import ContourTrackSettings, fit_shape_to_contours
from core.model_render import render_parts
from tests.core.test_contour_track import _contours, _swing, rig  # noqa: F401


def _truth(balls):
    """The template with every other metaball 12 % larger and the rest 10 % smaller."""
    return balls.copy(radii=balls.radii * np.where(np.arange(len(balls)) % 2, 1.12, 0.9)[:, None])


def _iou(skel, s, cams, theta, root, body, truth):
    """Mean silhouette IoU of ``body`` against ``truth``, both at the given poses."""
    out = []
    for th, rt in zip(theta, root, strict=True):
        for cam in cams:
            a = render_parts(cam, *body_ellipsoids(skel, th, rt, s, body)).mask
            b = render_parts(cam, *body_ellipsoids(skel, th, rt, s, truth)).mask
            out.append((a & b).sum() / (a | b).sum())
    return float(np.mean(out))


def test_several_frames_shape_the_frames_they_did_not_see_better_than_one(rig):  # noqa: F811
    skel, balls, s, cams = rig
    theta, root = _swing(skel, 8)
    truth = _truth(balls)
    frames, unseen = [0, 3, 5, 7], [1, 2, 4, 6]
    observed = [_contours(skel, theta[f], root[f], s, truth, cams) for f in frames]
    rng = np.random.default_rng(3)  # the poses as a first pass fitted them
    th0 = theta[frames] + rng.normal(0, 0.02, (len(frames), skel.n_dof))
    one, *_ = fit_shape_to_contours(
        skel, s, balls, th0[0], root[0], cams, observed[0], ContourTrackSettings(q_sigma_theta=0.1)
    )
    fitted, th, rt, rms = fit_shape_to_frames(skel, s, balls, th0, root[frames], cams, observed)
    iou = {
        name: _iou(skel, s, cams, theta[unseen], root[unseen], body, truth)
        for name, body in (("template", balls), ("one", one), ("four", fitted))
    }
    # measured: 0.893 (the template), 0.963 (frame 0's silhouettes), 0.967 (four frames')
    assert iou["four"] > iou["one"] + 0.002 > iou["template"] + 0.05
    assert (
        np.abs(fitted.radii - truth.radii).mean() < 0.8 * np.abs(balls.radii - truth.radii).mean()
    )
    assert rms < 1.0
    assert np.abs(th - theta[frames]).mean() < 0.03  # 0.016 rad at the start
    assert np.abs(rt - root[frames]).max() < 0.01
    assert np.array_equal(fitted.center0, balls.center0)


def test_frames_without_contours_keep_their_pose_and_nothing_else_moves(rig):  # noqa: F811
    skel, balls, s, cams = rig
    theta, root = _swing(skel, 2)
    empty = [[] for _ in cams]
    fitted, th, rt, rms = fit_shape_to_frames(skel, s, balls, theta, root, cams, [empty, empty])
    assert np.isnan(rms)
    assert np.array_equal(fitted.radii, balls.radii)
    assert np.array_equal(th, theta) and np.array_equal(rt, root)


@pytest.mark.slow
def test_core_fit_shape_frames_fits_the_take_again_with_the_shape_of_several(tmp_path, capsys):
    """``core fit --cues contours`` on a rig whose views lie 90° apart: the silhouettes
    shape the body at the clicked frame, the radii are solved again over five fitted
    frames by default (``--shape-frames``), and the take is fitted again with them, said
    so; finite output.  ``--shape-frames 0`` and ``--one-pass`` fit once."""
    from core.cli import main
    from core.state import read_state
    from tests.core._bodyscene import look_at
    from tests.core.test_fit_contours_sequence import _silhouette_scene

    wide = [
        look_at(n, p)
        for n, p in (("cam01", (0, -4, 1.2)), ("cam02", (4, 0, 1.2)), ("cam03", (-3, -3, 1.2)))
    ]
    _silhouette_scene(tmp_path, cams=wide)
    argv = ["fit", str(tmp_path), "--cues", "contours", "--model", "simplified"]
    assert main(argv) == 0
    out = capsys.readouterr().out
    line = next(ln for ln in out.splitlines() if "shape re-solved over frames" in ln)
    picked = [int(v) for v in line.split("frames [")[1].split("]")[0].split(",")]
    # five of the six frames (those not diverged), spread over the take
    assert len(picked) == 5 and picked[0] == 0 and picked[-1] == 5
    assert "the motion fitted again with it" in line
    st = read_state(tmp_path / "fit.json")
    for arr in (st.theta, st.root_xyz, st.metaballs.radii):
        assert np.all(np.isfinite(arr))
    assert st.quality.diverged.sum() <= 1
    # off, and a one-pass fit keeps one pass
    assert main([*argv, "--shape-frames", "0", "-o", str(tmp_path / "z.json")]) == 0
    out = capsys.readouterr().out
    assert "shape re-solved" not in out
    assert main([*argv, "--one-pass", "-o", str(tmp_path / "o.json")]) == 0
    assert "shape re-solved" not in capsys.readouterr().out


def test_core_fit_shape_frames_needs_two_frames_at_least(tmp_path, capsys):
    from core.cli import main

    scene = Path(__file__).resolve().parents[2] / "sample_scenes" / "walk_line3"
    assert main(["fit", str(scene), "--shape-frames", "1", "-o", str(tmp_path / "f.json")]) == 2
    err = capsys.readouterr().err
    assert "--shape-frames must be 0 (off) or at least 2" in err
    assert not (tmp_path / "f.json").exists()


def test_the_views_spread_tells_a_rig_in_a_line_from_an_orthogonal_one():
    from core.fit_passes import views_spread_deg
    from tests.core._bodyscene import cameras, look_at

    body = np.array([0.0, 0.0, 1.0])
    assert views_spread_deg(cameras(), body) == pytest.approx(41.1, abs=0.1)
    wide = [look_at("a", (0, -4, 1.0)), look_at("b", (4, 0, 1.0))]
    assert views_spread_deg(wide, body) == pytest.approx(90.0)
