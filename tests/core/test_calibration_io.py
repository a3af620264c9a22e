import numpy as np
import pytest

from core.calibration_io import read_calibration, write_calibration
from core.camera import Camera, rodrigues_to_matrix
from core.errors import InputError


def test_round_trip(tmp_path, rng):
    cams = [
        Camera(
            f"cam0{i}",
            (512, 384),
            [[700 + i, 0, 256], [0, 700 + i, 192], [0, 0, 1]],
            rng.normal(size=5) * 0.01,
            rodrigues_to_matrix(rng.normal(size=3)),
            rng.normal(size=3),
        )
        for i in range(1, 4)
    ]
    path = write_calibration(tmp_path / "calibration.toml", cams)
    back = read_calibration(path)
    assert [c.name for c in back] == ["cam01", "cam02", "cam03"]
    for a, b in zip(cams, back, strict=True):
        np.testing.assert_allclose(b.K, a.K)
        np.testing.assert_allclose(b.R, a.R, atol=1e-12)
        np.testing.assert_allclose(b.t, a.t)
        np.testing.assert_allclose(b.dist, a.dist)


def test_missing_key_names_file_and_key(tmp_path):
    p = tmp_path / "calibration.toml"
    p.write_text(
        '[cam_00]\nname = "cam01"\nsize = [10.0, 10.0]\n'
        "matrix = [[1,0,0],[0,1,0],[0,0,1]]\nrotation = [0.0, 0.0, 0.0]\n"
    )
    with pytest.raises(InputError, match=r"calibration.toml.*missing the key 'translation'"):
        read_calibration(p)


def test_garbled_file(tmp_path):
    p = tmp_path / "calibration.toml"
    p.write_text("[cam_00\nname=")
    with pytest.raises(InputError, match="not a valid TOML"):
        read_calibration(p)


def test_wrong_shape(tmp_path):
    p = tmp_path / "calibration.toml"
    p.write_text(
        '[cam_00]\nname = "cam01"\nsize = [10.0, 10.0]\nmatrix = [[1,0,0],[0,1,0]]\n'
        "rotation = [0.0, 0.0, 0.0]\ntranslation = [0.0, 0.0, 0.0]\n"
    )
    with pytest.raises(InputError, match=r"matrix has shape \(2, 3\)"):
        read_calibration(p)


def test_refuses_overwrite_when_asked(tmp_path):
    p = tmp_path / "calibration.toml"
    p.write_text("keep me")
    with pytest.raises(InputError, match="exists already"):
        write_calibration(p, [Camera("c", (1, 1), np.eye(3))], overwrite=False)
    assert p.read_text() == "keep me"
