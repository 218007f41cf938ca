"""Penumbra's core: pure NumPy / Numba / Embree. Never imports bpy.

Numba's on-disk cache goes to a per-user folder (``NUMBA_CACHE_DIR``) unless
the caller already chose one (the add-on sets the extension's user folder),
so a second run starts warm and the package folder stays read-only.

Numba checks a cached kernel against its own source file only, not against
the modules it inlines (``sampling``, ``kernels``): a change there would run
stale machine code. So the cache lives in a sub-folder named by a hash of
every core source file, and any change to core starts a fresh cache.
"""
import hashlib
import os


def _default_cache_root() -> str:
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "penumbra", "numba")


def _source_fingerprint() -> str:
    h = hashlib.sha1()
    here = os.path.dirname(os.path.abspath(__file__))
    for folder, _, files in sorted(os.walk(here)):
        for name in sorted(files):
            if name.endswith(".py"):
                with open(os.path.join(folder, name), "rb") as f:
                    h.update(name.encode() + b"\0" + f.read())
    return h.hexdigest()[:16]


def _set_cache_dir():
    """``PENUMBRA_NUMBA_CACHE_ROOT`` (set by the add-on inside Blender), else a
    ``NUMBA_CACHE_DIR`` the user chose, else ~/.cache/penumbra/numba; child
    processes inherit the root."""
    root = os.environ.get("PENUMBRA_NUMBA_CACHE_ROOT") or os.environ.get("NUMBA_CACHE_DIR") \
        or _default_cache_root()
    os.environ["PENUMBRA_NUMBA_CACHE_ROOT"] = root
    os.environ["NUMBA_CACHE_DIR"] = os.path.join(root, _source_fingerprint())
    import sys
    if "numba" in sys.modules:   # imported first: its config already read the environment
        sys.modules["numba"].config.CACHE_DIR = os.environ["NUMBA_CACHE_DIR"]


_set_cache_dir()
