"""Alpha-matte occluders, core side (``core/alpha.py``, ``core/alpha_rays.py``):
the texel lookup against hand-computed values (Cycles' Image Texture node),
and every method's transmittance on synthetic scenes with closed forms;
last, the map methods on the captured leaf_cards sample scene against
``embree``. The capture's side: test_alpha_capture.py; against Cycles:
test_alpha_cycles.py."""
import numpy as np
import pytest

from penumbra.core import alpha_rays, raycast
from penumbra.core.alpha import (AlphaMattes, CLIP, CLOSEST, EXTEND, LINEAR, REPEAT,
                                 alpha_at, matte_alpha)
from penumbra.core.buffers import FrameBuffers
from penumbra.core.methods import producer_of
from penumbra.core.metrics import errors, reach_mask
from helpers import buffers_of, embree_pass, run_method
from synthetic import (area_light, half_plane_scene, leaf_cloud_scene, matte_layers_scene, pixel_world_y,
                       sphere_light, sun_light, top_ortho_camera)

# a 2 x 2 matte, rows from v = 0: row 0 = (0, 1), row 1 = (0.25, 0.75)
TEXELS = [0.0, 1.0, 0.25, 0.75]


def one_matte(interpolation, extension, texels=TEXELS, w=2, h=2, tri_uv=None):
    tri_uv = np.array([[[0, 0], [1, 0], [0, 1]]], np.float32) if tri_uv is None else tri_uv
    return AlphaMattes(np.zeros(len(tri_uv), np.int32), tri_uv, texels, [0], [w], [h],
                       [interpolation], [extension], ["m / img"])


@pytest.mark.parametrize("interp, ext, s, t, expect", [
    (CLOSEST, REPEAT, 0.25, 0.25, 0.0), (CLOSEST, REPEAT, 0.75, 0.25, 1.0),
    (CLOSEST, REPEAT, 0.25, 0.75, 0.25), (CLOSEST, REPEAT, 1.25, 0.25, 0.0),
    (CLOSEST, REPEAT, -0.25, 0.25, 1.0), (CLOSEST, REPEAT, 0.75, -0.25, 0.75),
    (CLOSEST, EXTEND, -0.25, 0.25, 0.0), (CLOSEST, EXTEND, 1.25, 0.75, 0.75),
    (CLOSEST, CLIP, 1.25, 0.25, 0.0), (CLOSEST, CLIP, 0.75, 0.25, 1.0), (CLOSEST, CLIP, 0.75, 1.01, 0.0),
    (LINEAR, REPEAT, 0.25, 0.25, 0.0), (LINEAR, REPEAT, 0.5, 0.25, 0.5), (LINEAR, REPEAT, 0.5, 0.5, 0.5),
    (LINEAR, REPEAT, 0.0, 0.25, 0.5), (LINEAR, REPEAT, 1.0, 0.25, 0.5), (LINEAR, REPEAT, 0.375, 0.25, 0.25),
    (LINEAR, EXTEND, 0.0, 0.25, 0.0), (LINEAR, EXTEND, 1.0, 0.25, 1.0), (LINEAR, EXTEND, 0.75, 1.5, 0.75),
    (LINEAR, CLIP, 0.0, 0.25, 0.0), (LINEAR, CLIP, 1.0, 0.25, 0.5), (LINEAR, CLIP, 1.0, 0.75, 0.375),
    (LINEAR, CLIP, 1.5, 0.25, 0.0),
])
def test_matte_alpha_hand_values(interp, ext, s, t, expect):
    m = one_matte(interp, ext).packed()
    assert matte_alpha(m, 0, s, t) == pytest.approx(expect, abs=1e-12)


def test_alpha_at_interpolates_uvs_with_embree_barycentrics():
    # UV = (1-u-v) uv0 + u uv1 + v uv2; the second triangle maps to the top-left texel
    uv = np.array([[[0, 0], [1, 0], [0, 1]], [[0, 0.5], [0.5, 0.5], [0, 1]]], np.float32)
    a = AlphaMattes([0, -1], np.concatenate([uv[:1], uv[:1]]), TEXELS, [0], [2], [2], [CLOSEST], [REPEAT])
    b = AlphaMattes([0, 0], uv, TEXELS, [0], [2], [2], [CLOSEST], [REPEAT])
    assert alpha_at(a.packed(), 0, 0.6, 0.2) == 1.0       # UV (0.6, 0.2): texel (1, 0)
    assert alpha_at(a.packed(), 0, 0.2, 0.2) == 0.0       # UV (0.2, 0.2): texel (0, 0)
    assert alpha_at(a.packed(), 1, 0.2, 0.2) == 1.0       # no matte: opaque
    assert alpha_at(b.packed(), 1, 0.2, 0.2) == 0.25      # UV (0.1, 0.6): texel (0, 1)


def test_alpha_is_opaque_for_non_finite_uvs_and_clamped():
    uv = np.array([[[np.nan, 0], [1, 0], [0, 1]]], np.float32)
    assert alpha_at(one_matte(LINEAR, REPEAT, tri_uv=uv).packed(), 0, 0.2, 0.2) == 1.0
    m = one_matte(CLOSEST, REPEAT, texels=[-0.5, 2.0, 0.5, 0.5]).packed()
    assert matte_alpha(m, 0, 0.25, 0.25) == 0.0 and matte_alpha(m, 0, 0.75, 0.25) == 1.0
    assert matte_alpha(m, 0, 1e30, 0.25) in (0.0, 1.0)


# -- embree / embree_irr: transmittance --------------------------------------
HL, HO = 4.0, 2.0
SOLID_BELOW_Y0 = [[1.0], [0.0]]     # 1 x 2 matte: v < 0.5 (y < 0) solid, above clear


def run(method, scene, **params):
    """(``method``'s MethodResult on ``scene``'s first light, the buffers)."""
    fb = buffers_of(scene)
    return run_method(method, fb, scene.lights[0], **params), fb


def test_embree_half_clear_quad_is_the_half_plane_closed_form():
    """A card over the whole view, solid where y < 0 and clear above: the
    square light's V(y) = clamp((a/2 + y) / a, 0, 1), as an opaque half plane."""
    a = 1.0
    scene = matte_layers_scene(area_light(size=a, z=HL), [(HO, SOLID_BELOW_Y0, CLOSEST, REPEAT)], res=64)
    (r, fb) = run("embree", scene, samples=256)
    assert fb.shadow_scene.alpha is not None
    v = r.passes["embree"]
    ys = pixel_world_y(scene, np.arange(64))
    expect = np.clip((a / 2 + ys) / a, 0, 1)
    assert np.abs(v.mean(axis=1) - expect).max() < 0.01
    assert v[ys > a].min() == 1.0 and v[ys < -a].max() == 0.0
    opaque = run("embree", half_plane_scene(area_light(size=a, z=HL), res=64, occluder_z=HO), samples=256)[0]
    assert np.abs(v - opaque.passes["embree"]).max() <= 1.0 / 256 + 1e-6


@pytest.mark.parametrize("layers, expect", [
    ([(HO, [[0.5]], CLOSEST, REPEAT), (HO + 0.5, [[0.5]], LINEAR, EXTEND)], 0.25),
    ([(HO, [[0.3]], CLOSEST, REPEAT)], 0.7),
    ([(HO, [[0.0]], CLOSEST, REPEAT)] * alpha_rays.MAX_CROSSINGS, 1.0),
    ([(HO, [[0.0]], CLOSEST, REPEAT)] * (alpha_rays.MAX_CROSSINGS + 1), 0.0),
])
def test_fractional_mattes_multiply(layers, expect):
    """Every shadow ray crosses every layer: V = prod (1 - alpha) (two 0.5
    layers: 0.25), for both passes; past MAX_CROSSINGS matte surfaces a ray
    is blocked (Cycles' transparent_max_bounces)."""
    layers = [(z + 0.01 * k, tex, ip, ex) for k, (z, tex, ip, ex) in enumerate(layers)]
    scene = matte_layers_scene(area_light(size=1.0, z=HL), layers, res=16)
    r = run("embree", scene, samples=16)[0]
    for p in ("embree", "embree_irr"):
        assert np.allclose(r.passes[p], expect, atol=1e-6), p
    v = run("penumbra_casting", scene, samples=16)[0].passes["penumbra_casting"]   # the texture fetch
    assert np.allclose(v, expect, atol=1e-6)


def test_hard_shadow_of_a_checkerboard_matte():
    """Point light at (0, 0, 4), a 4 x 4 checkerboard card at z = 2: the ray
    from ground point (x, y) crosses the card at (x/2, y/2); V = 1 - texel there."""
    checker = (np.add.outer(np.arange(4), np.arange(4)) % 2).astype(np.float32)
    scene = matte_layers_scene(sphere_light(radius=0.0, z=HL), [(HO, checker, CLOSEST, REPEAT)], res=40)
    v = run("embree", scene)[0].passes["embree"]
    ys = pixel_world_y(scene, np.arange(40))
    xs = ys[::-1]
    s = ((xs[None, :] / 2 + 10) / 20 * 4).astype(int)
    t = ((ys[:, None] / 2 + 10) / 20 * 4).astype(int)
    assert np.array_equal(v, 1.0 - checker[t, s])


def test_scene_without_mattes_keeps_the_opaque_path():
    """Mattes that no shadow-casting triangle uses build no alpha data, and
    V is the opaque scene's to the bit."""
    base = half_plane_scene(area_light(size=1.0, z=HL), res=32, occluder_z=HO)
    T = len(base.triangles)
    with_none = half_plane_scene(area_light(size=1.0, z=HL), res=32, occluder_z=HO)
    with_none.alpha = AlphaMattes(np.full(T, -1), np.zeros((T, 3, 2)), [1.0], [0], [1], [1], [CLOSEST], [REPEAT])
    (a, fa), (b, fb) = run("embree", base, samples=64), run("embree", with_none, samples=64)
    assert fb.shadow_scene.alpha is None and fb.camera_scene.alpha is None
    for p in ("embree", "embree_irr"):
        assert np.array_equal(a.passes[p], b.passes[p])


# -- camera G-buffer and light maps: pass through clear texels -----------------
CHECKER = (np.add.outer(np.arange(4), np.arange(4)) % 2).astype(np.float32)   # texel (row t, col s)


def checker_card_scene(light, res=40, camera_sees=True):
    """A 4 x 4 checkerboard card at z = 2 over the ground square [-2, 2]^2,
    seen from an orthographic camera at z = 5 (cells of 1 unit)."""
    return matte_layers_scene(light, [(HO, CHECKER, CLOSEST, REPEAT)], res=res, ground=2.0,
                              camera=top_ortho_camera(2.0, height=5.0), camera_sees=camera_sees)


def test_gbuffer_sees_through_clear_texels():
    scene = checker_card_scene(area_light(size=1.0, z=HL))
    g = raycast.camera_gbuffer(scene, 40, 40)
    ys = pixel_world_y(scene, np.arange(40))
    xs = ys[::-1]
    solid = CHECKER[np.floor(ys + 2).astype(int)[:, None], np.floor(xs + 2).astype(int)[None, :]] == 1
    assert g.hit.all()
    assert np.array_equal(g.object_id, np.where(solid, 1, 0))
    assert np.allclose(g.depth, np.where(solid, 3.0, 5.0), atol=1e-5)
    assert np.allclose(g.position[..., 2], np.where(solid, HO, 0.0), atol=1e-5)
    assert np.allclose(g.normal[..., 2], 1.0)
    assert np.array_equal(g.triangle_id >= 2, solid)


def face_world_points(face, depth):
    """World points of a face's pixel centres at the map's depths."""
    h, w = depth.shape
    l, r, b, t = face.bounds
    x = l + (np.arange(w) + 0.5) / w * (r - l)
    y = t - (np.arange(h) + 0.5) / h * (t - b)
    X, Y = np.meshgrid(x, y)
    Z = depth
    vx, vy = (X, Y) if face.ortho else (X * Z, Y * Z)
    pts = np.stack([vx, vy, -Z, np.ones_like(Z)], -1)
    return (pts @ np.linalg.inv(face.view_from_world).T)[..., :3]


def test_light_map_depth_ignores_clear_texels():
    """Every light-map pixel that holds the card lands on a solid texel, every
    ground pixel under the card on a clear one (seen through it)."""
    scene = checker_card_scene(sphere_light(radius=0.2, z=HL))
    fb = FrameBuffers(scene, 40, 40, map_size=128)
    lv = fb.light_view(scene.lights[0])
    seen = 0
    for f, face in enumerate(lv.faces):
        d, ids = lv.depth[f], lv.object_id[f]
        ok = np.isfinite(d)
        P = face_world_points(face, np.where(ok, d, 1.0))
        inside = ok & (np.abs(P[..., 0]) < 2) & (np.abs(P[..., 1]) < 2)
        # where the ray from the light crosses the card (z = 2)
        L = scene.lights[0].position
        k = (HO - L[2]) / (P[..., 2] - L[2])
        cx, cy = L[0] + k * (P[..., 0] - L[0]), L[1] + k * (P[..., 1] - L[1])
        on_card = inside & (np.abs(cx) < 2) & (np.abs(cy) < 2)
        texel = CHECKER[np.clip(np.floor(cy + 2), 0, 3).astype(int), np.clip(np.floor(cx + 2), 0, 3).astype(int)]
        # pixel centres within a hair of a cell edge may land either side
        far = on_card & (np.abs(cx - np.round(cx)) > 1e-3) & (np.abs(cy - np.round(cy)) > 1e-3)
        assert np.all(ids[far & (texel == 1)] == 1)
        assert np.all(ids[far & (texel == 0)] == 0)
        assert np.allclose(P[far & (texel == 1)][:, 2], HO, atol=1e-3)
        seen += int(far.sum())
    assert seen > 1000


# -- penumbra_casting: the texture fetch on the relations, matte blockers last --
@pytest.mark.parametrize("alpha_fetch", [True, False])
def test_penumbra_casting_equals_embree_on_a_matte_scene(alpha_fetch):
    """A checkerboard card and an opaque half plane under a square light,
    the reference's own samples: the same relations, the same V (up to rays
    within rounding of a texel or triangle edge), with the paper's texture
    fetch and with Embree rays through the matte blockers."""
    checker = (np.add.outer(np.arange(8), np.arange(8)) % 2).astype(np.float32)
    scene = matte_layers_scene(area_light(size=0.5, z=HL), [(1.0, checker, CLOSEST, REPEAT)], res=48,
                               ground=2.0, camera=top_ortho_camera(2.0, height=0.5))
    e = run("embree", scene, samples=64)[0].passes["embree_irr"]
    p = run("penumbra_casting", scene, samples=64, shared_samples_with_reference=True,
            alpha_fetch=alpha_fetch)[0].passes["penumbra_casting"]      # both the irradiance ratio
    assert 0.3 < e.mean() < 0.7
    assert np.abs(p - e).mean() < 1e-3
    assert np.abs(p - e).max() <= 3 / 64 + 1e-6


@pytest.mark.parametrize("ground_casts", [True, False])
def test_penumbra_casting_fractional_mattes_multiply(ground_casts):
    """Every relation crosses both 0.5 layers: V = 0.25, with the paper's
    sample sets; also when every blocker has a matte (no opaque one)."""
    layers = [(HO, [[0.5]], CLOSEST, REPEAT), (HO + 0.5, [[0.5]], LINEAR, EXTEND)]
    scene = matte_layers_scene(area_light(size=1.0, z=HL), layers, res=16)
    scene.objects[0].casts_shadow = ground_casts
    v = run("penumbra_casting", scene, samples=64)[0].passes["penumbra_casting"]
    assert np.allclose(v, 0.25, atol=1e-6)


def matte_leaf_cloud(light=None, res=40):
    """``synthetic.leaf_cloud_scene`` with a matte on every leaf: a binary
    8 x 8 checkerboard (Closest) on half of them, a Linear gradient
    (fractional alpha) on the others."""
    scene = leaf_cloud_scene(n_leaves=60, res=res)
    n = (len(scene.triangles) - 2) // 2
    uv = np.zeros((len(scene.triangles), 3, 2), np.float32)
    uv[2:2 + n] = [[0, 0], [1, 0], [1, 1]]
    uv[2 + n:] = [[0, 0], [1, 1], [0, 1]]
    matte = np.full(len(scene.triangles), -1)
    leaf = np.arange(n) % 2
    matte[2:2 + n] = matte[2 + n:] = leaf
    checker = (np.add.outer(np.arange(8), np.arange(8)) % 2).ravel()
    gradient = np.linspace(0.0, 1.0, 16)
    scene.alpha = AlphaMattes(matte, uv, np.concatenate([checker, gradient]), [0, 64], [8, 4], [8, 4],
                              [CLOSEST, LINEAR], [REPEAT, EXTEND], ["leaf / checker", "leaf / gradient"])
    if light is not None:
        scene.lights = [light]
    return scene


@pytest.mark.parametrize("light", ["area", "sun", "sphere"])
def test_penumbra_casting_texture_fetch_equals_its_embree_rays(light):
    """The paper's texture fetch (section 4) against Embree rays through the
    matte blockers, on the same relations (the paper's sample sets): the
    same V up to relations within rounding of a texel or triangle edge and
    grazing second crossings that the rays' offset past each crossing steps
    over (a few relations in a few pixels), for binary and filtered mattes,
    area, sun and sphere lights."""
    lt = {"area": None, "sun": sun_light(angle=0.15), "sphere": sphere_light(radius=0.3, z=3.0)}[light]
    scene = matte_leaf_cloud(lt)
    fetch, _ = run("penumbra_casting", scene, samples=64)
    rays, _ = run("penumbra_casting", scene, samples=64, alpha_fetch=False)
    p, q = fetch.passes["penumbra_casting"], rays.passes["penumbra_casting"]
    assert fetch.stats["matte_pairs"] > 0
    assert float(((q > 0) & (q < 1)).mean()) > 0.03      # the mattes shadow part of the view
    assert np.abs(p - q).mean() < 2e-4
    assert float((np.abs(p - q) > 1e-4).mean()) < 0.03
    assert np.abs(p - q).max() <= 3 / 64 + 1e-6


def test_texture_fetch_counts_a_shared_edge_once():
    """Rays through the diagonal of a quad of two triangles (alpha 0.5):
    the edge functions are exactly 0 there, and the fixed vertex order
    gives the crossing to one triangle only (V = 0.5, not 0.25 or 1), from
    either side of the quad; rays beside the diagonal too."""
    from penumbra.core.methods.penumbra_casting import alpha_blockers as ab
    from penumbra.core.methods.penumbra_casting import prepare
    from penumbra.core.methods.penumbra_casting.cast import Receivers
    scene = matte_layers_scene(area_light(size=1.0, z=HL), [(HO, [[0.5]], CLOSEST, REPEAT)], res=4)
    m = producer_of("penumbra_casting")
    setup = prepare(FrameBuffers(scene, 4, 4), scene.lights[0], m.make_params({"samples": 64}))
    a, b, c, d = [-1, -1, 1], [1, -1, 1], [1, 1, 1], [-1, 1, 1]
    tris = np.array([[a, b, c], [a, c, d]], np.float64)
    mb = ab.MatteBlockers(tris, np.array([0, 1], np.int64), ab.corner_order(tris), np.zeros((2, 4, 1)),
                          np.zeros(2, np.int64))
    mattes = AlphaMattes([0, 0], np.zeros((2, 3, 2)), [0.5], [0], [1], [1], [CLOSEST], [REPEAT]).packed()
    t = np.linspace(-0.6, 0.6, 64)
    for z_rec, z_light in ((0.0, 2.0), (2.0, 0.0)):
        for off in (0.0, 1e-9, -0.3):
            SP = np.zeros((1, 64, 4))
            # the quad (z = 1) halfway: the ray crosses it at (t, t + off)
            SP[0, :, 0], SP[0, :, 1], SP[0, :, 2], SP[0, :, 3] = 2 * t, 2 * (t + off), z_light, 1.0
            smp = setup.light_samples()._replace(SP=SP)
            rec = Receivers(np.array([[0.0, 0.0, z_rec]]), np.zeros(1, np.int64), setup.idx[:1], setup.Pg[:1],
                            setup.M)
            V = np.empty(1)
            ab.fetch_visibility(smp, rec, np.zeros(1, np.uint8), np.full(1, -1, np.int64),
                                np.zeros((1, 1), np.uint64), 64, np.array([0, 2], np.int64),
                                np.array([0, 1], np.int64), mb, mattes, V)
            assert V[0] == 0.5, (z_rec, off, V[0])


def test_alpha_data_only_for_the_triangles_that_need_it():
    """Shadow BVHs carry alpha data only when a shadow-casting triangle has
    a matte, the camera's only when a visible one has."""
    scene = matte_layers_scene(area_light(size=1.0, z=HL), [(HO, [[0.5]], CLOSEST, REPEAT)], res=16)
    fb = FrameBuffers(scene, 16, 16)
    assert fb.shadow_scene.alpha is not None and fb.camera_scene.alpha is None
    scene.objects[1].casts_shadow = False
    assert FrameBuffers(scene, 16, 16).shadow_scene.alpha is None


def test_intersect_passes_through_clear_texels():
    """TriangleScene.intersect (depth_raytrace's rays) stops where the
    checkerboard is solid and reaches the ground where it is clear."""
    scene = checker_card_scene(area_light(size=1.0, z=HL))
    bvh = raycast.TriangleScene.from_scene(scene, np.ones(len(scene.triangles), bool))
    xy = np.array([[-1.5, -1.5], [-0.5, -1.5], [0.5, 0.5], [1.5, 0.5]])
    org = np.column_stack([xy, np.full(4, 5.0)])
    dirs = np.tile([0.0, 0.0, -1.0], (4, 1))
    tri, t, _, _ = bvh.intersect(org, dirs, np.full(4, 10.0))
    solid = CHECKER[np.floor(xy[:, 1] + 2).astype(int), np.floor(xy[:, 0] + 2).astype(int)] == 1
    assert np.array_equal(scene.tri_object[tri], np.where(solid, 1, 0))
    assert np.allclose(t, np.where(solid, 3.0, 5.0), atol=1e-5)


def test_irregular_multiplies_the_matte_transmittance():
    layers = [(HO, [[0.5]], CLOSEST, REPEAT), (HO + 0.5, [[0.5]], LINEAR, EXTEND)]
    scene = matte_layers_scene(area_light(size=1.0, z=HL), layers, res=16)
    v = run("irregular", scene)[0].passes["irregular"]
    assert np.allclose(v, 0.25, atol=1e-6)


@pytest.mark.parametrize("alphas, ground_share", [([0.5], 0.5), ([0.25], 0.75), ([0.5, 0.5], 0.25)])
def test_light_map_dithers_fractional_alpha(alphas, ground_share):
    """Cards of constant alpha a over the whole light view: an ordered-dither
    alpha test keeps a share a of the map pixels on each card, so the ground
    shows through in the share prod (1 - a) (two 0.5 layers: 1/4)."""
    layers = [(HO + 0.3 * k, [[a]], CLOSEST, REPEAT) for k, a in enumerate(alphas)]
    scene = matte_layers_scene(sphere_light(radius=0.2, z=HL), layers, res=32)
    lv = FrameBuffers(scene, 32, 32, map_size=64).light_view(scene.lights[0])
    assert abs(float((lv.object_id == 0).mean()) - ground_share) < 0.02
    # pcf filters the dithered map into a fractional shadow
    v = run("pcf", scene)[0].passes["pcf"]
    assert abs(float(v.mean()) - ground_share) < 0.05


# -- the light maps' alpha test (pass_through / dither) and the map methods on them --
def test_clear_hits_equals_the_alpha_lookup():
    """clear_hits decides hits on triangles without a matte itself (no
    lookup): the same answer as alpha_at < cut for every hit, matte or not."""
    scene = checker_card_scene(area_light(size=1.0, z=HL))
    mattes = scene.alpha.packed()
    rng = np.random.default_rng(3)
    n = 4000
    prim = rng.integers(-1, len(scene.triangles), n).astype(np.int32)
    u = rng.random(n).astype(np.float32)
    v = (rng.random(n) * (1 - u)).astype(np.float32)
    cut = alpha_rays.dither_band(0, n // 40, 40)
    tri_index = np.arange(len(scene.triangles), dtype=np.int32)
    clear = np.empty(n, bool)
    alpha_rays.clear_hits(prim, u, v, tri_index, mattes, cut, clear)
    expect = np.array([p >= 0 and alpha_at(mattes, p, float(a), float(b)) < c
                       for p, a, b, c in zip(prim, u, v, cut)])
    assert np.array_equal(clear, expect)
    assert clear.any() and (~clear[prim >= 2]).any() and not clear[(prim >= 0) & (prim < 2)].any()


#: how far a map method's mean V may be from prod (1 - a): layered's splat of
#: the dithered sample maps lets through about 0.04 more light on a 0.5 veil,
#: at every light-sample count from 64 to 512 and every seed (a bias, not noise)
MATTE_TOLERANCE = {"pcf": 0.035, "layered": 0.05}


@pytest.mark.parametrize("alphas, expect", [([0.5], 0.5), ([0.5, 0.5], 0.25)])
@pytest.mark.parametrize("method, params", [("pcf", {}), ("layered", {})])
def test_map_methods_see_fractional_mattes(method, params, alphas, expect):
    """Cards of constant alpha over the whole light view: every ground point
    sees the light through each card with transmittance 1 - a, V = prod
    (1 - a). The dithered light maps hold each card in a share a of their
    pixels; pcf filters them, layered's default splat (footprint, as the
    casters carry mattes) counts the ground where it shows through."""
    layers = [(HO + 0.5 * k, [[a]], CLOSEST if k == 0 else LINEAR, REPEAT if k == 0 else EXTEND)
              for k, a in enumerate(alphas)]
    scene = matte_layers_scene(area_light(size=1.0, z=HL), layers, res=16)
    v = run(method, scene, **params)[0].passes[method]
    assert abs(float(v.mean()) - expect) < MATTE_TOLERANCE[method], float(v.mean())


def test_layered_paper_splat_reads_a_dithered_veil_as_clear():
    """Why layered's default footprint splat matters on matte scenes: the
    paper's 4-neighbour splat spreads the ground seen through the dither's
    clear texels over the solid ones, and a 0.5 veil casts no shadow."""
    scene = matte_layers_scene(area_light(size=1.0, z=HL), [(HO, [[0.5]], CLOSEST, REPEAT)], res=16)
    paper = run("layered", scene, splat="neighbours")[0].passes["layered"]
    auto = run("layered", scene)[0].passes["layered"]
    assert paper.mean() > 0.95 and abs(float(auto.mean()) - 0.5) < MATTE_TOLERANCE["layered"]


@pytest.fixture(scope="module")
def leaf_cards_runs():
    """The leaf_cards sample scene at 128 x 128: the embree reference (256
    samples) and its reach mask."""
    from scenes import load_sample
    scene = load_sample("leaf_cards", (128, 128))
    fb = FrameBuffers(scene, 128, 128)
    light = scene.lights[0]
    ref = embree_pass(fb, light, 256)
    return fb, light, ref, reach_mask(fb.gbuffer, light)


@pytest.mark.parametrize("method, params, paper", [
    ("pcf", {}, {"region": "figure4"}),
    ("layered", {"samples": 128}, {"samples": 128, "splat": "neighbours"})])
def test_map_methods_on_leaf_cards(leaf_cards_runs, method, params, paper):
    """The map methods within 0.06 RMSE of the reference on the leaf-card
    scene (binary leaf mattes, a chain-link fence, linear mattes, a 0.5
    veil; area light), without a bias; the paper's settings (pcf's region,
    layered's splat) stay clearly worse in the penumbra."""
    fb, light, ref, mask = leaf_cards_runs
    m = producer_of(method)
    v = m.run(fb, light, m.make_params(params)).passes[method]
    p = m.run(fb, light, m.make_params(paper)).passes[method]
    e, ep = errors(v, ref, mask), errors(p, ref, mask)
    assert e["rmse"] < 0.06, e
    assert abs(e["mean_signed"]) < 0.01, e
    assert e["rmse_penumbra"] < 0.9 * ep["rmse_penumbra"], (e, ep)
