"""The fit's cue choice (texture / contours / both) from the pipeline, CLI, panel and
operator down to core's ``fit_scene``; core's fit is replaced by a recorder (seconds)."""

from __future__ import annotations

import inspect

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
    """Replace ``addon.pipeline.run_fit``: record the cues, write a 4-frame state."""
    from addon import pipeline

    calls = []

    def run_fit(scene_dir, out_json, progress=None, cues="texture", clicks_xyz=None):
        calls.append((scene_dir.name, cues))
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


def test_fit_button_uses_the_key_joints_the_user_moved(registered, monkeypatch, capfd):
    """Place key joints, drag one, press Fit: the fit gets that joint's new place (and
    refits rather than reading a cached fit.json); unmoved, it gets none."""
    from addon import pipeline
    from tests.conftest import DEFAULT_SCENE

    if not (DEFAULT_SCENE / "clicks.json").is_file():
        pytest.skip("default scene without clicks")
    bpy = registered
    got = []

    def run_fit(scene_dir, out_json, progress=None, cues="texture", clicks_xyz=None):
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
