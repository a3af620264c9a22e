"""bench.flow_truth: the texture flow's corners against the true mesh's material points."""

from __future__ import annotations

import numpy as np

from bench.flow_truth import main, measure
from core.scene import load_scene
from tests.conftest import DEFAULT_SCENE


def test_corners_follow_their_material_points_and_lsm_refines_them():
    """The walk moves each corner 7–13 px between frames: Lucas–Kanade follows the
    corners' true points to a fraction of a pixel, and LSM refined to less, keeping
    no corner that Lucas–Kanade lost."""
    scene = load_scene(DEFAULT_SCENE, check_images=False)
    rows = measure(scene, ["head", "l_knee"], step=25)
    for part in ("head", "l_knee"):
        lk, fine = rows[part, "LK"], rows[part, "LK + LSM"]
        assert len(lk) >= 40 and len(fine) <= len(lk)
        assert np.median(lk[:, 4]) > 5.0  # a real move, pixels
        assert np.all(lk[:, 2] >= 3.0)  # inside the outline by the erosion
        assert np.median(lk[:, 3]) < 0.2
        assert np.median(fine[:, 3]) < np.median(lk[:, 3])
        assert np.percentile(fine[:, 3], 90) < np.percentile(lk[:, 3], 90)
        assert np.all(np.abs(lk[:, 5]) <= lk[:, 3] + 1e-9)  # along: a component of the error


def test_the_command_line_prints_both_followers_and_refuses_bad_parts(capsys):
    assert main([str(DEFAULT_SCENE), "--step", "49", "--parts", "head"]) == 0
    out = capsys.readouterr().out
    assert "LK (Lucas–Kanade)" in out and "LK + LSM (refined)" in out
    assert sum(ln.startswith("head ") for ln in out.splitlines()) == 5  # one row per band
    assert main([str(DEFAULT_SCENE), "--parts", "head,tail"]) == 2
    assert "['tail'] are not truth joints" in capsys.readouterr().err
