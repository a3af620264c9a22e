"""bench.fit: the real-pipeline row printed under the default scene's truth-derived row."""

from pathlib import Path

import bench.fit as bf


class _Calls(list):
    shapes: list


def _record(monkeypatch):
    calls = _Calls()
    calls.shapes = []

    def fake_run_one(
        scene, frames, observations, model, cues="texture", tracks=None, shape="written"
    ):
        calls.append((Path(scene).name, observations, cues, tracks))
        calls.shapes.append(shape)
        return {"scene": Path(scene).name, "error": ["not run in this test"]}

    monkeypatch.setattr(bf, "run_one", fake_run_one)
    monkeypatch.setattr(bf, "default_tracks", lambda: bf.ROOT / "out" / "t.tracks.npz")
    return calls


def test_real_row_follows_the_truth_derived_row_of_the_default_scene(monkeypatch, capsys):
    calls = _record(monkeypatch)
    bf.main([str(bf.DEFAULT), "--real", "both"])
    tracks = bf.ROOT / "out" / "t.tracks.npz"
    assert calls == [
        ("walk_line3", "truth", "texture", None),
        ("walk_line3", "tracks", "both", tracks),
    ]
    assert "REAL pipeline" in capsys.readouterr().out


def test_no_real_row_when_asked_or_for_other_scenes(monkeypatch, tmp_path):
    calls = _record(monkeypatch)
    bf.main([str(bf.DEFAULT), "--real", "none"])
    bf.main([str(tmp_path), "--real", "both"])
    assert [c[1] for c in calls] == ["truth", "truth"]


def test_tracks_observations_use_the_cached_tracks_of_the_default_scene(monkeypatch):
    calls = _record(monkeypatch)
    bf.main([str(bf.DEFAULT), "--observations", "tracks", "--cues", "both"])
    assert calls == [("walk_line3", "tracks", "both", bf.ROOT / "out" / "t.tracks.npz")]


def test_the_body_shape_goes_to_every_fit(monkeypatch):
    calls = _record(monkeypatch)
    bf.main([str(bf.DEFAULT), "--real", "both"])
    bf.main([str(bf.DEFAULT), "--real", "both", "--shape", "template"])
    assert calls.shapes == ["written", "written", "template", "template"]
