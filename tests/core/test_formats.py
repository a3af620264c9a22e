import numpy as np
import pytest

from core.errors import InputError
from core.formats import read_opencv_yaml, read_qca, write_opencv_yaml
from tests.core.wand_truth import rig


def test_opencv_yaml_round_trip(tmp_path, rng):
    cam = rig("line3")[0]
    path = write_opencv_yaml(tmp_path / "cam01.yml", cam)
    back = read_opencv_yaml(path)
    xyz = rng.uniform(-0.5, 0.5, size=(20, 3)) + [0, 0, 1]
    np.testing.assert_allclose(back.project(xyz), cam.project(xyz), atol=1e-9)
    assert back.size == cam.size


def test_opencv_yaml_missing_key(tmp_path):
    path = tmp_path / "bad.yml"
    path.write_text(
        "%YAML:1.0\n---\nimage_width: 10\nimage_height: 10\n"
        "camera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n"
        "   data: [1., 0., 0., 0., 1., 0., 0., 0., 1.]\n"
    )
    with pytest.raises(InputError, match="missing the key 'R'"):
        read_opencv_yaml(path)


def test_qualisys_cameras_look_at_one_place(shared_data):
    cams = read_qca(shared_data / "video/pose2sim_single/calibration/Calib.qca.txt")
    assert len(cams) == 4
    assert cams[0].size == (1088, 1920)
    # the optical axes meet: least-squares point of the four axes is in front of all
    A, b = np.zeros((3, 3)), np.zeros(3)
    for c in cams:
        d = c.R[2]
        Q = np.eye(3) - np.outer(d, d)
        A += Q
        b += Q @ c.center
    X = np.linalg.solve(A, b)
    for c in cams:
        u, v = c.project(X)
        assert 0 <= u < c.size[0] and 0 <= v < c.size[1]
        assert np.linalg.norm(np.cross(c.R[2], X - c.center)) < 0.2
    assert 1000 < cams[0].K[0, 0] < 2000  # 107600 / 64 px


def test_qualisys_missing_key(tmp_path):
    p = tmp_path / "c.qca.txt"
    p.write_text(
        '<calibration><cameras><camera serial="c1"><transform r11="1"/>'
        '<intrinsic/><fov_video left="0" right="9" top="0" bottom="9"/>'
        "</camera></cameras></calibration>"
    )
    with pytest.raises(InputError, match="missing the key"):
        read_qca(p)
