"""Automatic bone mapping between humanoid rigs of common naming schemes (no bpy).

Every rig is mapped onto one canonical humanoid bone set, :data:`CANONICAL_BONES`
(names follow ``core.landmarks.SEGMENTS`` where they overlap).  A source bone and a
target bone that map to the same canonical bone are retargeted onto each other.

Schemes recognised (the names each one uses are in :data:`SCHEMES`):

``rigify_def`` / ``rigify_org`` / ``rigify_fk`` / ``rigify_metarig``
    Blender's Rigify: deform bones (``DEF-upper_arm.L``), original bones
    (``ORG-upper_arm.L``), FK controls (``upper_arm_fk.L``) and the meta-rig.
``mixamo``
    ``mixamorig:Hips`` … with any ``mixamorig<N>:`` (or other ``namespace:``) prefix,
    or none.
``cmu_mb`` / ``cmu_max`` / ``cmu_daz``
    The CMU BVH families: MotionBuilder-friendly (``LeftUpLeg``), 3ds Max-friendly
    (``LeftHip``, ``LeftKnee``) and Daz-friendly (``lThigh``, ``lShin``).
``mpfb``
    MakeHuman / MPFB default skeleton (``upperleg01.L``, ``spine05``).
``unreal``
    Unreal Engine mannequin (``thigh_l``, ``calf_l``, ``spine_01``); also MakeHuman's
    "game engine" rig.
``vrm``
    VRM humanoid (``leftUpperLeg``), also VRoid's ``J_Bip_L_UpperLeg``.
``somacap``
    This project's own armature (``core.skeleton`` bone names: ``l_shoulder`` is the
    upper arm, ``l_hip`` the thigh …).

Names are compared case-insensitively after stripping a ``namespace:`` prefix, so
``mixamorig7:LeftArm`` and ``LeftArm`` are the same.  The scheme is chosen by the number
of bones it explains; ties go to the scheme listed first.  The result names the bones it
could not map, and tells whether the rig looks humanoid (enough limb bones mapped).
"""

from __future__ import annotations

import json
import re
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

from .errors import InputError

_SIDED = ("clavicle", "upper_arm", "forearm", "hand", "thigh", "shin", "foot", "toe")

#: Canonical humanoid bones, parents before children.
CANONICAL_BONES = (
    "pelvis",
    "spine",
    "chest",
    "upper_chest",
    "neck",
    "head",
    *(f"{s}_{b}" for s in ("l", "r") for b in _SIDED),
)

#: Bones that must be mapped for a rig to count as humanoid.
REQUIRED_BONES = (
    "pelvis",
    "head",
    *(
        f"{s}_{b}"
        for s in ("l", "r")
        for b in ("upper_arm", "forearm", "hand", "thigh", "shin", "foot")
    ),
)

#: Canonical bone -> (head joint, tail joint) in ``core.landmarks.JOINTS`` terms.
BONE_JOINTS = {
    "pelvis": ("pelvis", "spine"),
    "spine": ("spine", "chest"),
    "chest": ("chest", "neck"),
    "upper_chest": ("chest", "neck"),
    "neck": ("neck", "head"),
    "head": ("head", "head_top"),
    **{f"{s}_clavicle": (f"{s}_clavicle", f"{s}_shoulder") for s in "lr"},
    **{f"{s}_upper_arm": (f"{s}_shoulder", f"{s}_elbow") for s in "lr"},
    **{f"{s}_forearm": (f"{s}_elbow", f"{s}_wrist") for s in "lr"},
    **{f"{s}_hand": (f"{s}_wrist", f"{s}_hand") for s in "lr"},
    **{f"{s}_thigh": (f"{s}_hip", f"{s}_knee") for s in "lr"},
    **{f"{s}_shin": (f"{s}_knee", f"{s}_ankle") for s in "lr"},
    **{f"{s}_foot": (f"{s}_ankle", f"{s}_toe") for s in "lr"},
    **{f"{s}_toe": (f"{s}_toe", f"{s}_toe") for s in "lr"},
}


def _sided(table: dict[str, str], fmt) -> dict[str, str]:
    """Expand ``{bone: template}`` with ``{S}`` placeholders for both sides."""
    out = {}
    for bone, template in table.items():
        if bone in _SIDED:
            for s in ("l", "r"):
                out[f"{s}_{bone}"] = template.format(S=fmt(s))
        else:
            out[bone] = template
    return out


def _rigify(prefix: str, fk: bool = False) -> dict[str, str]:
    limb = "_fk" if fk else ""
    names = {
        "pelvis": f"{prefix}spine",
        "spine": f"{prefix}spine.001",
        "chest": f"{prefix}spine.002",
        "upper_chest": f"{prefix}spine.003",
        "neck": f"{prefix}spine.004",
        "head": f"{prefix}spine.006",
        "clavicle": f"{prefix}shoulder{{S}}",
        "upper_arm": f"{prefix}upper_arm{limb}{{S}}",
        "forearm": f"{prefix}forearm{limb}{{S}}",
        "hand": f"{prefix}hand{limb}{{S}}",
        "thigh": f"{prefix}thigh{limb}{{S}}",
        "shin": f"{prefix}shin{limb}{{S}}",
        "foot": f"{prefix}foot{limb}{{S}}",
        "toe": f"{prefix}toe{limb}{{S}}",
    }
    if fk:  # Rigify's FK spine chain (drives DEF-spine … DEF-spine.003 rigidly), neck, head
        names.update(
            {
                "pelvis": "spine_fk",
                "spine": "spine_fk.001",
                "chest": "spine_fk.002",
                "upper_chest": "spine_fk.003",
                "neck": "neck",
                "head": "head",
                "clavicle": "shoulder{S}",
                "toe": "toe_fk{S}",
            }
        )
    return _sided(names, lambda s: ".L" if s == "l" else ".R")


def _side_word(s: str) -> str:
    return "Left" if s == "l" else "Right"


#: scheme -> canonical bone -> bone name in that scheme.
SCHEMES: dict[str, dict[str, str]] = {
    # This project's armature (core.skeleton: a bone is named after its head joint).
    "somacap": _sided(
        {
            "pelvis": "pelvis",
            "spine": "lowerback",
            "chest": "spine",
            "upper_chest": "chest",
            "neck": "neck",
            "head": "head",
            "clavicle": "{S}_clavicle",
            "upper_arm": "{S}_shoulder",
            "forearm": "{S}_elbow",
            "hand": "{S}_wrist",
            "thigh": "{S}_hip",
            "shin": "{S}_knee",
            "foot": "{S}_ankle",
        },
        lambda s: s,
    ),
    "rigify_def": _rigify("DEF-"),
    "rigify_org": _rigify("ORG-"),
    "rigify_fk": _rigify("", fk=True),
    "rigify_metarig": _rigify(""),
    "mixamo": _sided(
        {
            "pelvis": "Hips",
            "spine": "Spine",
            "chest": "Spine1",
            "upper_chest": "Spine2",
            "neck": "Neck",
            "head": "Head",
            "clavicle": "{S}Shoulder",
            "upper_arm": "{S}Arm",
            "forearm": "{S}ForeArm",
            "hand": "{S}Hand",
            "thigh": "{S}UpLeg",
            "shin": "{S}Leg",
            "foot": "{S}Foot",
            "toe": "{S}ToeBase",
        },
        _side_word,
    ),
    "cmu_mb": _sided(
        {
            "pelvis": "Hips",
            "spine": "LowerBack",
            "chest": "Spine",
            "upper_chest": "Spine1",
            "neck": "Neck",
            "head": "Head",
            "clavicle": "{S}Shoulder",
            "upper_arm": "{S}Arm",
            "forearm": "{S}ForeArm",
            "hand": "{S}Hand",
            "thigh": "{S}UpLeg",
            "shin": "{S}Leg",
            "foot": "{S}Foot",
            "toe": "{S}ToeBase",
        },
        _side_word,
    ),
    "cmu_max": _sided(
        {
            "pelvis": "Hips",
            "spine": "lowerback",
            "chest": "Chest",
            "upper_chest": "Chest2",
            "neck": "lowerneck",
            "head": "Head",
            "clavicle": "{S}Collar",
            "upper_arm": "{S}Shoulder",
            "forearm": "{S}Elbow",
            "hand": "{S}Wrist",
            "thigh": "{S}Hip",
            "shin": "{S}Knee",
            "foot": "{S}Ankle",
            "toe": "{S}Toe",
        },
        _side_word,
    ),
    "cmu_daz": _sided(
        {
            "pelvis": "hip",
            "spine": "abdomen",
            "chest": "chest",
            "neck": "neck",
            "head": "head",
            "clavicle": "{S}Collar",
            "upper_arm": "{S}Shldr",
            "forearm": "{S}ForeArm",
            "hand": "{S}Hand",
            "thigh": "{S}Thigh",
            "shin": "{S}Shin",
            "foot": "{S}Foot",
            "toe": "{S}Toe",
        },
        lambda s: s,
    ),
    "mpfb": _sided(
        {
            "pelvis": "spine05",
            "spine": "spine04",
            "chest": "spine03",
            "upper_chest": "spine02",
            "neck": "neck01",
            "head": "head",
            "clavicle": "clavicle{S}",
            "upper_arm": "upperarm01{S}",
            "forearm": "lowerarm01{S}",
            "hand": "wrist{S}",
            "thigh": "upperleg01{S}",
            "shin": "lowerleg01{S}",
            "foot": "foot{S}",
            "toe": "toe1-1{S}",
        },
        lambda s: ".L" if s == "l" else ".R",
    ),
    "unreal": _sided(
        {
            "pelvis": "pelvis",
            "spine": "spine_01",
            "chest": "spine_02",
            "upper_chest": "spine_03",
            "neck": "neck_01",
            "head": "head",
            "clavicle": "clavicle_{S}",
            "upper_arm": "upperarm_{S}",
            "forearm": "lowerarm_{S}",
            "hand": "hand_{S}",
            "thigh": "thigh_{S}",
            "shin": "calf_{S}",
            "foot": "foot_{S}",
            "toe": "ball_{S}",
        },
        lambda s: s,
    ),
    "vrm": _sided(
        {
            "pelvis": "hips",
            "spine": "spine",
            "chest": "chest",
            "upper_chest": "upperChest",
            "neck": "neck",
            "head": "head",
            "clavicle": "{S}Shoulder",
            "upper_arm": "{S}UpperArm",
            "forearm": "{S}LowerArm",
            "hand": "{S}Hand",
            "thigh": "{S}UpperLeg",
            "shin": "{S}LowerLeg",
            "foot": "{S}Foot",
            "toe": "{S}Toes",
        },
        lambda s: "left" if s == "l" else "right",
    ),
    "vroid": _sided(
        {
            "pelvis": "J_Bip_C_Hips",
            "spine": "J_Bip_C_Spine",
            "chest": "J_Bip_C_Chest",
            "upper_chest": "J_Bip_C_UpperChest",
            "neck": "J_Bip_C_Neck",
            "head": "J_Bip_C_Head",
            "clavicle": "J_Bip_{S}_Shoulder",
            "upper_arm": "J_Bip_{S}_UpperArm",
            "forearm": "J_Bip_{S}_LowerArm",
            "hand": "J_Bip_{S}_Hand",
            "thigh": "J_Bip_{S}_UpperLeg",
            "shin": "J_Bip_{S}_LowerLeg",
            "foot": "J_Bip_{S}_Foot",
            "toe": "J_Bip_{S}_ToeBase",
        },
        lambda s: s.upper(),
    ),
}

#: Rigs whose deform bones are driven by constraints from animator controls (a generated
#: Rigify rig): scheme of the deform bones -> how to animate them.  ``controls`` maps a
#: canonical bone to the control that is keyed (its deform bone follows it rigidly, with
#: the limbs' IK/FK switches set to FK), ``root`` is the control whose location carries
#: the root motion, ``switches`` the custom properties set (and keyed) for FK.
CONTROL_SCHEMES: dict[str, dict] = {
    scheme: {
        "controls": SCHEMES["rigify_fk"],
        "root": "torso",
        "switches": {
            f'pose.bones["{b}{s}"]["IK_FK"]': 1.0
            for b in ("upper_arm_parent", "thigh_parent")
            for s in (".L", ".R")
        },
    }
    for scheme in ("rigify_def", "rigify_org")
}

_NAMESPACE = re.compile(r"^[^:]*:")


def normalise(name: str) -> str:
    """Comparison key of a bone name: ``namespace:`` prefix stripped, lower case."""
    return _NAMESPACE.sub("", name).strip().lower()


@dataclass
class BoneMapping:
    """Canonical bone -> rig bone name, with what could not be mapped.

    Attributes
    ----------
    bones : dict
        Canonical bone name -> the rig's bone name (only mapped ones).
    scheme : str
        The naming scheme that explained most bones (``"custom"`` for a preset).
    unmapped : list of str
        The rig's bones that map to no canonical bone, in the rig's order.
    missing : list of str
        Canonical bones the rig lacks.
    controls : dict
        For constraint-driven rigs (see :data:`CONTROL_SCHEMES`): canonical bone -> the
        control bone to key instead of ``bones[canonical]`` (which is still the bone
        whose world direction is matched).  Empty for plain rigs.
    root_control : str or None
        The control that carries the root motion (its location is keyed).
    switches : dict
        ``data_path -> value`` of custom properties to set and key (IK/FK switches).
    """

    bones: dict[str, str]
    scheme: str
    unmapped: list[str] = field(default_factory=list)
    missing: list[str] = field(default_factory=list)
    controls: dict[str, str] = field(default_factory=dict)
    root_control: str | None = None
    switches: dict[str, float] = field(default_factory=dict)

    @property
    def is_humanoid(self) -> bool:
        """True when every bone of :data:`REQUIRED_BONES` is mapped."""
        return all(b in self.bones for b in REQUIRED_BONES)

    @property
    def missing_required(self) -> list[str]:
        return [b for b in REQUIRED_BONES if b not in self.bones]

    def to_dict(self) -> dict:
        return {"scheme": self.scheme, "bones": dict(self.bones)}


def map_bones(names: Iterable[str], scheme: str | None = None) -> BoneMapping:
    """Map a rig's bone names onto :data:`CANONICAL_BONES`.

    Parameters
    ----------
    names : iterable of str
        The rig's bone names, in any order.
    scheme : str, optional
        Force a scheme of :data:`SCHEMES`; default: the one that maps most bones.
    """
    names = list(names)
    keyed: dict[str, str] = {}
    for n in names:
        keyed.setdefault(normalise(n), n)
    if scheme is not None and scheme not in SCHEMES:
        raise ValueError(f"unknown bone naming scheme {scheme!r}; known: {sorted(SCHEMES)}")
    candidates = [scheme] if scheme else list(SCHEMES)
    best, best_bones = candidates[0], {}
    for sch in candidates:
        bones = {c: keyed[normalise(n)] for c, n in SCHEMES[sch].items() if normalise(n) in keyed}
        if len(bones) > len(best_bones):
            best, best_bones = sch, bones
    used = set(best_bones.values())
    return _with_controls(
        BoneMapping(
            bones=best_bones,
            scheme=best,
            unmapped=[n for n in names if n not in used],
            missing=[c for c in CANONICAL_BONES if c not in best_bones],
        ),
        keyed,
    )


def _with_controls(mapping: BoneMapping, keyed: dict[str, str]) -> BoneMapping:
    """Attach the controls of :data:`CONTROL_SCHEMES` when the rig has all of them
    for its mapped bones (and the root control); otherwise the bones are keyed."""
    plan = CONTROL_SCHEMES.get(mapping.scheme)
    if plan is None:
        return mapping
    wanted = {c: plan["controls"][c] for c in mapping.bones if c in plan["controls"]}
    names = [*wanted.values(), plan["root"]]
    if len(wanted) < len(mapping.bones) or not all(normalise(n) in keyed for n in names):
        return mapping
    mapping.controls = {c: keyed[normalise(n)] for c, n in wanted.items()}
    mapping.root_control = keyed[normalise(plan["root"])]
    mapping.switches = dict(plan["switches"])
    return mapping


def pair_bones(source: BoneMapping, target: BoneMapping) -> dict[str, str]:
    """Source bone name -> target bone name for canonical bones both rigs have."""
    return {
        source.bones[c]: target.bones[c]
        for c in CANONICAL_BONES
        if c in source.bones and c in target.bones
    }


def save_preset(mapping: BoneMapping, path: str | Path) -> Path:
    """Write a (possibly hand-edited) mapping as a JSON preset."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(
        json.dumps({"format": "somacap-bone-mapping", "version": 1, **mapping.to_dict()}, indent=2),
        encoding="utf-8",
    )
    return path


def load_preset(path: str | Path, names: Iterable[str] | None = None) -> BoneMapping:
    """Read a JSON preset; with ``names`` (the rig's bones), check they exist."""
    path = Path(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError as exc:
        raise InputError(f"{path}: bone-mapping preset not found") from exc
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: not a JSON bone-mapping preset ({exc})") from exc
    if not isinstance(data, dict) or data.get("format") != "somacap-bone-mapping":
        raise InputError(f"{path}: not a somacap bone-mapping preset")
    bones = data.get("bones")
    if not isinstance(bones, dict) or not all(isinstance(v, str) for v in bones.values()):
        raise InputError(f"{path}: 'bones' must map canonical bone names to bone names")
    unknown = sorted(set(bones) - set(CANONICAL_BONES))
    if unknown:
        raise InputError(f"{path}: unknown canonical bones {unknown}")
    names = list(names) if names is not None else None
    if names is not None:
        absent = sorted(set(bones.values()) - set(names))
        if absent:
            raise InputError(f"{path}: the rig has no bones named {absent}")
    used = set(bones.values())
    mapping = BoneMapping(
        bones=dict(bones),
        scheme=str(data.get("scheme", "custom")),
        unmapped=[n for n in (names or []) if n not in used],
        missing=[c for c in CANONICAL_BONES if c not in bones],
    )
    return _with_controls(mapping, {normalise(n): n for n in names or []})
