"""Somacap Blender extension entry point (see blender_manifest.toml).

Blender imports this package as ``bl_ext.<repo>.somacap``; everything that touches
``bpy`` lives in :mod:`.addon`, the numerical pipeline in :mod:`.core`.
"""


def register():
    from .addon import register as _register

    _register()


def unregister():
    from .addon import unregister as _unregister

    _unregister()
