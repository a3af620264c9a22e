"""The opt-out of the refined-flow second fit (``SequenceSettings(flow_choice=False)``:
the panel's "Refined-flow second fit", ``--one-flow``) from the pipeline, CLI, panel and
operator down to core's ``fit_scene``; core's fit is replaced by a recorder (seconds)."""

from __future__ import annotations

from dataclasses import replace

import pytest

from .fit_fixtures import cli, make_scene

pytestmark = [pytest.mark.blender]

# The second fit with LSM-refined flow corners of a take the silhouettes shape: on by
# default (core's default too), so it is the switch off that reaches core, as
# SequenceSettings(flow_choice=False).


def flow_choice_of(kw):
    """The ``flow_choice`` that one recorded ``fit_scene`` call fits with (core's
    default when no settings are passed)."""
    from core.fit import SequenceSettings

    assert set(kw) <= {"cues", "settings"}
    return kw.get("settings", SequenceSettings()).flow_choice


@pytest.mark.parametrize("flow_choice", [True, False])
def test_run_fit_flow_choice_passes_sequence_settings(tmp_path, fake_fit_scene, flow_choice):
    from addon import pipeline
    from core.fit import SequenceSettings

    assert SequenceSettings().flow_choice is True  # on is core's default
    pipeline.run_fit(
        tmp_path / "sc", tmp_path / "fit.json", cues="contours", flow_choice=flow_choice
    )
    (kw,) = fake_fit_scene
    if flow_choice:
        assert kw == {"cues": "contours"}  # core's own default
    else:
        assert kw["settings"] == replace(SequenceSettings(), flow_choice=False)
    assert flow_choice_of(kw) is flow_choice
    # with other options: one SequenceSettings with all of them
    pipeline.run_fit(
        tmp_path / "sc",
        tmp_path / "b.json",
        smooth_motion=True,
        contour_starts=False,
        late_shape=False,
        flow_choice=flow_choice,
    )
    want = replace(
        SequenceSettings(),
        smooth_motion=True,
        contour_starts=False,
        late_shape_points=None,
        flow_choice=flow_choice,
    )
    assert fake_fit_scene[-1]["settings"] == want


def test_flow_choice_is_a_fit_option():
    from addon import pipeline

    assert pipeline.FIT_OPTIONS["flow_choice"] is True
    assert pipeline.asks_new_fit(flow_choice=False)
    assert not pipeline.asks_new_fit(flow_choice=True)


def test_state_for_scene_one_flow_refits_down_to_core(tmp_path, fake_fit_scene):
    from addon import pipeline

    scene = make_scene(tmp_path / "walk", with_fit=True)
    before = (scene / "fit.json").read_bytes()
    assert pipeline.state_for_scene(scene, flow_choice=True).n_frames == 3  # cached
    assert fake_fit_scene == []
    assert pipeline.state_for_scene(scene, cues="contours", flow_choice=False).n_frames == 5
    (kw,) = fake_fit_scene
    assert kw["cues"] == "contours" and flow_choice_of(kw) is False
    assert (scene / "fit.json").read_bytes() == before  # not overwritten
    assert pipeline.state_for_scene(scene, scene / "fit.json", flow_choice=False).n_frames == 3
    assert len(fake_fit_scene) == 1


@pytest.mark.parametrize("flag", [False, True])
def test_cli_fit_one_flow(tmp_path, fake_fit_scene, empty_blend, capsys, flag):
    """``--one-flow`` reaches core as ``flow_choice=False``; without it the fit keeps
    core's second fit with refined flow corners."""
    scene = make_scene(tmp_path / "walk")  # no fit.json: fitted either way
    extra = ["--one-flow"] if flag else []
    assert cli(["fit", scene, "--out", tmp_path / "a.blend", "--cues", "contours", *extra]) == 0
    (kw,) = fake_fit_scene
    assert kw["cues"] == "contours" and flow_choice_of(kw) is (not flag)
    assert "walk: 5 frames" in capsys.readouterr().out

    takes = tmp_path / "takes"
    make_scene(takes / "run")
    assert cli(["batch", takes, "--out", tmp_path / "out", *extra]) == 0
    assert len(fake_fit_scene) == 2 and flow_choice_of(fake_fit_scene[-1]) is (not flag)


def test_cli_one_flow_refits_and_conflicts_with_fit(tmp_path, fake_run_fit, empty_blend, capsys):
    scene = make_scene(tmp_path / "walk", with_fit=True)
    before = (scene / "fit.json").read_bytes()
    assert cli(["fit", scene, "--out", tmp_path / "a.blend", "--one-flow"]) == 0
    assert fake_run_fit == [("walk", "texture", "one_flow")]  # not the cached fit
    assert (scene / "fit.json").read_bytes() == before
    argv = ["fit", scene, "--out", tmp_path / "b.blend", "--fit", scene / "fit.json"]
    assert cli([*argv, "--one-pass", "--one-flow"]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.endswith(
        "--fit uses a fitted state and --one-pass and --one-flow ask for a new fit: "
        "give one of them"
    )
    assert len(fake_run_fit) == 1 and not (tmp_path / "b.blend").exists()


def test_cli_help_explains_one_flow(capsys):
    from addon.cli_command import build_parser

    for cmd in ("fit", "batch"):
        with pytest.raises(SystemExit):
            build_parser().parse_args([cmd, "--help"])
        text = " ".join(capsys.readouterr().out.split())
        for words in (
            "--one-flow",
            "the silhouettes shape",
            "least squares matching",
            "foregrounds explain better",
            "twice the fit time",
        ):
            assert words in text
        args = build_parser().parse_args([cmd, "x", "--out", "o"])
        assert args.one_flow is False  # the second fit by default
    with pytest.raises(SystemExit):
        build_parser().parse_args(["retarget", "--help"])
    assert "--one-flow" not in capsys.readouterr().out


def test_panel_flow_choice(registered, tmp_path, fake_fit_scene, capfd):
    """The check box last among the fit's options, on by default; unticked, Fit refits
    with ``flow_choice=False`` although the scene has a fit.json; ticked, it uses that
    fit.json, and a scene without one is fitted with the second fit."""
    bpy = registered
    s = bpy.context.scene.somacap
    prop = s.bl_rna.properties["flow_choice"]
    assert prop.type == "BOOLEAN" and prop.default is True and s.flow_choice is True
    assert prop.name == "Refined-flow second fit"
    for words in ("silhouettes alone", "second time", "LSM-refined", "About twice", "one fit"):
        assert words in prop.description
    assert prop.name in s.bl_rna.properties["fit_cues"].description  # refits

    from .user_scenario import panel_dump

    log = panel_dump(bpy.context)
    i = log.index("field late_shape")
    assert log[i + 1] == "field flow_choice"

    scene = make_scene(tmp_path / "walk", with_fit=True)
    s.scene_dir = str(scene)
    s.take = "walk"
    capfd.readouterr()
    assert bpy.ops.somacap.fit() == {"FINISHED"}  # ticked: the scene's fit.json
    assert fake_fit_scene == []
    assert "Used the scene's existing fit.json" in capfd.readouterr().out
    s.flow_choice = False
    assert bpy.ops.somacap.fit() == {"FINISHED"}
    (kw,) = fake_fit_scene
    assert flow_choice_of(kw) is False
    assert "existing fit.json" not in capfd.readouterr().out
    assert len(s.body["somacap_rmse_mm"]) == 5  # the new fit was built

    s.flow_choice = True
    s.scene_dir = str(make_scene(tmp_path / "run"))  # no fit.json: fitted
    assert bpy.ops.somacap.fit() == {"FINISHED"}
    assert len(fake_fit_scene) == 2 and flow_choice_of(fake_fit_scene[-1]) is True
