"""Install the built extension zip into the bpy module as a user would (run in a subprocess).

Usage: ``BLENDER_USER_RESOURCES=<tmp> python tests/addon/install_scenario.py ZIP``.
The environment variable points Blender's user directory (extensions, preferences) at a
temporary folder, so nothing touches the real user's Blender.  Prints one JSON object as
the last line of stdout: what was registered after each step.
"""

from __future__ import annotations

import json
import os
import sys

import bpy

MODULE = "bl_ext.user_default.somacap"


def snapshot() -> dict:
    ops = sorted(dir(bpy.ops.somacap))
    types = sorted(n for n in dir(bpy.types) if "SOMACAP" in n.upper())
    return {
        "ops": ops,
        "types": types,
        "scene_prop": hasattr(bpy.types.Scene, "somacap"),
        "enabled": MODULE in {a.module for a in bpy.context.preferences.addons},
        "n_types": len(dir(bpy.types)),
        "modules": sorted(m for m in sys.modules if m.startswith(MODULE)),
    }


def main(zip_path: str) -> None:
    steps = {"before": snapshot()}
    res = bpy.ops.extensions.package_install_files(
        filepath=zip_path, repo="user_default", enable_on_install=True
    )
    steps["install_result"] = sorted(res)
    steps["installed"] = snapshot()
    bpy.ops.preferences.addon_disable(module=MODULE)
    steps["disabled"] = snapshot()
    bpy.ops.preferences.addon_enable(module=MODULE)
    steps["reenabled"] = snapshot()
    mod = sys.modules[MODULE]
    steps["package_file"] = mod.__file__
    steps["core_module"] = sys.modules[MODULE + ".addon._core"].core.__name__
    print(json.dumps(steps))


if __name__ == "__main__":
    main(sys.argv[1])
    if bpy.app.version < (4, 3, 0):  # bpy 4.2 crashes at exit once Rigify was enabled
        sys.stdout.flush()
        os._exit(0)
