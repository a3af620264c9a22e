"""Automatic bone mapping across naming schemes (no Blender needed)."""

from __future__ import annotations

import re

import pytest

from core.bone_mapping import (
    CANONICAL_BONES,
    REQUIRED_BONES,
    SCHEMES,
    load_preset,
    map_bones,
    pair_bones,
    save_preset,
)
from core.errors import InputError

# Hand-written rigs as their tools name them (extra bones included), canonical -> name.
RIGS = {
    "rigify_def": (
        {
            "pelvis": "DEF-spine",
            "head": "DEF-spine.006",
            "l_upper_arm": "DEF-upper_arm.L",
            "r_shin": "DEF-shin.R",
            "l_clavicle": "DEF-shoulder.L",
        },
        ["DEF-upper_arm.L.001", "ORG-spine", "MCH-spine", "root", "DEF-breast.L"],
    ),
    "mixamo": (
        {
            "pelvis": "mixamorig12:Hips",
            "upper_chest": "mixamorig12:Spine2",
            "l_forearm": "mixamorig12:LeftForeArm",
            "r_thigh": "mixamorig12:RightUpLeg",
            "l_toe": "mixamorig12:LeftToeBase",
        },
        ["mixamorig12:HeadTop_End", "mixamorig12:LeftHandIndex1"],
    ),
    "unreal": (
        {
            "pelvis": "pelvis",
            "l_shin": "calf_l",
            "r_upper_arm": "upperarm_r",
            "chest": "spine_02",
            "l_toe": "ball_l",
        },
        ["root", "ik_foot_root", "upperarm_twist_01_l", "spine_04", "spine_05"],
    ),
    "vrm": (
        {
            "pelvis": "hips",
            "l_thigh": "leftUpperLeg",
            "r_forearm": "rightLowerArm",
            "upper_chest": "upperChest",
        },
        ["leftEye", "jaw"],
    ),
    "vroid": (
        {"pelvis": "J_Bip_C_Hips", "l_thigh": "J_Bip_L_UpperLeg", "r_hand": "J_Bip_R_Hand"},
        ["J_Sec_Hair1_01", "J_Adj_L_FaceEye"],
    ),
    "mpfb": (
        {
            "pelvis": "spine05",
            "l_thigh": "upperleg01.L",
            "r_shin": "lowerleg01.R",
            "l_forearm": "lowerarm01.L",
        },
        ["root", "upperleg02.L", "lowerarm02.L", "pelvis.L", "breast.L"],
    ),
}


def _full_rig(scheme, extra):
    return list(SCHEMES[scheme].values()) + list(extra)


@pytest.mark.parametrize("scheme", sorted(RIGS))
def test_each_scheme_maps_its_rig(scheme):
    expect, extra = RIGS[scheme]
    names = list(extra) + [
        re.sub("^", "mixamorig12:", n) if scheme == "mixamo" else n
        for n in SCHEMES[scheme].values()
    ]
    m = map_bones(reversed(names))
    assert m.scheme == scheme
    assert m.is_humanoid
    for canonical, name in expect.items():
        assert m.bones[canonical] == name
    assert sorted(m.unmapped) == sorted(extra)
    assert set(m.bones.values()).isdisjoint(m.unmapped)


def test_mixamo_any_prefix_and_none():
    for prefix in ("mixamorig:", "mixamorig7:", "Armature|mixamorig:", ""):
        m = map_bones([prefix + n for n in SCHEMES["mixamo"].values()])
        assert m.scheme == "mixamo", prefix
        assert m.bones["l_upper_arm"] == prefix + "LeftArm"


def _bvh_names(path):
    return re.findall(r"^\s*(?:ROOT|JOINT)\s+(\S+)", path.read_text(), flags=re.M)


@pytest.mark.parametrize(
    "clip, scheme, check",
    [
        (
            "02_01",
            "cmu_mb",
            {"l_clavicle": "LeftShoulder", "l_upper_arm": "LeftArm", "spine": "LowerBack"},
        ),
        (
            "131_01",
            "cmu_max",
            {"l_clavicle": "LeftCollar", "l_upper_arm": "LeftShoulder", "r_shin": "RightKnee"},
        ),
        ("pirouette", "cmu_daz", {"l_upper_arm": "lShldr", "r_thigh": "rThigh", "pelvis": "hip"}),
        (
            "mixamo_named_test",
            "mixamo",
            {"upper_chest": "mixamorig:Spine2", "r_foot": "mixamorig:RightFoot"},
        ),
    ],
)
def test_real_bvh_skeletons(shared_data, clip, scheme, check):
    names = _bvh_names(shared_data / "mocap" / f"{clip}.bvh")
    m = map_bones(names)
    assert m.scheme == scheme
    assert m.is_humanoid, m.missing_required
    for canonical, name in check.items():
        assert m.bones[canonical] == name
    # Fingers and helper joints are reported, never silently mapped.
    assert all("Finger" not in n and "Thumb" not in n for n in m.bones.values())


def test_cmu_vs_mixamo_disambiguated_by_spine():
    cmu = _full_rig("cmu_mb", ["LHipJoint", "Neck1"])
    assert map_bones(cmu).bones["chest"] == "Spine"
    assert map_bones(_full_rig("mixamo", [])).bones["chest"] == "Spine1"


def test_non_humanoid_reports_missing_and_unmapped():
    names = ["root", "body", "tail.001", "tail.002", "leg_front.L", "leg_front.R", "head", "ear.L"]
    m = map_bones(names)
    assert not m.is_humanoid
    assert "l_thigh" in m.missing_required
    assert "tail.001" in m.unmapped and "ear.L" in m.unmapped


def test_pair_bones_cross_scheme():
    src = map_bones(_full_rig("cmu_mb", []))
    dst = map_bones(_full_rig("rigify_def", []))
    pairs = pair_bones(src, dst)
    assert pairs["LeftUpLeg"] == "DEF-thigh.L"
    assert pairs["RightForeArm"] == "DEF-forearm.R"
    assert len(pairs) == len(CANONICAL_BONES)
    daz = map_bones(_full_rig("cmu_daz", []))  # Daz names no upper chest
    assert len(pair_bones(daz, dst)) == len(CANONICAL_BONES) - 1
    assert set(REQUIRED_BONES) <= set(src.bones)


def test_preset_round_trip_and_errors(tmp_path):
    names = _full_rig("unreal", ["root"])
    m = map_bones(names)
    m.bones["l_hand"] = "root"  # a hand edit in the panel
    path = save_preset(m, tmp_path / "p.json")
    back = load_preset(path, names)
    assert back.bones == m.bones and back.scheme == "unreal"
    with pytest.raises(InputError, match="no bones named"):
        load_preset(path, ["pelvis"])
    (tmp_path / "bad.json").write_text("{nope")
    with pytest.raises(InputError, match="bad.json: not a JSON"):
        load_preset(tmp_path / "bad.json")
    (tmp_path / "other.json").write_text('{"format": "somacap-bone-mapping", "bones": {"x": "y"}}')
    with pytest.raises(InputError, match="unknown canonical bones"):
        load_preset(tmp_path / "other.json")
    with pytest.raises(InputError, match="not found"):
        load_preset(tmp_path / "missing.json")


def test_unknown_scheme_rejected():
    with pytest.raises(ValueError, match="unknown bone naming scheme"):
        map_bones(["Hips"], scheme="nope")


def test_somacap_armature_names():
    from core.skeleton import BONES

    m = map_bones(BONES)
    assert m.scheme == "somacap" and m.is_humanoid
    assert m.bones["l_upper_arm"] == "l_shoulder" and m.bones["r_thigh"] == "r_hip"
    assert m.unmapped == []


def test_generated_rigify_rig_keys_fk_controls():
    """DEF bones are matched, the FK controls (and torso) keyed, switches set to FK;
    without the controls (a DEF-only export) the DEF bones themselves are keyed."""
    from core.bone_mapping import CONTROL_SCHEMES

    defs = list(SCHEMES["rigify_def"].values())
    ctrls = list(SCHEMES["rigify_fk"].values()) + ["torso", "MCH-spine", "ORG-spine"]
    m = map_bones(defs + ctrls)
    assert m.scheme == "rigify_def" and m.bones["l_shin"] == "DEF-shin.L"
    assert m.controls["l_shin"] == "shin_fk.L" and m.controls["pelvis"] == "spine_fk"
    assert set(m.controls) == set(m.bones) and m.root_control == "torso"
    assert m.switches == CONTROL_SCHEMES["rigify_def"]["switches"]
    assert m.switches['pose.bones["thigh_parent.R"]["IK_FK"]'] == 1.0
    plain = map_bones(defs)
    assert plain.scheme == "rigify_def" and not plain.controls and plain.root_control is None
    no_torso = map_bones(defs + ctrls[:-3])
    assert not no_torso.controls
    meta = map_bones(SCHEMES["rigify_metarig"].values())
    assert meta.scheme == "rigify_metarig" and not meta.controls
