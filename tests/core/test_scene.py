"""Scene folder loading and validation (SPEC.md, "A scene folder")."""

import json

import cv2
import numpy as np
import pytest

from core.calibration_io import write_calibration
from core.camera import Camera
from core.errors import InputError
from core.scene import load_scene


def _make_scene(root, frames=(3, 3), size=(32, 24), field="none"):
    cams = [f"cam0{i + 1}" for i in range(len(frames))]
    w, h = size
    (root / "scene.toml").write_text(
        f'name = "tiny"\nfps = 25.0\nframes = {frames[0]}\ncameras = {json.dumps(cams)}\n'
        f'size = [{w}, {h}]\nfield = "{field}"\n'
    )
    for cam, n in zip(cams, frames, strict=True):
        folder = root / "images" / cam
        folder.mkdir(parents=True)
        for i in range(n):
            img = np.full((h, w, 3), 10 * i, np.uint8)
            img[np.arange(h) % 2 == 1] = 200  # odd rows (0-based) bright
            cv2.imwrite(str(folder / f"{i:06d}.png"), img)
    half = h if field == "none" else (h + 1) // 2
    write_calibration(
        root / "calibration.toml", [Camera(c, (w, half), np.diag([50.0, 50.0, 1.0])) for c in cams]
    )
    return cams


def test_loads_and_reads_images(tmp_path):
    cams = _make_scene(tmp_path)
    scene = load_scene(tmp_path)
    assert scene.cameras == cams and scene.n_frames == 3 and scene.image_size == (32, 24)
    img = scene.image("cam02", 2)
    assert img.shape == (24, 32) and img.dtype == np.uint8 and img[0, 0] == 20
    assert [c.name for c in scene.calibration()] == cams


def test_odd_field_keeps_even_rows(tmp_path):
    _make_scene(tmp_path, field="odd")
    scene = load_scene(tmp_path)
    img = scene.image("cam01", 1)
    assert img.shape == (12, 32) and np.all(img == 10)
    assert scene.calibration()[0].size == (32, 12)


def test_unequal_frame_counts(tmp_path):
    _make_scene(tmp_path, frames=(3, 2))
    with pytest.raises(InputError, match="cam02 has 2 frames, cam01 has 3"):
        load_scene(tmp_path)


def test_frame_count_disagrees_with_scene_toml(tmp_path):
    _make_scene(tmp_path)
    text = (tmp_path / "scene.toml").read_text().replace("frames = 3", "frames = 5")
    (tmp_path / "scene.toml").write_text(text)
    with pytest.raises(InputError, match=r"scene.toml: says 5 frames but the images hold 3"):
        load_scene(tmp_path)


def test_missing_scene_toml(tmp_path):
    with pytest.raises(InputError, match=r"scene.toml: file not found"):
        load_scene(tmp_path)


def test_missing_camera_folder(tmp_path):
    _make_scene(tmp_path)
    text = (tmp_path / "scene.toml").read_text().replace('"cam02"]', '"cam02", "cam09"]')
    (tmp_path / "scene.toml").write_text(text)
    with pytest.raises(InputError, match="cam09"):
        load_scene(tmp_path)


def test_calibration_missing_camera(tmp_path):
    _make_scene(tmp_path)
    write_calibration(
        tmp_path / "calibration.toml", [Camera("cam01", (32, 24), np.diag([50.0, 50.0, 1.0]))]
    )
    with pytest.raises(InputError, match=r"calibration.toml: .*missing \['cam02'\]"):
        load_scene(tmp_path).calibration()


def test_malformed_calibration(tmp_path):
    _make_scene(tmp_path)
    (tmp_path / "calibration.toml").write_text("this is = = not toml")
    with pytest.raises(InputError, match=r"calibration.toml: not a valid TOML"):
        load_scene(tmp_path).calibration()


def test_clicks_validation(tmp_path):
    _make_scene(tmp_path)
    path = tmp_path / "clicks.json"
    path.write_text(json.dumps({"frame": 0, "joints": {"head": {"cam01": [1, 2]}}}))
    clicks = load_scene(tmp_path).clicks()
    np.testing.assert_array_equal(clicks["joints"]["head"]["cam01"], [1.0, 2.0])
    path.write_text(json.dumps({"frame": 0, "joints": {"head": {"cam07": [1, 2]}}}))
    with pytest.raises(InputError, match="unknown camera 'cam07'"):
        load_scene(tmp_path).clicks()
    path.write_text("{not json")
    with pytest.raises(InputError, match="clicks.json: not valid JSON"):
        load_scene(tmp_path).clicks()
