"""bpy Operators; thin: settings -> ``bridge`` -> report. They never import
``addon``. Nothing here imports bpy until ``register()``.

Each operator module exposes ``classes``; they register in this order.
"""
import importlib

MODULES = ("compute", "preview", "cycles_reference", "compositor_ops", "clear")


def _classes():
    out = []
    for name in MODULES:
        try:
            mod = importlib.import_module(f"{__name__}.{name}")
        except ModuleNotFoundError as exc:
            if exc.name != f"{__name__}.{name}":
                raise
            continue
        out.extend(getattr(mod, "classes", ()))
    return out


def register():
    import bpy
    for cls in _classes():
        bpy.utils.register_class(cls)


def unregister():
    import bpy
    for cls in reversed(_classes()):
        bpy.utils.unregister_class(cls)
