"""Everything that imports bpy: properties, operators, panels, builders, CLI command.

Importing this package does not import bpy (``python -m addon.packaging`` runs without
Blender); :func:`register` does.  Registration order: properties, operators, panels;
unregistration in reverse (Rigify's habit), then the ``somacap`` CLI command.
"""

_cli_handle = None


def _modules():
    from . import operators, panel, props

    return (props, operators, panel)


def register():
    import bpy

    global _cli_handle
    for mod in _modules():
        for cls in mod.classes:
            bpy.utils.register_class(cls)
    from . import cli_command, props

    props.register_properties()
    if hasattr(bpy.utils, "register_cli_command"):
        _cli_handle = bpy.utils.register_cli_command("somacap", cli_command.main)


def unregister():
    import bpy

    global _cli_handle
    if _cli_handle is not None:
        bpy.utils.unregister_cli_command(_cli_handle)
        _cli_handle = None
    from . import props

    props.unregister_properties()
    for mod in reversed(_modules()):
        for cls in reversed(mod.classes):
            bpy.utils.unregister_class(cls)
