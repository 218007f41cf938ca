"""The bundled sample scenes as captured core Scenes, for tests and the bench.

Loading a .blend needs bpy (``bridge/capture.py`` is the one boundary);
each capture is cached per (name, resolution) for the test session.
"""
from __future__ import annotations

import functools
import os

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SAMPLES = os.path.join(ROOT, "sample_blends")

#: Every scene ``sample_blends/make_samples.py`` builds (its ``SCENES``).
SAMPLE_NAMES = ("grids", "sphere_plane", "torus_plane", "foliage", "sun_pillars", "leaf_cards")


def sample_path(name: str) -> str:
    return os.path.join(SAMPLES, f"{name}.blend")


def open_sample(name: str):
    """Open ``sample_blends/<name>.blend`` in bpy; returns its scene."""
    import bpy
    bpy.ops.wm.open_mainfile(filepath=sample_path(name), load_ui=False)
    return bpy.context.scene


@functools.lru_cache(maxsize=16)
def load_sample(name: str, resolution=(128, 128)):
    """Capture ``sample_blends/<name>.blend`` at ``resolution`` (W, H)."""
    from penumbra.bridge.capture import capture_scene
    sc = capture_scene(open_sample(name), resolution=tuple(resolution))
    sc.name = name
    return sc
