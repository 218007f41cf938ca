"""The bundled sample scenes as captured core Scenes, for tests and the bench.

Loading a .blend needs bpy (``bridge/capture.py`` is the one boundary);
each capture is cached per (name, resolution) for the test session.
"""
from __future__ import annotations

import functools
import os

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SAMPLES = os.path.join(ROOT, "sample_blends")


def sample_path(name: str) -> str:
    return os.path.join(SAMPLES, f"{name}.blend")


@functools.lru_cache(maxsize=16)
def load_sample(name: str, resolution=(128, 128)):
    """Capture ``sample_blends/<name>.blend`` at ``resolution`` (W, H)."""
    import bpy
    from penumbra.bridge.capture import capture_scene
    bpy.ops.wm.open_mainfile(filepath=sample_path(name), load_ui=False)
    sc = capture_scene(bpy.context.scene, resolution=tuple(resolution))
    sc.name = name
    return sc
