"""The fit-spread benchmark's click perturbation and its summary."""

import numpy as np
import pytest

from bench.fit_spread import fit_once, parse_settings, perturbed_clicks, summary
from core.landmarks import CLICK_JOINTS

SCENE = "sample_scenes/walk_line3"


def _clicks(n=200):
    rng = np.random.default_rng(7)
    return {
        "frame": 3,
        "joints": {
            f"j{k}": {"cam01": rng.uniform(0, 500, 2), "cam02": rng.uniform(0, 500, 2)}
            for k in range(n)
        },
    }


def test_run_zero_and_zero_noise_keep_the_clicks():
    c = _clicks()
    assert perturbed_clicks(c, 0.5, 0) is c
    assert perturbed_clicks(c, 0.0, 3) is c


def test_clicks_move_by_the_noise_and_repeat_per_seed():
    c = _clicks()
    before = {j: {k: v.copy() for k, v in p.items()} for j, p in c["joints"].items()}
    a, b, other = (perturbed_clicks(c, 0.5, s) for s in (1, 1, 2))
    d = np.array(
        [a["joints"][j][k] - c["joints"][j][k] for j in c["joints"] for k in c["joints"][j]]
    )
    assert d.std() == pytest.approx(0.5, rel=0.1)
    assert abs(d.mean()) < 0.05
    assert a["frame"] == 3
    assert all(
        np.array_equal(a["joints"][j][k], b["joints"][j][k])
        for j in a["joints"]
        for k in a["joints"][j]
    )
    assert not np.array_equal(a["joints"]["j0"]["cam01"], other["joints"]["j0"]["cam01"])
    # the input is not touched
    assert all(
        np.array_equal(before[j][k], c["joints"][j][k]) for j in c["joints"] for k in c["joints"][j]
    )


def test_clicking_the_toes_too_leaves_the_other_joints_moves_as_they_were():
    """Runs with and without the optional joints are paired: theirs are drawn last."""
    rng = np.random.default_rng(3)
    c = {"frame": 0, "joints": {j: {"cam01": rng.uniform(0, 500, 2)} for j in CLICK_JOINTS}}
    with_toes = {
        **c,
        "joints": {**c["joints"], "l_toe": {"cam01": np.zeros(2)}, "r_toe": {"cam01": np.ones(2)}},
    }
    a, b = perturbed_clicks(c, 0.5, 4), perturbed_clicks(with_toes, 0.5, 4)
    for j in c["joints"]:
        for k in c["joints"][j]:
            np.testing.assert_array_equal(a["joints"][j][k], b["joints"][j][k])
    assert not np.array_equal(b["joints"]["l_toe"]["cam01"], np.zeros(2))


def test_the_fit_initialises_from_the_perturbed_clicks(monkeypatch):
    """fit_once hands the perturbed clicks to the pipeline (which reads Scene.clicks())."""
    seen = {}

    class Stop(Exception):
        pass

    def fake_run_scene(scene, **kw):
        seen["clicks"] = scene.clicks()
        raise Stop

    import core.fit_scene

    monkeypatch.setattr(core.fit_scene, "run_scene", fake_run_scene)
    from core.scene import load_scene

    orig = load_scene(SCENE, check_images=False).clicks()
    with pytest.raises(Stop):
        fit_once(SCENE, "unused.npz", "both", 0.5, 4)
    want = perturbed_clicks(orig, 0.5, 4)
    for j, per_cam in want["joints"].items():
        for cam, uv in per_cam.items():
            np.testing.assert_array_equal(seen["clicks"]["joints"][j][cam], uv)
            assert not np.array_equal(uv, orig["joints"][j][cam])


def test_summary_median_and_range():
    rows = [
        {"mpjpe_mm": m, "accel_mm": m / 4, "per_joint_mm": {"a": m, "b": 2 * m}}
        for m in (14.0, 12.0, 17.0)
    ]
    s = summary(rows)
    assert (s["mpjpe_median_mm"], s["mpjpe_min_mm"], s["mpjpe_max_mm"]) == (14.0, 12.0, 17.0)
    assert s["accel_median_mm"] == 3.5
    assert s["per_joint"]["b"] == (28.0, 24.0, 34.0)


def test_settings_are_sequence_settings_fields_in_json():
    def error(msg):
        raise ValueError(msg)

    assert parse_settings(["shape_scales=true", "sigma_pred=0.2", 'shape="template"'], error) == {
        "shape_scales": True,
        "sigma_pred": 0.2,
        "shape": "template",
    }
    with pytest.raises(ValueError, match="SequenceSettings field"):
        parse_settings(["no_such_field=1"], error)
    with pytest.raises(ValueError, match="not JSON"):
        parse_settings(["shape_scales=yes"], error)
    with pytest.raises(ValueError, match="only a number"):
        parse_settings(['fit={"max_nfev": 3}'], error)


def test_flow_settings_are_flow_settings_fields_a_tuple_from_a_list():
    from core.fit_flow import FlowSettings

    def error(msg):
        raise ValueError(msg)

    got = parse_settings(
        ["reference=false", 'reference_parts=["pelvis", "spine"]'], error, FlowSettings, "--flow"
    )
    assert got == {"reference": False, "reference_parts": ("pelvis", "spine")}
    FlowSettings(**got)
    with pytest.raises(ValueError, match="--flow 'sigma=1': expected NAME=VALUE with NAME a Flow"):
        parse_settings(["sigma=1"], error, FlowSettings, "--flow")
    with pytest.raises(ValueError, match="only a number"):
        parse_settings(["sigma_px=[1, 2]"], error, FlowSettings, "--flow")


def test_the_flow_settings_reach_the_pipeline(monkeypatch):
    seen = {}

    class Stop(Exception):
        pass

    def fake_run_scene(scene, **kw):
        seen.update(kw)
        raise Stop

    import core.fit_scene

    monkeypatch.setattr(core.fit_scene, "run_scene", fake_run_scene)
    with pytest.raises(Stop):
        fit_once(SCENE, "unused.npz", "both", 0.5, 0, 3.0, flow={"reference": False})
    assert seen["flow"].sigma_px == 3.0 and seen["flow"].reference is False
    with pytest.raises(Stop):
        fit_once(SCENE, "unused.npz", "both", 0.5, 0)
    assert seen["flow"] == "auto"


def test_the_shape_settings_reach_the_pipeline_and_the_states_are_written(monkeypatch, tmp_path):
    from core.shape_fit import ShapeSettings

    def error(msg):
        raise ValueError(msg)

    shape = parse_settings(["sigma_one_sided=0"], error, ShapeSettings, "--shape")
    assert shape == {"sigma_one_sided": 0}
    with pytest.raises(ValueError, match="--shape 'sigma=1': expected NAME=VALUE"):
        parse_settings(["sigma=1"], error, ShapeSettings, "--shape")
    seen = {}

    def fake_run_scene(scene, **kw):
        seen.update(kw)
        return _StateOnly(truth_to_state(scene.truth, scene.fps)[0])

    import core.fit_scene
    from core.truth_state import truth_to_state

    monkeypatch.setattr(core.fit_scene, "run_scene", fake_run_scene)
    row = fit_once(SCENE, "unused.npz", "both", 0.5, 2, shape=shape, states=str(tmp_path / "s"))
    assert seen["settings"].shape_fit.sigma_one_sided == 0
    assert (tmp_path / "s" / "run2.json").is_file()
    assert np.isfinite(row["surface_mm"]) and np.isnan(row["visibility"])
    # the truth's own state against its mesh: the template's shape, a small but real |ΔVI|
    row = fit_once(SCENE, "unused.npz", "both", 0.5, 0, visibility=True)
    assert 0.0 < row["visibility"] < 0.15


def test_the_contour_settings_reach_the_pipeline(monkeypatch):
    from core.fit_contours import ContourSettings

    def error(msg):
        raise ValueError(msg)

    contour = parse_settings(['shape_held_parts=["head"]'], error, ContourSettings, "--contour")
    assert contour == {"shape_held_parts": ("head",)}
    seen = {}

    def fake_run_scene(scene, **kw):
        seen.update(kw)
        return _StateOnly(truth_to_state(scene.truth, scene.fps)[0])

    import core.fit_scene
    from core.truth_state import truth_to_state

    monkeypatch.setattr(core.fit_scene, "run_scene", fake_run_scene)
    fit_once(SCENE, "unused.npz", "both", 0.5, 1, contour=contour)
    assert seen["contour_settings"].shape_held_parts == ("head",)
    fit_once(SCENE, "unused.npz", "both", 0.5, 1)
    assert seen["contour_settings"] is None


class _StateOnly:
    """What fit_once reads of run_scene's result."""

    def __init__(self, state):
        self.state = state


def test_dragged_clicks_move_only_the_depth_onto_the_truth():
    """A knee clicked 2 px apart in the outer cameras: its intersection is off in depth;
    dragged, it moves along its long axis only, to where no error is left along it, and
    the other joints' clicks stay as they were."""
    from pathlib import Path

    from bench.fit_spread import dragged_clicks
    from core.evaluate import truth_joints
    from core.fit_init import triangulate_clicks
    from core.scene import load_scene

    sc = load_scene(Path(SCENE), check_images=False)
    if not sc.has_truth:
        pytest.skip("default scene without truth")
    cams = sc.calibration()
    c = sc.clicks()
    views = sorted(c["joints"]["l_knee"])  # the outer cameras moved apart: depth
    shift = dict(zip(views, np.linspace(2.0, -2.0, len(views)), strict=True))
    c["joints"]["l_knee"] = {
        k: np.asarray(v) + [shift[k], 0.0] for k, v in c["joints"]["l_knee"].items()
    }
    d = dragged_clicks(c, cams, sc.truth, ["l_knee"])
    before, after = triangulate_clicks(c, cams), triangulate_clicks(d, cams)
    txyz, names = truth_joints(sc.truth)
    t = txyz[c["frame"], names.index("l_knee")]
    k = before.names.index("l_knee")
    axis = np.linalg.eigh(before.cov[k])[1][:, 2]
    moved = after.xyz[k] - before.xyz[k]
    assert np.linalg.norm(np.cross(moved, axis)) < 1e-4  # along the long axis only
    assert abs((after.xyz[k] - t) @ axis) < 1e-4  # no error left along it
    assert abs((before.xyz[k] - t) @ axis) > 0.003
    for j in c["joints"]:
        if j != "l_knee":
            assert d["joints"][j] == c["joints"][j]


def test_a_scene_that_is_not_there_is_one_clear_error(tmp_path, capsys):
    from bench.fit_spread import main

    with pytest.raises(SystemExit):
        main([str(tmp_path / "pirouette_ortho3"), "--runs", "1"])
    err = capsys.readouterr().err
    assert "pirouette_ortho3: no such scene folder, nor a studio scene (walk_ortho3" in err
    assert not (tmp_path / "pirouette_ortho3").exists()  # nothing tracked or created


def test_other_tracks_must_exist(tmp_path, capsys):
    from bench.fit_spread import main

    with pytest.raises(SystemExit):
        main([SCENE, "--tracks", str(tmp_path / "none.npz"), "--runs", "1"])
    assert "none.npz: no such file" in capsys.readouterr().err
