"""Blender-facing state and UI (properties, panels, preferences, handlers).

Kept apart from ``operators/`` (actions) and ``core/`` (no bpy at all), the
way Blender's glTF add-on keeps its Blender side apart from its format code.
Each module listed here has ``register()`` / ``unregister()``.
"""
import importlib

MODULES = ("preferences", "properties", "panels", "handlers")


def _modules():
    out = []
    for name in MODULES:
        try:
            out.append(importlib.import_module(f"{__name__}.{name}"))
        except ModuleNotFoundError as exc:
            if exc.name != f"{__name__}.{name}":
                raise
    return out


def register():
    for m in _modules():
        m.register()


def unregister():
    for m in reversed(_modules()):
        m.unregister()
