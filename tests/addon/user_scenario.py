"""A new user's session with the installed extension (run in a subprocess).

Usage: ``BLENDER_USER_RESOURCES=<tmp> python tests/addon/user_scenario.py ZIP SCENE OUT``.
Installs the zip, enables it, then does what the panel's buttons do: set the panel's
fields, call the operators (``bpy.ops.somacap.*``) as the UI calls them, and dumps the
panel's contents (what ``draw`` puts in the sidebar region).  Prints one JSON line.
"""

from __future__ import annotations

import json
import os
import sys

import bpy


class Recorder:
    """Stands in for ``UILayout``: records what a panel draws."""

    def __init__(self, log):
        self.log = log

    def __getattr__(self, name):
        def call(*args, **kw):
            if name == "operator":
                self.log.append(f"button {args[0]}")
            elif name == "prop":
                self.log.append(f"field {args[1]}")
            elif name == "label":
                self.log.append(f"label {kw.get('text', '')}")
            return Recorder(self.log)

        return call


def panel_dump(context) -> list[str]:
    log = []
    for name in ("SOMACAP_PT_main", "SOMACAP_PT_quality", "SOMACAP_PT_retarget"):
        cls = getattr(bpy.types, name)
        log.append(
            f"panel {cls.bl_label} ({cls.bl_space_type}/{cls.bl_region_type}/{cls.bl_category})"
        )
        fake = type("P", (), {"layout": Recorder(log)})()
        cls.draw(fake, context)
    return log


def main(zip_path, scene_dir, out_dir):
    res = {}
    bpy.ops.wm.read_factory_settings(use_empty=True)
    res["install"] = sorted(
        bpy.ops.extensions.package_install_files(
            filepath=zip_path, repo="user_default", enable_on_install=True
        )
    )
    import addon_utils

    addon_utils.enable("rigify", default_set=True)
    ctx = bpy.context
    s = ctx.scene.somacap
    s.scene_dir = scene_dir
    s.take = "demo"
    res["cameras"] = sorted(bpy.ops.somacap.create_cameras())
    res["fit"] = sorted(bpy.ops.somacap.fit())  # EXEC: synchronous, as from a script
    res["body"] = s.body.name if s.body else None
    bpy.ops.object.armature_human_metarig_add()
    s.target = ctx.active_object
    res["map"] = sorted(bpy.ops.somacap.map_bones())
    res["mapped"] = sum(1 for row in s.mapping if row.bone)
    res["retarget"] = sorted(bpy.ops.somacap.retarget())
    res["target_action"] = s.target.animation_data.action.name
    s.export_format = "BVH"
    res["export"] = sorted(bpy.ops.somacap.export(filepath=f"{out_dir}/demo.bvh"))
    s.state_path = f"{scene_dir}/fit.json"
    res["build_again"] = sorted(bpy.ops.somacap.build_body())
    res["actions"] = sorted(a.name for a in bpy.data.actions)
    res["panel"] = panel_dump(ctx)
    res["camera_objects"] = sorted(o.name for o in bpy.data.objects if o.type == "CAMERA")
    # A bad state file: a clear error, nothing built.
    n_obj = len(bpy.data.objects)
    s.state_path = f"{out_dir}/nope.json"
    try:
        bpy.ops.somacap.build_body()
        res["bad_state"] = "no error"
    except RuntimeError as exc:  # operator reported an ERROR
        res["bad_state"] = str(exc).strip()
    res["objects_unchanged"] = len(bpy.data.objects) == n_obj
    print(json.dumps(res))


if __name__ == "__main__":
    main(*sys.argv[1:4])
    if bpy.app.version < (4, 3, 0):  # bpy 4.2 crashes at exit once Rigify was enabled
        sys.stdout.flush()
        os._exit(0)
