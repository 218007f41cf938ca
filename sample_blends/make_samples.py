"""Build Penumbra's sample scenes (run: ``.venv/bin/python sample_blends/make_samples.py``).

Writes, next to this script, three .blend files (Cycles, 512x512 at 100 %):

* ``grids.blend``        - Laine & Aila 2005's GRIDS test scene: three stacked
  lattices of thin crossing bars over a ground plane, each lattice rotated
  against the others, lit by one square area light a quarter of the lattice
  span wide. Large penumbrae, many overlapping occluders.
* ``sphere_plane.blend`` - Reeves, Salesin & Cook 1987, figure 5: a red sphere
  in front of an upright green plane, an area light "Key.Light" off to the
  left: the sphere's shadow falls on the plane and the sphere self-shadows.
  The dot in the light's name exercises EXR layer-name sanitising.
* ``torus_plane.blend``  - Brabec & Seidel 2002, figure 7: a torus above a
  ground plane, lit by a spot light of non-zero radius from above.

Everything is built from arrays (no operators, no randomness), so the scenes
are the same on every run. ``main(out_dir)`` builds them elsewhere.
"""
from __future__ import annotations

import math
import os
import sys

import bpy  # first: with the PyPI bpy module, bmesh and mathutils exist only after it
import bmesh
import numpy as np
from mathutils import Vector

HERE = os.path.dirname(os.path.abspath(__file__))
SCENES = ("grids", "sphere_plane", "torus_plane")

# GRIDS parameters
GRID_SPAN = 6.0          # lattice side length
GRID_BARS = 16           # bars per direction in one lattice
GRID_BAR_WIDTH = 0.07    # thin bars: square cross-section
GRID_SEGMENTS = 32       # length subdivisions per bar (triangle budget)
GRID_HEIGHTS = (1.2, 2.4, 3.6)
GRID_ROTATIONS_DEG = (0.0, 30.0, 60.0)


# --------------------------------------------------------------------------
# helpers
def _reset(name: str):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.name = name
    r = scene.render
    r.engine = "CYCLES"
    r.resolution_x = 512
    r.resolution_y = 512
    r.resolution_percentage = 100
    scene.cycles.device = "CPU"
    scene.cycles.samples = 128
    scene.frame_start = scene.frame_end = scene.frame_current = 1
    world = bpy.data.worlds.new("World")
    world.color = (0.0, 0.0, 0.0)
    # a new World in 5.0 already has a node tree (Background 0.05 grey) that
    # would light the scene: make it black, so the one light is all there is
    if world.node_tree is not None:
        for node in world.node_tree.nodes:
            if node.bl_idname == "ShaderNodeBackground":
                node.inputs["Color"].default_value = (0.0, 0.0, 0.0, 1.0)
                node.inputs["Strength"].default_value = 0.0
    scene.world = world
    return scene


def _material(name: str, rgb) -> bpy.types.Material:
    mat = bpy.data.materials.new(name)
    mat.diffuse_color = (*rgb, 1.0)
    bsdf = mat.node_tree.nodes.get("Principled BSDF") if mat.node_tree else None
    if bsdf is not None:
        bsdf.inputs["Base Color"].default_value = (*rgb, 1.0)
        bsdf.inputs["Roughness"].default_value = 1.0
    return mat


def _mesh_object(scene, name: str, verts: np.ndarray, faces, material=None, recalc=True):
    me = bpy.data.meshes.new(name)
    me.from_pydata(np.asarray(verts, float).tolist(), [], [list(map(int, f)) for f in faces])
    if recalc:                      # closed meshes: outward normals
        bm = bmesh.new()
        bm.from_mesh(me)
        bmesh.ops.recalc_face_normals(bm, faces=bm.faces)
        bm.to_mesh(me)
        bm.free()
    me.validate()
    if material is not None:
        me.materials.append(material)
    ob = bpy.data.objects.new(name, me)
    scene.collection.objects.link(ob)
    return ob


def _plane(scene, name: str, size_x: float, size_y: float, material=None):
    hx, hy = 0.5 * size_x, 0.5 * size_y
    v = np.array([[-hx, -hy, 0], [hx, -hy, 0], [hx, hy, 0], [-hx, hy, 0]], float)
    return _mesh_object(scene, name, v, [[0, 1, 2, 3]], material, recalc=False)


def _look_at(ob, target):
    d = Vector(target) - ob.location
    ob.rotation_euler = d.to_track_quat("-Z", "Y").to_euler()


def _camera(scene, location, target, lens=50.0):
    data = bpy.data.cameras.new("Camera")
    data.lens = lens
    data.clip_start = 0.1
    data.clip_end = 200.0
    ob = bpy.data.objects.new("Camera", data)
    scene.collection.objects.link(ob)
    ob.location = location
    _look_at(ob, target)
    scene.camera = ob
    return ob


def _light(scene, name: str, kind: str, location, target, energy: float, **props):
    data = bpy.data.lights.new(name, kind)
    data.energy = energy
    for k, v in props.items():
        setattr(data, k, v)
    ob = bpy.data.objects.new(name, data)
    scene.collection.objects.link(ob)
    ob.location = location
    _look_at(ob, target)
    return ob


def _bar_arrays(length: float, width: float, segments: int):
    """A box along X, centred at the origin, cross-section ``width`` square,
    split into ``segments`` along its length: (verts[V,3], quads[F,4])."""
    xs = np.linspace(-0.5 * length, 0.5 * length, segments + 1)
    h = 0.5 * width
    ring = np.array([[-h, -h], [h, -h], [h, h], [-h, h]])          # (y, z)
    verts = np.empty((segments + 1, 4, 3))
    verts[:, :, 0] = xs[:, None]
    verts[:, :, 1:] = ring[None]
    verts = verts.reshape(-1, 3)
    quads = []
    for k in range(segments):
        a, b = 4 * k, 4 * (k + 1)
        for j in range(4):
            jn = (j + 1) % 4
            quads.append([a + j, a + jn, b + jn, b + j])
    last = 4 * segments
    quads.append([3, 2, 1, 0])
    quads.append([last, last + 1, last + 2, last + 3])
    return verts, np.array(quads, np.int64)


def _lattice_arrays():
    """One lattice: GRID_BARS bars along X at z=0, GRID_BARS along Y on top."""
    bar_v, bar_f = _bar_arrays(GRID_SPAN + GRID_BAR_WIDTH, GRID_BAR_WIDTH, GRID_SEGMENTS)
    positions = np.linspace(-0.5 * GRID_SPAN, 0.5 * GRID_SPAN, GRID_BARS)
    verts, faces, base = [], [], 0
    for axis in (0, 1):
        for p in positions:
            v = bar_v.copy()
            if axis == 0:                       # along X at y = p
                v[:, 1] += p
            else:                               # along Y at x = p, on top of the X bars
                v = v[:, [1, 0, 2]]
                v[:, 0] += p
                v[:, 2] += GRID_BAR_WIDTH
            verts.append(v)
            faces.append(bar_f + base)
            base += len(v)
    return np.concatenate(verts), np.concatenate(faces)


def _uv_sphere_arrays(radius: float, segments: int, rings: int):
    """UV sphere (poles on Z): triangles at the poles, quads between.
    (bmesh.ops.create_uvsphere is not used: its face order varies run to run.)"""
    theta = np.arange(1, rings) * (math.pi / rings)                  # ring polar angles
    phi = np.arange(segments) * (2 * math.pi / segments)
    T, P = np.meshgrid(theta, phi, indexing="ij")
    ring_v = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1)
    verts = np.concatenate([[[0, 0, 1]], ring_v.reshape(-1, 3), [[0, 0, -1]]]) * radius
    top, bottom = 0, len(verts) - 1
    j = np.arange(segments)
    jn = (j + 1) % segments
    faces = [[top, 1 + j[k], 1 + jn[k]] for k in range(segments)]
    for r in range(rings - 2):
        a, b = 1 + r * segments, 1 + (r + 1) * segments
        faces += [[a + j[k], b + j[k], b + jn[k], a + jn[k]] for k in range(segments)]
    last = 1 + (rings - 2) * segments
    faces += [[last + jn[k], last + j[k], bottom] for k in range(segments)]
    return verts, faces


def _torus_arrays(major: float, minor: float, n_major: int, n_minor: int):
    u = np.arange(n_major) * (2 * math.pi / n_major)
    v = np.arange(n_minor) * (2 * math.pi / n_minor)
    U, V = np.meshgrid(u, v, indexing="ij")
    r = major + minor * np.cos(V)
    verts = np.stack([r * np.cos(U), r * np.sin(U), minor * np.sin(V)], -1).reshape(-1, 3)
    i = np.arange(n_major)[:, None]
    j = np.arange(n_minor)[None, :]
    a = i * n_minor + j
    b = ((i + 1) % n_major) * n_minor + j
    c = ((i + 1) % n_major) * n_minor + (j + 1) % n_minor
    d = i * n_minor + (j + 1) % n_minor
    faces = np.stack([a, b, c, d], -1).reshape(-1, 4)
    return verts, faces


# --------------------------------------------------------------------------
# the scenes
def build_grids():
    scene = _reset("grids")
    white = _material("Diffuse", (0.8, 0.8, 0.8))
    _plane(scene, "Ground", 16.0, 16.0, white)
    verts, faces = _lattice_arrays()
    for k, (z, rot) in enumerate(zip(GRID_HEIGHTS, GRID_ROTATIONS_DEG)):
        ob = _mesh_object(scene, f"Grid{k + 1}", verts, faces, white)
        ob.location = (0.0, 0.0, z)
        ob.rotation_euler = (0.0, 0.0, math.radians(rot))
    _light(scene, "AreaLight", "AREA", (0.0, 0.0, 7.5), (0.0, 0.0, 0.0), 1500.0,
           shape="SQUARE", size=GRID_SPAN / 4.0)
    _camera(scene, (9.0, -9.0, 8.5), (0.0, 0.0, 1.0), lens=35.0)
    return scene


def build_sphere_plane():
    scene = _reset("sphere_plane")
    red = _material("Red", (0.8, 0.05, 0.05))
    green = _material("Green", (0.05, 0.6, 0.1))
    verts, faces = _uv_sphere_arrays(1.0, 64, 32)
    sphere = _mesh_object(scene, "Sphere", verts, faces, red)
    sphere.data.shade_smooth()
    wall = _plane(scene, "Plane", 24.0, 16.0, green)      # upright, facing -Y
    wall.location = (0.0, 3.0, 0.0)
    wall.rotation_euler = (math.radians(90.0), 0.0, 0.0)
    _light(scene, "Key.Light", "AREA", (-4.0, -5.0, 1.5), (0.0, 0.0, 0.0), 600.0,
           shape="SQUARE", size=1.0)
    _camera(scene, (0.0, -11.0, 0.8), (0.9, 0.0, -0.2), lens=40.0)
    return scene


def build_torus_plane():
    scene = _reset("torus_plane")
    white = _material("Diffuse", (0.8, 0.8, 0.8))
    _plane(scene, "Ground", 12.0, 12.0, white)
    verts, faces = _torus_arrays(1.0, 0.3, 64, 32)
    torus = _mesh_object(scene, "Torus", verts, faces, _material("Torus", (0.7, 0.55, 0.2)))
    torus.location = (0.0, 0.0, 1.5)
    torus.rotation_euler = (math.radians(20.0), 0.0, 0.0)
    _light(scene, "Spot", "SPOT", (0.5, -0.5, 6.0), (0.0, 0.0, 0.0), 2500.0,
           spot_size=math.radians(70.0), spot_blend=0.15, shadow_soft_size=0.4)
    _camera(scene, (0.0, -9.0, 6.5), (0.0, 0.0, 0.6), lens=40.0)
    return scene


BUILDERS = {"grids": build_grids, "sphere_plane": build_sphere_plane,
            "torus_plane": build_torus_plane}


def main(out_dir: str = HERE, names=SCENES):
    """Build and save the scenes into ``out_dir``; returns the written paths."""
    os.makedirs(out_dir, exist_ok=True)
    paths = []
    for name in names:
        BUILDERS[name]()
        path = os.path.join(out_dir, name + ".blend")
        bpy.ops.wm.save_as_mainfile(filepath=path, check_existing=False, compress=True)
        backup = path + "1"
        if os.path.exists(backup):
            os.remove(backup)
        paths.append(path)
    return paths


if __name__ == "__main__":
    out = sys.argv[1] if len(sys.argv) > 1 else HERE
    for p in main(out):
        print(p)
