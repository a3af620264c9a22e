"""The "Somacap" tab of the 3D viewport sidebar."""

from __future__ import annotations

import bpy


class SOMACAP_UL_mapping(bpy.types.UIList):
    def draw_item(self, context, layout, data, item, icon, active_data, active_propname):
        s = context.scene.somacap
        row = layout.row(align=True)
        row.label(text=item.canonical)
        if s.target is not None:
            row.prop_search(item, "bone", s.target.data, "bones", text="")
        else:
            row.prop(item, "bone", text="")


class SOMACAP_PT_main(bpy.types.Panel):
    bl_idname = "SOMACAP_PT_main"
    bl_label = "Somacap"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "Somacap"

    def draw(self, context):
        s = context.scene.somacap
        col = self.layout.column()
        col.prop(s, "scene_dir")
        col.prop(s, "calibration")
        col.operator("somacap.create_cameras", icon="CAMERA_DATA")
        col.operator("somacap.place_clicks", icon="EMPTY_AXIS")
        col.separator()
        col.prop(s, "take")
        row = col.row(align=True)
        row.prop(s, "fit_cues", text="")
        row.operator("somacap.fit", icon="PLAY")
        opts = col.column(align=True)
        opts.prop(s, "feet_from_points")
        opts.prop(s, "smooth_motion")
        opts.prop(s, "contour_starts")
        opts.prop(s, "late_shape")
        opts.prop(s, "flow_choice")
        if s.status:
            col.label(text=s.status)
        col.prop(s, "state_path")
        col.operator("somacap.build_body", icon="ARMATURE_DATA")


class SOMACAP_PT_quality(bpy.types.Panel):
    bl_idname = "SOMACAP_PT_quality"
    bl_label = "Fit quality"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "Somacap"
    bl_parent_id = "SOMACAP_PT_main"

    def draw(self, context):
        body = context.scene.somacap.body
        if body is None or "somacap_rmse_mm" not in body:
            self.layout.label(text="No fitted body")
            return
        rmse = list(body["somacap_rmse_mm"])
        i = context.scene.frame_current - context.scene.frame_start
        if 0 <= i < len(rmse):
            v = rmse[i]
            self.layout.label(
                text=f"Frame {context.scene.frame_current}: RMSE "
                + (f"{v:.1f} mm" if v >= 0 else "unknown")
            )
            if list(body.get("somacap_diverged", []))[i : i + 1] == [1]:
                self.layout.label(text="Diverged on this frame", icon="ERROR")
        good = [v for v in rmse if v >= 0]
        if good:
            self.layout.label(text=f"Take: median {sorted(good)[len(good) // 2]:.1f} mm")


class SOMACAP_PT_retarget(bpy.types.Panel):
    bl_idname = "SOMACAP_PT_retarget"
    bl_label = "Retarget & export"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "Somacap"
    bl_parent_id = "SOMACAP_PT_main"

    def draw(self, context):
        s = context.scene.somacap
        col = self.layout.column()
        col.prop(s, "body")
        col.prop(s, "target")
        col.prop(s, "foot_lock")
        row = col.row(align=True)
        row.operator("somacap.map_bones", icon="GROUP_BONE")
        row.operator("somacap.save_mapping", icon="FILE_TICK", text="Save preset")
        row.operator("somacap.load_mapping", icon="FILEBROWSER", text="Load preset")
        if len(s.mapping):
            col.label(text=f"Mapping ({s.mapping_scheme})")
            col.template_list("SOMACAP_UL_mapping", "", s, "mapping", s, "mapping_index", rows=6)
        col.operator("somacap.retarget", icon="OUTLINER_OB_ARMATURE")
        col.separator()
        row = col.row(align=True)
        row.prop(s, "export_format", expand=True)
        col.operator("somacap.export", icon="EXPORT")


classes = (SOMACAP_UL_mapping, SOMACAP_PT_main, SOMACAP_PT_quality, SOMACAP_PT_retarget)
