"""The opt-outs of the fit's default-on options (``fit_fixtures.DEFAULT_ON``): the extra
starts of a frame fitted from contours alone (``SequenceSettings(contour_starts=False)``:
the panel's "Extra starts (contours alone)", ``--prediction-start-only``), the late
shape's second pass (``SequenceSettings(late_shape_points=None)``: "Second pass (late
shape)", ``--one-pass``) and the refined-flow second fit
(``SequenceSettings(flow_choice=False)``: "Refined-flow second fit", ``--one-flow``),
from the pipeline, CLI, panel and operator down to core's ``fit_scene``; core's fit is
replaced by a recorder (seconds)."""

from __future__ import annotations

from dataclasses import replace

import pytest

from .fit_fixtures import DEFAULT_ON, OPTIONS, cli, make_scene

pytestmark = [pytest.mark.blender]

# On by default (core's default too), so it is the switch off that reaches core, as
# SequenceSettings with the option's field set to its off value.


def setting_of(kw, opt):
    """The value of ``opt``'s field that one recorded ``fit_scene`` call fits with
    (core's default when no settings are passed)."""
    from core.fit import SequenceSettings

    assert set(kw) <= {"cues", "settings"}
    return getattr(kw.get("settings", SequenceSettings()), opt.field)


def before(option):
    """The default-on options drawn before ``option`` (the table is in the panel's
    order)."""
    names = list(DEFAULT_ON)
    return names[: names.index(option)]


def same(got, want):
    """``got == want`` and of its type: ``True`` is not ``1``, ``None`` is ``None``."""
    return got == want and type(got) is type(want)


@pytest.mark.parametrize("on", [True, False], ids=["on", "off"])
@pytest.mark.parametrize("option", DEFAULT_ON)
def test_run_fit_option_passes_sequence_settings(tmp_path, fake_fit_scene, option, on):
    from addon import pipeline
    from core.fit import SequenceSettings

    opt = DEFAULT_ON[option]
    assert same(getattr(SequenceSettings(), opt.field), opt.on)  # on is core's default
    pipeline.run_fit(tmp_path / "sc", tmp_path / "fit.json", cues=opt.cues, **{option: on})
    (kw,) = fake_fit_scene
    if on:
        assert kw == {"cues": opt.cues}  # core's own default
    else:
        assert kw["settings"] == replace(SequenceSettings(), **{opt.field: opt.off})
    value = opt.on if on else opt.off
    assert same(setting_of(kw, opt), value)
    # with smooth motion and the default-on options drawn before it off: one
    # SequenceSettings with all of them
    pipeline.run_fit(
        tmp_path / "sc",
        tmp_path / "b.json",
        smooth_motion=True,
        **dict.fromkeys(before(option), False),
        **{option: on},
    )
    want = replace(
        SequenceSettings(),
        smooth_motion=True,
        **{DEFAULT_ON[b].field: DEFAULT_ON[b].off for b in before(option)},
        **{opt.field: value},
    )
    assert fake_fit_scene[-1]["settings"] == want


def test_asks_new_fit_names_every_option():
    from addon import pipeline

    assert list(pipeline.FIT_OPTIONS) == [*OPTIONS, *DEFAULT_ON]  # the tables, in order
    assert not pipeline.asks_new_fit(**pipeline.FIT_OPTIONS)
    for name, default in pipeline.FIT_OPTIONS.items():
        assert pipeline.asks_new_fit(**{name: not default}), name
    with pytest.raises(KeyError):
        pipeline.asks_new_fit(one_pass=True)  # a misspelt option is an error, not "no"


@pytest.mark.parametrize("option", DEFAULT_ON)
def test_option_is_a_fit_option(option):
    from addon import pipeline

    assert pipeline.FIT_OPTIONS[option] is True
    assert pipeline.asks_new_fit(**{option: False})
    assert not pipeline.asks_new_fit(**{option: True})


@pytest.mark.parametrize("option", DEFAULT_ON)
def test_state_for_scene_option_off_refits_down_to_core(tmp_path, fake_fit_scene, option):
    from addon import pipeline

    opt = DEFAULT_ON[option]
    scene = make_scene(tmp_path / "walk", with_fit=True)
    before = (scene / "fit.json").read_bytes()
    assert pipeline.state_for_scene(scene, **{option: True}).n_frames == 3  # cached
    assert fake_fit_scene == []
    assert pipeline.state_for_scene(scene, cues=opt.cues, **{option: False}).n_frames == 5
    (kw,) = fake_fit_scene
    assert kw["cues"] == opt.cues and same(setting_of(kw, opt), opt.off)
    assert (scene / "fit.json").read_bytes() == before  # not overwritten
    assert pipeline.state_for_scene(scene, scene / "fit.json", **{option: False}).n_frames == 3
    assert len(fake_fit_scene) == 1
    # without cues: texture
    assert pipeline.state_for_scene(scene, **{option: False}).n_frames == 5
    kw = fake_fit_scene[-1]
    assert kw["cues"] == "texture" and same(setting_of(kw, opt), opt.off)
    assert (scene / "fit.json").read_bytes() == before


@pytest.mark.parametrize("flag", [False, True], ids=["without", "with"])
@pytest.mark.parametrize("option", DEFAULT_ON)
def test_cli_fit_flag(tmp_path, fake_fit_scene, empty_blend, capsys, option, flag):
    """The option's flag reaches core as its field's off value; without it the fit keeps
    core's default."""
    opt = DEFAULT_ON[option]
    scene = make_scene(tmp_path / "walk")  # no fit.json: fitted either way
    extra = [opt.flag] if flag else []
    assert cli(["fit", scene, "--out", tmp_path / "a.blend", "--cues", opt.cues, *extra]) == 0
    (kw,) = fake_fit_scene
    want = opt.off if flag else opt.on
    assert kw["cues"] == opt.cues and same(setting_of(kw, opt), want)
    assert "walk: 5 frames" in capsys.readouterr().out

    takes = tmp_path / "takes"
    make_scene(takes / "run")
    assert cli(["batch", takes, "--out", tmp_path / "out", *extra]) == 0
    assert len(fake_fit_scene) == 2 and same(setting_of(fake_fit_scene[-1], opt), want)


@pytest.mark.parametrize("option", DEFAULT_ON)
def test_cli_flag_refits_and_conflicts_with_fit(
    tmp_path, fake_run_fit, empty_blend, capsys, option
):
    opt = DEFAULT_ON[option]
    scene = make_scene(tmp_path / "walk", with_fit=True)
    before = (scene / "fit.json").read_bytes()
    assert cli(["fit", scene, "--out", tmp_path / "a.blend", opt.flag]) == 0
    assert fake_run_fit == [("walk", "texture", opt.record)]  # not the cached fit
    assert (scene / "fit.json").read_bytes() == before
    argv = ["fit", scene, "--out", tmp_path / "b.blend", "--fit", scene / "fit.json"]
    assert cli([*argv, opt.flag]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.endswith(
        f"--fit uses a fitted state and {opt.flag} asks for a new fit: give one of them"
    )
    # with the flag of the option before it (contour_starts: --smooth)
    prev = {**OPTIONS, **DEFAULT_ON}[opt.after].flag
    assert cli([*argv, prev, opt.flag]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.endswith(
        f"--fit uses a fitted state and {prev} and {opt.flag} ask for a new fit: give one of them"
    )
    assert len(fake_run_fit) == 1 and not (tmp_path / "b.blend").exists()


@pytest.mark.parametrize("option", DEFAULT_ON)
def test_cli_help_explains_flag(capsys, option):
    from addon.cli_command import build_parser

    opt = DEFAULT_ON[option]
    for cmd in ("fit", "batch"):
        with pytest.raises(SystemExit):
            build_parser().parse_args([cmd, "--help"])
        text = " ".join(capsys.readouterr().out.split())
        for words in opt.help:
            assert words in text
        args = build_parser().parse_args([cmd, "x", "--out", "o"])
        assert getattr(args, opt.record) is False  # the option on by default
    with pytest.raises(SystemExit):
        build_parser().parse_args(["retarget", "--help"])
    assert opt.flag not in capsys.readouterr().out


@pytest.mark.parametrize("option", DEFAULT_ON)
def test_panel_option(registered, tmp_path, fake_fit_scene, capfd, option):
    """The check box after the opt-in ones, on by default; unticked, Fit refits with its
    field off although the scene has a fit.json; ticked, it uses that fit.json, and a
    scene without one is fitted with core's default."""
    bpy = registered
    s = bpy.context.scene.somacap
    opt = DEFAULT_ON[option]
    prop = s.bl_rna.properties[option]
    assert prop.type == "BOOLEAN" and prop.default is True and getattr(s, option) is True
    assert prop.name == opt.label
    for words in opt.description:
        assert words in prop.description
    assert prop.name in s.bl_rna.properties["fit_cues"].description  # refits

    from .user_scenario import panel_dump

    log = panel_dump(bpy.context)
    i = log.index(f"field {opt.after}")
    assert log[i + 1] == f"field {option}"
    # the cues, the Fit button, then the options in the tables' order up to this one
    # (contour_starts: feet_from_points, smooth_motion, contour_starts)
    drawn = [*OPTIONS, *before(option), option]
    i = log.index("button somacap.fit")
    assert log[i - 1 : i + 1 + len(drawn)] == [
        "field fit_cues",
        "button somacap.fit",
        *(f"field {name}" for name in drawn),
    ]

    scene = make_scene(tmp_path / "walk", with_fit=True)
    s.scene_dir = str(scene)
    s.take = "walk"
    s.fit_cues = opt.cues
    capfd.readouterr()
    assert bpy.ops.somacap.fit() == {"FINISHED"}  # ticked: the scene's fit.json
    assert fake_fit_scene == []
    assert "Used the scene's existing fit.json" in capfd.readouterr().out
    setattr(s, option, False)
    assert bpy.ops.somacap.fit() == {"FINISHED"}
    (kw,) = fake_fit_scene
    assert kw["cues"] == opt.cues and same(setting_of(kw, opt), opt.off)
    assert "existing fit.json" not in capfd.readouterr().out
    assert len(s.body["somacap_rmse_mm"]) == 5  # the new fit was built

    setattr(s, option, True)
    s.scene_dir = str(make_scene(tmp_path / "run"))  # no fit.json: fitted
    assert bpy.ops.somacap.fit() == {"FINISHED"}
    assert len(fake_fit_scene) == 2 and same(setting_of(fake_fit_scene[-1], opt), opt.on)
