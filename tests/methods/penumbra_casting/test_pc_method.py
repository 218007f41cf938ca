"""Hierarchical penumbra casting (Laine & Aila 2005) against Embree's rays
to the very samples it used, the ``embree`` reference, closed forms, the
switches that must not change a bit, hard cases and the culls; each pass
both ways (``visibility``: the average and the irradiance ratio) where the
reference gives both."""
import math

import numpy as np
import pytest

from helpers import buffers_of, embree_pass, in_range, run_method
from pc_helpers import LIGHTS, PC, assert_exact, clutter_scene, own_rays, own_weights, relation_share, run_pc
from penumbra.core.methods.penumbra_casting import prepare
from penumbra.core.metrics import errors
from penumbra.core.scene import Light, ObjectInfo, Scene
from synthetic import area_light, box, half_plane_scene, light_matrix, pixel_world_y, quad, sphere_light, \
    sun_light, top_ortho_camera

SWITCHES = ["umbra_bits", "active_plane_sets", "lazy_volumes", "masks_on_demand", "coarse_sort"]
VISIBILITIES = ["average", "irradiance"]
REFERENCE = {"average": "embree", "irradiance": "embree_irr"}    # the embree pass of each visibility


def run_pc_pass(fb, light, **params):
    """The method's MethodResult on buffers ``fb``."""
    return run_method("penumbra_casting", fb, light, **params)


# --------------------------------------------------------------------------
# exactness against the same rays
@pytest.mark.parametrize("visibility", VISIBILITIES)
@pytest.mark.parametrize("kind", list(LIGHTS))
def test_same_samples_as_embree_rays_is_exact(kind, visibility):
    """8 sample sets (the default): V equals Embree's answer for the very same
    receiver points and light sample positions (averaged, or weighted as the
    reference weighs them)."""
    light = LIGHTS[kind]()
    scene = clutter_scene(light)
    fb, setup, V, stats = run_pc(scene, samples=64, visibility=visibility)
    ref = own_rays(fb, setup)
    assert ((ref > 0) & (ref < 1)).sum() > 200          # a real penumbra is tested
    assert (ref == 0).any()
    assert_exact(V, ref, 64, share=relation_share(setup))
    assert stats["sample_sets"] == 8 and len(np.unique(setup.set_id)) == 8


@pytest.mark.parametrize("visibility", VISIBILITIES)
@pytest.mark.parametrize("kind", ["square", "ellipse", "sphere", "sun"])
def test_shared_samples_with_reference_equals_embree_pass(kind, visibility):
    """With the reference's own per-pixel samples the pass is the ``embree``
    pass itself (same seed, same strata, same maps, same ray origins): the
    average ``embree``, the irradiance ratio ``embree_irr`` (same weights;
    compared where some weight is positive: elsewhere the ratio is undefined,
    the reference writes 0 and the frame 1)."""
    light = LIGHTS[kind]()
    scene = clutter_scene(light)
    fb = buffers_of(scene)
    for seed in (0, 5):
        params = dict(samples=64, seed=seed, shared_samples_with_reference=True, visibility=visibility)
        r = run_pc_pass(fb, light, **params)
        ref = embree_pass(fb, light, samples=64, seed=seed, pass_id=REFERENCE[visibility])
        setup = prepare(fb, light, PC.make_params(params))
        v = r.passes["penumbra_casting"].reshape(-1)[setup.idx]
        ref_v = ref.reshape(-1)[setup.idx]
        share = relation_share(setup)
        lit = own_weights(setup).sum(1) > 0 if visibility == "irradiance" else np.ones(len(v), bool)
        assert lit.mean() > 0.9
        assert_exact(v[lit], ref_v[lit], 64, share=share[lit])
        hit = fb.gbuffer.hit
        assert (r.passes["penumbra_casting"][~hit] == 1.0).all() and (~hit).any()     # background = 1


# --------------------------------------------------------------------------
# closed forms
def test_square_light_half_plane_closed_form():
    """Square light a = 1 at height 4, edge at height 2: the average
    V = clamp(0.5 + y, 0, 1)."""
    scene = half_plane_scene(area_light(1.0), res=64)
    r = run_pc_pass(buffers_of(scene), scene.lights[0], samples=256, visibility="average")
    v = r.passes["penumbra_casting"]
    ys = pixel_world_y(scene, np.arange(64))
    expect = np.clip(0.5 + ys, 0, 1)
    assert np.abs(v.mean(axis=1) - expect).max() < 0.012
    assert np.abs(v - expect[:, None]).max() < 0.05
    assert v[ys > 0.55].min() == 1.0 and v[ys < -0.55].max() == 0.0


def test_disk_light_closed_form():
    """Disk light of radius R = 0.5 at height 4, edge at height 2: the
    average V is the share of the disk beyond the edge's shadow line,
    (acos d - d sqrt(1 - d^2)) / pi."""
    R = 0.5
    scene = half_plane_scene(area_light(2 * R, shape="DISK"), res=64)
    r = run_pc_pass(buffers_of(scene), scene.lights[0], samples=256, visibility="average")
    ys = pixel_world_y(scene, np.arange(64))
    d = np.clip(ys * (1 - 4.0 / 2.0) / R, -1, 1)
    expect = (np.arccos(d) - d * np.sqrt(1 - d * d)) / np.pi
    assert np.abs(r.passes["penumbra_casting"].mean(axis=1) - expect).max() < 0.012


@pytest.mark.parametrize("visibility", VISIBILITIES)
@pytest.mark.parametrize("make", [lambda: area_light(0.0), lambda: sphere_light(0.0), lambda: sun_light(0.0)])
def test_zero_size_light_is_the_hard_shadow(make, visibility):
    """One sample at the light's centre (or its axis): V in {0, 1}, equal to
    the reference, and the half-plane's hard edge at y = 0."""
    scene = half_plane_scene(make(), res=48)
    fb = buffers_of(scene)
    r = run_pc_pass(fb, scene.lights[0], samples=256, visibility=visibility)
    v = r.passes["penumbra_casting"]
    assert r.stats["samples"] == 1 and r.stats["sample_sets"] == 1
    assert set(np.unique(v)) == {0.0, 1.0}
    np.testing.assert_array_equal(v, embree_pass(fb, scene.lights[0], samples=256, pass_id=REFERENCE[visibility]))
    ys = pixel_world_y(scene, np.arange(48))
    np.testing.assert_array_equal(v, np.where(ys > 0, 1.0, 0.0)[:, None] * np.ones((1, 48)))


# --------------------------------------------------------------------------
# switches
def test_switches_change_nothing_and_a_d_do_their_job():
    """Ground, a big occluder over y < 0 and 400 small triangles whose
    shadows fall into its umbra: with A the small ones are pruned at the
    nodes and the hierarchy is rebuilt; D keeps fewer masks; C builds group
    volumes only for triangles that reach a receiver; output bit-identical."""
    rng = np.random.default_rng(0)
    tris = quad(-10, 10, -10, 10, 0.0) + quad(-10, 10, -10, 0.0, 2.0)
    c = np.stack([rng.uniform(-2, 2, 400), rng.uniform(-2.0, -1.0, 400), rng.uniform(0.5, 1.5, 400)], 1)
    tris += [(c[k] + rng.normal(0, 0.05, (3, 3))).tolist() for k in range(400)]
    scene = Scene(np.array(tris, np.float32), np.zeros(len(tris), np.int32), [ObjectInfo("a", 0)],
                  top_ortho_camera(2.0, 1.0), [area_light(1.0)], (64, 64))
    out = {}
    for name, over in [("all", {}), ("noA", {"umbra_bits": False}), ("noB", {"active_plane_sets": False}),
                       ("noC", {"lazy_volumes": False}), ("noD", {"masks_on_demand": False}),
                       ("nosort", {"coarse_sort": False}), ("none", {k: False for k in SWITCHES})]:
        _, _, V, st = run_pc(scene, samples=64, **over)
        out[name] = (V, st)
    V0, st0 = out["all"]
    for name, (V, st) in out.items():
        np.testing.assert_array_equal(V, V0, err_msg=name)
    assert 0.3 < (V0 == 0).mean() < 0.45
    assert st0["rebuilds"] >= 1 and out["noA"][1]["rebuilds"] == 0
    assert st0["nodes_visited"] * 4 < out["noA"][1]["nodes_visited"]
    assert st0["peak_masks"] * 2 <= out["noD"][1]["peak_masks"] == 64 * 64
    assert st0["triangles_with_group_volumes"] * 10 < out["noC"][1]["triangles_with_group_volumes"]


@pytest.mark.parametrize("visibility", VISIBILITIES)
@pytest.mark.parametrize("name", ["grids", "sphere_plane", "torus_plane"])
def test_switches_are_bit_identical_on_samples(name, visibility):
    """Every optimization off (A-D, the coarse sort), other chunkings, early
    rebuilds and the paper's V_li planes on the sample scenes: the same V
    (the irradiance ratio too: D's released and never allocated masks are
    0 and 1 there as well)."""
    from scenes import load_sample
    scene = load_sample(name, (64, 64))
    base = run_pc(scene, samples=64, visibility=visibility)[2]
    variants = [{k: False} for k in SWITCHES] + [{k: False for k in SWITCHES}, {"chunks": 1}, {"chunks": 5},
                                                  {"RebuildFraction": 0.01}, {"materialize_hard_volumes": True}]
    for over in variants:
        V = run_pc(scene, samples=64, visibility=visibility, **over)[2]
        np.testing.assert_array_equal(V, base, err_msg=str(over))


# --------------------------------------------------------------------------
# the sample scenes against the reference
@pytest.mark.parametrize("name", ["grids", "sphere_plane", "torus_plane"])
def test_matches_embree_on_samples(name):
    """Independent samples (8 sets) vs the reference at 256 samples, the
    default pass (the irradiance ratio) against ``embree_irr``: only
    sampling noise (per pixel std <= 0.5/16 for each), on the pixels the
    light can reach (the frame sets the others to 1)."""
    from scenes import load_sample
    scene = load_sample(name, (96, 96))
    fb = buffers_of(scene)
    light = scene.lights[0]
    r = run_pc_pass(fb, light, samples=256)
    ref = embree_pass(fb, light, samples=256, pass_id="embree_irr")
    err = errors(r.passes["penumbra_casting"], ref, fb.gbuffer.hit & fb.reach(light))
    assert err["penumbra_pixels"] > 150
    assert err["rmse"] < 0.025 and err["rmse_penumbra"] < 0.03, err
    assert abs(err["mean_signed"]) < 0.004, err
    assert err["max_abs"] < 0.2, err
    # and exact against Embree rays to its own samples
    fb, setup, V, _ = run_pc(scene, samples=64)
    assert_exact(V, own_rays(fb, setup), 64)


# --------------------------------------------------------------------------
# hard cases (DESIGN.md "Numerical robustness")
def _transformed(scene, s=1.0, offset=(0, 0, 0)):
    """``scene`` scaled by ``s`` about the origin, then moved by ``offset``
    (geometry, camera and lights)."""
    off = np.asarray(offset, np.float64)
    scene.triangles = (scene.triangles.astype(np.float64) * s + off).astype(np.float32)
    cam = scene.camera
    cam.world_from_camera = cam.world_from_camera.copy()
    cam.world_from_camera[:3, 3] = cam.world_from_camera[:3, 3] * s + off
    cam.ortho_scale *= s
    cam.clip_start *= s
    cam.clip_end *= s
    for lt in scene.lights:
        lt.world_from_light = lt.world_from_light.copy()
        lt.world_from_light[:3, 3] = lt.world_from_light[:3, 3] * s + off
        lt.size *= s
        lt.size_y *= s
        lt.radius *= s
    return scene


def _with(scene, extra):
    """Add triangles as a new visible, shadow-casting object."""
    oid = len(scene.objects)
    scene.objects = list(scene.objects) + [ObjectInfo("extra", oid)]
    tris = np.concatenate([scene.triangles, np.array(extra, np.float32).reshape(-1, 3, 3)])
    ids = np.concatenate([scene.tri_object, np.full(len(tris) - len(scene.tri_object), oid, np.int32)])
    scene.triangles, scene.tri_object = tris, ids
    return scene


def _grazing():
    lt = Light("Graze", "area", light_matrix((0, 30.0, 0.4), forward=(0, -1.0, -0.01)), shape="SQUARE", size=1.0)
    return half_plane_scene(lt, res=40)


HARD = {
    "grazing": _grazing,
    "contact_box": lambda: _with(half_plane_scene(area_light(1.0), res=40), box(-0.5, 0.5, 0.5, 1.5, 0.0, 1.0)),
    "coplanar_occluder": lambda: _with(half_plane_scene(area_light(1.0), res=40), quad(-1, 1, 0.5, 1.5, 0.0)),
    "occluder_behind_light": lambda: _with(half_plane_scene(area_light(1.0), res=40), quad(-5, 5, -5, 5, 6.0)),
    "light_inside_box": lambda: _with(half_plane_scene(sphere_light(0.3), res=40), box(-1, 1, -1, 1, 3, 5)),
    "camera_inside_box": lambda: _with(half_plane_scene(area_light(1.0), res=40), box(-3, 3, -3, 3, 0.2, 1.5)),
    "tiny_scale": lambda: _transformed(half_plane_scene(area_light(1.0), res=40), s=1e-3),
    "huge_scale": lambda: _transformed(half_plane_scene(area_light(1.0), res=40), s=1e4),
    "far_from_origin": lambda: _transformed(half_plane_scene(area_light(1.0), res=40), offset=(1e4, -1e4, 1e4)),
    "degenerate_and_subpixel": lambda: _with(half_plane_scene(area_light(1.0), res=40), [
        [[0, 0, 1], [0, 0, 1], [0, 0, 1]], [[0, 0, 1], [1, 1, 1], [2, 2, 1]],
        [[0.3, 0.3, 1.0], [0.3001, 0.3, 1.0], [0.3, 0.3001, 1.0]]] + [
        [[x, 0.7, 1.5], [x + 1e-4, 0.7, 1.5], [x, 0.7 + 1e-4, 1.5]] for x in np.linspace(-1, 1, 50)]),
    "no_occluder": lambda: _with(Scene(np.array(quad(-10, 10, -10, 10, 0.0), np.float32), np.zeros(2, np.int32),
                                       [ObjectInfo("g", 0)], top_ortho_camera(2.0, 1.0),
                                       [area_light(1.0)], (40, 40)), np.zeros((0, 3, 3))),
    "very_large_light": lambda: half_plane_scene(area_light(50.0), res=40),
    "huge_sphere_light": lambda: half_plane_scene(sphere_light(30.0), res=40),
    "wide_sun": lambda: half_plane_scene(sun_light(3.0), res=40),
    "widest_sun": lambda: half_plane_scene(sun_light(math.pi), res=40),
}


@pytest.mark.parametrize("visibility", VISIBILITIES)
@pytest.mark.parametrize("case", list(HARD))
def test_hard_cases_finite_and_exact(case, visibility):
    """DESIGN.md's hard cases: a pass in range, the method's pass equal to
    the casting's V, exact against its own rays, and the known answers."""
    scene = HARD[case]()
    fb, setup, V, _ = run_pc(scene, samples=16, visibility=visibility)
    v = run_pc_pass(fb, scene.lights[0], samples=16, visibility=visibility).passes["penumbra_casting"]
    assert in_range(v)
    np.testing.assert_array_equal(V.astype(np.float32), v.reshape(-1)[setup.idx])
    assert_exact(V, own_rays(fb, setup), 16, frac=0.003, share=relation_share(setup))
    if case == "no_occluder":
        assert (v == 1).all()
    if case == "light_inside_box":
        assert (v == 0).all()
    if case in ("tiny_scale", "huge_scale", "far_from_origin"):
        ys = pixel_world_y(half_plane_scene(area_light(1.0), res=40), np.arange(40))
        assert np.abs(v.mean(axis=1) - np.clip(0.5 + ys, 0, 1)).max() < 0.1


def test_triangles_that_cannot_shadow_are_culled():
    """Triangles beside the light / receiver hull, below the receivers and
    above the light never enter the traversal (and the result stays exact;
    the added triangles change the scene extent, hence the ray offsets)."""
    scene = clutter_scene(area_light(1.5, z=5.0))
    base = run_pc(scene, samples=16)[3]
    extra = quad(20, 21, 20, 21, 1.0) + quad(-1, 1, -1, 1, -3.0) + quad(-1, 1, -1, 1, 9.0)
    scene2 = _with(clutter_scene(area_light(1.5, z=5.0)), extra)
    fb, setup, V, st = run_pc(scene2, samples=16)
    assert st["triangles_in"] == base["triangles_in"] + 6
    assert st["triangles_box_culled"] + st["triangles_volume_culled"] == \
        base["triangles_box_culled"] + base["triangles_volume_culled"] + 6
    assert st["blockers"] == base["blockers"] < base["triangles_in"]
    assert_exact(V, own_rays(fb, setup), 16)
