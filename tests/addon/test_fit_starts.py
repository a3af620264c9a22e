"""The opt-out of the extra starts of a frame fitted from contours alone
(``SequenceSettings(contour_starts=False)``: the panel's "Extra starts (contours alone)",
``--prediction-start-only``) from the pipeline, CLI, panel and operator down to core's
``fit_scene``; core's fit is replaced by a recorder (seconds)."""

from __future__ import annotations

from dataclasses import replace

import pytest

from .fit_fixtures import cli, make_scene

pytestmark = [pytest.mark.blender]

# The extra starts of a frame fitted from contours alone: on by default (core's default
# too), so it is the switch off that reaches core, as SequenceSettings(contour_starts=False).


def contour_starts_of(kw):
    """The ``contour_starts`` that one recorded ``fit_scene`` call fits with (core's
    default when no settings are passed)."""
    from core.fit import SequenceSettings

    assert set(kw) <= {"cues", "settings"}
    return kw.get("settings", SequenceSettings()).contour_starts


@pytest.mark.parametrize("contour_starts", [True, False])
def test_run_fit_contour_starts_passes_sequence_settings(tmp_path, fake_fit_scene, contour_starts):
    from addon import pipeline
    from core.fit import SequenceSettings

    assert SequenceSettings().contour_starts is True  # on is core's default
    pipeline.run_fit(
        tmp_path / "sc", tmp_path / "fit.json", cues="contours", contour_starts=contour_starts
    )
    (kw,) = fake_fit_scene
    if contour_starts:
        assert kw == {"cues": "contours"}  # core's own default
    else:
        assert kw["settings"] == replace(SequenceSettings(), contour_starts=False)
    assert contour_starts_of(kw) is contour_starts
    # with an opt-in option: one SequenceSettings with both
    pipeline.run_fit(
        tmp_path / "sc", tmp_path / "b.json", smooth_motion=True, contour_starts=contour_starts
    )
    want = replace(SequenceSettings(), smooth_motion=True, contour_starts=contour_starts)
    assert fake_fit_scene[-1]["settings"] == want


def test_state_for_scene_without_contour_starts_refits_down_to_core(tmp_path, fake_fit_scene):
    from addon import pipeline

    scene = make_scene(tmp_path / "walk", with_fit=True)
    before = (scene / "fit.json").read_bytes()
    assert pipeline.state_for_scene(scene, contour_starts=True).n_frames == 3  # cached
    assert fake_fit_scene == []
    assert pipeline.state_for_scene(scene, cues="contours", contour_starts=False).n_frames == 5
    (kw,) = fake_fit_scene
    assert kw["cues"] == "contours" and contour_starts_of(kw) is False
    assert (scene / "fit.json").read_bytes() == before  # not overwritten
    assert pipeline.state_for_scene(scene, scene / "fit.json", contour_starts=False).n_frames == 3
    assert len(fake_fit_scene) == 1


@pytest.mark.parametrize("flag", [False, True])
def test_cli_fit_prediction_start_only(tmp_path, fake_fit_scene, empty_blend, capsys, flag):
    """``--prediction-start-only`` reaches core as ``contour_starts=False``; without
    it the fit keeps core's three starts."""
    scene = make_scene(tmp_path / "walk")  # no fit.json: fitted either way
    extra = ["--prediction-start-only"] if flag else []
    assert cli(["fit", scene, "--out", tmp_path / "a.blend", "--cues", "contours", *extra]) == 0
    (kw,) = fake_fit_scene
    assert kw["cues"] == "contours" and contour_starts_of(kw) is (not flag)
    assert "walk: 5 frames" in capsys.readouterr().out

    takes = tmp_path / "takes"
    make_scene(takes / "run")
    assert cli(["batch", takes, "--out", tmp_path / "out", *extra]) == 0
    assert len(fake_fit_scene) == 2 and contour_starts_of(fake_fit_scene[-1]) is (not flag)


def test_cli_prediction_start_only_refits_and_conflicts_with_fit(
    tmp_path, fake_run_fit, empty_blend, capsys
):
    scene = make_scene(tmp_path / "walk", with_fit=True)
    before = (scene / "fit.json").read_bytes()
    assert cli(["fit", scene, "--out", tmp_path / "a.blend", "--prediction-start-only"]) == 0
    assert fake_run_fit == [("walk", "texture", "prediction_start_only")]  # not the cached fit
    assert (scene / "fit.json").read_bytes() == before
    argv = ["fit", scene, "--out", tmp_path / "b.blend", "--fit", scene / "fit.json"]
    assert cli([*argv, "--smooth", "--prediction-start-only"]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.endswith(
        "--fit uses a fitted state and --smooth and --prediction-start-only ask for a new "
        "fit: give one of them"
    )
    assert len(fake_run_fit) == 1 and not (tmp_path / "b.blend").exists()


def test_cli_help_explains_prediction_start_only(capsys):
    from addon.cli_command import build_parser

    for cmd in ("fit", "batch"):
        with pytest.raises(SystemExit):
            build_parser().parse_args([cmd, "--help"])
        text = " ".join(capsys.readouterr().out.split())
        for words in ("--prediction-start-only", "contours alone", "from the prediction only"):
            assert words in text
        args = build_parser().parse_args([cmd, "x", "--out", "o"])
        assert args.prediction_start_only is False  # the three starts by default
    with pytest.raises(SystemExit):
        build_parser().parse_args(["retarget", "--help"])
    assert "--prediction-start-only" not in capsys.readouterr().out


def test_panel_contour_starts(registered, tmp_path, fake_fit_scene, capfd):
    """The check box under the other options, on by default; unticked, Fit refits with
    ``contour_starts=False`` although the scene has a fit.json; ticked, it uses that
    fit.json, and a scene without one is fitted with the three starts."""
    bpy = registered
    s = bpy.context.scene.somacap
    prop = s.bl_rna.properties["contour_starts"]
    assert prop.type == "BOOLEAN" and prop.default is True and s.contour_starts is True
    assert prop.name == "Extra starts (contours alone)"
    for words in ("without texture points", "three starts", "about 2x", "fast limbs"):
        assert words in prop.description
    assert prop.name in s.bl_rna.properties["fit_cues"].description  # refits

    from .user_scenario import panel_dump

    log = panel_dump(bpy.context)
    i = log.index("button somacap.fit")
    assert log[i - 1 : i + 4] == [
        "field fit_cues",
        "button somacap.fit",
        "field feet_from_points",
        "field smooth_motion",
        "field contour_starts",
    ]

    scene = make_scene(tmp_path / "walk", with_fit=True)
    s.scene_dir = str(scene)
    s.take = "walk"
    s.fit_cues = "contours"
    capfd.readouterr()
    assert bpy.ops.somacap.fit() == {"FINISHED"}  # ticked: the scene's fit.json
    assert fake_fit_scene == []
    assert "Used the scene's existing fit.json" in capfd.readouterr().out
    s.contour_starts = False
    assert bpy.ops.somacap.fit() == {"FINISHED"}
    (kw,) = fake_fit_scene
    assert kw["cues"] == "contours" and contour_starts_of(kw) is False
    assert "existing fit.json" not in capfd.readouterr().out
    assert len(s.body["somacap_rmse_mm"]) == 5  # the new fit was built

    s.contour_starts = True
    s.scene_dir = str(make_scene(tmp_path / "run"))  # no fit.json: fitted
    assert bpy.ops.somacap.fit() == {"FINISHED"}
    assert len(fake_fit_scene) == 2 and contour_starts_of(fake_fit_scene[-1]) is True
