"""The fit's cue choice (texture / contours / both) and its opt-in options, feet from
points (``SequenceSettings(foot_heading=True)``) and smooth motion
(``SequenceSettings(smooth_motion=True)``), from the pipeline, CLI, panel and operator
down to core's ``fit_scene`` (its default-on options, which are switched off, are in
``test_fit_default_on_options.py``); core's fit is replaced by a recorder (seconds)."""

from __future__ import annotations

import inspect
from dataclasses import replace

import pytest

from core.errors import InputError
from core.state import write_state

from .fit_fixtures import OPTIONS, cli, make_scene
from .state_fixtures import synthetic_state

pytestmark = [pytest.mark.blender]

CUES = ("texture", "contours", "both")


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


@pytest.mark.parametrize("cues", CUES)
@pytest.mark.parametrize("option", OPTIONS)
def test_run_fit_option_passes_sequence_settings(tmp_path, fake_fit_scene, option, cues):
    from addon import pipeline
    from core.fit import SequenceSettings

    field = OPTIONS[option].field
    out = pipeline.run_fit(tmp_path / "sc", tmp_path / "fit.json", cues=cues, **{option: True})
    assert pipeline.read_state(out).n_frames == 5
    (kw,) = fake_fit_scene
    assert set(kw) == {"cues", "settings"} and kw["cues"] == cues
    assert isinstance(kw["settings"], SequenceSettings)
    assert getattr(kw["settings"], field) is True
    # core's defaults otherwise, as `core fit --feet-from-points` / `--smooth` leave the rest
    assert kw["settings"] == replace(SequenceSettings(), **{field: True})
    assert getattr(SequenceSettings(), field) is False  # off is core's default


def test_run_fit_both_options_pass_one_sequence_settings(tmp_path, fake_fit_scene):
    from addon import pipeline
    from core.fit import SequenceSettings

    pipeline.run_fit(tmp_path / "sc", tmp_path / "fit.json", **dict.fromkeys(OPTIONS, True))
    (kw,) = fake_fit_scene
    assert set(kw) == {"cues", "settings"}
    want = replace(SequenceSettings(), **{o.field: True for o in OPTIONS.values()})
    assert kw["settings"] == want
    assert kw["settings"].foot_heading is True and kw["settings"].smooth_motion is True


def test_run_fit_without_options_passes_no_settings(tmp_path, fake_fit_scene):
    from addon import pipeline

    pipeline.run_fit(tmp_path / "sc", tmp_path / "a.json")
    pipeline.run_fit(tmp_path / "sc", tmp_path / "b.json", cues="both", feet_from_points=False)
    pipeline.run_fit(tmp_path / "sc", tmp_path / "c.json", smooth_motion=False)
    pipeline.run_fit(tmp_path / "sc", tmp_path / "d.json", **dict.fromkeys(OPTIONS, False))
    # core's own default
    assert fake_fit_scene == [{"cues": "texture"}, {"cues": "both"}] + [{"cues": "texture"}] * 2


@pytest.mark.parametrize("option", OPTIONS)
def test_state_for_scene_option_refits_down_to_core(tmp_path, fake_fit_scene, option):
    """A scene with a fit.json: asked for the option, the state is a new fit with its
    field on (through the real run_fit), and fit.json is left as it is."""
    from addon import pipeline

    scene = make_scene(tmp_path / "walk", with_fit=True)
    before = (scene / "fit.json").read_bytes()
    assert pipeline.state_for_scene(scene).n_frames == 3  # cached
    assert fake_fit_scene == []
    assert pipeline.state_for_scene(scene, cues="both", **{option: True}).n_frames == 5
    (kw,) = fake_fit_scene
    assert kw["cues"] == "both" and getattr(kw["settings"], OPTIONS[option].field) is True
    assert (scene / "fit.json").read_bytes() == before  # not overwritten
    # an explicit fitted state still wins, as it does over refit
    assert pipeline.state_for_scene(scene, scene / "fit.json", **{option: True}).n_frames == 3
    assert len(fake_fit_scene) == 1


@pytest.mark.parametrize("option", OPTIONS)
def test_state_for_scene_option_not_cached(tmp_path, fake_run_fit, option):
    from addon import pipeline

    scene = make_scene(tmp_path / "walk", with_fit=True)
    before = (scene / "fit.json").read_bytes()
    assert pipeline.state_for_scene(scene, **{option: True}).n_frames == 4
    assert fake_run_fit == [("walk", "texture", option)]
    assert pipeline.state_for_scene(scene, **dict.fromkeys(OPTIONS, True)).n_frames == 4
    assert fake_run_fit[-1] == ("walk", "texture", *OPTIONS)  # one fit with both
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


@pytest.mark.parametrize("option", OPTIONS)
def test_cli_fit_option(tmp_path, fake_run_fit, empty_blend, capsys, option):
    flag = OPTIONS[option].flag
    scene = make_scene(tmp_path / "walk", with_fit=True)
    before = (scene / "fit.json").read_bytes()
    assert cli(["fit", scene, "--out", tmp_path / "a.blend", flag]) == 0
    assert fake_run_fit == [("walk", "texture", option)]  # refitted, not the cached fit
    assert "walk: 4 frames" in capsys.readouterr().out
    argv = ["fit", scene, "--out", tmp_path / "b.blend", "--cues", "both", flag]
    assert cli(argv) == 0
    assert fake_run_fit[-1] == ("walk", "both", option)
    assert (scene / "fit.json").read_bytes() == before

    fake_run_fit.clear()
    argv = ["fit", scene, "--out", tmp_path / "c.blend", "--fit", scene / "fit.json"]
    assert cli([*argv, flag]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        f"somacap: error: {scene / 'fit.json'}: --fit uses a fitted state and "
        f"{flag} asks for a new fit: give one of them"
    ]
    assert cli([*argv, flag, "--cues", "both"]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert f"--cues and {flag} ask for a new fit" in err
    assert fake_run_fit == [] and not (tmp_path / "c.blend").exists()


def test_cli_fit_both_options(tmp_path, fake_run_fit, empty_blend, capsys):
    scene = make_scene(tmp_path / "walk", with_fit=True)
    flags = [o.flag for o in OPTIONS.values()]
    assert cli(["fit", scene, "--out", tmp_path / "a.blend", *flags]) == 0
    assert fake_run_fit == [("walk", "texture", *OPTIONS)]  # one fit with both
    argv = ["fit", scene, "--out", tmp_path / "b.blend", "--fit", scene / "fit.json"]
    assert cli([*argv, "--cues", "both", *flags]) == 2
    assert (
        capsys.readouterr()
        .err.strip()
        .splitlines()[-1]
        .endswith("--cues, --feet-from-points and --smooth ask for a new fit: give one of them")
    )
    assert len(fake_run_fit) == 1 and not (tmp_path / "b.blend").exists()


@pytest.mark.parametrize("option", OPTIONS)
def test_cli_batch_option(tmp_path, fake_run_fit, empty_blend, capsys, option):
    takes = tmp_path / "takes"
    make_scene(takes / "run", with_fit=True)
    make_scene(takes / "walk")
    write_state(takes / "jump.json", synthetic_state(6, seed=5))
    assert cli(["batch", takes, "--out", tmp_path / "out", OPTIONS[option].flag]) == 0
    assert sorted(fake_run_fit) == [("run", "texture", option), ("walk", "texture", option)]
    assert "3 converted, 0 failed" in capsys.readouterr().out  # jump.json as it is


@pytest.mark.parametrize("option", OPTIONS)
def test_cli_help_explains_option(capsys, option):
    from addon.cli_command import build_parser

    opt = OPTIONS[option]
    for cmd in ("fit", "batch"):
        with pytest.raises(SystemExit):
            build_parser().parse_args([cmd, "--help"])
        text = " ".join(capsys.readouterr().out.split())
        for words in opt.help:
            assert words in text
        args = vars(build_parser().parse_args([cmd, "x", "--out", "o"]))
        assert args[opt.flag[2:].replace("-", "_")] is False  # off by default
    with pytest.raises(SystemExit):
        build_parser().parse_args(["retarget", "--help"])
    assert opt.flag not in capsys.readouterr().out


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


@pytest.mark.parametrize("option", OPTIONS)
def test_panel_option(registered, tmp_path, fake_run_fit, capfd, option):
    """The check boxes under the cues and the Fit button; ticked, Fit refits with the
    option although the scene has a fit.json, unticked it uses that fit.json."""
    bpy = registered
    s = bpy.context.scene.somacap
    opt = OPTIONS[option]
    prop = s.bl_rna.properties[option]
    assert prop.type == "BOOLEAN" and prop.default is False and getattr(s, option) is False
    assert prop.name == opt.label
    for words in opt.description:
        assert words in prop.description
    assert opt.label in s.bl_rna.properties["fit_cues"].description  # refits

    from .user_scenario import panel_dump

    log = panel_dump(bpy.context)
    i = log.index("button somacap.fit")
    assert log[i - 1 : i + 3] == [
        "field fit_cues",
        "button somacap.fit",
        "field feet_from_points",
        "field smooth_motion",
    ]

    scene = make_scene(tmp_path / "walk", with_fit=True)
    before = (scene / "fit.json").read_bytes()
    s.scene_dir = str(scene)
    s.take = "walk"
    capfd.readouterr()
    assert bpy.ops.somacap.fit() == {"FINISHED"}  # unticked: the scene's fit.json
    assert fake_run_fit == []
    assert "Used the scene's existing fit.json" in capfd.readouterr().out
    setattr(s, option, True)
    s.fit_cues = "both"
    assert bpy.ops.somacap.fit() == {"FINISHED"}
    assert fake_run_fit == [("walk", "both", option)]
    assert "existing fit.json" not in capfd.readouterr().out  # not "cached"
    assert s.body is not None and s.body["somacap_rmse_mm"] is not None
    assert len(s.body["somacap_rmse_mm"]) == 4  # the new fit was built
    for name in OPTIONS:
        setattr(s, name, True)
    assert bpy.ops.somacap.fit() == {"FINISHED"}
    assert fake_run_fit[-1] == ("walk", "both", *OPTIONS)  # both ticked: one fit with both
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
        scene_dir,
        out_json,
        progress=None,
        cues="texture",
        clicks_xyz=None,
        feet_from_points=False,
        smooth_motion=False,
        contour_starts=True,
        late_shape=True,
        flow_choice=True,
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
