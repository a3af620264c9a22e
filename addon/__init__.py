"""Everything that imports bpy: properties, operators, panels, builders, CLI command."""

classes: tuple = ()


def register():
    import bpy

    for cls in classes:
        bpy.utils.register_class(cls)


def unregister():
    import bpy

    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
