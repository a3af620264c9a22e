"""The extension as a user gets it: manifest validation, the built zip, install/enable cycles."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from addon import packaging

HERE = Path(__file__).resolve().parent

pytestmark = pytest.mark.blender


@pytest.fixture(scope="module")
def built_zip(tmp_path_factory):
    """The extension zip built by Blender's tool (no wheels: the env has scipy and cv2)."""
    pytest.importorskip("bpy")
    tmp = tmp_path_factory.mktemp("ext")
    zips = packaging.build(tmp / "dist", with_wheels=False, staging=tmp / "stage")
    assert len(zips) == 1
    return zips[0]


def test_manifest_passes_blenders_validator(tmp_path):
    pytest.importorskip("bpy")
    # The tags of extensions.blender.org, as Blender ships them for translation.
    from _bpy_internal.extensions import tags as blender_tags

    tags = tmp_path / "tags.json"
    tags.write_text(
        json.dumps(
            {"add-on": sorted(blender_tags.addons - {"All"}), "theme": sorted(blender_tags.themes)}
        )
    )
    proc = packaging.run_blender_ext("validate", "--valid-tags", str(tags), str(packaging.REPO))
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "Success" in proc.stdout


def test_validator_rejects_a_bad_manifest(tmp_path):
    """The check can fail: an over-long tagline is refused by the same tool."""
    pytest.importorskip("bpy")
    text = (packaging.REPO / "blender_manifest.toml").read_text()
    (tmp_path / "blender_manifest.toml").write_text(
        text.replace('tagline = "', 'tagline = "' + "x" * 80, 1)
    )
    proc = packaging.run_blender_ext("validate", str(tmp_path))
    assert proc.returncode != 0
    assert "tagline" in proc.stdout + proc.stderr


def test_split_platform_build_bundles_the_right_wheels(tmp_path):
    """Each platform zip gets its own wheels (both Pythons) and a validating manifest."""
    pytest.importorskip("bpy")
    fake = []
    for tag in ("manylinux_2_17_x86_64", "win_amd64", "macosx_12_0_arm64", "macosx_10_13_x86_64"):
        for py in ("cp311", "cp313"):
            fake.append(tmp_path / "w" / f"scipy-1.0-{py}-{py}-{tag}.whl")
        fake.append(tmp_path / "w" / f"opencv_python_headless-4.10.0.84-cp37-abi3-{tag}.whl")
    for f in fake:
        f.parent.mkdir(exist_ok=True)
        with zipfile.ZipFile(f, "w") as z:
            z.writestr("x.txt", "x")
    src = packaging.stage(tmp_path / "stage", fake)
    (tmp_path / "out").mkdir()
    assert packaging.validate(src).returncode == 0
    proc = packaging.run_blender_ext(
        "build",
        "--split-platforms",
        "--source-dir",
        str(src),
        "--output-dir",
        str(tmp_path / "out"),
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    zips = sorted((tmp_path / "out").glob("*.zip"))
    assert [z.name.split("-")[-1] for z in zips] == [
        "linux_x64.zip",
        "macos_arm64.zip",
        "macos_x64.zip",
        "windows_x64.zip",
    ]
    for z in zips:
        names = zipfile.ZipFile(z).namelist()
        wheels = [n for n in names if n.endswith(".whl")]
        assert len(wheels) == 3, (z.name, wheels)
        assert not any("numpy" in n for n in names)
        assert "core/camera.py" in names and "addon/_core.py" in names
        assert not any(n.startswith(("tests/", "bench/", ".venv")) for n in names)
        assert packaging.validate(z).returncode == 0


def test_install_enable_disable_reenable(built_zip, tmp_path):
    env = {**os.environ, "BLENDER_USER_RESOURCES": str(tmp_path / "user")}
    proc = subprocess.run(
        [sys.executable, str(HERE / "install_scenario.py"), str(built_zip)],
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "Traceback" not in proc.stderr, proc.stderr[-3000:]
    s = json.loads(proc.stdout.strip().splitlines()[-1])
    assert s["install_result"] == ["FINISHED"]
    assert Path(s["package_file"]).is_relative_to(tmp_path / "user")
    assert s["core_module"] == "bl_ext.user_default.somacap.core"
    before, inst, off, again = s["before"], s["installed"], s["disabled"], s["reenabled"]
    assert not before["enabled"] and not before["ops"] and not before["types"]
    assert inst["enabled"] and inst["scene_prop"]
    assert {"fit", "build_body", "retarget", "create_cameras"} <= set(inst["ops"])
    assert any(t.startswith("SOMACAP_PT_") for t in inst["types"])
    # Disabled: nothing of ours is left registered.
    assert not off["enabled"] and not off["ops"] and not off["types"] and not off["scene_prop"]
    assert off["n_types"] == before["n_types"]
    # Re-enabled: exactly what the first enable registered.
    for key in ("ops", "types", "scene_prop", "enabled", "n_types"):
        assert again[key] == inst[key], key


def test_new_user_runs_the_panel_operators(built_zip, tmp_path):
    """Install the zip, then press the panel's buttons in order, as a new user would."""
    import numpy as np

    from core.calibration_io import write_calibration
    from core.camera import Camera, rodrigues_to_matrix
    from core.state import write_state

    from .state_fixtures import synthetic_state

    scene = tmp_path / "scene"
    scene.mkdir()
    cams = [
        Camera(
            f"cam{i}",
            (64, 48),
            [[80, 0, 32], [0, 80, 24], [0, 0, 1]],
            np.zeros(5),
            rodrigues_to_matrix([1.6, 0, 0.5 * i]),
            [0, -1, 5],
        )
        for i in range(2)
    ]
    write_calibration(scene / "calibration.toml", cams)
    write_state(scene / "fit.json", synthetic_state(5))
    env = {**os.environ, "BLENDER_USER_RESOURCES": str(tmp_path / "user")}
    proc = subprocess.run(
        [sys.executable, str(HERE / "user_scenario.py"), str(built_zip), str(scene), str(tmp_path)],
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    r = json.loads(proc.stdout.strip().splitlines()[-1])
    for step in ("install", "cameras", "fit", "map", "retarget", "export", "build_again"):
        assert r[step] == ["FINISHED"], step
    assert r["camera_objects"] == ["cam0", "cam1"]
    assert r["body"] == "demo_armature" and r["mapped"] >= 18
    assert r["target_action"] == "demo.001"
    assert {"demo", "demo.001", "demo.002"} <= set(r["actions"])
    assert (tmp_path / "demo.bvh").read_text().startswith("HIERARCHY")
    assert "panel Somacap (VIEW_3D/UI/Somacap)" in r["panel"]
    assert "button somacap.fit" in r["panel"] and "button somacap.retarget" in r["panel"]
    assert any(line.startswith("label Frame 1: RMSE") for line in r["panel"])
    assert "nope.json: fitted-state file not found" in r["bad_state"]
    assert r["objects_unchanged"]
