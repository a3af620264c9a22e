"""Scene settings of the Somacap panel (``scene.somacap``)."""

from __future__ import annotations

import bpy
from bpy.props import (
    BoolProperty,
    CollectionProperty,
    EnumProperty,
    FloatProperty,
    IntProperty,
    PointerProperty,
    StringProperty,
)


def _is_armature(self, obj):
    return obj.type == "ARMATURE"


class SOMACAP_PG_bone_pair(bpy.types.PropertyGroup):
    """One row of the editable bone mapping: canonical bone -> target bone name."""

    canonical: StringProperty(name="Canonical bone")
    bone: StringProperty(name="Target bone")


class SOMACAP_PG_settings(bpy.types.PropertyGroup):
    scene_dir: StringProperty(
        name="Scene folder",
        subtype="DIR_PATH",
        description="A Somacap scene folder (scene.toml, images/, …)",
    )
    calibration: StringProperty(
        name="Calibration",
        subtype="FILE_PATH",
        description="calibration.toml (default: the scene's)",
    )
    state_path: StringProperty(
        name="Fitted state", subtype="FILE_PATH", description="fit.json to build the body from"
    )
    take: StringProperty(name="Take", default="take", description="Name of the new action(s)")
    body: PointerProperty(
        name="Body",
        type=bpy.types.Object,
        poll=_is_armature,
        description="The recovered armature (source of retargeting)",
    )
    target: PointerProperty(
        name="Target",
        type=bpy.types.Object,
        poll=_is_armature,
        description="A rigged character to retarget onto",
    )
    foot_lock: BoolProperty(
        name="Foot locking",
        default=False,
        description="Pin each foot while it is in contact (low and slow), "
        "bending the leg to reach it",
    )
    mapping: CollectionProperty(type=SOMACAP_PG_bone_pair)
    mapping_index: IntProperty()
    mapping_scheme: StringProperty(name="Scheme")
    fit_cues: EnumProperty(
        name="Cues",
        default="texture",
        description="Observations the fit uses (a scene's existing fit.json is used "
        "as it is, unless Feet from points or Smooth motion is on or Extra starts "
        "(contours alone), Second pass (late shape) or Refined-flow second fit is off)",
        items=[
            ("texture", "Texture", "3-D surface points from the tracker (needs textured clothing)"),
            (
                "contours",
                "Contours",
                "Silhouette contours of each camera's foreground (no tracker; works on bare skin)",
            ),
            (
                "both",
                "Both",
                "Points and contours together, and each camera's texture "
                "flow in frames without points: the most accurate, about "
                "2.7x the fit's CPU time",
            ),
        ],
    )
    feet_from_points: BoolProperty(
        name="Feet from points",
        default=False,
        description="Turn each foot about its shin at the clicked frame to the heading of "
        "the surface points under it, and fit anew (a scene's fit.json is not used). Off by "
        "default: on the default scene it fixes the right foot's turn, but the fit's joint "
        "error as a whole does not gain. Needs the Texture or Both cues (contours give no "
        "points)",
    )
    smooth_motion: BoolProperty(
        name="Smooth motion",
        default=False,
        description="Smooth the whole fitted motion over the take, each joint's path (less "
        "jitter on walks and jumps; the hidden limbs' angles are always smoothed), and fit "
        "anew (a scene's fit.json is not used). Off by default: a sudden kick of one limb "
        "gets spread over its neighbouring frames",
    )
    contour_starts: BoolProperty(
        name="Extra starts (contours alone)",
        default=True,
        description="Fit each frame without texture points (contours alone) from three "
        "starts: the prediction, the previous frame's pose and its extrapolation, keeping "
        "the fit that best matches the foreground. Slower (about 2x the fit time on a rig "
        "without points) but keeps fast limbs, e.g. the crossing legs of a dance on the "
        "orthogonal rig. Off: the prediction only, and a new fit (a scene's fit.json is "
        "not used)",
    )
    late_shape: BoolProperty(
        name="Second pass (late shape)",
        default=True,
        description="After the motion, shape the bones the first frames hardly saw (e.g. a "
        "hand that comes into view later) over the fitted take, and fit the motion a "
        "second time from that shape. About 2x the fit time where a bone qualifies (the "
        "default scene's walk: 12.9 to 11.1 mm joint error). Off: one pass, and a new "
        "fit (a scene's fit.json is not used)",
    )
    flow_choice: BoolProperty(
        name="Refined-flow second fit",
        default=True,
        description="Where the silhouettes alone shape the body (no texture points at the "
        "clicked frame, e.g. the orthogonal rig) and the texture flow is followed, fit the "
        "take a second time with LSM-refined flow corners and keep the fit the foregrounds "
        "explain better. About twice the fit time there. Off: one fit with Lucas-Kanade's "
        "flow corners, and a new fit (a scene's fit.json is not used)",
    )
    export_format: EnumProperty(name="Format", items=[("BVH", "BVH", ""), ("FBX", "FBX", "")])
    progress: FloatProperty(name="Progress", subtype="PERCENTAGE", min=0, max=100)
    status: StringProperty(name="Status")


classes = (SOMACAP_PG_bone_pair, SOMACAP_PG_settings)


def register_properties():
    bpy.types.Scene.somacap = PointerProperty(type=SOMACAP_PG_settings)


def unregister_properties():
    del bpy.types.Scene.somacap
