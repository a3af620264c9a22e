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
    ref.write_text(
        '[cam_00]\nname = "cam01"\nsize = [64.0, 48.0]\n'
        "matrix = [[1, 0, 0], [0, 1, 0], [0, 0, 1]]\nrotation = [0, 0, 0]\n"
    )
    assert (
        main(["calibrate", str(scene), "-o", str(tmp_path / "o.toml"), "--reference", str(ref)])
        == 2
    )
    assert "missing the key 'translation'" in capsys.readouterr().err


def test_unequal_camera_counts(tmp_path, capsys):
    scene = _wand_scene(tmp_path / "s", n_cams=3)
    ref = tmp_path / "ref.toml"
    write_calibration(ref, rig("ring4"))
    assert (
        main(["calibrate", str(scene), "-o", str(tmp_path / "o.toml"), "--reference", str(ref)])
        == 2
    )
    assert "camera counts must match" in capsys.readouterr().err


def test_unknown_free_parameter(tmp_path, capsys):
    scene = _wand_scene(tmp_path / "s")
    assert main(["calibrate", str(scene), "-o", str(tmp_path / "o.toml"), "--free", "f,zoom"]) == 2
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
            cv2.imwrite(
                str(root / "wand" / c.name / f"{f:06d}.png"), np.clip(img, 0, 255).astype(np.uint8)
            )
    ref = tmp_path / "truth.toml"
    write_calibration(ref, cams)
    out = tmp_path / "cal.toml"
    assert main(["calibrate", str(root), "-o", str(out), "--reference", str(ref)]) == 0
    text = capsys.readouterr().out
    assert "centre error" in text and out.is_file()


def test_z_up_world_from_camera_up_vectors_and_wand_volume():
    from core.calibrate import z_up_world
    from core.camera import Camera
    from tests.core.wand_truth import wand_capture

    cams = rig("ring4")
    xyz, _, _ = wand_capture(cams, n=40, seed=2)
    # the adjustment's world: camera 1's frame, i.e. an arbitrary rigid motion of truth
    R0, t0 = cams[0].R, cams[0].t
    datum = [Camera(c.name, c.size, c.K, c.dist, c.R @ R0.T, c.t - c.R @ R0.T @ t0) for c in cams]
    xyz_d = xyz @ R0.T + t0
    out, T = z_up_world(datum, xyz_d)
    up_truth = np.mean([-c.R[1] for c in cams], axis=0)
    up_truth /= np.linalg.norm(up_truth)
    # the new Z is the truth's mean camera up, so the truth maps by a rotation about it
    xyz_new = xyz_d.reshape(-1, 3) @ T[:3, :3].T + T[:3, 3]
    rel_truth = xyz.reshape(-1, 3) - xyz.reshape(-1, 3)[0]
    rel_new = xyz_new - xyz_new[0]
    np.testing.assert_allclose(rel_new @ [0, 0, 1], rel_truth @ up_truth, atol=1e-9)
    assert abs(xyz_new[:, 2].min()) < 1e-9  # lowest target at Z = 0
    np.testing.assert_allclose(xyz_new[:, :2].mean(axis=0), 0.0, atol=1e-9)
    np.testing.assert_allclose(np.linalg.det(T[:3, :3]), 1.0)
    # images unchanged: the same points project to the same pixels
    for a, b in zip(datum, out, strict=True):
        np.testing.assert_allclose(b.project(xyz_new), a.project(xyz_d.reshape(-1, 3)), atol=1e-7)
