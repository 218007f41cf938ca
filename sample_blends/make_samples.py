"""Build Penumbra's sample scenes (run: ``.venv/bin/python sample_blends/make_samples.py``).

Writes, next to this script, eight .blend files (Cycles, 512x512 at 100 %):

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
* ``foliage.blend``      - a shrub of ~3,000 small, randomly oriented,
  single-sided leaves on thin stems over a ground plane, under a 1.5 x 0.8 m
  rectangular area light (about the leaf cluster's size). Many small occluders.
* ``sun_pillars.blend``  - two colonnades of thin pillars and arches
  over a ground plane, under a low sun of 4 degrees angular diameter.
* ``dense_sphere.blend`` - a production triangle count: the contact
  scene of ``bench/scaling.py`` (a smooth sphere resting on a ground plane
  under a 1 m square area light) with the sphere a 64 x 32 UV sphere under a
  Catmull-Clark Subdivision Surface modifier of 4 levels: 1,032,192 triangles
  once evaluated, a few KB of mesh in the file.
* ``dense_foliage.blend`` - ``foliage``'s shrub (the same stems,
  leaf placements and light) with every leaf one hexagon under a
  Catmull-Clark Subdivision Surface modifier of 3 levels and a Displace
  modifier (Clouds texture, along the normals): curved leaves of 192
  triangles, 576K leaf triangles once evaluated.
* ``leaf_cards.blend``   - alpha-matte occluders under an area light:
  36 leaf cards with a binary leaf matte (Closest), a chain-link fence card
  (binary, tiled), and four cards with a soft leaf matte (Linear). Each matte
  is an Image Texture whose Alpha drives the Principled BSDF's Alpha; the
  images are generated with NumPy, saved once and packed into the .blend.
  Two more wirings: a "Veil" card with a constant Principled Alpha of 0.5, and
  two "MixLeaf" cards whose Mix Shader takes a Transparent BSDF (first) and a
  Principled BSDF (second) by the leaf matte's Alpha.

Everything is built from arrays (no operators; "random" placements come from a
seeded NumPy Generator), so the scenes are the same on every run. ``main(out_dir)`` builds them elsewhere.
"""
from __future__ import annotations

import math
import os
import sys
import tempfile

import bpy  # first: with the PyPI bpy module, bmesh and mathutils exist only after it
import bmesh
import numpy as np
from mathutils import Vector

HERE = os.path.dirname(os.path.abspath(__file__))
SCENES = ("grids", "sphere_plane", "torus_plane", "foliage", "sun_pillars", "leaf_cards", "dense_sphere",
          "dense_foliage")

# GRIDS parameters
GRID_SPAN = 6.0          # lattice side length
GRID_BARS = 16           # bars per direction in one lattice
GRID_BAR_WIDTH = 0.07    # thin bars: square cross-section
GRID_SEGMENTS = 32       # length subdivisions per bar (triangle budget)
GRID_HEIGHTS = (1.2, 2.4, 3.6)
GRID_ROTATIONS_DEG = (0.0, 30.0, 60.0)

# foliage parameters
FOLIAGE_SEED = 17
FOLIAGE_LEAVES = 3000            # single-sided leaves, 4 triangles each
FOLIAGE_LEAF_LENGTH = 0.08
FOLIAGE_LEAF_WIDTH = 0.045
FOLIAGE_BRANCHES = 28
FOLIAGE_STEM_WIDTH = 0.012
FOLIAGE_CROWN_CENTRE = (0.0, 0.0, 1.25)
FOLIAGE_CROWN_RADII = (0.75, 0.45, 0.45)   # ellipsoid the branch tips fill
FOLIAGE_LIGHT_SIZE = (1.5, 0.8)            # rectangle, about the crown's size

# dense scenes (production triangle counts, made by modifiers)
DENSE_SPHERE_LEVELS = 4          # Catmull-Clark levels on a 64 x 32 UV sphere: 1,032,192 triangles
DENSE_LEAF_LEVELS = 3            # Catmull-Clark levels on a hexagonal leaf: 192 triangles
DENSE_LEAF_DISPLACE = 0.02       # Displace strength (m) along the leaf normal (Clouds, midlevel 0.5)
DENSE_LEAF_NOISE = 0.06          # the Clouds texture's noise size (m): about a leaf

# sun and pillars parameters
SUN_ANGLE_DEG = 4.0              # angular diameter (SunLight.angle)
PILLAR_WIDTH = 0.12
PILLAR_HEIGHT = 2.4
PILLAR_SPACING = 1.2             # arch span between neighbouring pillars
PILLARS_PER_ROW = 5
PILLAR_ROWS_X = (0.0, 1.8)

# leaf cards parameters
CARDS_SEED = 18
CARDS_BINARY = 36
CARDS_SOFT = 4
CARD_SIZE = 0.35
MATTE_RES = 128                  # leaf matte texels per side
FENCE_CELL_RES = 64              # one chain-link diamond cell, tiled (Repeat)
FENCE_SIZE = (3.0, 1.5)
FENCE_CELLS = (12, 6)            # UV repeats over the fence card
VEIL_ALPHA = 0.5                 # constant Principled Alpha of the veil card
VEIL_CENTRE = (1.15, -0.55, 0.65)
MIX_CENTRES = ((-1.1, 0.05, 0.7), (-0.55, -0.85, 0.6))


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


def _random_rotations(rng, n: int) -> np.ndarray:
    """``n`` rotation matrices uniform over SO(3) (normalised Gaussian quaternions)."""
    q = rng.standard_normal((n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], 1)


def _leaf_arrays(length: float, width: float):
    """One flat leaf in its local XY plane, base at the origin, tip on +Y:
    six vertices, fanned from the base into four triangles."""
    h = 0.5 * width
    verts = np.array([[0, 0, 0], [-h, 0.3 * length, 0], [-0.8 * h, 0.65 * length, 0],
                      [0, length, 0], [0.8 * h, 0.65 * length, 0], [h, 0.3 * length, 0]])
    tris = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 4, 5]], np.int64)
    return verts, tris


def _tube_arrays(points, side, width: float):
    """A closed square tube of side ``width`` swept along the polyline
    ``points[N,3]``; ``side`` is a unit vector perpendicular to every segment
    (one side of the cross-section): (verts[4N,3], quads[4(N-1)+2,4])."""
    points = np.asarray(points, float)
    side = np.asarray(side, float)
    t = np.gradient(points, axis=0)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    other = np.cross(t, side)
    h = 0.5 * width
    ring = np.array([[-h, -h], [h, -h], [h, h], [-h, h]])
    verts = (points[:, None, :] + ring[None, :, 0, None] * side
             + ring[None, :, 1, None] * other[:, None, :]).reshape(-1, 3)
    n = len(points)
    k = np.arange(n - 1)[:, None]
    j = np.arange(4)[None, :]
    jn = (j + 1) % 4
    quads = np.stack([4 * k + j, 4 * k + jn, 4 * (k + 1) + jn, 4 * (k + 1) + j], -1).reshape(-1, 4)
    last = 4 * (n - 1)
    caps = np.array([[3, 2, 1, 0], [last, last + 1, last + 2, last + 3]])
    return verts, np.concatenate([quads, caps])


def _perpendicular(d) -> np.ndarray:
    d = np.asarray(d, float)
    a = np.array([1.0, 0.0, 0.0]) if abs(d[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    p = np.cross(d, a)
    return p / np.linalg.norm(p)


def _merge(parts):
    """[(verts, faces), ...] -> one (verts, faces) with the indices offset."""
    verts, faces, base = [], [], 0
    for v, f in parts:
        verts.append(v)
        faces.append(np.asarray(f) + base)
        base += len(v)
    return np.concatenate(verts), np.concatenate(faces)


def _card_object(scene, name: str, corners, uv_max=(1.0, 1.0), material=None):
    """A single quad (corners[4,3], counter-clockwise from its (0, 0) corner)
    with an active UV map running 0..uv_max over it."""
    ob = _mesh_object(scene, name, corners, [[0, 1, 2, 3]], material, recalc=False)
    uv = ob.data.uv_layers.new(name="UVMap")
    u, v = uv_max
    uv.data.foreach_set("uv", np.array([[0, 0], [u, 0], [u, v], [0, v]], np.float32).ravel())
    return ob


def _leaf_alpha(res: int, soft_texels: float = 0.0) -> np.ndarray:
    """A leaf matte, alpha[res, res] in [0, 1] (row 0 = v 0): a pointed ellipse
    along v. ``soft_texels`` = 0 gives a binary matte; otherwise the edge ramps
    linearly over that many texels."""
    c = (np.arange(res) + 0.5) / res
    u, v = np.meshgrid(c, c)                       # rows run along v
    x, y = (u - 0.5) * 2.0, (v - 0.5) * 2.0
    half_width = 0.55 * (1.0 - y * y) ** 1.5        # pointed at both ends
    dist = (np.abs(x) - half_width) * (0.5 * res)   # ~ texels outside the edge
    dist = np.where(np.abs(y) < 0.95, dist, np.inf)
    if soft_texels <= 0.0:
        return (dist <= 0.0).astype(np.float32)
    return np.clip(0.5 - dist / soft_texels, 0.0, 1.0).astype(np.float32)


def _chain_link_alpha(res: int, wire: float = 0.12) -> np.ndarray:
    """One chain-link cell, alpha[res, res] binary, tileable: wires along both
    diagonals, ``wire`` of the cell wide; the diamonds between are holes."""
    c = (np.arange(res) + 0.5) / res
    u, v = np.meshgrid(c, c)
    d1 = np.abs(((u + v) % 1.0) - 0.5)              # distance to a diagonal, in [0, 0.5]
    d2 = np.abs(((u - v) % 1.0) - 0.5)
    return ((d1 > 0.5 - 0.5 * wire) | (d2 > 0.5 - 0.5 * wire)).astype(np.float32)


def _matte_image(name: str, alpha: np.ndarray, rgb) -> bpy.types.Image:
    """A generated RGBA image (colour ``rgb``, the given alpha), saved once as a
    PNG in a temporary folder and packed (a generated image packs only after it
    has been saved: BLENDER_NOTES "Alpha mattes")."""
    h, w = alpha.shape
    img = bpy.data.images.new(name, width=w, height=h, alpha=True)
    px = np.empty((h, w, 4), np.float32)
    px[..., :3] = rgb
    px[..., 3] = alpha
    img.pixels.foreach_set(px.ravel())
    img.alpha_mode = "STRAIGHT"
    with tempfile.TemporaryDirectory() as tmp:
        img.filepath_raw = os.path.join(tmp, name + ".png")
        img.file_format = "PNG"
        img.save()
        img.pack()
    img.filepath_raw = "//" + name + ".png"
    return img


def _matte_material(name: str, image, interpolation: str) -> bpy.types.Material:
    """Principled BSDF whose Base Color and Alpha come from ``image``'s Image
    Texture node (Color -> Base Color, Alpha -> Alpha), as glTF / FBX wire it."""
    mat = _material(name, (0.2, 0.5, 0.1))
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    bsdf = nodes["Principled BSDF"]
    tex = nodes.new("ShaderNodeTexImage")
    tex.image = image
    tex.interpolation = interpolation
    tex.extension = "REPEAT"
    tex.location = (-400, 200)
    links.new(tex.outputs["Color"], bsdf.inputs["Base Color"])
    links.new(tex.outputs["Alpha"], bsdf.inputs["Alpha"])
    return mat


def _mix_matte_material(name: str, image) -> bpy.types.Material:
    """Mix Shader(Factor = the image's Alpha, Shader 1 = Transparent BSDF,
    Shader 2 = Principled BSDF): alpha = the Principled's share = Factor."""
    mat = _material(name, (0.25, 0.45, 0.1))
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    bsdf, out = nodes["Principled BSDF"], nodes["Material Output"]
    clear = nodes.new("ShaderNodeBsdfTransparent")
    mix = nodes.new("ShaderNodeMixShader")
    tex = nodes.new("ShaderNodeTexImage")
    tex.image = image
    tex.interpolation = "Closest"
    tex.extension = "REPEAT"
    links.new(tex.outputs["Alpha"], mix.inputs[0])
    links.new(clear.outputs["BSDF"], mix.inputs[1])
    links.new(bsdf.outputs["BSDF"], mix.inputs[2])
    links.new(mix.outputs["Shader"], out.inputs["Surface"])
    return mat


def _level_card(scene, name: str, centre, size: float, material):
    h = 0.5 * size
    corners = np.array([[-h, -h, 0], [h, -h, 0], [h, h, 0], [-h, h, 0]]) + np.asarray(centre)
    return _card_object(scene, name, corners, material=material)


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


def _foliage_parts(rng):
    """foliage's stems (verts, quads) and leaves (per leaf a rotation and a
    base point), drawn from ``rng`` in a fixed order."""
    centre = np.array(FOLIAGE_CROWN_CENTRE)
    radii = np.array(FOLIAGE_CROWN_RADII)
    fork = np.array([0.0, 0.0, centre[2] - radii[2]])
    # branch tips spread through the crown ellipsoid (direction x radius^(1/3))
    d = rng.standard_normal((FOLIAGE_BRANCHES, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    tips = centre + d * radii * rng.uniform(0.55, 1.0, (FOLIAGE_BRANCHES, 1))
    stems = [_tube_arrays(np.linspace([0, 0, 0], fork, 4), [1, 0, 0], 2 * FOLIAGE_STEM_WIDTH)]
    for tip in tips:
        stems.append(_tube_arrays(np.linspace(fork, tip, 4), _perpendicular(tip - fork),
                                  FOLIAGE_STEM_WIDTH))
    # leaves: base on a branch (its outer 60 %), a little off it, any orientation
    branch = rng.integers(0, FOLIAGE_BRANCHES, FOLIAGE_LEAVES)
    t = rng.uniform(0.4, 1.0, (FOLIAGE_LEAVES, 1))
    bases = fork + t * (tips[branch] - fork) + rng.normal(0.0, 0.06, (FOLIAGE_LEAVES, 3))
    rot = _random_rotations(rng, FOLIAGE_LEAVES)
    return _merge(stems), rot, bases


def _foliage_base(name: str):
    """A new scene ``name`` with foliage's ground and stems; returns it and
    the leaves' rotations and base points."""
    scene = _reset(name)
    rng = np.random.default_rng(FOLIAGE_SEED)
    white = _material("Diffuse", (0.8, 0.8, 0.8))
    _plane(scene, "Ground", 10.0, 10.0, white)
    (sv, sf), rot, bases = _foliage_parts(rng)
    _mesh_object(scene, "Stems", sv, sf, _material("Stem", (0.35, 0.22, 0.1)))
    return scene, rot, bases


def build_foliage():
    scene, rot, bases = _foliage_base("foliage")
    leaf_v, leaf_t = _leaf_arrays(FOLIAGE_LEAF_LENGTH, FOLIAGE_LEAF_WIDTH)
    verts = np.einsum("nij,vj->nvi", rot, leaf_v) + bases[:, None, :]
    tris = leaf_t[None] + (len(leaf_v) * np.arange(FOLIAGE_LEAVES))[:, None, None]
    _mesh_object(scene, "Leaves", verts.reshape(-1, 3), tris.reshape(-1, 3),
                 _material("Leaf", (0.15, 0.5, 0.1)), recalc=False)
    _foliage_light_camera(scene)
    return scene


def _foliage_light_camera(scene):
    _light(scene, "AreaLight", "AREA", (0.8, -0.4, 3.6), tuple(FOLIAGE_CROWN_CENTRE), 800.0,
           shape="RECTANGLE", size=FOLIAGE_LIGHT_SIZE[0], size_y=FOLIAGE_LIGHT_SIZE[1])
    _camera(scene, (2.0, -3.0, 2.1), (-0.45, 0.3, 0.55), lens=30.0)


def _subdivided(ob, levels: int):
    """A Catmull-Clark Subdivision Surface modifier of ``levels`` (viewport and render)."""
    mod = ob.modifiers.new("Subdivision", "SUBSURF")
    mod.subdivision_type = "CATMULL_CLARK"
    mod.levels = mod.render_levels = levels
    return mod


def build_dense_foliage():
    """``foliage`` at 576K leaf triangles: each leaf one hexagon face (the six
    corners of ``_leaf_arrays``) under Catmull-Clark (``DENSE_LEAF_LEVELS``)
    and a Displace along the normals: curved, no longer coplanar leaves."""
    scene, rot, bases = _foliage_base("dense_foliage")
    leaf_v, _ = _leaf_arrays(FOLIAGE_LEAF_LENGTH, FOLIAGE_LEAF_WIDTH)
    verts = np.einsum("nij,vj->nvi", rot, leaf_v) + bases[:, None, :]
    hexagons = np.arange(len(leaf_v))[None] + (len(leaf_v) * np.arange(FOLIAGE_LEAVES))[:, None]
    leaves = _mesh_object(scene, "Leaves", verts.reshape(-1, 3), hexagons, _material("Leaf", (0.15, 0.5, 0.1)),
                          recalc=False)
    _subdivided(leaves, DENSE_LEAF_LEVELS)
    tex = bpy.data.textures.new("LeafBend", "CLOUDS")
    tex.noise_scale = DENSE_LEAF_NOISE
    disp = leaves.modifiers.new("Displace", "DISPLACE")
    disp.texture = tex
    disp.texture_coords = "LOCAL"
    disp.direction = "NORMAL"
    disp.strength = DENSE_LEAF_DISPLACE
    _foliage_light_camera(scene)
    return scene


def build_dense_sphere():
    """The contact scene of ``bench/scaling.smooth_sphere_scene`` at about 1M
    triangles: a UV sphere (64 x 32) of radius 1 resting on the ground under
    ``DENSE_SPHERE_LEVELS`` of Catmull-Clark (which pulls its coarse faces in
    by under 1 %: it floats that little above the ground)."""
    scene = _reset("dense_sphere")
    white = _material("Diffuse", (0.8, 0.8, 0.8))
    _plane(scene, "Ground", 16.0, 16.0, white)
    verts, faces = _uv_sphere_arrays(1.0, 64, 32)
    sphere = _mesh_object(scene, "Sphere", verts, faces, _material("Sphere", (0.7, 0.7, 0.75)))
    sphere.location = (0.0, 0.0, 1.0)
    sphere.data.shade_smooth()
    _subdivided(sphere, DENSE_SPHERE_LEVELS)
    _light(scene, "AreaLight", "AREA", (-2.5, -1.5, 4.5), (0.0, 0.0, 0.5), 1000.0, shape="SQUARE", size=1.0)
    _camera(scene, (5.0, -6.0, 4.0), (-0.8, 0.6, 0.4), lens=35.0)
    return scene


def build_sun_pillars():
    scene = _reset("sun_pillars")
    white = _material("Diffuse", (0.8, 0.8, 0.8))
    stone = _material("Stone", (0.7, 0.65, 0.55))
    _plane(scene, "Ground", 30.0, 30.0, white)
    ys = (np.arange(PILLARS_PER_ROW) - 0.5 * (PILLARS_PER_ROW - 1)) * PILLAR_SPACING
    r = 0.5 * PILLAR_SPACING
    phi = np.linspace(0.0, math.pi, 25)
    parts = []
    for x in PILLAR_ROWS_X:
        for y in ys:                                   # upright pillars
            parts.append(_tube_arrays(np.linspace([x, y, 0], [x, y, PILLAR_HEIGHT], 5),
                                      [1, 0, 0], PILLAR_WIDTH))
        for y in ys[:-1]:                              # semicircular arches between them
            arc = np.stack([np.full_like(phi, x), y + r - r * np.cos(phi),
                            PILLAR_HEIGHT + r * np.sin(phi)], -1)
            parts.append(_tube_arrays(arc, [1, 0, 0], PILLAR_WIDTH))
    verts, faces = _merge(parts)
    _mesh_object(scene, "Colonnade", verts, faces, stone)
    # low sun from -X: elevation ~20 degrees, shadows ~6.5 m long
    _light(scene, "Sun", "SUN", (-10.0, -2.5, 3.7), (0.0, 0.0, 0.0), 3.0,
           angle=math.radians(SUN_ANGLE_DEG))
    _camera(scene, (5.0, -9.0, 5.5), (5.0, 0.5, 0.0), lens=28.0)
    return scene


def build_leaf_cards():
    scene = _reset("leaf_cards")
    scene.cycles.transparent_max_bounces = 64      # Cycles shows the mattes
    rng = np.random.default_rng(CARDS_SEED)
    _plane(scene, "Ground", 12.0, 12.0, _material("Diffuse", (0.8, 0.8, 0.8)))
    leaf_image = _matte_image("leaf_matte", _leaf_alpha(MATTE_RES), (0.15, 0.5, 0.1))
    leaf = _matte_material("LeafMatte", leaf_image, "Closest")
    soft = _matte_material("LeafSoft", _matte_image("leaf_soft", _leaf_alpha(MATTE_RES, 12.0),
                                                    (0.3, 0.55, 0.1)), "Linear")
    fence = _matte_material("ChainLink", _matte_image("chain_link",
                                                      _chain_link_alpha(FENCE_CELL_RES),
                                                      (0.5, 0.5, 0.55)), "Closest")
    # cards: a square in the card's XY plane, tilted at most 50 degrees from level
    h = 0.5 * CARD_SIZE
    square = np.array([[-h, -h, 0], [h, -h, 0], [h, h, 0], [-h, h, 0]])
    n = CARDS_BINARY + CARDS_SOFT
    centres = np.stack([rng.uniform(-1.4, 1.4, n), rng.uniform(-1.2, 0.4, n),
                        rng.uniform(0.9, 1.9, n)], -1)
    yaw = rng.uniform(0.0, 2 * math.pi, n)
    tilt = rng.uniform(-math.radians(50.0), math.radians(50.0), n)
    for k in range(n):
        cy, sy, ct, st = math.cos(yaw[k]), math.sin(yaw[k]), math.cos(tilt[k]), math.sin(tilt[k])
        rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
        rx = np.array([[1, 0, 0], [0, ct, -st], [0, st, ct]])
        corners = square @ (rz @ rx).T + centres[k]
        if k < CARDS_BINARY:
            _card_object(scene, f"Leaf{k + 1:02d}", corners, material=leaf)
        else:
            _card_object(scene, f"SoftLeaf{k - CARDS_BINARY + 1}", corners, material=soft)
    fx, fz = FENCE_SIZE
    fence_corners = np.array([[-0.5 * fx, 1.2, 0.0], [0.5 * fx, 1.2, 0.0],
                              [0.5 * fx, 1.2, fz], [-0.5 * fx, 1.2, fz]])
    _card_object(scene, "Fence", fence_corners, uv_max=FENCE_CELLS, material=fence)
    veil = _material("Veil", (0.6, 0.6, 0.6))
    veil.node_tree.nodes["Principled BSDF"].inputs["Alpha"].default_value = VEIL_ALPHA
    _level_card(scene, "Veil", VEIL_CENTRE, 0.6, veil)
    mix = _mix_matte_material("MixLeaf", leaf_image)
    for k, centre in enumerate(MIX_CENTRES):
        _level_card(scene, f"MixLeaf{k + 1}", centre, CARD_SIZE * 1.4, mix)
    _light(scene, "AreaLight", "AREA", (0.3, -1.5, 5.0), (0.0, 0.5, 0.0), 1000.0,
           shape="SQUARE", size=1.0)
    _camera(scene, (0.4, -4.8, 3.6), (0.0, 0.7, 0.5), lens=30.0)
    return scene


BUILDERS = {"grids": build_grids, "sphere_plane": build_sphere_plane,
            "torus_plane": build_torus_plane, "foliage": build_foliage,
            "sun_pillars": build_sun_pillars, "leaf_cards": build_leaf_cards,
            "dense_sphere": build_dense_sphere, "dense_foliage": build_dense_foliage}


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
