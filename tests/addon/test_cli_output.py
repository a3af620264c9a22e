"""``blender -c somacap fit | retarget`` refuse an unusable --out before any work."""

import pytest

from core.state import write_state

from .fit_fixtures import cli, make_scene
from .state_fixtures import synthetic_state

pytestmark = [pytest.mark.blender]


def test_fit_refuses_a_folder_or_another_suffix_before_fitting(tmp_path, fake_run_fit, capsys):
    scene = make_scene(tmp_path / "walk")
    folder = tmp_path / "takes"
    folder.mkdir()
    assert cli(["fit", scene, "--out", folder]) == 2
    assert capsys.readouterr().err.strip().splitlines()[-1] == (
        f"somacap: error: {folder}: is a folder; give a file name for the take"
    )
    assert cli(["fit", scene, "--out", tmp_path / "take.fbx"]) == 2
    assert "must end in .blend" in capsys.readouterr().err
    assert fake_run_fit == []  # nothing was fitted
    # a folder that does not exist yet is made, as before
    assert cli(["fit", scene, "--out", tmp_path / "new" / "take.blend"]) == 0
    assert (tmp_path / "new" / "take.blend").is_file() and fake_run_fit == [("walk", "texture")]


def test_retarget_refuses_a_folder(tmp_path, bpy_module, capsys):
    state = write_state(tmp_path / "fit.json", synthetic_state(3, seed=1))
    assert cli(["retarget", state, "--target", tmp_path / "c.blend", "--out", tmp_path]) == 2
    assert "is a folder" in capsys.readouterr().err
