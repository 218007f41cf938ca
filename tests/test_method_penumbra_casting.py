"""Hierarchical penumbra casting (Laine & Aila 2005) against its own rays cast
by Embree, the ``embree`` reference, closed forms and invariants."""
import math

import numpy as np
import pytest

from penumbra.core import sampling
from penumbra.core.buffers import FrameBuffers
from penumbra.core.methods.base import PhaseTimer
from penumbra.core.methods.embree_ref import EmbreeReference
from penumbra.core.methods.penumbra_casting import (PenumbraCasting, _bucket_sort_by_area, _chunk_receivers, cast,
                                                     prepare, scene_blockers)
from penumbra.core.methods.penumbra_casting.geometry import (MAXB, MAXP, blocked_by_edges, hard_volume, in_hard_volume,
                                                 penumbra_volume, point_in_volume, receiver_edge_functions,
                                                 triangle_plane)
from penumbra.core.methods.penumbra_casting.hierarchy import _stable_order, build_hierarchy
from penumbra.core.methods.penumbra_casting.light import MODE_SPHERE, group_layout
from penumbra.core.metrics import errors
from penumbra.core.scene import Camera, Light, ObjectInfo, Scene
from penumbra.core.views import look_rotation
from synthetic import area_light, half_plane_scene, light_matrix, pixel_world_y, quad, sphere_light, \
    sun_light, top_ortho_camera

PC = PenumbraCasting()
SWITCHES = ["umbra_bits", "active_plane_sets", "lazy_volumes", "masks_on_demand", "coarse_sort"]


# --------------------------------------------------------------------------
# helpers
def clutter_scene(light, res=48, n=60, seed=1):
    """Ground plane under random triangles, perspective camera (sees some sky)."""
    rng = np.random.default_rng(seed)
    tris = quad(-6, 6, -6, 6, 0.0)
    c = rng.uniform([-2.5, -2.5, 0.3], [2.5, 2.5, 2.5], (n, 3))
    for k in range(n):
        tris.append((c[k] + rng.normal(0, 0.35, (3, 3))).tolist())
    m = np.eye(4)
    eye = np.array([5.0, -6.0, 6.0])
    m[:3, :3] = look_rotation(-eye)
    m[:3, 3] = eye
    return Scene(np.array(tris, np.float32), np.zeros(len(tris), np.int32), [ObjectInfo("all", 0)],
                 Camera(m, lens=35.0), [light], (res, res))


def run_pc(scene, light=None, **over):
    fb = FrameBuffers(scene, *scene.resolution)
    light = light or scene.lights[0]
    p = PC.make_params(over)
    setup = prepare(fb, light, p)
    V, stats = cast(setup, scene_blockers(scene), p, PhaseTimer())
    return fb, setup, V, stats


def own_rays(fb, setup):
    """V from Embree shadow rays from the same receiver points to the same
    light samples the casting used (segments end 1e-6 short, as the reference's)."""
    P = setup.sample_points(np.arange(len(setup.idx)))
    n, S, _ = P.shape
    o = np.repeat(setup.pts, S, axis=0)
    p = P.reshape(-1, 4)
    isdir = p[:, 3] == 0
    d = np.where(isdir[:, None], p[:, :3], p[:, :3] - o)
    dist = np.linalg.norm(d, axis=1)
    d = d / np.where(dist > 0, dist, 1.0)[:, None]
    tfar = np.where(isdir, 1e30, dist * (1 - 1e-6))
    occ = fb.shadow_scene.occluded(o.astype(np.float32), d.astype(np.float32), tfar.astype(np.float32))
    return 1.0 - occ.reshape(n, S).mean(1)


def assert_exact(V, ref, S, frac=0.002):
    """Every blocked relation is a geometric fact: only rays grazing an edge
    within float32 rounding may differ."""
    diff = np.abs(V - ref)
    assert (diff > 1e-12).mean() <= frac, ((diff > 1e-12).sum(), len(V))
    assert diff.max() <= 2.0 / S + 1e-12


def check_range(V):
    assert np.isfinite(V).all() and V.min() >= 0.0 and V.max() <= 1.0


LIGHTS = {
    "square": lambda: area_light(1.5, z=5.0),
    "rectangle": lambda: area_light(2.0, size_y=0.6, shape="RECTANGLE", z=5.0),
    "disk": lambda: area_light(1.5, shape="DISK", z=5.0),
    "ellipse": lambda: area_light(2.0, size_y=0.8, shape="ELLIPSE", z=5.0),
    "sphere": lambda: sphere_light(0.6, z=5.0),
    "spot": lambda: sphere_light(0.4, z=5.0, spot_size=1.2),
    "sun": lambda: sun_light(0.3),
}


# --------------------------------------------------------------------------
# exactness against the same rays
@pytest.mark.parametrize("kind", list(LIGHTS))
def test_same_samples_as_embree_rays_is_exact(kind):
    """8 sample sets (the default): V equals Embree's answer for the very same
    receiver points and light sample positions."""
    light = LIGHTS[kind]()
    scene = clutter_scene(light)
    fb, setup, V, stats = run_pc(scene, samples=64)
    ref = own_rays(fb, setup)
    assert ((ref > 0) & (ref < 1)).sum() > 200          # a real penumbra is tested
    assert (ref == 0).any()
    assert_exact(V, ref, 64)
    assert stats["sample_sets"] == 8 and len(np.unique(setup.set_id)) == 8


@pytest.mark.parametrize("kind", ["square", "ellipse", "sphere", "sun"])
def test_shared_samples_with_reference_equals_embree_pass(kind):
    """With the reference's own per-pixel samples the pass is the ``embree``
    pass itself (same seed, same strata, same maps, same ray origins)."""
    light = LIGHTS[kind]()
    scene = clutter_scene(light)
    fb = FrameBuffers(scene, *scene.resolution)
    for seed in (0, 5):
        r = PC.run(fb, light, PC.make_params({"samples": 64, "seed": seed,
                                               "shared_samples_with_reference": True}))
        e = EmbreeReference()
        ref = e.run(fb, light, e.make_params({"samples": 64, "seed": seed})).passes["embree"]
        v = r.passes["penumbra_casting"]
        hit = fb.gbuffer.hit
        assert_exact(v[hit], ref[hit], 64)
        assert (v[~hit] == 1.0).all() and (~hit).any()     # background = 1


# --------------------------------------------------------------------------
# closed forms
def test_square_light_half_plane_closed_form():
    """Square light a = 1 at height 4, edge at height 2: V = clamp(0.5 + y, 0, 1)."""
    scene = half_plane_scene(area_light(1.0), res=64)
    r = PC.run(FrameBuffers(scene, 64, 64), scene.lights[0], PC.make_params({"samples": 256}))
    v = r.passes["penumbra_casting"]
    ys = pixel_world_y(scene, np.arange(64))
    expect = np.clip(0.5 + ys, 0, 1)
    assert np.abs(v.mean(axis=1) - expect).max() < 0.012
    assert np.abs(v - expect[:, None]).max() < 0.05
    assert v[ys > 0.55].min() == 1.0 and v[ys < -0.55].max() == 0.0


def test_disk_light_closed_form():
    R = 0.5
    scene = half_plane_scene(area_light(2 * R, shape="DISK"), res=64)
    r = PC.run(FrameBuffers(scene, 64, 64), scene.lights[0], PC.make_params({"samples": 256}))
    ys = pixel_world_y(scene, np.arange(64))
    d = np.clip(ys * (1 - 4.0 / 2.0) / R, -1, 1)
    expect = (np.arccos(d) - d * np.sqrt(1 - d * d)) / np.pi
    assert np.abs(r.passes["penumbra_casting"].mean(axis=1) - expect).max() < 0.012


@pytest.mark.parametrize("make", [lambda: area_light(0.0), lambda: sphere_light(0.0), lambda: sun_light(0.0)])
def test_zero_size_light_is_the_hard_shadow(make):
    """One sample at the light's centre (or its axis): V in {0, 1}, equal to
    the reference, and the half-plane's hard edge at y = 0."""
    scene = half_plane_scene(make(), res=48)
    fb = FrameBuffers(scene, 48, 48)
    r = PC.run(fb, scene.lights[0], PC.make_params({"samples": 256}))
    v = r.passes["penumbra_casting"]
    assert r.stats["samples"] == 1 and r.stats["sample_sets"] == 1
    assert set(np.unique(v)) == {0.0, 1.0}
    e = EmbreeReference()
    np.testing.assert_array_equal(v, e.run(fb, scene.lights[0], e.make_params({"samples": 256})).passes["embree"])
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


@pytest.mark.parametrize("name", ["grids", "sphere_plane", "torus_plane"])
def test_switches_are_bit_identical_on_samples(name):
    from scenes import load_sample
    scene = load_sample(name, (64, 64))
    base = run_pc(scene, samples=64)[2]
    variants = [{k: False} for k in SWITCHES] + [{k: False for k in SWITCHES}, {"chunks": 1}, {"chunks": 5},
                                                  {"RebuildFraction": 0.01}, {"materialize_hard_volumes": True}]
    for over in variants:
        V = run_pc(scene, samples=64, **over)[2]
        np.testing.assert_array_equal(V, base, err_msg=str(over))


# --------------------------------------------------------------------------
# the sample scenes against the reference
@pytest.mark.parametrize("name", ["grids", "sphere_plane", "torus_plane"])
def test_matches_embree_on_samples(name):
    """Independent samples (8 sets) vs the reference at 256 samples: only
    sampling noise (per pixel std <= 0.5/16 for each)."""
    from scenes import load_sample
    scene = load_sample(name, (96, 96))
    fb = FrameBuffers(scene, 96, 96)
    light = scene.lights[0]
    r = PC.run(fb, light, PC.make_params({"samples": 256}))
    e = EmbreeReference()
    ref = e.run(fb, light, e.make_params({"samples": 256})).passes["embree"]
    err = errors(r.passes["penumbra_casting"], ref, fb.gbuffer.hit)
    assert err["penumbra_pixels"] > 150
    assert err["rmse"] < 0.025 and err["rmse_penumbra"] < 0.03, err
    assert abs(err["mean_signed"]) < 0.004, err
    assert err["max_abs"] < 0.2, err
    # and exact against Embree rays to its own samples
    p = PC.make_params({"samples": 64})
    setup = prepare(fb, light, p)
    V, _ = cast(setup, scene_blockers(scene), p, PhaseTimer())
    assert_exact(V, own_rays(fb, setup), 64)


# --------------------------------------------------------------------------
# hard cases (DESIGN.md "Numerical robustness")
def _transformed(scene, s=1.0, offset=(0, 0, 0)):
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


def _box(lo, hi):
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    v = np.array([[x0, y0, z0], [x1, y0, z0], [x1, y1, z0], [x0, y1, z0],
                  [x0, y0, z1], [x1, y0, z1], [x1, y1, z1], [x0, y1, z1]], float)
    f = [(0, 2, 1), (0, 3, 2), (4, 5, 6), (4, 6, 7), (0, 1, 5), (0, 5, 4), (1, 2, 6), (1, 6, 5),
         (2, 3, 7), (2, 7, 6), (3, 0, 4), (3, 4, 7)]
    return [[v[a].tolist(), v[b].tolist(), v[c].tolist()] for a, b, c in f]


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
    "contact_box": lambda: _with(half_plane_scene(area_light(1.0), res=40), _box((-0.5, 0.5, 0.0), (0.5, 1.5, 1.0))),
    "coplanar_occluder": lambda: _with(half_plane_scene(area_light(1.0), res=40), quad(-1, 1, 0.5, 1.5, 0.0)),
    "occluder_behind_light": lambda: _with(half_plane_scene(area_light(1.0), res=40), quad(-5, 5, -5, 5, 6.0)),
    "light_inside_box": lambda: _with(half_plane_scene(sphere_light(0.3), res=40), _box((-1, -1, 3), (1, 1, 5))),
    "camera_inside_box": lambda: _with(half_plane_scene(area_light(1.0), res=40), _box((-3, -3, 0.2), (3, 3, 1.5))),
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


@pytest.mark.parametrize("case", list(HARD))
def test_hard_cases_finite_and_exact(case):
    scene = HARD[case]()
    fb = FrameBuffers(scene, *scene.resolution)
    r = PC.run(fb, scene.lights[0], PC.make_params({"samples": 16}))
    v = r.passes["penumbra_casting"]
    check_range(v)
    p = PC.make_params({"samples": 16})
    setup = prepare(fb, scene.lights[0], p)
    V, _ = cast(setup, scene_blockers(scene), p, PhaseTimer())
    np.testing.assert_array_equal(V.astype(np.float32), v.reshape(-1)[setup.idx])
    assert_exact(V, own_rays(fb, setup), 16, frac=0.003)
    if case == "no_occluder":
        assert (v == 1).all()
    if case == "light_inside_box":
        assert (v == 0).all()
    if case in ("tiny_scale", "huge_scale", "far_from_origin"):
        ys = pixel_world_y(half_plane_scene(area_light(1.0), res=40), np.arange(40))
        assert np.abs(v.mean(axis=1) - np.clip(0.5 + ys, 0, 1)).max() < 0.1


# --------------------------------------------------------------------------
# building blocks
def _random_blocker(rng, nb):
    """A random triangle (nb = 3), or a random convex planar polygon (nb = 4,
    6: a quad, a leaf's hexagon): corners on an ellipse at sorted angles, in
    a randomly turned plane; returned as float64[MAXB, 3] with the last
    corner repeated."""
    if nb == 3:
        tri = rng.normal(0, 1, (3, 3))
    else:
        ang = np.sort(rng.uniform(0, 2 * np.pi, nb))
        while np.diff(np.concatenate([ang, [ang[0] + 2 * np.pi]])).max() > 0.9 * np.pi:
            ang = np.sort(rng.uniform(0, 2 * np.pi, nb))
        ab = rng.uniform(0.3, 1.5, 2)
        flat = np.stack([ab[0] * np.cos(ang), ab[1] * np.sin(ang), np.zeros(nb)], axis=1)
        rot, _ = np.linalg.qr(rng.normal(0, 1, (3, 3)))
        tri = flat @ rot.T + rng.normal(0, 0.5, 3)
    out = np.empty((MAXB, 3))
    out[:nb] = tri
    out[nb:] = tri[nb - 1]
    return out


def _segment_crosses(poly, nb, r, l, margin=1e-9):
    """Segment r -> l (l excluded, r excluded) meets the convex polygon: as a
    fan of triangles (Moller-Trumbore); None when it passes within ``margin``
    of an edge of the fan or of an end point (undecidable in floating point)."""
    hit = False
    for j in range(1, nb - 1):
        a, b, c = poly[0], poly[j], poly[j + 1]
        e1, e2 = b - a, c - a
        d = l - r
        p = np.cross(d, e2)
        det = e1 @ p
        s = r - a
        u = s @ p / det
        q = np.cross(s, e1)
        v = d @ q / det
        t = e2 @ q / det
        if min(abs(u), abs(v), abs(1 - u - v), abs(t), abs(1 - t)) <= margin:
            return None
        hit |= (u >= 0) and (v >= 0) and (u + v <= 1) and (0 < t < 1)
    return hit


@pytest.mark.parametrize("nb", [3, 4, 6])
def test_penumbra_volume_contains_every_hard_volume(nb):
    """Random blockers (triangles; convex quads, section 5), light polygons
    (finite and directional) and points: whenever a sample in the polygon
    blocks r (exact hard volume test), r is inside the penumbra volume (no
    slack), and both hard volume forms agree."""
    rng = np.random.default_rng(3 + nb)
    out = np.zeros((4, MAXP))
    hv = np.zeros((MAXB + 1, 4))
    ef = np.zeros((MAXB, 4))
    tn = np.zeros(4)
    DE = np.array([[0, 1], [1, 2], [2, 3], [3, 0]] + [[0, 0]] * 12, np.int64)
    hits = 0
    for trial in range(90):
        tri = _random_blocker(rng, nb) + [0, 0, 2.0]
        directional = trial % 3 == 0
        a, b = rng.uniform(0.1, 1.5, 2)
        corners = np.array([[-a, -b], [a, -b], [a, b], [-a, b]])
        DV = np.zeros((16, 4))
        if directional:
            DV[:4, :2] = corners * 0.3
            DV[:4, 2] = 1.0
        else:
            DV[:4, :2] = corners + rng.normal(0, 0.5, 2)
            DV[:4, 2] = 5.0
            DV[:4, 3] = 1.0
        k = penumbra_volume(tri, nb, DV, 4, DE, 4, 1e-12, out)
        assert k >= 0
        triangle_plane(tri, nb, tn)
        uv = rng.uniform(0, 1, (24, 2))
        for r in rng.normal(0, 2.5, (80, 3)):
            rho = receiver_edge_functions(tri, nb, tn, r[0], r[1], r[2], ef)
            inside = point_in_volume(out[None], 0, k, -1, r[0], r[1], r[2], 0.0)
            for u, v in uv:
                p = (DV[0] * (1 - u) * (1 - v) + DV[1] * u * (1 - v) + DV[2] * u * v + DV[3] * (1 - u) * v)
                blk = hard_volume(tri, nb, p[0], p[1], p[2], p[3], hv) and in_hard_volume(hv, nb, r[0], r[1], r[2])
                assert blk == blocked_by_edges(ef, rho, tn, p[0], p[1], p[2], p[3])
                if blk:
                    hits += 1
                    assert inside
    assert hits > 300


@pytest.mark.parametrize("nb", [3, 4, 6])
def test_hard_volume_is_the_segment_test(nb):
    """V_l holds r iff the segment from r to l crosses T (Moller-Trumbore on
    T, or on the two triangles of a convex quad)."""
    rng = np.random.default_rng(4 + nb)
    hv = np.zeros((MAXB + 1, 4))
    ef = np.zeros((MAXB, 4))
    tn = np.zeros(4)
    n_in = n_out = 0
    for _ in range(3000):
        tri = _random_blocker(rng, nb)
        r, l = rng.normal(0, 2, 3), rng.normal(0, 2, 3)
        ok = hard_volume(tri, nb, l[0], l[1], l[2], 1.0, hv) and in_hard_volume(hv, nb, *r)
        triangle_plane(tri, nb, tn)
        rho = receiver_edge_functions(tri, nb, tn, r[0], r[1], r[2], ef)
        assert ok == blocked_by_edges(ef, rho, tn, l[0], l[1], l[2], 1.0)
        mt = _segment_crosses(tri, nb, r, l)
        if mt is not None:
            assert ok == mt
            n_in += ok
            n_out += not ok
    assert n_in > 100 and n_out > 100


def test_hierarchy_midpoint_sah_and_leaves():
    rng = np.random.default_rng(5)
    pts = np.concatenate([rng.uniform(0, 1, (3000, 3)) * [4, 2, 0.01], rng.uniform(0, 1, (500, 3)) + [3, 0, 0]])
    perm, bb, left, right, start, count, depth = build_hierarchy(pts, np.arange(len(pts)), 16, 1024)
    assert sorted(perm) == list(range(len(pts)))
    assert depth < 40
    for n in range(len(left)):
        P = pts[perm[start[n]:start[n] + count[n]]]
        assert (P >= bb[n, :3]).all() and (P <= bb[n, 3:]).all()
        if left[n] < 0:
            assert 1 <= count[n] <= 16
            continue
        l, r = left[n], right[n]
        assert count[l] + count[r] == count[n] and count[l] > 0 and count[r] > 0
        if count[n] > 1024:      # midpoint split of the longest axis
            ax = int(np.argmax(bb[n, 3:] - bb[n, :3]))
            mid = 0.5 * (bb[n, ax] + bb[n, 3 + ax])
            assert bb[l, 3 + ax] < mid <= bb[r, ax]


@pytest.mark.parametrize("c", [0, 1, 2, 7, 64, 1000])
def test_sah_key_order_is_numpys_stable_argsort(c):
    """The hierarchy's own merge sort orders keys as np.argsort(kind="mergesort"):
    ascending, ties in index order (the SAH split depends on it)."""
    rng = np.random.default_rng(c)
    for keys in (rng.integers(0, 4, 1024).astype(float), rng.normal(0, 1, 1024), np.zeros(1024)):
        order, tmp = np.empty(1024, np.int64), np.empty(1024, np.int64)
        _stable_order(keys, c, order, tmp, np.empty(1024), np.empty(1024))
        assert np.array_equal(order[:c], np.argsort(keys[:c], kind="mergesort"))


def test_receiver_chunks_are_median_splits():
    """The chunks partition the receivers with rows in increasing order; the
    first split halves them (sizes within one) across the longest axis (x)."""
    rng = np.random.default_rng(8)
    pts = rng.normal(0, 1, (10_000, 3)) * [4.0, 1.0, 0.5]
    for n in (1, 2, 5, 8):
        parts = _chunk_receivers(pts, n)
        assert len(parts) == n
        rows = np.concatenate(parts)
        assert np.array_equal(np.sort(rows), np.arange(len(pts)))
        assert all((np.diff(p) > 0).all() for p in parts)
    a, b = _chunk_receivers(pts, 2)
    assert abs(len(a) - len(b)) <= 1
    assert pts[a, 0].max() <= pts[b, 0].min() or pts[b, 0].max() <= pts[a, 0].min()


def test_coarse_sort_is_largest_first_by_bucket():
    rng = np.random.default_rng(6)
    s = 10.0 ** rng.uniform(-4, 1, 500)
    tris = rng.normal(0, 1, (500, 3, 3)) * s[:, None, None]
    order = _bucket_sort_by_area(tris, np.full(len(tris), 3), 8)
    area = 0.5 * np.linalg.norm(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]), axis=1)
    la = np.log(area[order])
    b = np.minimum(7, ((la.max() - la) / (la.max() - la.min()) * 8).astype(int))
    assert sorted(order) == list(range(500))
    assert np.all(np.diff(b) >= 0)
    assert b[0] == 0 and b[-1] == 7            # coarse: buckets in order, stable inside one
    assert area[order[:np.sum(b == 0)]].min() > area[order[np.sum(b == 0):]].max()


def test_coarse_sort_takes_a_polygons_area_from_all_its_corners():
    """Blocker polygons (corners past ``nverts`` repeated, as the merge
    stores them) are bucketed by their whole area: regular triangles,
    squares and hexagons of circumradius r in any orientation, whose area
    is n sin(2 pi / n) r^2 / 2 (closed form)."""
    rng = np.random.default_rng(9)
    polys, nv, area = [], [], []
    for k in range(300):
        kind = k % 3
        n = (3, 4, 6)[kind]
        size = 10.0 ** rng.uniform(-3, 1)
        ang = np.arange(n) * 2 * np.pi / n
        pts = np.stack([np.cos(ang), np.sin(ang), np.zeros(n)], 1) * size
        R, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        pts = pts @ R.T + rng.normal(0, 5, 3)
        p = np.repeat(pts[-1:], MAXB, 0)
        p[:n] = pts
        polys.append(p)
        nv.append(n)
        area.append(0.5 * n * np.sin(2 * np.pi / n) * size ** 2)    # regular n-gon of circumradius size
    polys, nv, area = np.array(polys), np.array(nv, np.int64), np.array(area)
    order = _bucket_sort_by_area(polys, nv, 8)
    la = np.log(area)
    b = np.minimum(7, ((la.max() - la) / (la.max() - la.min()) * 8).astype(int))
    assert sorted(order) == list(range(len(area)))
    assert np.all(np.diff(b[order]) >= 0)
    assert np.all(np.diff(order[b[order] == 3]) > 0)       # stable inside a bucket


def test_groups_of_32_on_a_jittered_grid():
    nx, ny, G, bit2s, g_start, blocks = group_layout(256, 32)
    assert (nx, ny, G) == (16, 16, 8)
    assert np.all(np.diff(g_start) == 32) and sorted(bit2s) == list(range(256))
    nx, ny, G, bit2s, g_start, blocks = group_layout(1024, 32)
    assert G == 32 and g_start[-1] == 1024


def _local2(points, centre, ax, ay, az, directional):
    d = points - (0 if directional else centre)
    if directional:
        return np.stack([d @ ax / (d @ az), d @ ay / (d @ az)], -1)
    return np.stack([d @ ax, d @ ay], -1)


def _inside_convex(poly, q, tol):
    """q (m,2) inside the convex polygon (k,2), either orientation."""
    k = len(poly)
    if k < 3:
        return np.ones(len(q), bool)
    s = np.zeros((len(q), k))
    for i in range(k):
        a, b = poly[i], poly[(i + 1) % k]
        s[:, i] = (b[0] - a[0]) * (q[:, 1] - a[1]) - (b[1] - a[1]) * (q[:, 0] - a[0])
    area2 = sum(poly[i, 0] * poly[(i + 1) % k, 1] - poly[(i + 1) % k, 0] * poly[i, 1] for i in range(k))
    return np.all(s * np.sign(area2) >= -tol, axis=1)


@pytest.mark.parametrize("kind", ["square", "rectangle", "disk", "ellipse", "sun", "sphere"])
@pytest.mark.parametrize("shared", [False, True])
def test_group_polygons_bound_every_sample_of_every_set(kind, shared):
    """Section 3.4: Delta_Gk bounds the group's samples in all sample sets
    (here every receiver's samples), and Delta_L bounds them all."""
    light = LIGHTS[kind]()
    scene = clutter_scene(light, res=24)
    fb = FrameBuffers(scene, 24, 24)
    setup = prepare(fb, light, PC.make_params({"samples": 256, "shared_samples_with_reference": shared}))
    L = setup.light
    P = setup.sample_points(np.arange(len(setup.idx)))
    m = light.world_from_light
    ax, ay, az = m[:3, 0], m[:3, 1], m[:3, 2]
    c = light.position
    if light.kind == "sphere":
        if L.mode == MODE_SPHERE:
            e1, e2 = (np.array(v) for v in sampling.orthonormal_basis(*L.w0))
            frame = np.stack([e1, e2, L.w0])
        else:
            frame = np.eye(3)
        for g in range(L.G):
            loc = (P[:, L.g_start[g]:L.g_start[g + 1], :3] - c) @ frame.T
            box = (L.DVg[g, :L.nvg[g], :3] - c) @ frame.T
            assert (loc >= box.min(0) - 1e-9).all() and (loc <= box.max(0) + 1e-9).all()
        return
    directional = light.kind == "sun"
    full = _local2(L.DVL[:L.nvl, :3], c, ax, ay, az, directional)
    allq = _local2(P[..., :3].reshape(-1, 3), c, ax, ay, az, directional)
    assert _inside_convex(full, allq, 1e-9).all()
    for g in range(L.G):
        poly = _local2(L.DVg[g, :L.nvg[g], :3], c, ax, ay, az, directional)
        q = _local2(P[:, L.g_start[g]:L.g_start[g + 1], :3].reshape(-1, 3), c, ax, ay, az, directional)
        assert _inside_convex(poly, q, 1e-9).all(), g


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
