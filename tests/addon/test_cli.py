"""The headless commands through the documented launcher (``python -m addon.launch``)."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from core.calibration_io import write_calibration
from core.camera import Camera, rodrigues_to_matrix
from core.state import write_state

from .state_fixtures import synthetic_state

pytestmark = [pytest.mark.blender]

REPO = __import__("pathlib").Path(__file__).resolve().parents[2]


def launch(*args, timeout=300):
    return subprocess.run(
        [sys.executable, "-m", "addon.launch", *map(str, args)],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def blend_contents(path):
    import bpy

    with bpy.data.libraries.load(str(path)) as (src, _):
        return {
            "objects": list(src.objects),
            "actions": list(src.actions),
            "cameras": list(src.cameras),
        }


def test_batch_continues_past_a_corrupt_take(tmp_path, bpy_module):
    takes = tmp_path / "takes"
    takes.mkdir()
    write_state(takes / "walk_a.json", synthetic_state(6, seed=1))
    (takes / "broken.json").write_text('{"format": "somacap.state", "version": 1, "fps": ')
    write_state(takes / "walk_b.json", synthetic_state(4, seed=2))
    out = tmp_path / "out"
    proc = launch("batch", takes, "--out", out, "--export", "bvh")
    assert proc.returncode == 1, proc.stdout + proc.stderr
    assert "2 converted, 1 failed" in proc.stdout
    assert "FAILED broken.json: " in proc.stderr and "broken.json: not valid JSON" in proc.stderr
    assert sorted(p.name for p in out.glob("*.blend")) == ["walk_a.blend", "walk_b.blend"]
    assert (out / "walk_a.bvh").read_text().startswith("HIERARCHY")
    c = blend_contents(out / "walk_a.blend")
    assert "walk_a" in c["actions"] and "walk_a_armature" in c["objects"]
    assert sum(n.startswith("walk_a_body") for n in c["objects"]) > 10


def test_fit_with_state_and_cameras(tmp_path, bpy_module):
    scene = tmp_path / "scene01"
    scene.mkdir()
    cams = [
        Camera(
            f"cam{i}",
            (64, 48),
            [[80, 0, 32], [0, 80, 24], [0, 0, 1]],
            np.zeros(5),
            rodrigues_to_matrix([1.6, 0, 0.3 * i]),
            [0, -1, 5],
        )
        for i in range(3)
    ]
    write_calibration(scene / "calibration.toml", cams)
    write_state(scene / "fit.json", synthetic_state(5))
    proc = launch("fit", scene, "--out", tmp_path / "take.blend")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    c = blend_contents(tmp_path / "take.blend")
    assert sorted(c["cameras"]) == ["cam0", "cam1", "cam2"]
    assert "scene01" in c["actions"]


def test_retarget_onto_character(tmp_path, makehuman):
    write_state(tmp_path / "fit.json", synthetic_state(5))
    char = makehuman
    proc = launch(
        "retarget",
        tmp_path / "fit.json",
        "--target",
        char,
        "--out",
        tmp_path / "take.blend",
        "--export",
        "fbx",
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "retargeted" in proc.stdout and "MakeHuman_cmu_mb" in proc.stdout
    c = blend_contents(tmp_path / "take.blend")
    assert {"fit", "fit.001"} <= set(c["actions"])  # the body's and the character's
    assert (tmp_path / "take.fbx").stat().st_size > 1000


def test_bad_input_is_one_clear_line(tmp_path, bpy_module):
    proc = launch(
        "retarget",
        tmp_path / "missing.json",
        "--target",
        tmp_path / "c.blend",
        "--out",
        tmp_path / "o.blend",
    )
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines()[-1] == (
        f"somacap: error: {tmp_path / 'missing.json'}: fitted-state file not found"
    )
    assert not (tmp_path / "o.blend").exists()
