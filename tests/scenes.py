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
SAMPLE_NAMES = ("grids", "sphere_plane", "torus_plane", "foliage", "sun_pillars", "leaf_cards", "dense_sphere",
                "dense_foliage")


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


def tiny_cycles_scene(width: int, height: int, world_color=None):
    """A factory-empty bpy scene for compositor checks: Cycles at 1 sample,
    no denoising, ``width`` x ``height`` at 100 %, one camera (and a world of
    ``world_color`` when given). The compositor evaluates headless only in a
    render with ``write_still``, so these tests render this."""
    import bpy
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.samples = 1
    scene.cycles.use_denoising = False
    scene.render.resolution_x, scene.render.resolution_y = width, height
    scene.render.resolution_percentage = 100
    if world_color is not None:
        scene.world = bpy.data.worlds.new("World")
        scene.world.color = world_color
    cam = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    scene.collection.objects.link(cam)
    scene.camera = cam
    return scene
