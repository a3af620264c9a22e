"""Operators of the panel: thin wrappers over :mod:`.pipeline` (gather, call, report)."""

from __future__ import annotations

import tempfile
from pathlib import Path

import bpy
import numpy as np
from bpy.props import StringProperty

from . import _core, pipeline
from . import retarget as rt


def _settings(context):
    return context.scene.somacap


def _fail(op, exc) -> set:
    op.report({"ERROR"}, str(exc))
    return {"CANCELLED"}


class SOMACAP_OT_create_cameras(bpy.types.Operator):
    """Create Blender cameras from the scene's calibration, footage as background"""

    bl_idname = "somacap.create_cameras"
    bl_label = "Create cameras"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        s = _settings(context)
        return bool(s.scene_dir or s.calibration)

    def execute(self, context):
        s = _settings(context)
        try:
            objs = pipeline.create_scene_cameras(
                bpy.path.abspath(s.scene_dir) or None, bpy.path.abspath(s.calibration) or None
            )
        except _core.errors.InputError as exc:
            return _fail(self, exc)
        self.report({"INFO"}, f"Created {len(objs)} cameras")
        return {"FINISHED"}


class SOMACAP_OT_place_clicks(bpy.types.Operator):
    """Place editable empties at the intersection of the scene's key-joint clicks"""

    bl_idname = "somacap.place_clicks"
    bl_label = "Place key joints"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return bool(_settings(context).scene_dir)

    def execute(self, context):
        try:
            out = pipeline.place_clicks(bpy.path.abspath(_settings(context).scene_dir))
        except _core.errors.InputError as exc:
            return _fail(self, exc)
        if not out:
            self.report({"WARNING"}, "No key joint could be placed from the clicks")
            return {"FINISHED"}
        sig = np.median([list(e["somacap_sigma_mm"]) for e in out.values()], axis=0)
        self.report(
            {"INFO"},
            f"Placed {len(out)} key joints, drawn as their 3σ ellipsoids for 1 px clicks: "
            f"±{sig[1]:.1f} mm across, ±{sig[2]:.1f} mm along the long axis (median); "
            "check a joint's depth along it in a side view",
        )
        return {"FINISHED"}


def _build(op, context, state) -> set:
    s = _settings(context)
    arm, balls, action = pipeline.build_take(state, s.take or "take")
    s.body = arm
    op.report(
        {"INFO"},
        f"Built {arm.name}: {len(arm.data.bones)} bones, {len(balls)} metaball "
        f"objects, action '{action.name}' ({state.n_frames} frames)",
    )
    return {"FINISHED"}


class SOMACAP_OT_build_body(bpy.types.Operator):
    """Build the armature, metaball body and action from a fitted state (fit.json)"""

    bl_idname = "somacap.build_body"
    bl_label = "Build body"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return bool(_settings(context).state_path)

    def execute(self, context):
        try:
            state = pipeline.read_state(bpy.path.abspath(_settings(context).state_path))
        except _core.errors.InputError as exc:
            return _fail(self, exc)
        return _build(self, context, state)


class SOMACAP_OT_fit(bpy.types.Operator):
    """Fit the body to the scene (runs in the background; Esc cancels), then build it"""

    bl_idname = "somacap.fit"
    bl_label = "Fit"
    bl_options = {"REGISTER"}

    _job = None
    _timer = None

    @classmethod
    def poll(cls, context):
        return bool(_settings(context).scene_dir)

    def _job_fn(self, context):
        """The background job: the settings are read here, on the main thread."""
        s = _settings(context)
        scene_dir, state_path = bpy.path.abspath(s.scene_dir), bpy.path.abspath(s.state_path)
        cues = s.fit_cues
        options = {
            "feet_from_points": s.feet_from_points,
            "smooth_motion": s.smooth_motion,
            "contour_starts": s.contour_starts,
            "late_shape": s.late_shape,
            "flow_choice": s.flow_choice,
        }
        moved = {} if state_path else pipeline.moved_clicks(scene_dir)
        self._moved = sorted(moved)
        self._cached = (
            not state_path
            and not moved
            and not pipeline.asks_new_fit(**options)
            and (Path(scene_dir) / "fit.json").is_file()
        )

        def job(progress):
            return pipeline.state_for_scene(
                scene_dir, state_path or None, progress, cues=cues, clicks_xyz=moved, **options
            )

        return job

    def execute(self, context):  # scripts and background mode: synchronous
        job = pipeline.BackgroundJob(self._job_fn(context)).start()
        job.join()
        return self._finish(context, job)

    def invoke(self, context, event):
        self._job = pipeline.BackgroundJob(self._job_fn(context)).start()
        wm = context.window_manager
        self._timer = wm.event_timer_add(0.1, window=context.window)
        wm.progress_begin(0, 100)
        wm.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        s = _settings(context)
        if event.type == "ESC":
            self._job.cancel()
            s.status = "Cancelling…"
        if event.type != "TIMER":
            return {"RUNNING_MODAL"} if event.type != "ESC" else {"RUNNING_MODAL"}
        s.progress = 100.0 * self._job.fraction
        s.status = self._job.message
        context.window_manager.progress_update(s.progress)
        for area in context.screen.areas if context.screen else ():
            area.tag_redraw()
        if not self._job.done:
            return {"RUNNING_MODAL"}
        wm = context.window_manager
        wm.event_timer_remove(self._timer)
        wm.progress_end()
        return self._finish(context, self._job)

    def _finish(self, context, job) -> set:
        s = _settings(context)
        if job.cancelled:
            s.status = "Cancelled"
            self.report({"WARNING"}, "Fit cancelled; nothing was changed")
            return {"CANCELLED"}
        if job.error is not None:
            s.status = "Failed"
            if isinstance(job.error, _core.errors.InputError):
                return _fail(self, job.error)
            return _fail(self, f"fit failed: {job.error!r}")
        s.status = "Done"
        if getattr(self, "_moved", None):
            self.report(
                {"INFO"},
                f"Fitted with the key joints you moved: {', '.join(self._moved)} "
                "(clicks.json unchanged)",
            )
        if getattr(self, "_cached", False):
            self.report(
                {"WARNING"},
                "Used the scene's existing fit.json: the Cues setting "
                "applies to a new fit (move fit.json away to refit)",
            )
        return _build(self, context, job.result)


def _mapping_from_settings(s):
    if not len(s.mapping):
        return None
    bones = {row.canonical: row.bone for row in s.mapping if row.bone}
    return _core.bone_mapping.BoneMapping(bones=bones, scheme=s.mapping_scheme or "custom")


class SOMACAP_OT_map_bones(bpy.types.Operator):
    """Map the target's bones automatically (editable in the list below)"""

    bl_idname = "somacap.map_bones"
    bl_label = "Auto-map"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return _settings(context).target is not None

    def execute(self, context):
        s = _settings(context)
        m = rt.rig_mapping(s.target)
        s.mapping.clear()
        for c in _core.bone_mapping.CANONICAL_BONES:
            row = s.mapping.add()
            row.canonical, row.bone = c, m.bones.get(c, "")
        s.mapping_scheme = m.scheme
        self.report(
            {"INFO"},
            f"{m.scheme}: mapped {len(m.bones)} bones; unmapped: "
            f"{', '.join(m.unmapped[:12]) or 'none'}",
        )
        return {"FINISHED"}


class SOMACAP_OT_save_mapping(bpy.types.Operator):
    """Save the bone mapping as a JSON preset"""

    bl_idname = "somacap.save_mapping"
    bl_label = "Save mapping preset"
    filepath: StringProperty(subtype="FILE_PATH")

    def invoke(self, context, event):
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}

    def execute(self, context):
        m = _mapping_from_settings(_settings(context))
        if m is None:
            return _fail(self, "no mapping to save: press Auto-map first")
        _core.bone_mapping.save_preset(m, bpy.path.abspath(self.filepath))
        return {"FINISHED"}


class SOMACAP_OT_load_mapping(bpy.types.Operator):
    """Load a bone-mapping preset for the target"""

    bl_idname = "somacap.load_mapping"
    bl_label = "Load mapping preset"
    filepath: StringProperty(subtype="FILE_PATH")

    def invoke(self, context, event):
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}

    def execute(self, context):
        s = _settings(context)
        names = [b.name for b in s.target.data.bones] if s.target else None
        try:
            m = _core.bone_mapping.load_preset(bpy.path.abspath(self.filepath), names)
        except _core.errors.InputError as exc:
            return _fail(self, exc)
        s.mapping.clear()
        for c in _core.bone_mapping.CANONICAL_BONES:
            row = s.mapping.add()
            row.canonical, row.bone = c, m.bones.get(c, "")
        s.mapping_scheme = m.scheme
        return {"FINISHED"}


class SOMACAP_OT_retarget(bpy.types.Operator):
    """Retarget the body's action onto the target rig as a new action named after the take"""

    bl_idname = "somacap.retarget"
    bl_label = "Retarget"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        s = _settings(context)
        return s.body is not None and s.target is not None

    def execute(self, context):
        s = _settings(context)
        try:
            res = rt.retarget(
                s.body,
                s.target,
                take=s.take or "take",
                target_preset=_mapping_from_settings(s),
                foot_lock=s.foot_lock,
            )
        except _core.errors.InputError as exc:
            return _fail(self, exc)
        msg = (
            f"Retargeted {len(res.pairs)} bones onto {s.target.name} as "
            f"'{res.action.name}' (leg scale {res.scale:.3f})"
        )
        if res.foot_skate_mm:
            msg += "; foot skate " + ", ".join(
                f"{k} {b:.0f}->{a:.0f} mm" for k, (b, a) in res.foot_skate_mm.items()
            )
        if res.unmapped_target:
            msg += f"; unmapped: {', '.join(res.unmapped_target[:10])}"
            if len(res.unmapped_target) > 10:
                msg += f" and {len(res.unmapped_target) - 10} more"
        self.report({"INFO"}, msg)
        return {"FINISHED"}


class SOMACAP_OT_export(bpy.types.Operator):
    """Export the recovered motion with Blender's BVH or FBX exporter"""

    bl_idname = "somacap.export"
    bl_label = "Export motion"
    filepath: StringProperty(subtype="FILE_PATH")

    @classmethod
    def poll(cls, context):
        return _settings(context).body is not None

    def invoke(self, context, event):
        s = _settings(context)
        self.filepath = str(Path(tempfile.gettempdir()) / f"{s.take}.{s.export_format.lower()}")
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}

    def execute(self, context):
        s = _settings(context)
        path = Path(bpy.path.abspath(self.filepath))
        if path.suffix.lower() not in (".bvh", ".fbx"):
            path = path.with_suffix("." + s.export_format.lower())
        try:
            pipeline.export_motion(s.body, path)
        except _core.errors.InputError as exc:
            return _fail(self, exc)
        self.report({"INFO"}, f"Wrote {path}")
        return {"FINISHED"}


classes = (
    SOMACAP_OT_create_cameras,
    SOMACAP_OT_place_clicks,
    SOMACAP_OT_build_body,
    SOMACAP_OT_fit,
    SOMACAP_OT_map_bones,
    SOMACAP_OT_save_mapping,
    SOMACAP_OT_load_mapping,
    SOMACAP_OT_retarget,
    SOMACAP_OT_export,
)
