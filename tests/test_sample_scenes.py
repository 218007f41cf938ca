"""The sample scenes of issues 17 and 18 (foliage, sun_pillars, leaf_cards;
dense_sphere and dense_foliage, issue 17's production triangle counts):
what each is built to stress, checked on the .blend as captured, and an
embree render of each through the CLI that shows a real shadow."""
import math
import os

import bpy
import numpy as np
import pytest

from penumbra.cli import main
from penumbra.core import exr
from scenes import SAMPLE_NAMES, SAMPLES, load_sample, open_sample, sample_path

NEW_SCENES = ("foliage", "sun_pillars", "leaf_cards")
#: issue 17's production triangle counts, made by modifiers (the files stay small)
DENSE_SCENES = ("dense_sphere", "dense_foliage")
#: light kind and triangle range each new scene is built for
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
    for name in NEW_SCENES + DENSE_SCENES:
        assert os.path.getsize(sample_path(name)) < 2_000_000


@pytest.mark.parametrize("name", NEW_SCENES)
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
    w, h = image.size
    px = np.empty(w * h * 4, np.float32)
    image.pixels.foreach_get(px)
    return px.reshape(h, w, 4)[..., 3]


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


@pytest.mark.parametrize("name", NEW_SCENES)
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
