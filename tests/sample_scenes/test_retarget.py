"""Retargeting the CMU walk onto the A-pose MakeHuman character looks natural."""

from __future__ import annotations

import numpy as np
import pytest

from sample_scenes.bvh import CMU_SCALE, read_bvh
from sample_scenes.retarget import Rig, retarget

pytestmark = pytest.mark.blender


@pytest.fixture(scope="module")
def character_rig():
    from tests.conftest import SHARED_DATA

    path = SHARED_DATA / "characters" / "makehuman_cmu_mb.blend"
    if not path.is_file():
        pytest.skip(f"shared data not found at {SHARED_DATA}")
    bpy = pytest.importorskip("bpy")
    # Load only the armature data block: leaves whatever file is open untouched.
    with bpy.data.libraries.load(str(path)) as (src, dst):
        dst.armatures = list(src.armatures)
    arm = dst.armatures[0]
    bones = list(arm.bones)
    names = [b.name for b in bones]
    rig = Rig(
        names,
        np.array([names.index(b.parent.name) if b.parent else -1 for b in bones]),
        np.array([np.array(b.matrix_local) for b in bones]),
        np.array([np.array(b.tail_local) for b in bones]),
    )
    bpy.data.armatures.remove(arm)
    return rig


def _pos(rt, rig, name):
    return rt.matrices[:, rig.names.index(name), :3, 3]


def test_knees_and_ankles_follow_the_scaled_bvh(character_rig, shared_data):
    rig = character_rig
    bvh = read_bvh(shared_data / "mocap" / "02_01.bvh")
    times = np.arange(bvh.n_frames) * bvh.frame_time
    rt = retarget(rig, bvh, times, CMU_SCALE)
    assert 0.85 < rt.scale < 1.15
    for bone in ("LeftLeg", "RightLeg", "LeftFoot", "RightFoot"):
        err = np.linalg.norm(_pos(rt, rig, bone) - rt.bvh_xyz[:, bvh.index(bone)], axis=1)
        assert err.max() < 0.04, (bone, err.max())
    # Heads follow parents' tails: bone lengths are the character's own.
    for bone, child in (("LeftUpLeg", "LeftLeg"), ("RightLeg", "RightFoot")):
        rest = np.linalg.norm(rig.heads[rig.names.index(child)] - rig.heads[rig.names.index(bone)])
        posed = np.linalg.norm(_pos(rt, rig, child) - _pos(rt, rig, bone), axis=1)
        np.testing.assert_allclose(posed, rest, atol=1e-5)


def test_legs_neither_cross_nor_twist(character_rig, shared_data):
    rig = character_rig
    bvh = read_bvh(shared_data / "mocap" / "02_01.bvh")
    times = np.arange(bvh.n_frames) * bvh.frame_time
    rt = retarget(rig, bvh, times, CMU_SCALE)
    lateral = _pos(rt, rig, "LeftUpLeg") - _pos(rt, rig, "RightUpLeg")
    lateral /= np.linalg.norm(lateral, axis=1, keepdims=True)
    # Not crossed: the left knee and ankle stay on the left of the right ones.
    for a, b in (("LeftLeg", "RightLeg"), ("LeftFoot", "RightFoot")):
        sep = np.sum((_pos(rt, rig, a) - _pos(rt, rig, b)) * lateral, axis=1)
        assert sep.min() > 0.02, (a, sep.min())
    # Not twisted: each knee hinges about the hip axis (thigh x shin ~ lateral) and the
    # toes point forward, where the knee is bent.
    for side in ("Left", "Right"):
        hip, knee, ankle, toe = (
            _pos(rt, rig, f"{side}{n}") for n in ("UpLeg", "Leg", "Foot", "ToeBase")
        )
        thigh, shin = knee - hip, ankle - knee
        hinge = np.cross(thigh, shin)
        sin = np.linalg.norm(hinge, axis=1) / (
            np.linalg.norm(thigh, axis=1) * np.linalg.norm(shin, axis=1)
        )
        bent = sin > np.sin(np.radians(20))
        assert bent.sum() > 20
        cos = np.sum(hinge * lateral, axis=1) / np.linalg.norm(hinge, axis=1)
        assert np.all(cos[bent] > 0.8), (side, cos[bent].min())
        # Feet flat on the floor (stance) point forward, within 45 degrees.
        forward = np.cross(lateral, [0.0, 0.0, 1.0])  # facing direction (Z up)
        foot = toe - ankle
        flat = ankle[:, 2] < ankle[:, 2].min() + 0.04
        assert flat.sum() > 20
        heading = np.sum(foot[flat, :2] * forward[flat, :2], axis=1) / np.linalg.norm(
            foot[flat, :2], axis=1
        )
        assert heading.min() > np.cos(np.radians(45)), (side, heading.min())
