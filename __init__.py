"""Penumbra: physically grounded soft-shadow passes for Blender.

``register()`` wires the Blender-facing parts (``addon/``, ``operators/``,
both built on ``bridge/``) and the ``penumbra`` command (``blender --command
penumbra ...``). Importing this
package does not import bpy, so ``penumbra.core`` and the CLI work outside
Blender (tests, the PyPI bpy module).
"""
import os

_cli_handle = None


def _set_numba_cache():
    """Numba's cache goes to the extension's user folder inside Blender, never
    into the extension's own (possibly read-only) folder."""
    if "PENUMBRA_NUMBA_CACHE_ROOT" in os.environ:
        return
    try:
        import bpy
        path = bpy.utils.extension_path_user(__package__, path="numba", create=True)
    except (ValueError, AttributeError, ImportError):
        return  # imported as a plain package: core/__init__ picks a user cache folder
    os.environ["PENUMBRA_NUMBA_CACHE_ROOT"] = path


def _cli_execute(argv):
    from .cli import main
    return main(list(argv))


def register():
    global _cli_handle
    _set_numba_cache()
    import bpy
    from . import addon, operators
    addon.register()
    operators.register()
    if _cli_handle is None:
        _cli_handle = bpy.utils.register_cli_command("penumbra", _cli_execute)
    if not bpy.app.background:
        # the first click finds the default method compiled (a daemon thread: it never
        # holds up register() or Blender's exit; headless runs compile on first use)
        from .bridge.pipeline import start_warm_up
        start_warm_up()


def unregister():
    global _cli_handle
    import bpy
    from . import addon, operators
    from .bridge.pipeline import stop_warm_up
    stop_warm_up()
    if _cli_handle is not None:
        bpy.utils.unregister_cli_command(_cli_handle)
        _cli_handle = None
    operators.unregister()
    addon.unregister()
