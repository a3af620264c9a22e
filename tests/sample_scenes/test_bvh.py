"""BVH reading and world-space retargeting (numpy; the rig comes from the shared character)."""

from __future__ import annotations

import numpy as np
import pytest

from core.errors import InputError
from sample_scenes.bvh import CMU_SCALE, read_bvh

TINY = """HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation
  JOINT Leg
  {
    OFFSET 0 -10 0
    CHANNELS 3 Zrotation Yrotation Xrotation
    End Site
    {
      OFFSET 0 -5 0
    }
  }
}
MOTION
Frames: 2
Frame Time: 0.5
0 20 0 0 0 0 0 0 0
0 20 0 0 0 0 90 0 0
"""


def test_tiny_bvh_forward_kinematics(tmp_path):
    path = tmp_path / "tiny.bvh"
    path.write_text(TINY)
    bvh = read_bvh(path)
    assert bvh.names == ["Hips", "Leg"]
    G, xyz = bvh.sample(np.array([0.0, 0.5, 0.25]), scale=0.1)
    # BVH Y up -> Blender Z up: the hips at 2 m height, the leg 1 m below.
    np.testing.assert_allclose(xyz[0, 0], [0, 0, 2.0], atol=1e-12)
    np.testing.assert_allclose(xyz[0, 1], [0, 0, 1.0], atol=1e-12)
    # 90 deg about BVH X (= Blender X) swings the leg's child end forward/back; the
    # midway sample is the slerp half-way (45 deg).
    end = G[:, 1] @ (bvh.ends[1] * 0.1)
    np.testing.assert_allclose(np.linalg.norm(end, axis=1), 0.5)
    angle = np.degrees(np.arccos(np.clip(-end[:, 2] / 0.5, -1, 1)))
    np.testing.assert_allclose(angle, [0, 90, 45], atol=1e-9)


@pytest.mark.parametrize(
    "text, match",
    [
        ("hello", "not a valid BVH"),
        (TINY.replace("Frames: 2", "Frames: 3"), "expected 3 frames"),
        (TINY.replace("Xrotation\n  JOINT", "Wrotation\n  JOINT"), "unknown channel"),
        (TINY.split("MOTION")[0], "not a valid BVH"),
    ],
)
def test_garbled_bvh_names_the_file(tmp_path, text, match):
    path = tmp_path / "bad.bvh"
    path.write_text(text)
    with pytest.raises(InputError, match=match) as err:
        read_bvh(path)
    assert str(path) in str(err.value)


def test_missing_bvh(tmp_path):
    with pytest.raises(InputError, match="BVH file not found"):
        read_bvh(tmp_path / "nope.bvh")


def test_cmu_walk_units(shared_data):
    bvh = read_bvh(shared_data / "mocap" / "02_01.bvh")
    assert bvh.n_frames == 343 and len(bvh.names) == 31
    _, xyz = bvh.sample(np.arange(0, 2.8, 0.1), CMU_SCALE)
    hips = xyz[:, bvh.index("Hips")]
    assert 0.85 < hips[:, 2].mean() < 1.1  # hips about 1 m above the floor, Z up
    feet = xyz[:, [bvh.index("LeftToeBase"), bvh.index("RightToeBase")], 2]
    assert feet.min() > -0.05 and feet.min() < 0.1
