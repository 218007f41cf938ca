"""Add-on preferences: the Numba cache folder and the thread count.

The cache folder defaults to the extension's user folder
(``bpy.utils.extension_path_user``), or ``~/.cache/penumbra`` when the
package is not installed as an extension (tests, the CLI). Numba reads its
cache folder once, when it is first imported: a new folder takes effect the
next time Blender starts (``register`` applies the saved one before any
Penumbra kernel is imported). The thread count applies to every computation.
"""
from __future__ import annotations

import os
import sys
from types import SimpleNamespace

import bpy

from ..bridge.pipeline import set_threads
from ..bridge.settings import ROOT_PACKAGE, addon_preferences, preferred_threads
CACHE_ENV = "PENUMBRA_NUMBA_CACHE_ROOT"


def default_cache_folder() -> str:
    try:
        return bpy.utils.extension_path_user(ROOT_PACKAGE, path="numba", create=False)
    except (ValueError, AttributeError):
        base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
        return os.path.join(base, "penumbra", "numba")


def _core_loaded() -> bool:
    return f"{ROOT_PACKAGE}.core" in sys.modules


def _on_cache_folder(self, context):
    apply_cache_folder(self.numba_cache)


def apply_cache_folder(folder: str) -> bool:
    """Point Penumbra's Numba cache at ``folder`` if no kernel is loaded yet;
    returns whether it took effect now."""
    folder = bpy.path.abspath(folder) if folder else ""
    if not folder or _core_loaded():
        return False
    os.environ[CACHE_ENV] = folder
    return True


class PENUMBRA_AP_preferences(bpy.types.AddonPreferences):
    bl_idname = ROOT_PACKAGE

    # numba_cache: StringProperty, added by register() once its default is known
    threads: bpy.props.IntProperty(
        name="Threads", default=0, min=0, max=1024,
        description="Threads for Penumbra's kernels; 0 = all cores. Results are bit-identical "
                    "for the same thread count")

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.prop(self, "numba_cache")
        if _core_loaded() and os.environ.get(CACHE_ENV) and \
                os.path.normpath(os.environ[CACHE_ENV]) != os.path.normpath(bpy.path.abspath(self.numba_cache)):
            layout.label(text=f"In use until restart: {os.environ[CACHE_ENV]}", icon="INFO")
        layout.prop(self, "threads")


def get_prefs():
    """The add-on's preferences, or the defaults when it is registered as a
    plain package (``import penumbra; penumbra.register()``)."""
    prefs = addon_preferences()
    return prefs if prefs is not None else SimpleNamespace(numba_cache=default_cache_folder(), threads=0)


def apply_threads() -> int:
    """Set Numba's thread count from the preferences; returns it."""
    return set_threads(preferred_threads())


def register():
    PENUMBRA_AP_preferences.__annotations__["numba_cache"] = bpy.props.StringProperty(
        name="Numba Cache Folder", subtype="DIR_PATH", default=default_cache_folder(),
        update=_on_cache_folder,
        description="Where compiled kernels are kept so later sessions start warm "
                    "(takes effect the next time Blender starts)")
    bpy.utils.register_class(PENUMBRA_AP_preferences)
    prefs = get_prefs()
    # a folder the user chose (not the default) wins over the one __init__ set
    if isinstance(prefs, PENUMBRA_AP_preferences) and prefs.numba_cache and \
            os.path.normpath(prefs.numba_cache) != os.path.normpath(default_cache_folder()):
        apply_cache_folder(prefs.numba_cache)


def unregister():
    if getattr(PENUMBRA_AP_preferences, "is_registered", False):
        bpy.utils.unregister_class(PENUMBRA_AP_preferences)

