"""A command's output path is checked before any long work: one clear error, nothing
written, nothing computed."""

import pytest

import core.fit_scene
import core.track_cli
from core.cli import main as cli_main
from core.errors import InputError, check_output
from tests.conftest import DEFAULT_SCENE


def test_check_output_accepts_a_file_in_an_existing_folder(tmp_path):
    assert check_output(tmp_path / "tracks.npz", "the tracks", ".npz") == tmp_path / "tracks.npz"
    assert check_output(tmp_path / "fit.json", "the fitted state").name == "fit.json"
    # a writer that makes its folder (the calibration's) may be given a new one
    assert check_output(tmp_path / "new" / "c.toml", "the calibration", makes_folder=True)


@pytest.mark.parametrize(
    "name, suffix, words",
    [
        (".", ".npz", "is a folder"),
        ("missing/tracks.npz", ".npz", "does not exist"),
        ("tracks", ".npz", "must end in .npz"),
        ("tracks.json", ".npz", "must end in .npz"),
    ],
)
def test_check_output_names_the_path_and_the_problem(tmp_path, name, suffix, words):
    with pytest.raises(InputError) as exc:
        check_output(tmp_path / name, "the tracks", suffix)
    assert words in str(exc.value) and str(tmp_path / name) in str(exc.value)


def _refuse(*_a, **_k):
    raise AssertionError("the command started its work before checking its output path")


def test_track_refuses_a_folder_before_tracking(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(core.track_cli, "load_scene", _refuse)
    before = sorted(p.name for p in tmp_path.iterdir())
    assert cli_main(["track", str(DEFAULT_SCENE), "-o", str(tmp_path)]) == 2
    assert "is a folder" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == before  # no '<folder>.npz' either
    assert not (tmp_path.parent / f"{tmp_path.name}.npz").exists()


def test_fit_refuses_a_missing_folder_before_fitting(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(core.fit_scene, "run_scene", _refuse)
    out = tmp_path / "no_such_folder" / "fit.json"
    assert cli_main(["fit", str(DEFAULT_SCENE), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "does not exist" in err and str(out) in err


def test_calibrate_refuses_a_folder(tmp_path, capsys):
    assert cli_main(["calibrate", str(DEFAULT_SCENE), "-o", str(tmp_path)]) == 2
    assert "is a folder" in capsys.readouterr().err
