"""The fit's cue choice (texture / contours / both) and its opt-in feet from points
(``SequenceSettings(foot_heading=True)``) from the pipeline, CLI, panel and operator
down to core's ``fit_scene``; core's fit is replaced by a recorder (seconds)."""

from __future__ import annotations

import inspect
from dataclasses import replace

import numpy as np
import pytest

from core.calibration_io import write_calibration
from core.camera import Camera, rodrigues_to_matrix
from core.errors import InputError
from core.state import write_state

from .state_fixtures import synthetic_state

pytestmark = [pytest.mark.blender]

CUES = ("texture", "contours", "both")


def make_scene(root, with_fit=False):
    """A scene folder with a 2-camera calibration (and a fit.json of 3 frames)."""
    root.mkdir(parents=True)
    cams = [
        Camera(
            f"cam{i}",
            (64, 48),
            [[80, 0, 32], [0, 80, 24], [0, 0, 1]],
            np.zeros(5),
            rodrigues_to_matrix([1.6, 0, 0.5 * i]),
            [0, -1, 5],
        )
        for i in range(2)
    ]
    write_calibration(root / "calibration.toml", cams)
    (root / "scene.toml").write_text("# stand-in: core's fit is replaced in these tests\n")
    if with_fit:
        write_state(root / "fit.json", synthetic_state(3, seed=3))
    return root


@pytest.fixture
def fake_run_fit(bpy_module, monkeypatch):
    """Replace ``addon.pipeline.run_fit``: record ``(scene, cues)`` (``(scene, cues,
    "feet")`` with feet from points), write a 4-frame state."""
    from addon import pipeline

    calls = []

    def run_fit(
        scene_dir, out_json, progress=None, cues="texture", clicks_xyz=None, feet_from_points=False
    ):
        calls.append((scene_dir.name, cues, "feet") if feet_from_points else (scene_dir.name, cues))
        write_state(out_json, synthetic_state(4, seed=len(calls)))
        return out_json

    monkeypatch.setattr(pipeline, "run_fit", run_fit)
    return calls


def test_cue_names_match_core():
    from addon import pipeline
    from core import fit_scene

    assert tuple(pipeline.FIT_CUES) == fit_scene.CUES
    assert "cues" in inspect.signature(fit_scene.run_scene).parameters
    assert all(len(v) > 20 for v in pipeline.FIT_CUES.values())


@pytest.mark.parametrize("cues", CUES)
def test_run_fit_forwards_cues_to_core(bpy_module, tmp_path, monkeypatch, cues):
    from addon import pipeline
    from core import fit_scene, scene

    seen = {}

    def fake_fit_scene(sc, progress=None, **kwargs):
        seen.update(kwargs, scene=sc, progress=progress)
        return synthetic_state(5, seed=11)

    monkeypatch.setattr(scene, "load_scene", lambda path, **kw: ("scene", path))
    monkeypatch.setattr(fit_scene, "fit_scene", fake_fit_scene)
    out = pipeline.run_fit(tmp_path / "sc", tmp_path / "fit.json", "P", cues=cues)
    assert seen == {"cues": cues, "scene": ("scene", tmp_path / "sc"), "progress": "P"}
    assert pipeline.read_state(out).n_frames == 5


def test_run_fit_rejects_unknown_cues_before_fitting(bpy_module, tmp_path, monkeypatch):
    from addon import pipeline
    from core import fit_scene

    monkeypatch.setattr(fit_scene, "fit_scene", lambda *a, **k: pytest.fail("fit ran"))
    with pytest.raises(
        InputError, match="unknown fit cues 'skin': choose one of texture, contours, both"
    ):
        pipeline.run_fit(tmp_path, tmp_path / "fit.json", cues="skin")
    assert not (tmp_path / "fit.json").exists()


@pytest.fixture
def fake_fit_scene(bpy_module, monkeypatch):
    """Replace core's scene loading and ``fit_scene``: record each call's keywords."""
    from core import fit_scene, scene

    calls = []

    def fit(sc, progress=None, **kwargs):
        calls.append(kwargs)
        return synthetic_state(5, seed=11)

    monkeypatch.setattr(scene, "load_scene", lambda path, **kw: ("scene", path))
    monkeypatch.setattr(fit_scene, "fit_scene", fit)
    return calls


@pytest.mark.parametrize("cues", CUES)
def test_run_fit_feet_from_points_passes_foot_heading(tmp_path, fake_fit_scene, cues):
    from addon import pipeline
    from core.fit import SequenceSettings

    out = pipeline.run_fit(tmp_path / "sc", tmp_path / "fit.json", cues=cues, feet_from_points=True)
    assert pipeline.read_state(out).n_frames == 5
    (kw,) = fake_fit_scene
    assert set(kw) == {"cues", "settings"} and kw["cues"] == cues
    assert isinstance(kw["settings"], SequenceSettings)
    assert kw["settings"].foot_heading is True
    # core's defaults otherwise, as `core fit --feet-from-points` leaves the rest
    assert kw["settings"] == replace(SequenceSettings(), foot_heading=True)
    assert SequenceSettings().foot_heading is False  # off is core's default


def test_run_fit_without_feet_from_points_passes_no_settings(tmp_path, fake_fit_scene):
    from addon import pipeline

    pipeline.run_fit(tmp_path / "sc", tmp_path / "a.json")
    pipeline.run_fit(tmp_path / "sc", tmp_path / "b.json", cues="both", feet_from_points=False)
    assert fake_fit_scene == [{"cues": "texture"}, {"cues": "both"}]  # core's own default


def test_state_for_scene_feet_from_points_refits_down_to_core(tmp_path, fake_fit_scene):
    """A scene with a fit.json: asked for feet from points, the state is a new fit with
    ``foot_heading`` on (through the real run_fit), and fit.json is left as it is."""
    from addon import pipeline

    scene = make_scene(tmp_path / "walk", with_fit=True)
    before = (scene / "fit.json").read_bytes()
    assert pipeline.state_for_scene(scene).n_frames == 3  # cached
    assert fake_fit_scene == []
    assert pipeline.state_for_scene(scene, cues="both", feet_from_points=True).n_frames == 5
    (kw,) = fake_fit_scene
    assert kw["cues"] == "both" and kw["settings"].foot_heading is True
    assert (scene / "fit.json").read_bytes() == before  # not overwritten
    # an explicit fitted state still wins, as it does over refit
    assert pipeline.state_for_scene(scene, scene / "fit.json", feet_from_points=True).n_frames == 3
    assert len(fake_fit_scene) == 1


def test_state_for_scene_feet_from_points_not_cached(tmp_path, fake_run_fit):
    from addon import pipeline

    scene = make_scene(tmp_path / "walk", with_fit=True)
    before = (scene / "fit.json").read_bytes()
    assert pipeline.state_for_scene(scene, feet_from_points=True).n_frames == 4
    assert fake_run_fit == [("walk", "texture", "feet")]
    assert (scene / "fit.json").read_bytes() == before


def test_state_for_scene_cached_unless_refit(tmp_path, fake_run_fit):
    from addon import pipeline

    scene = make_scene(tmp_path / "walk", with_fit=True)
    before = (scene / "fit.json").read_bytes()
    assert pipeline.state_for_scene(scene, cues="both").n_frames == 3  # the cached fit
    assert fake_run_fit == []
    assert pipeline.state_for_scene(scene, cues="both", refit=True).n_frames == 4
    assert fake_run_fit == [("walk", "both")]
    assert (scene / "fit.json").read_bytes() == before  # not overwritten


def cli(argv):
    from addon.cli_command import main

    return main([str(a) for a in argv])


def test_cli_fit_cues(tmp_path, fake_run_fit, empty_blend, capsys):
    scene = make_scene(tmp_path / "walk", with_fit=True)
    assert cli(["fit", scene, "--out", tmp_path / "a.blend"]) == 0  # no --cues: cached
    assert fake_run_fit == []
    assert cli(["fit", scene, "--out", tmp_path / "b.blend", "--cues", "contours"]) == 0
    assert fake_run_fit == [("walk", "contours")]
    assert (tmp_path / "b.blend").stat().st_size > 1000
    assert "walk: 4 frames" in capsys.readouterr().out  # the new fit was built

    assert (
        cli(
            [
                "fit",
                scene,
                "--out",
                tmp_path / "c.blend",
                "--cues",
                "both",
                "--fit",
                scene / "fit.json",
            ]
        )
        == 2
    )
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err == (
        f"somacap: error: {scene / 'fit.json'}: --fit uses a fitted state and "
        "--cues asks for a new fit: give one of them"
    )
    assert cli(["fit", scene, "--out", tmp_path / "d.blend", "--cues", "skin"]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "argument --cues: invalid choice: 'skin'" in err
    for c in CUES:
        assert repr(c) in err
    assert fake_run_fit == [("walk", "contours")]
    assert not (tmp_path / "c.blend").exists() and not (tmp_path / "d.blend").exists()


def test_cli_batch_cues(tmp_path, fake_run_fit, empty_blend, capsys):
    takes = tmp_path / "takes"
    make_scene(takes / "run", with_fit=True)
    make_scene(takes / "walk")
    write_state(takes / "jump.json", synthetic_state(6, seed=5))
    assert cli(["batch", takes, "--out", tmp_path / "out", "--cues", "both"]) == 0
    assert sorted(fake_run_fit) == [("run", "both"), ("walk", "both")]
    assert "3 converted, 0 failed" in capsys.readouterr().out
    fake_run_fit.clear()
    assert cli(["batch", takes, "--out", tmp_path / "out2"]) == 0
    assert fake_run_fit == [("walk", "texture")]  # run uses its fit.json


def test_cli_fit_feet_from_points(tmp_path, fake_run_fit, empty_blend, capsys):
    scene = make_scene(tmp_path / "walk", with_fit=True)
    before = (scene / "fit.json").read_bytes()
    assert cli(["fit", scene, "--out", tmp_path / "a.blend", "--feet-from-points"]) == 0
    assert fake_run_fit == [("walk", "texture", "feet")]  # refitted, not the cached fit
    assert "walk: 4 frames" in capsys.readouterr().out
    argv = ["fit", scene, "--out", tmp_path / "b.blend", "--cues", "both", "--feet-from-points"]
    assert cli(argv) == 0
    assert fake_run_fit[-1] == ("walk", "both", "feet")
    assert (scene / "fit.json").read_bytes() == before

    fake_run_fit.clear()
    argv = ["fit", scene, "--out", tmp_path / "c.blend", "--fit", scene / "fit.json"]
    assert cli([*argv, "--feet-from-points"]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err == (
        f"somacap: error: {scene / 'fit.json'}: --fit uses a fitted state and "
        "--feet-from-points asks for a new fit: give one of them"
    )
    assert cli([*argv, "--feet-from-points", "--cues", "both"]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "--cues and --feet-from-points ask for a new fit" in err
    assert fake_run_fit == [] and not (tmp_path / "c.blend").exists()


def test_cli_batch_feet_from_points(tmp_path, fake_run_fit, empty_blend, capsys):
    takes = tmp_path / "takes"
    make_scene(takes / "run", with_fit=True)
    make_scene(takes / "walk")
    write_state(takes / "jump.json", synthetic_state(6, seed=5))
    assert cli(["batch", takes, "--out", tmp_path / "out", "--feet-from-points"]) == 0
    assert sorted(fake_run_fit) == [("run", "texture", "feet"), ("walk", "texture", "feet")]
    assert "3 converted, 0 failed" in capsys.readouterr().out  # jump.json as it is


def test_cli_help_explains_feet_from_points(capsys):
    from addon.cli_command import build_parser

    for cmd in ("fit", "batch"):
        with pytest.raises(SystemExit):
            build_parser().parse_args([cmd, "--help"])
        text = " ".join(capsys.readouterr().out.split())
        assert "--feet-from-points turn each foot about its shin at the clicked frame" in text
        assert "contours give no points" in text
        assert not build_parser().parse_args([cmd, "x", "--out", "o"]).feet_from_points
    with pytest.raises(SystemExit):
        build_parser().parse_args(["retarget", "--help"])
    assert "--feet-from-points" not in capsys.readouterr().out


def test_cli_help_explains_each_cue(capsys):
    from addon import pipeline
    from addon.cli_command import build_parser

    for cmd in ("fit", "batch"):
        with pytest.raises(SystemExit):
            build_parser().parse_args([cmd, "--help"])
        text = " ".join(capsys.readouterr().out.split())
        assert "--cues {texture,contours,both}" in text
        for name, line in pipeline.FIT_CUES.items():
            assert f"{name}: {' '.join(line.split())}" in text


@pytest.fixture
def registered(empty_blend):
    import addon

    addon.register()
    yield empty_blend
    addon.unregister()


def test_panel_property_and_operator(registered, tmp_path, fake_run_fit):
    bpy = registered
    s = bpy.context.scene.somacap
    prop = s.bl_rna.properties["fit_cues"]
    assert prop.default == "texture"
    assert [(i.identifier, i.name) for i in prop.enum_items] == [
        ("texture", "Texture"),
        ("contours", "Contours"),
        ("both", "Both"),
    ]
    assert all(i.description for i in prop.enum_items)
    assert prop.enum_items["both"].description.count("2.7x") == 1

    from .user_scenario import panel_dump

    log = panel_dump(bpy.context)
    i = log.index("button somacap.fit")
    assert log[i - 1] == "field fit_cues"  # drawn next to the Fit button

    scene = make_scene(tmp_path / "walk")
    s.scene_dir = str(scene)
    s.take = "walk"
    for cues in ("contours", "both"):
        s.fit_cues = cues
        assert bpy.ops.somacap.fit() == {"FINISHED"}
    assert fake_run_fit == [("walk", "contours"), ("walk", "both")]
    assert s.body is not None and s.body.name.startswith("walk_armature")
    with pytest.raises(TypeError):
        s.fit_cues = "skin"


def test_panel_feet_from_points(registered, tmp_path, fake_run_fit, capfd):
    """The check box under the cues and the Fit button; ticked, Fit refits with the feet
    from points although the scene has a fit.json, unticked it uses that fit.json."""
    bpy = registered
    s = bpy.context.scene.somacap
    prop = s.bl_rna.properties["feet_from_points"]
    assert prop.type == "BOOLEAN" and prop.default is False and s.feet_from_points is False
    assert prop.name == "Feet from points"
    assert "heading of the surface points" in prop.description
    assert "Texture or Both" in prop.description

    from .user_scenario import panel_dump

    log = panel_dump(bpy.context)
    i = log.index("button somacap.fit")
    assert log[i - 1 : i + 2] == ["field fit_cues", "button somacap.fit", "field feet_from_points"]

    scene = make_scene(tmp_path / "walk", with_fit=True)
    before = (scene / "fit.json").read_bytes()
    s.scene_dir = str(scene)
    s.take = "walk"
    capfd.readouterr()
    assert bpy.ops.somacap.fit() == {"FINISHED"}  # unticked: the scene's fit.json
    assert fake_run_fit == []
    assert "Used the scene's existing fit.json" in capfd.readouterr().out
    s.feet_from_points = True
    s.fit_cues = "both"
    assert bpy.ops.somacap.fit() == {"FINISHED"}
    assert fake_run_fit == [("walk", "both", "feet")]
    assert "existing fit.json" not in capfd.readouterr().out  # not "cached"
    assert s.body is not None and s.body["somacap_rmse_mm"] is not None
    assert len(s.body["somacap_rmse_mm"]) == 4  # the new fit was built
    assert (scene / "fit.json").read_bytes() == before


def test_fit_button_uses_the_key_joints_the_user_moved(registered, monkeypatch, capfd):
    """Place key joints, drag one, press Fit: the fit gets that joint's new place (and
    refits rather than reading a cached fit.json); unmoved, it gets none."""
    from addon import pipeline
    from tests.conftest import DEFAULT_SCENE

    if not (DEFAULT_SCENE / "clicks.json").is_file():
        pytest.skip("default scene without clicks")
    bpy = registered
    got = []

    def run_fit(
        scene_dir, out_json, progress=None, cues="texture", clicks_xyz=None, feet_from_points=False
    ):
        got.append(clicks_xyz)
        write_state(out_json, synthetic_state(4, seed=5))
        return out_json

    monkeypatch.setattr(pipeline, "run_fit", run_fit)
    s = bpy.context.scene.somacap
    s.scene_dir = str(DEFAULT_SCENE)
    assert bpy.ops.somacap.place_clicks() == {"FINISHED"}
    bpy.data.objects["click_r_wrist"].location.z += 0.03
    assert bpy.ops.somacap.fit() == {"FINISHED"}
    assert list(got[-1]) == ["r_wrist"]
    assert "key joints you moved: r_wrist" in capfd.readouterr().out
    bpy.data.objects["click_r_wrist"].location.z -= 0.03
    if not (DEFAULT_SCENE / "fit.json").is_file():
        assert bpy.ops.somacap.fit() == {"FINISHED"}
        assert got[-1] == {}
