"""The opt-out of the late shape's second pass (``SequenceSettings(late_shape_points=
None)``: the panel's "Second pass (late shape)", ``--one-pass``) from the pipeline, CLI,
panel and operator down to core's ``fit_scene``; core's fit is replaced by a recorder
(seconds)."""

from __future__ import annotations

from dataclasses import replace

import pytest

from .fit_fixtures import cli, make_scene

pytestmark = [pytest.mark.blender]


def late_shape_of(kw):
    """The ``late_shape_points`` that one recorded ``fit_scene`` call fits with (core's
    default when no settings are passed; None: one pass)."""
    from core.fit import SequenceSettings

    assert set(kw) <= {"cues", "settings"}
    return kw.get("settings", SequenceSettings()).late_shape_points


@pytest.mark.parametrize("late_shape", [True, False])
def test_run_fit_late_shape_passes_sequence_settings(tmp_path, fake_fit_scene, late_shape):
    from addon import pipeline
    from core.fit import SequenceSettings

    default = SequenceSettings().late_shape_points
    assert default == 100  # on is core's default
    pipeline.run_fit(tmp_path / "sc", tmp_path / "fit.json", cues="both", late_shape=late_shape)
    (kw,) = fake_fit_scene
    if late_shape:
        assert kw == {"cues": "both"}  # core's own default
    else:
        assert kw["settings"] == replace(SequenceSettings(), late_shape_points=None)
    assert late_shape_of(kw) == (default if late_shape else None)
    # with other options: one SequenceSettings with all of them
    pipeline.run_fit(
        tmp_path / "sc",
        tmp_path / "b.json",
        smooth_motion=True,
        contour_starts=False,
        late_shape=late_shape,
    )
    want = replace(
        SequenceSettings(),
        smooth_motion=True,
        contour_starts=False,
        late_shape_points=default if late_shape else None,
    )
    assert fake_fit_scene[-1]["settings"] == want


def test_asks_new_fit_names_every_option():
    from addon import pipeline

    assert not pipeline.asks_new_fit(**pipeline.FIT_OPTIONS)
    for name, default in pipeline.FIT_OPTIONS.items():
        assert pipeline.asks_new_fit(**{name: not default}), name
    with pytest.raises(KeyError):
        pipeline.asks_new_fit(one_pass=True)  # a misspelt option is an error, not "no"


def test_state_for_scene_one_pass_refits_down_to_core(tmp_path, fake_fit_scene):
    from addon import pipeline

    scene = make_scene(tmp_path / "walk", with_fit=True)
    before = (scene / "fit.json").read_bytes()
    assert pipeline.state_for_scene(scene, late_shape=True).n_frames == 3  # cached
    assert fake_fit_scene == []
    assert pipeline.state_for_scene(scene, late_shape=False).n_frames == 5
    (kw,) = fake_fit_scene
    assert kw["cues"] == "texture" and late_shape_of(kw) is None
    assert (scene / "fit.json").read_bytes() == before  # not overwritten
    assert pipeline.state_for_scene(scene, scene / "fit.json", late_shape=False).n_frames == 3
    assert len(fake_fit_scene) == 1


@pytest.mark.parametrize("flag", [False, True])
def test_cli_fit_one_pass(tmp_path, fake_fit_scene, empty_blend, capsys, flag):
    """``--one-pass`` reaches core as ``late_shape_points=None``; without it the fit
    keeps core's late shape."""
    from core.fit import SequenceSettings

    scene = make_scene(tmp_path / "walk")  # no fit.json: fitted either way
    extra = ["--one-pass"] if flag else []
    assert cli(["fit", scene, "--out", tmp_path / "a.blend", "--cues", "both", *extra]) == 0
    (kw,) = fake_fit_scene
    want = None if flag else SequenceSettings().late_shape_points
    assert kw["cues"] == "both" and late_shape_of(kw) == want
    assert "walk: 5 frames" in capsys.readouterr().out

    takes = tmp_path / "takes"
    make_scene(takes / "run")
    assert cli(["batch", takes, "--out", tmp_path / "out", *extra]) == 0
    assert len(fake_fit_scene) == 2 and late_shape_of(fake_fit_scene[-1]) == want


def test_cli_one_pass_refits_and_conflicts_with_fit(tmp_path, fake_run_fit, empty_blend, capsys):
    scene = make_scene(tmp_path / "walk", with_fit=True)
    before = (scene / "fit.json").read_bytes()
    assert cli(["fit", scene, "--out", tmp_path / "a.blend", "--one-pass"]) == 0
    assert fake_run_fit == [("walk", "texture", "one_pass")]  # not the cached fit
    assert (scene / "fit.json").read_bytes() == before
    argv = ["fit", scene, "--out", tmp_path / "b.blend", "--fit", scene / "fit.json"]
    assert cli([*argv, "--one-pass"]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.endswith(
        "--fit uses a fitted state and --one-pass asks for a new fit: give one of them"
    )
    assert len(fake_run_fit) == 1 and not (tmp_path / "b.blend").exists()


def test_cli_help_explains_one_pass(capsys):
    from addon.cli_command import build_parser

    for cmd in ("fit", "batch"):
        with pytest.raises(SystemExit):
            build_parser().parse_args([cmd, "--help"])
        text = " ".join(capsys.readouterr().out.split())
        for words in ("--one-pass", "fit the motion once", "late shape", "half the fit time"):
            assert words in text
        args = build_parser().parse_args([cmd, "x", "--out", "o"])
        assert args.one_pass is False  # the late shape by default
    with pytest.raises(SystemExit):
        build_parser().parse_args(["retarget", "--help"])
    assert "--one-pass" not in capsys.readouterr().out


def test_panel_late_shape(registered, tmp_path, fake_fit_scene, capfd):
    """The check box last among the fit's options, on by default; unticked, Fit refits
    with one pass although the scene has a fit.json; ticked, it uses that fit.json, and a
    scene without one is fitted with the late shape."""
    from core.fit import SequenceSettings

    bpy = registered
    s = bpy.context.scene.somacap
    prop = s.bl_rna.properties["late_shape"]
    assert prop.type == "BOOLEAN" and prop.default is True and s.late_shape is True
    assert prop.name == "Second pass (late shape)"
    for words in ("hardly saw", "second time", "About 2x", "one pass"):
        assert words in prop.description
    assert prop.name in s.bl_rna.properties["fit_cues"].description  # refits

    from .user_scenario import panel_dump

    log = panel_dump(bpy.context)
    i = log.index("field contour_starts")
    assert log[i + 1] == "field late_shape"

    scene = make_scene(tmp_path / "walk", with_fit=True)
    s.scene_dir = str(scene)
    s.take = "walk"
    capfd.readouterr()
    assert bpy.ops.somacap.fit() == {"FINISHED"}  # ticked: the scene's fit.json
    assert fake_fit_scene == []
    assert "Used the scene's existing fit.json" in capfd.readouterr().out
    s.late_shape = False
    assert bpy.ops.somacap.fit() == {"FINISHED"}
    (kw,) = fake_fit_scene
    assert late_shape_of(kw) is None
    assert "existing fit.json" not in capfd.readouterr().out
    assert len(s.body["somacap_rmse_mm"]) == 5  # the new fit was built

    s.late_shape = True
    s.scene_dir = str(make_scene(tmp_path / "run"))  # no fit.json: fitted
    assert bpy.ops.somacap.fit() == {"FINISHED"}
    want = SequenceSettings().late_shape_points
    assert len(fake_fit_scene) == 2 and late_shape_of(fake_fit_scene[-1]) == want
