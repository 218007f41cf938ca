"""Penumbra's core: pure NumPy / Numba / Embree. Never imports bpy.

Numba's on-disk cache goes to a per-user folder (``NUMBA_CACHE_DIR``) unless
the caller already chose one (the add-on sets the extension's user folder),
so a second run starts warm and the package folder stays read-only.
"""
import os


def _default_cache_dir() -> str:
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "penumbra", "numba")


os.environ.setdefault("NUMBA_CACHE_DIR", _default_cache_dir())
