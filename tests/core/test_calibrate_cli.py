import cv2
import numpy as np
import pytest

from core.calibration_io import write_calibration
from core.cli import main
from tests.core.wand_truth import rig


def _wand_scene(root, n_cams=3, frames=6, both=True):
    root.mkdir(parents=True)
    (root / "wand.toml").write_text("length_m = 0.5\n")
    for c in range(n_cams):
        folder = root / "wand" / f"cam{c + 1:02d}"
        folder.mkdir(parents=True)
        for f in range(frames):
            img = np.zeros((48, 64), np.uint8)
            cv2.circle(img, (10 + f, 20), 2, 255, -1)
            if both:
                cv2.circle(img, (40, 30 - f), 2, 255, -1)
            cv2.imwrite(str(folder / f"{f:06d}.png"), img)
    return root


def test_no_frame_with_both_targets_is_one_clear_error(tmp_path, capsys):
    scene = _wand_scene(tmp_path / "s", both=False)
    assert main(["calibrate", str(scene), "-o", str(tmp_path / "out.toml")]) == 2
    err = capsys.readouterr().err
    assert "no frame shows both wand targets" in err and "Traceback" not in err
    assert not (tmp_path / "out.toml").exists()


def test_existing_calibration_is_not_overwritten(tmp_path, capsys):
    scene = _wand_scene(tmp_path / "s")
    existing = scene / "calibration.toml"
    existing.write_text("# mine\n")
    assert main(["calibrate", str(scene)]) == 2
    assert "exists already" in capsys.readouterr().err
    assert existing.read_text() == "# mine\n"


def test_reference_with_missing_key(tmp_path, capsys):
    scene = _wand_scene(tmp_path / "s")
    ref = tmp_path / "ref.toml"
    ref.write_text('[cam_00]\nname = "cam01"\nsize = [64.0, 48.0]\n'
                   'matrix = [[1, 0, 0], [0, 1, 0], [0, 0, 1]]\nrotation = [0, 0, 0]\n')
    assert main(["calibrate", str(scene), "-o", str(tmp_path / "o.toml"),
                 "--reference", str(ref)]) == 2
    assert "missing the key 'translation'" in capsys.readouterr().err


def test_unequal_camera_counts(tmp_path, capsys):
    scene = _wand_scene(tmp_path / "s", n_cams=3)
    ref = tmp_path / "ref.toml"
    write_calibration(ref, rig("ring4"))
    assert main(["calibrate", str(scene), "-o", str(tmp_path / "o.toml"),
                 "--reference", str(ref)]) == 2
    assert "camera counts must match" in capsys.readouterr().err


def test_unknown_free_parameter(tmp_path, capsys):
    scene = _wand_scene(tmp_path / "s")
    assert main(["calibrate", str(scene), "-o", str(tmp_path / "o.toml"), "--free",
                 "f,zoom"]) == 2
    assert "unknown interior parameter 'zoom'" in capsys.readouterr().err


@pytest.mark.slow
def test_calibrates_rendered_blobs_end_to_end(tmp_path, capsys):
    cams = rig("line3")
    rng = np.random.default_rng(4)
    root = tmp_path / "scene"
    (root / "wand").mkdir(parents=True)
    (root / "wand.toml").write_text("length_m = 0.5\n")
    mid = rng.uniform([-0.6, -0.6, 0.5], [0.6, 0.6, 1.6], size=(60, 3))
    d = rng.normal(size=(60, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    xyz = np.stack([mid - d * 0.25, mid + d * 0.25], axis=1)
    vv, uu = np.indices((384, 512))
    for c in cams:
        (root / "wand" / c.name).mkdir()
        uv = c.project(xyz)
        for f in range(len(xyz)):
            img = np.zeros((384, 512))
            for u, v in uv[f]:
                img += 240 * np.exp(-((uu - u) ** 2 + (vv - v) ** 2) / (2 * 1.3**2))
            cv2.imwrite(str(root / "wand" / c.name / f"{f:06d}.png"), np.clip(img, 0, 255)
                        .astype(np.uint8))
    ref = tmp_path / "truth.toml"
    write_calibration(ref, cams)
    out = tmp_path / "cal.toml"
    assert main(["calibrate", str(root), "-o", str(out), "--reference", str(ref)]) == 0
    text = capsys.readouterr().out
    assert "centre error" in text and out.is_file()
