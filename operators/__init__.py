"""bpy Operators; thin: capture -> core -> write back. ``capture.py`` is the
one bpy -> numpy boundary. Nothing here imports bpy until ``register()``."""


def _classes():
    from . import compute
    return compute.classes


def register():
    import bpy
    for cls in _classes():
        bpy.utils.register_class(cls)


def unregister():
    import bpy
    for cls in reversed(_classes()):
        bpy.utils.unregister_class(cls)
