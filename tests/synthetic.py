"""Scenes built in code (no bpy) for the core tests."""
from __future__ import annotations

import numpy as np

from penumbra.core.scene import Camera, Light, ObjectInfo, Scene
from penumbra.core.views import look_rotation


def quad(x0, x1, y0, y1, z):
    a, b, c, d = [x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z]
    return [[a, b, c], [a, c, d]]


def light_matrix(pos, forward=(0, 0, -1.0)):
    m = np.eye(4)
    m[:3, :3] = look_rotation(np.asarray(forward, float), np.array([0, 1.0, 0]))
    m[:3, 3] = pos
    return m


def top_ortho_camera(half=2.0, height=1.0, center=(0.0, 0.0)):
    """Orthographic camera looking straight down at z=0, +Y up in the image."""
    m = light_matrix((center[0], center[1], height))
    return Camera(m, kind="ORTHO", ortho_scale=2 * half, clip_start=1e-3, clip_end=100.0)


def half_plane_scene(light: Light, res=64, occluder_z=2.0, edge_y=0.0, half=2.0, ground=10.0):
    """Ground z=0, an opaque plane at ``occluder_z`` covering y < edge_y, and an
    orthographic camera between them looking down at the ground."""
    tris = quad(-ground, ground, -ground, ground, 0.0) + quad(-ground, ground, -ground, edge_y, occluder_z)
    ids = [0, 0, 1, 1]
    objs = [ObjectInfo("ground", 0, casts_shadow=True), ObjectInfo("occluder", 1, visible_camera=False)]
    cam = top_ortho_camera(half, height=min(1.0, occluder_z * 0.5))
    return Scene(np.array(tris, np.float32), np.array(ids), objs, cam, [light], (res, res))


def area_light(size=1.0, size_y=None, shape="SQUARE", z=4.0, name="Area"):
    return Light(name, "area", light_matrix((0, 0, z)), blender_type="AREA", shape=shape,
                 size=size, size_y=size if size_y is None else size_y)


def sphere_light(radius=0.5, z=4.0, name="Point", spot_size=np.pi):
    return Light(name, "sphere", light_matrix((0, 0, z)), blender_type="SPOT" if spot_size < np.pi else "POINT",
                 radius=radius, spot_size=spot_size)


def sun_light(angle=0.1, name="Sun"):
    return Light(name, "sun", light_matrix((0, 0, 10.0)), blender_type="SUN", angle=angle)


def pixel_world_y(scene: Scene, row):
    """World y of a pixel row's centre for ``top_ortho_camera``."""
    W, H = scene.resolution
    half = scene.camera.ortho_scale / 2
    return half - (row + 0.5) / H * 2 * half
