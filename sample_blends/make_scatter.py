"""Build a production-style instanced scatter scene for the benchmark (run:
``.venv/bin/python sample_blends/make_scatter.py OUT.blend [--instances N] [--light sun|area] [--seed N]``).

Not one of the sample scenes (``make_samples.SCENES``): its .blend files are
built on demand and never committed. ``build_scatter(path, instances=2000,
light="sun", seed=0, resolution=(480, 270))`` writes one .blend (Cycles, the
given resolution at 100 %, the default pixel filter):

* ``Ground``  - a square ground plane reaching 10 m past the scatter on
  every side (room for the trees' shadows).
* ``Tree``    - one mesh object at the origin: an 8-sided trunk 2.2 m tall
  (0.1 m radius, capped at the top) and 2,400 square leaf quads of 0.15 m at
  random orientations (uniform over rotations) with their centres uniform in
  a crown ellipsoid of radii 1.5 x 1.5 x 1.1 m around 3 m height: 4,822
  triangles. ``hide_render`` is set, so the object itself does not render,
  only its instances.
* ``Scatter`` - a mesh of exactly ``instances`` vertices (no edges or faces)
  uniform over a square of side ``sqrt(instances) * 4`` m centred at the
  origin, with two point attributes, ``scatter_rot_z`` (rotation about Z,
  uniform in [0, 2 pi)) and ``scatter_scale`` (uniform scale in [0.7, 1.3]),
  and a Geometry Nodes modifier "Instance on Points" (node group
  "Scatter Trees": Object Info(Tree, As Instance) -> Instance on Points, the
  rotation and scale read from those attributes): ``instances`` instances of
  the one Tree mesh.
* light ``sun``  - "Sun": a sun of 2 degrees angular diameter at an elevation
  of 50 degrees (azimuth 30 degrees from +X towards +Y), strength 3.
  light ``area`` - "AreaLight": a 4 m square area light 12 m above the
  centre facing straight down, 5000 W.
* ``Camera``  - a 24 mm lens outside the scatter's -Y edge (0.12 side + 3 m
  beyond it, 0.4 side + 4 m up) looking down at the centre: about 80 % of
  the trees are in view, the far ground edge below the top of the frame.

The tree's leaves come from ``numpy.random.default_rng([seed, 0])`` and the
scatter points from ``default_rng([seed, 1])``, so a seed gives the same tree
for every instance count, and every build is the same. Everything is built
from arrays and node API calls, with ``make_samples.py``'s helpers (the only
operators are its factory reset and the final save).
"""
from __future__ import annotations

import argparse
import importlib.util
import math
import os
import sys

import bpy  # first: with the PyPI bpy module, bmesh and mathutils exist only after it
import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))


def _load_samples():
    """make_samples.py (beside this file) as a module, for its scene helpers."""
    spec = importlib.util.spec_from_file_location("penumbra_make_samples_helpers",
                                                  os.path.join(HERE, "make_samples.py"))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


_S = _load_samples()

LIGHTS = ("sun", "area")

# the tree
TRUNK_HEIGHT = 2.2
TRUNK_RADIUS = 0.1
TRUNK_SIDES = 8
LEAVES = 2400                    # square quads, 2 triangles each
LEAF_SIZE = 0.15
CROWN_CENTRE = (0.0, 0.0, 3.0)
CROWN_RADII = (1.5, 1.5, 1.1)

# the scatter
SPACING = 4.0                    # square side = sqrt(instances) * SPACING
SCALE_RANGE = (0.7, 1.3)
ROT_ATTR = "scatter_rot_z"
SCALE_ATTR = "scatter_scale"

# lights
SUN_ANGLE_DEG = 2.0              # angular diameter (SunLight.angle)
SUN_ELEVATION_DEG = 50.0
SUN_AZIMUTH_DEG = 30.0
SUN_STRENGTH = 3.0
AREA_SIZE = 4.0
AREA_HEIGHT = 12.0
AREA_ENERGY = 5000.0


def _trunk_arrays():
    """An 8-sided prism from z = 0 to TRUNK_HEIGHT, outward faces, top cap:
    (verts[16,3], faces) - 8 quads and one octagon."""
    a = 2.0 * np.pi * np.arange(TRUNK_SIDES) / TRUNK_SIDES
    ring = np.stack([TRUNK_RADIUS * np.cos(a), TRUNK_RADIUS * np.sin(a)], -1)
    bottom = np.concatenate([ring, np.zeros((TRUNK_SIDES, 1))], 1)
    top = np.concatenate([ring, np.full((TRUNK_SIDES, 1), TRUNK_HEIGHT)], 1)
    verts = np.concatenate([bottom, top])
    j = np.arange(TRUNK_SIDES)
    jn = (j + 1) % TRUNK_SIDES
    sides = np.stack([j, jn, jn + TRUNK_SIDES, j + TRUNK_SIDES], -1)      # counter-clockwise seen from outside
    return verts, [list(f) for f in sides] + [list(j + TRUNK_SIDES)]


def _leaf_arrays(rng):
    """LEAVES square quads of side LEAF_SIZE, random orientations, centres
    uniform in the crown ellipsoid: (verts[4 LEAVES,3], quads[LEAVES,4])."""
    d = rng.standard_normal((LEAVES, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    r = rng.random(LEAVES) ** (1.0 / 3.0)
    centres = np.asarray(CROWN_CENTRE) + d * r[:, None] * np.asarray(CROWN_RADII)
    rot = _S._random_rotations(rng, LEAVES)
    h = 0.5 * LEAF_SIZE
    corners = np.array([[-h, -h, 0.0], [h, -h, 0.0], [h, h, 0.0], [-h, h, 0.0]])
    verts = centres[:, None, :] + np.einsum("nij,kj->nki", rot, corners)
    quads = np.arange(4 * LEAVES).reshape(LEAVES, 4)
    return verts.reshape(-1, 3), quads


def _tree(scene, seed: int):
    rng = np.random.default_rng([seed, 0])
    tv, tf = _trunk_arrays()
    lv, lq = _leaf_arrays(rng)
    verts = np.concatenate([tv, lv])
    faces = tf + [list(q) for q in (lq + len(tv))]
    bark = _S._material("Bark", (0.25, 0.16, 0.08))
    leaf = _S._material("Leaf", (0.15, 0.4, 0.1))
    ob = _S._mesh_object(scene, "Tree", verts, faces, bark, recalc=False)
    ob.data.materials.append(leaf)
    index = np.zeros(len(faces), np.int32)
    index[len(tf):] = 1
    ob.data.polygons.foreach_set("material_index", index)
    ob.data.update()
    ob.hide_render = True           # only its instances render
    return ob


def _scatter_points(instances: int, seed: int):
    """(co[N,3], rot_z[N], scale[N]) of the scatter, uniform on its square."""
    rng = np.random.default_rng([seed, 1])
    half = 0.5 * SPACING * math.sqrt(instances)
    co = np.zeros((instances, 3))
    co[:, :2] = rng.uniform(-half, half, (instances, 2))
    rot_z = rng.uniform(0.0, 2.0 * np.pi, instances)
    scale = rng.uniform(*SCALE_RANGE, instances)
    return co, rot_z, scale


def _scatter_node_group(tree_ob):
    """Group input points -> Instance on Points(Object Info(tree, As Instance),
    Rotation = Euler(0, 0, scatter_rot_z), Scale = scatter_scale) -> output."""
    ng = bpy.data.node_groups.new("Scatter Trees", "GeometryNodeTree")
    ng.interface.new_socket(name="Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    ng.interface.new_socket(name="Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    n = ng.nodes
    gin = n.new("NodeGroupInput")
    gout = n.new("NodeGroupOutput")
    info = n.new("GeometryNodeObjectInfo")
    info.transform_space = "ORIGINAL"
    info.inputs["Object"].default_value = tree_ob
    info.inputs["As Instance"].default_value = True
    rot = n.new("GeometryNodeInputNamedAttribute")
    rot.data_type = "FLOAT"
    rot.inputs["Name"].default_value = ROT_ATTR
    scale = n.new("GeometryNodeInputNamedAttribute")
    scale.data_type = "FLOAT"
    scale.inputs["Name"].default_value = SCALE_ATTR
    euler = n.new("ShaderNodeCombineXYZ")
    to_rot = n.new("FunctionNodeEulerToRotation")
    iop = n.new("GeometryNodeInstanceOnPoints")
    links = ng.links
    links.new(gin.outputs["Geometry"], iop.inputs["Points"])
    links.new(info.outputs["Geometry"], iop.inputs["Instance"])
    links.new(rot.outputs["Attribute"], euler.inputs["Z"])
    links.new(euler.outputs["Vector"], to_rot.inputs["Euler"])
    links.new(to_rot.outputs["Rotation"], iop.inputs["Rotation"])
    links.new(scale.outputs["Attribute"], iop.inputs["Scale"])      # float -> uniform (s, s, s)
    links.new(iop.outputs["Instances"], gout.inputs["Geometry"])
    for k, node in enumerate((gin, info, rot, scale, euler, to_rot, iop, gout)):
        node.location = (200.0 * k, 0.0)
    return ng


def _scatter(scene, tree_ob, instances: int, seed: int):
    co, rot_z, scale = _scatter_points(instances, seed)
    me = bpy.data.meshes.new("ScatterPoints")
    me.vertices.add(instances)
    me.vertices.foreach_set("co", co.astype(np.float32).ravel())
    for name, values in ((ROT_ATTR, rot_z), (SCALE_ATTR, scale)):
        attr = me.attributes.new(name, "FLOAT", "POINT")
        attr.data.foreach_set("value", values.astype(np.float32))
    me.update()
    ob = bpy.data.objects.new("Scatter", me)
    scene.collection.objects.link(ob)
    mod = ob.modifiers.new("Instance on Points", "NODES")
    mod.node_group = _scatter_node_group(tree_ob)
    return ob


def _lights(scene, light: str):
    if light == "sun":
        el, az = math.radians(SUN_ELEVATION_DEG), math.radians(SUN_AZIMUTH_DEG)
        towards = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
        return _S._light(scene, "Sun", "SUN", tuple(20.0 * towards), (0.0, 0.0, 0.0), SUN_STRENGTH,
                         angle=math.radians(SUN_ANGLE_DEG))
    return _S._light(scene, "AreaLight", "AREA", (0.0, 0.0, AREA_HEIGHT), (0.0, 0.0, 0.0), AREA_ENERGY,
                     shape="SQUARE", size=AREA_SIZE)


def build_scatter(path: str, instances: int = 2000, light: str = "sun", seed: int = 0,
                  resolution=(480, 270)) -> str:
    """Build the scatter scene and save it to ``path``; returns ``path``."""
    instances = int(instances)
    if instances < 1:
        raise ValueError(f"instances must be at least 1, got {instances}")
    if light not in LIGHTS:
        raise ValueError(f"light must be one of {', '.join(LIGHTS)}, got {light!r}")
    W, H = (int(v) for v in resolution)
    scene = _S._reset("scatter")
    scene.render.resolution_x = W
    scene.render.resolution_y = H
    scene.render.resolution_percentage = 100
    side = SPACING * math.sqrt(instances)
    ground = side + 20.0
    _S._plane(scene, "Ground", ground, ground, _S._material("Soil", (0.35, 0.3, 0.25)))
    tree = _tree(scene, int(seed))
    _scatter(scene, tree, instances, int(seed))
    _lights(scene, light)
    cam = _S._camera(scene, (0.0, -0.62 * side - 3.0, 0.4 * side + 4.0), (0.0, 0.0, 2.0), lens=24.0)
    cam.data.clip_end = 4.0 * side + 100.0
    path = os.path.abspath(path)
    os.makedirs(os.path.dirname(path), exist_ok=True)
    bpy.ops.wm.save_as_mainfile(filepath=path, check_existing=False, compress=True)
    if os.path.exists(path + "1"):
        os.remove(path + "1")
    return path


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description="Build the instanced scatter benchmark scene.")
    ap.add_argument("out", metavar="OUT.blend")
    ap.add_argument("--instances", type=int, default=2000)
    ap.add_argument("--light", choices=LIGHTS, default="sun")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(sys.argv[1:] if argv is None else argv)
    if args.instances < 1:
        ap.error("--instances must be at least 1")
    print(build_scatter(args.out, args.instances, args.light, args.seed))
    return 0


if __name__ == "__main__":
    sys.exit(main())
