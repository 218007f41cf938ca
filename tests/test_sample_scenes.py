"""The bundled sample scenes (``sample_blends/``): every scene committed
and rebuilt bit for bit by ``make_samples.py``; the first three's contents
and a Cycles render of each; what the stress scenes (foliage, sun_pillars,
leaf_cards; dense_sphere and dense_foliage at production triangle counts)
are built to stress, checked on the .blend as captured, and an embree
render of each through the CLI that shows a real shadow."""
import math
import os

import bpy
import numpy as np
import pytest

from penumbra.bridge.capture import capture_scene
from penumbra.cli import main
from penumbra.core import exr
from scenes import SAMPLE_NAMES, SAMPLES, image_rgba, load_sample, open_sample, sample_path

#: the first sample scenes, whose contents are checked one by one
BASIC_SCENES = ("grids", "sphere_plane", "torus_plane")
#: scenes built to stress the methods: many small or thin occluders, alpha mattes
STRESS_SCENES = ("foliage", "sun_pillars", "leaf_cards")
#: production triangle counts, made by modifiers (the files stay small)
DENSE_SCENES = ("dense_sphere", "dense_foliage")
#: light kind and triangle range each stress scene is built for
EXPECTED = {"foliage": ("area", 8_000, 15_000),
            "sun_pillars": ("sun", 1_000, 5_000),
            "leaf_cards": ("area", 80, 100)}


def _object_triangles(scene, name):
    oid = next(o.id for o in scene.objects if o.name == name)
    return scene.triangles[scene.tri_object == oid].astype(np.float64)


def _unit_normals(tris):
    n = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def test_every_sample_scene_is_committed():
    assert sorted(SAMPLE_NAMES) == sorted(f[:-6] for f in os.listdir(SAMPLES) if f.endswith(".blend"))
    for name in BASIC_SCENES:
        assert os.path.isfile(sample_path(name)), name
    assert os.path.isfile(os.path.join(SAMPLES, "make_samples.py"))
    for name in STRESS_SCENES + DENSE_SCENES:
        assert os.path.getsize(sample_path(name)) < 2_000_000


def test_make_samples_is_deterministic(tmp_path):
    """The generator rebuilds exactly the geometry of the committed files."""
    import importlib.util

    spec = importlib.util.spec_from_file_location(
        "penumbra_make_samples", os.path.join(SAMPLES, "make_samples.py"))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    paths = mod.main(str(tmp_path))
    assert [os.path.basename(p) for p in paths] == [n + ".blend" for n in SAMPLE_NAMES]
    assert not any(p.endswith(".blend1") for p in os.listdir(tmp_path))
    for name, path in zip(SAMPLE_NAMES, paths):
        bpy.ops.wm.open_mainfile(filepath=path)
        fresh = capture_scene()
        bpy.ops.wm.open_mainfile(filepath=sample_path(name))
        committed = capture_scene()
        assert np.array_equal(fresh.triangles, committed.triangles), name
        assert [o.name for o in fresh.objects] == [o.name for o in committed.objects]
        assert [(lt.name, lt.size, lt.radius, lt.energy) for lt in fresh.lights] == \
            [(lt.name, lt.size, lt.radius, lt.energy) for lt in committed.lights]
        assert np.allclose(fresh.camera.world_from_camera, committed.camera.world_from_camera)


@pytest.mark.parametrize("name", BASIC_SCENES)
def test_sample_blend_contents_and_cycles_render(name, tmp_path):
    bpy.ops.wm.open_mainfile(filepath=sample_path(name))
    sc = bpy.context.scene
    assert sc.render.engine == "CYCLES"
    assert (sc.render.resolution_x, sc.render.resolution_y,
            sc.render.resolution_percentage) == (512, 512, 100)
    captured = capture_scene()
    assert captured.name == name and captured.camera is not None
    assert captured.resolution == (512, 512)
    assert len(captured.lights) == 1
    light = captured.lights[0]
    assert light.casts_shadow and light.extent > 0
    n = len(captured.triangles)
    if name == "grids":
        assert 20_000 <= n <= 30_000
        assert light.kind == "area" and light.shape == "SQUARE"
        lattice = [o for o in captured.objects if o.name.startswith("Grid")]
        assert len(lattice) == 3
        unrotated = _object_triangles(captured, "Grid1").reshape(-1, 3)
        span = unrotated[:, 0].max() - unrotated[:, 0].min()
        assert light.size == pytest.approx(span / 4, rel=0.05)
        heights = sorted(float(_object_triangles(captured, o.name)[..., 2].mean()) for o in lattice)
        assert heights[0] > 0.5 and heights[1] - heights[0] > 0.5 and heights[2] - heights[1] > 0.5
    elif name == "sphere_plane":
        assert "." in light.name and light.kind == "area"
        assert {o.name for o in captured.objects} == {"Sphere", "Plane"}
    else:
        assert light.blender_type == "SPOT" and light.radius > 0 and light.is_spot
        assert {o.name for o in captured.objects} == {"Torus", "Ground"}

    # renders with Cycles: 32x32, 4 samples
    sc.render.resolution_x = sc.render.resolution_y = 32
    sc.cycles.samples = 4
    sc.cycles.use_denoising = False
    out = str(tmp_path / f"{name}.png")
    sc.render.filepath = out
    sc.render.image_settings.file_format = "PNG"
    bpy.ops.render.render(write_still=True)
    assert os.path.isfile(out)
    img = bpy.data.images.load(out)
    assert tuple(img.size) == (32, 32)
    rgb = image_rgba(img)[..., :3]
    assert rgb.max() > 0.2                     # something is lit
    assert (rgb.max(-1) < 0.05).any()          # and something is dark (shadow / background)


# --------------------------------------------------------------------------
# the stress scenes


@pytest.mark.parametrize("name", STRESS_SCENES)
def test_light_kind_and_triangle_count(name):
    kind, lo, hi = EXPECTED[name]
    scene = load_sample(name)
    assert [light.kind for light in scene.lights] == [kind]
    assert lo <= len(scene.triangles) <= hi
    assert scene.resolution == (128, 128)


def test_foliage_leaves_single_sided_and_randomly_oriented():
    scene = load_sample("foliage")
    light = scene.lights[0]
    assert (light.shape, round(light.size, 3), round(light.size_y, 3)) == ("RECTANGLE", 1.5, 0.8)
    leaves = _object_triangles(scene, "Leaves")
    assert len(leaves) == 4 * 3000                    # 3,000 leaves of four triangles
    n = _unit_normals(leaves).reshape(3000, 4, 3)
    # each leaf is one flat sheet: its four triangles share a normal (no back face)
    assert np.all(np.einsum("lki,li->lk", n, n[:, 0]) > 0.999)
    centroids = leaves.mean(axis=1).round(6)
    assert len(np.unique(centroids, axis=0)) == len(leaves)   # no doubled (two-sided) triangle
    # orientations spread over the sphere: uniform gives mean |n.z| = 1/2, mean n = 0
    leaf_n = n[:, 0]
    assert abs(np.abs(leaf_n[:, 2]).mean() - 0.5) < 0.05
    assert np.all(np.abs(leaf_n.mean(axis=0)) < 0.05)
    # small leaves, thin stems
    assert np.ptp(leaves, axis=1).max() < 0.1
    stems = _object_triangles(scene, "Stems")
    assert 0 < len(stems) < 2000


def test_dense_sphere_is_one_closed_smooth_million_triangle_solid():
    scene = load_sample("dense_sphere", (64, 64))
    sphere = _object_triangles(scene, "Sphere")
    assert 1_000_000 <= len(sphere) <= 1_100_000
    # one closed, consistently wound surface: every directed edge once, its reverse once
    v = sphere.reshape(-1, 3)
    _, ids = np.unique(v, axis=0, return_inverse=True)
    ids = ids.reshape(-1, 3)
    edges = np.stack([ids, np.roll(ids, -1, axis=1)], -1).reshape(-1, 2)
    code = edges[:, 0] * (ids.max() + 1) + edges[:, 1]
    back = edges[:, 1] * (ids.max() + 1) + edges[:, 0]
    assert len(np.unique(code)) == len(code) and np.isin(back, code).all()
    # smooth: a sphere of radius about 1 resting on the ground
    r = np.linalg.norm(v - [0.0, 0.0, 1.0], axis=1)
    assert r.max() < 1.0 + 1e-6 and r.min() > 0.98
    assert 0.0 < v[:, 2].min() < 0.02
    light = scene.lights[0]
    assert (light.kind, light.shape) == ("area", "SQUARE") and light.size == pytest.approx(1.0)


def test_dense_foliage_is_foliage_with_curved_leaves():
    dense = load_sample("dense_foliage", (64, 64))
    base = load_sample("foliage", (64, 64))
    leaves = _object_triangles(dense, "Leaves")
    assert len(leaves) == 192 * 3000 and len(dense.triangles) > 500_000
    assert np.array_equal(_object_triangles(dense, "Stems"), _object_triangles(base, "Stems"))
    # the same leaves, each within its flat leaf's box, curved: normals spread within a leaf
    flat = _object_triangles(base, "Leaves").reshape(3000, 12, 3)
    curved = leaves.reshape(3000, 192 * 3, 3)
    assert np.all(np.ptp(curved, axis=1) < np.ptp(flat, axis=1) + 0.03)
    n = _unit_normals(leaves).reshape(3000, 192, 3)
    mean = n.mean(1)
    mean /= np.linalg.norm(mean, axis=1, keepdims=True)
    spread = np.degrees(np.arccos(np.clip(np.einsum("lki,li->lk", n, mean), -1.0, 1.0))).max(1)
    assert np.median(spread) > 10.0 and np.all(spread < 90.0)
    assert [(lt.name, lt.size, lt.size_y) for lt in dense.lights] == [(lt.name, lt.size, lt.size_y)
                                                                      for lt in base.lights]


def test_sun_pillars_sun_is_four_degrees_and_low():
    scene = load_sample("sun_pillars")
    sun = scene.lights[0]
    assert math.isclose(sun.angle, math.radians(4.0), rel_tol=1e-6)
    # light travels along the sun's local -Z: elevation below 30 degrees (long shadows)
    travel = -np.asarray(sun.world_from_light)[:3, 2]
    elevation = math.degrees(math.asin(-travel[2] / np.linalg.norm(travel)))
    assert 10.0 < elevation < 30.0
    colonnade = _object_triangles(scene, "Colonnade")
    assert np.ptp(colonnade[:, :, 2]) > 2.5          # pillars with arches on top


def _matte_links(mat):
    """(image texture node, Principled BSDF) pairs wired Image Alpha -> BSDF Alpha."""
    return [(link.from_node, link.to_node) for link in mat.node_tree.links
            if link.from_node.bl_idname == "ShaderNodeTexImage" and link.from_socket.name == "Alpha"
            and link.to_node.bl_idname == "ShaderNodeBsdfPrincipled" and link.to_socket.name == "Alpha"]


def _alpha(image):
    return image_rgba(image)[..., 3]


@pytest.mark.parametrize("material, interpolation, binary, cards", [
    ("LeafMatte", "Closest", True, 36), ("ChainLink", "Closest", True, 1),
    ("LeafSoft", "Linear", False, 4)])
def test_leaf_cards_materials_wire_a_packed_matte(material, interpolation, binary, cards):
    scene = open_sample("leaf_cards")
    assert scene.cycles.transparent_max_bounces >= 64
    mat = bpy.data.materials[material]
    (tex, _bsdf), = _matte_links(mat)
    assert tex.interpolation == interpolation
    image = tex.image
    assert image.packed_file is not None and image.packed_file.size > 0
    assert image.size[0] > 0 and image.size[1] > 0
    alpha = _alpha(image)
    assert (alpha == 0).any() and (alpha == 1).any()
    between = (alpha > 0) & (alpha < 1)
    assert not between.any() if binary else between.mean() > 0.02
    users = [ob for ob in scene.objects if ob.type == "MESH" and mat.name in ob.data.materials]
    assert len(users) == cards
    for ob in users:                                  # quads with an active UV map
        assert len(ob.data.polygons) == 1 and ob.data.uv_layers.active is not None


@pytest.mark.parametrize("name", STRESS_SCENES)
def test_embree_shows_a_real_shadow_through_the_cli(name, tmp_path):
    rc = main(["render", sample_path(name), "--out", str(tmp_path), "--methods", "embree",
               "--resolution", "64x64", "--samples", "64", "--quiet", "--no-previews"])
    assert rc == 0
    layers = exr.read_multilayer(str(tmp_path / f"{name}.0001.exr"))
    (passes,) = layers.values()
    v = passes["embree"]
    assert v.shape == (64, 64) and np.isfinite(v).all()
    assert v.min() >= 0.0 and v.max() <= 1.0
    # a real shadow, not a few stray pixels: its mass (which the default pixel filter
    # keeps: the weights are normalised) and its extent (thin pillars' shadows are a
    # pixel or two wide, so filtered they do not reach V < 0.5 everywhere)
    assert (1.0 - v).mean() > 0.005 and (v < 0.9).mean() > 0.01
    assert (v > 0.99).mean() > 0.1                   # and lit ground around it
