"""Blender-facing state and UI (properties, panels, preferences, handlers).

Kept apart from ``operators/`` (actions) and ``core/`` (no bpy at all), the
way Blender's glTF add-on keeps its Blender side apart from its format code.
"""

_modules = []


def register():
    for m in _modules:
        m.register()


def unregister():
    for m in reversed(_modules):
        m.unregister()
