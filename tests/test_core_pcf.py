"""Percentage-closer filtering (Reeves et al. 1987) against the hard test and invariants."""
import numpy as np
import pytest

from penumbra.core import views
from penumbra.core.buffers import FrameBuffers
from penumbra.core.kernels import finite_bbox
from penumbra.core.methods import producer_of
from penumbra.core.methods.pcf import PCFParams, resolved_bias, scene_extent
from penumbra.core.methods.pcf.footprint import pixel_footprint, pixel_ray_terms
from penumbra.core.methods.pcf.samples import hard_shadow_kernel, sample_shadow

from synthetic import (area_light, half_plane_scene, make_scene, persp_camera, pixel_world_y, quad, sphere_light,
                       sun_light)

NOPLANE = (0.0,) * 6    # figure 4's constant receiver depth


def run_pcf(scene, **over):
    m = producer_of("pcf")
    fb = FrameBuffers(scene, *scene.resolution)
    return m.run(fb, scene.lights[0], m.make_params(over)), fb


def hard(fb, light, bias):
    g = fb.gbuffer
    lv = fb.light_view(light)
    idx = np.flatnonzero(g.hit.reshape(-1))
    out = np.ones(g.hit.size)
    vals = np.empty(len(idx))
    hard_shadow_kernel(np.ascontiguousarray(g.position.reshape(-1, 3)[idx]), lv.packed_faces(), lv.depth, bias, vals)
    out[idx] = vals
    return out.reshape(g.shape)


@pytest.mark.parametrize("make", [lambda: area_light(1.0), lambda: sphere_light(0.3), lambda: sun_light(0.1)])
def test_zero_region_equals_hard_shadow_test(make):
    """Figure 4's region shrunk to nothing is Williams' hard test."""
    scene = half_plane_scene(make(), res=48)
    r, fb = run_pcf(scene, region="figure4", ResFactor=0.0, MinSize=0.0, MinSamples=1, Bias0=0.01, Bias1=0.01)
    np.testing.assert_array_equal(r.passes["pcf"], hard(fb, scene.lights[0], 0.01))
    v = r.passes["pcf"]
    assert (v == 0).any() and (v == 1).any()


def test_zero_size_light_gives_hard_shadow():
    scene = half_plane_scene(area_light(0.0), res=48)
    r, fb = run_pcf(scene, Bias0=0.02, Bias1=0.02)
    np.testing.assert_array_equal(r.passes["pcf"], hard(fb, scene.lights[0], 0.02))


def test_soft_edge_is_monotone_and_in_range():
    scene = half_plane_scene(area_light(1.0), res=64)
    r, _ = run_pcf(scene, ResFactor=4.0, NumSamples=64)
    v = r.passes["pcf"]
    assert np.isfinite(v).all() and v.min() >= 0 and v.max() <= 1
    rm = v.mean(axis=1)[::-1]             # from shadow (y < 0) to light
    assert rm[0] == 0.0 and rm[-1] == 1.0
    assert np.all(np.diff(rm) >= -0.05)
    assert ((v > 0) & (v < 1)).any()      # it filters: some partial values


def test_region_outside_map_bbox_is_lit():
    """sample_shadow returns 0 (not in shadow) when the region misses the map's
    bounding box of finite depths, and for points behind the light."""
    depth = np.full((8, 8), np.inf, np.float32)
    depth[2:4, 2:4] = 1.0
    bbox = finite_bbox(depth[None])[0]
    assert list(bbox) == [2, 3, 2, 3]
    assert sample_shadow(depth, bbox, 6.5, 6.5, 5.0, 0.5, 0.5, 16, 1, 0.0, 0.0, 0, 0, NOPLANE) == 0.0
    assert sample_shadow(depth, bbox, 3.0, 3.0, -1.0, 1.0, 1.0, 16, 1, 0.0, 0.0, 0, 0, NOPLANE) == 0.0
    assert sample_shadow(depth, bbox, 3.0, 3.0, 5.0, 0.9, 0.9, 16, 1, 0.0, 0.0, 0, 0, NOPLANE) == 1.0


def test_sample_counts_follow_figure_4():
    """A large region takes about NumSamples samples; a small one at least
    MinSamples per axis: count the distinct outcomes' denominators."""
    depth = np.zeros((64, 64), np.float32)
    bbox = np.array([0, 63, 0, 63])
    # half the map in shadow: fraction is a multiple of 1/(ns nt)
    depth[:, 32:] = 10.0
    f = sample_shadow(depth, bbox, 32.0, 32.0, 5.0, 16.0, 16.0, 16, 2, 0.0, 0.0, 0, 0, NOPLANE)
    assert f == pytest.approx(0.5)
    f1 = sample_shadow(depth, bbox, 20.0, 20.0, 5.0, 0.0, 0.0, 16, 3, 0.0, 0.0, 0, 0, NOPLANE)
    assert f1 == 1.0


def test_bias_scales_with_scene_size():
    scene = half_plane_scene(area_light(1.0), res=8)
    p = producer_of("pcf").make_params({})
    b0, b1 = resolved_bias(p, scene_extent(scene))
    assert b0 == pytest.approx(0.003 * 20) and b1 == pytest.approx(0.004 * 20)


def test_receiver_plane_removes_self_shadowing_on_a_tilted_plane():
    """A lone plane tilted 60 degrees to a light above: with the paper's
    constant z and zero bias the large regions shadow the plane itself
    (section 4.2's Moire); comparing with the tangent-plane depth per texel
    leaves it fully lit with zero bias."""
    import numpy as np
    from penumbra.core.scene import Scene, ObjectInfo
    from synthetic import top_ortho_camera
    c, s = np.cos(np.radians(60)), np.sin(np.radians(60))
    tris = np.array([[[-5 * c, -5, -5 * s], [5 * c, -5, 5 * s], [5 * c, 5, 5 * s]],
                     [[-5 * c, -5, -5 * s], [5 * c, 5, 5 * s], [-5 * c, 5, -5 * s]]], np.float32)
    cam = top_ortho_camera(1.5, height=8.0)
    sc = Scene(tris, np.zeros(2, np.int32), [ObjectInfo("p", 0)], cam, [area_light(1.0, z=10.0)], (48, 48))
    on, _ = run_pcf(sc, Bias0=0.0, Bias1=0.0, ResFactor=4.0)
    off, _ = run_pcf(sc, Bias0=0.0, Bias1=0.0, ResFactor=4.0, receiver_plane=False)
    assert on.passes["pcf"].min() == 1.0
    assert off.passes["pcf"].mean() < 0.95


@pytest.mark.parametrize("region", ["light", "figure4"])
def test_tile_early_out_changes_nothing(region):
    """Reeves et al. 3.3's tiles only skip regions whose result they decide:
    the pass is bit-identical with them off (region="light": the tiles test
    the blocker search's region, which holds the filter's)."""
    for make in (lambda: area_light(1.0), lambda: sphere_light(0.3), lambda: sun_light(0.1)):
        scene = half_plane_scene(make(), res=48)
        a, _ = run_pcf(scene, tiles=True, region=region)
        b, _ = run_pcf(scene, tiles=False, region=region)
        np.testing.assert_array_equal(a.passes["pcf"], b.passes["pcf"])


def _rmse(a, b):
    return float(np.sqrt(np.mean((np.asarray(a, np.float64) - b) ** 2)))


def test_light_region_is_the_square_light_closed_form():
    """region="light" on the half-plane scene (a square light of side 1 at
    height 4, the occluder's edge at height 2): the blocker search finds the
    occluder's depth, the filter region is the light's extent there, and a
    box region over a straight edge is the exact penumbra of a square light,
    V = clamp(1/2 + y) on the ground (linear over a unit width). Figure 4's
    region follows the pixel footprint (a few texels): nearly a hard edge."""
    scene = half_plane_scene(area_light(1.0), res=64)
    exact = np.clip(0.5 + pixel_world_y(scene, np.arange(64)), 0.0, 1.0)[:, None] * np.ones(64)
    v = run_pcf(scene, PenumbraSamples=256)[0].passes["pcf"]
    paper = run_pcf(scene, region="figure4")[0].passes["pcf"]
    assert _rmse(v, exact) < 0.03, _rmse(v, exact)
    assert _rmse(paper, exact) > 0.1
    # the umbra and the lit side are decided whole (tiles or no blocker found)
    assert v[exact == 0.0].max() == 0.0 and v[exact == 1.0].min() == 1.0


def test_light_region_widens_with_the_light():
    """The penumbra's width follows the light's size (it does not with
    figure 4's region): more partial pixels under a larger light."""
    partial = {}
    for size in (0.5, 1.0, 2.0):
        v = run_pcf(half_plane_scene(area_light(size), res=64))[0].passes["pcf"]
        partial[size] = int(((v > 0.02) & (v < 0.98)).sum())
    assert partial[0.5] < partial[1.0] < partial[2.0]
    assert partial[2.0] > 3 * partial[0.5]


def test_light_reach_closed_forms():
    """light_reach: an area light along the view's axes gives its half
    sides over the texel size; a sphere light its radius; a sun tan(half
    angle) on an orthographic face; zero size: zero."""
    from penumbra.core.methods.pcf.light_region import light_reach
    for light, half in ((area_light(1.0, size_y=0.5, shape="RECTANGLE"), (0.5, 0.25)),
                        (sphere_light(0.3), (0.3, 0.3)), (sun_light(0.1), (np.tan(0.05),) * 2)):
        fb = FrameBuffers(half_plane_scene(light, res=16), 16, 16)
        face = fb.light_view(light).faces[0]
        l, r, b, t = face.bounds
        k = light_reach(light, [face])[0]
        np.testing.assert_allclose(k[:2], [half[0] * face.width / (r - l), half[1] * face.height / (t - b)],
                                   rtol=1e-9)
        assert k[2] == (1.0 if face.ortho else 0.0)


def test_unknown_region_is_an_error():
    with pytest.raises(ValueError, match="region"):
        run_pcf(half_plane_scene(area_light(1.0), res=8), region="pcss")


@pytest.mark.parametrize("ortho", [False, True])
def test_receiver_form_compares_as_plane_depth(ortho):
    """The fast sampler's division-free test (``_receiver_form``) says
    "behind" exactly where ``plane_depth`` does, texel by texel, for
    tangent planes of random slopes (perspective and orthographic faces),
    over boxes where the form holds (mode 1 / 2), and falls back (mode 3)
    where ``plane_depth``'s own fallback is reached."""
    from penumbra.core.methods.pcf.receiver import _receiver_form, plane_depth
    rng = np.random.default_rng(3)
    checked = fallback = 0
    for _ in range(300):
        a, b = rng.normal(0.0, 1e-3, 2)
        if ortho:
            plane = (1.0, 1.0, a, b, rng.uniform(-1.0, 20.0), 0.0)
        else:
            plane = (1.0, 0.0, a, b, rng.uniform(-0.3, 1.0), rng.choice([-5.0, 5.0]))
        u0, v0 = rng.uniform(0.0, 400.0, 2) + 0.5
        u1, v1 = u0 + rng.integers(0, 64), v0 + rng.integers(0, 64)
        mode, fa, fb, fc, fk = _receiver_form(plane, 7.0, u0, u1, v0, v1)
        us, vs = np.arange(u0, u1 + 1.0), np.arange(v0, v1 + 1.0)
        if mode == 3:
            fallback += 1
            assert any(plane_depth(plane, u, v, -1.0) == -1.0 for u in (u0, u1) for v in (v0, v1))
            continue
        for u in us[::7]:
            for v in vs[::7]:
                zs = plane_depth(plane, u, v, -1.0)
                assert zs > 0.0
                for thr in (0.5 * zs, zs * (1 - 1e-9), zs * (1 + 1e-9), 2.0 * zs):
                    fast = fk > thr * (fa * u + fb * v + fc) if mode == 2 else fa * u + fb * v + fc > thr
                    assert fast == (zs > thr)
                    checked += 1
    assert checked > 1000 and fallback > 10


@pytest.mark.parametrize("camera", [None, persp_camera((0.3, -3.0, 2.5), (0.0, 0.0, 0.0))])
def test_pixel_ray_terms_meet_the_gbuffer_hits(camera):
    """The affine camera rays pcf carries pixel corners along pass, at pixel
    centres, through the G-buffer's hit points on the ground z = 0."""
    scene = make_scene(quad(-20, 20, -20, 20, 0.0), [0, 0], [area_light(1.0)], res=40, camera=camera,
                       names=("ground",))
    fb = FrameBuffers(scene, 40, 40)
    g = fb.gbuffer
    rt = pixel_ray_terms(views.pack_camera(scene.camera, 40, 40))
    rows, cols = np.nonzero(g.hit)
    c, r = cols + 0.5, rows + 0.5
    o = rt[0] + c[:, None] * rt[1] + r[:, None] * rt[2]
    d = rt[3] + c[:, None] * rt[4] + r[:, None] * rt[5]
    t = -o[:, 2] / d[:, 2]
    assert (t > 0).all()
    np.testing.assert_allclose(o + t[:, None] * d, g.position[rows, cols], atol=1e-4)


def test_pixel_footprint_closed_form_for_a_sun_straight_down():
    """Orthographic camera and sun both looking straight down at z = 0: a
    camera pixel covers (4 / 64)^2 world units, so its half extents in the
    map are half a pixel over the texel size, on both axes."""
    scene = half_plane_scene(sun_light(0.0), res=64)
    fb = FrameBuffers(scene, 64, 64)
    face = fb.light_view(scene.lights[0]).packed_faces()[0]
    texel_u = (face[18] - face[17]) / face[21]
    texel_v = (face[20] - face[19]) / face[22]
    rt = pixel_ray_terms(views.pack_camera(scene.camera, 64, 64))
    g = fb.gbuffer
    for row, col in [(3, 5), (40, 20), (63, 63)]:
        p = g.position[row, col].astype(np.float64)
        hs, ht = pixel_footprint(rt, face, float(col), float(row), p[0], p[1], p[2], 0.0, 0.0, 1.0,
                                 *_centre_texel(face, p), 1e9)
        assert hs == pytest.approx(0.5 * (4.0 / 64) / texel_u, rel=1e-4)   # P is float32
        assert ht == pytest.approx(0.5 * (4.0 / 64) / texel_v, rel=1e-4)
    # a camera ray parallel to the receiver plane: the region is capped
    p = g.position[10, 10].astype(np.float64)
    assert pixel_footprint(rt, face, 10.0, 10.0, p[0], p[1], p[2], 1.0, 0.0, 0.0,
                           *_centre_texel(face, p), 7.0) == (7.0, 7.0)


def _centre_texel(face, p):
    from penumbra.core.kernels import face_project
    u, v, _ = face_project(face, p[0], p[1], p[2])
    return u, v


def test_tile_tables_give_the_min_and_max_of_any_block_of_tiles():
    """The tile test's sparse tables: the min / max over any block of tiles
    in four lookups equal a loop over the tiles, on maps of odd sizes with
    empty (+inf) texels, one and several faces; with ``span``, over any
    block of at most that many tiles a side."""
    from penumbra.core.methods.pcf.tiles import tile_minmax, tile_range, tile_tables
    rng = np.random.default_rng(3)
    for shape in ((1, 8, 8), (1, 37, 101), (3, 64, 17)):
        depth = rng.uniform(1.0, 5.0, shape).astype(np.float32)
        depth[rng.random(shape) < 0.2] = np.inf
        lo, hi = tile_minmax(depth)
        tt = tile_tables(lo, hi)
        F, th, tw = lo.shape
        for _ in range(200):
            f = rng.integers(F)
            y0, y1 = sorted(rng.integers(0, th, 2))
            x0, x1 = sorted(rng.integers(0, tw, 2))
            dmin, dmax = tile_range(tt[f], y0, y1, x0, x1)
            assert dmin == lo[f, y0:y1 + 1, x0:x1 + 1].min() and dmax == hi[f, y0:y1 + 1, x0:x1 + 1].max()
        span = 5                                    # blocks of at most 5 tiles a side: fewer levels
        st = tile_tables(lo, hi, span)
        assert st.shape[1:3] == (min(3, tt.shape[1]), min(3, tt.shape[2]))
        for _ in range(200):
            f = rng.integers(F)
            y0, x0 = rng.integers(0, th), rng.integers(0, tw)
            y1, x1 = min(th - 1, y0 + rng.integers(0, span)), min(tw - 1, x0 + rng.integers(0, span))
            dmin, dmax = tile_range(st[f], y0, y1, x0, x1)
            assert dmin == lo[f, y0:y1 + 1, x0:x1 + 1].min() and dmax == hi[f, y0:y1 + 1, x0:x1 + 1].max()


def _slanted_map(rng, h=64, w=72, boxes=8):
    """A perspective face's map of the plane 1 / depth = a u + b v + c (at
    texel centres) with a few nearer boxes and an empty corner: (depth
    float32[1, h, w], (a, b, c))."""
    a, b, c = 2e-3, -1.5e-3, 0.25
    v, u = np.mgrid[0:h, 0:w] + 0.5
    depth = (1.0 / (a * u + b * v + c))[None].astype(np.float32)
    for _ in range(boxes):
        y0, x0 = rng.integers(0, h - 12), rng.integers(0, w - 12)
        depth[0, y0:y0 + rng.integers(1, 12), x0:x0 + rng.integers(1, 12)] *= np.float32(rng.uniform(0.5, 0.97))
    depth[0, :5, :7] = np.inf
    return depth, (a, b, c)


def test_tile_planes_fit_a_plane_exactly():
    """tile_planes: on a perspective map of a plane, every full block's
    plane is 1 / depth (a u + b v + c at the block's centre) within float32
    rounding; blocks with an empty texel or past the map get r = inf; on an
    orthographic face the depth itself is fitted."""
    from penumbra.core.methods.pcf.tiles import TILE, tile_planes
    depth, (a, b, c) = _slanted_map(np.random.default_rng(0), boxes=0)
    pl = tile_planes(depth, np.array([False]))[0]
    th, tw = pl.shape[:2]
    for ty in range(th):
        for tx in range(tw):
            full = (ty + 1) * TILE <= 64 and (tx + 1) * TILE <= 72 and not (ty == 0 and tx == 0)
            if not full:
                assert pl[ty, tx, 3] == np.inf
                continue
            cu, cv = tx * TILE + TILE / 2, ty * TILE + TILE / 2
            np.testing.assert_allclose(pl[ty, tx, :3], [a, b, a * cu + b * cv + c], rtol=1e-5)
            assert pl[ty, tx, 3] < 1e-6 * c
    ortho = tile_planes(np.full((1, 16, 16), 3.0, np.float32), np.array([True]))[0]
    np.testing.assert_allclose(ortho[..., :3], [[[0.0, 0.0, 3.0]] * 2] * 2, atol=1e-12)


def test_region_decided_lit_holds_for_every_texel():
    """The tile test with the blocks' planes (planar_lit) is exact: where it
    says lit, no texel centre of the region has the receiver (on the map's
    slanted plane, or in front of it) behind it by more than Bias0; where
    it says shadow, every one is behind by more than Bias1. And the planes
    decide regions the min / max cannot (a receiver on the slanted plane
    with no box nearby)."""
    from penumbra.core.methods.pcf.receiver import DEPTH_REL_EPS, plane_depth
    from penumbra.core.methods.pcf.tiles import (_texel_box, region_decided, tile_minmax, tile_planes, tile_range,
                                                tile_tables)
    rng = np.random.default_rng(5)
    decided_by_planes = 0
    for trial in range(6):
        depth, (a, b, c) = _slanted_map(rng)
        lo, hi = tile_minmax(depth)
        tt = tile_tables(lo, hi)
        planes = tile_planes(depth, np.array([False]))
        h, w = depth.shape[1:]
        for _ in range(300):
            s, t = rng.uniform(0, w), rng.uniform(0, h)
            lift = rng.choice([1.0, 1.0, 1.02])          # on the plane, or in front of it
            plane = (1.0, 0.0, a * lift, b * lift, c * lift, 1.0)
            z = plane_depth(plane, s, t, -1.0)
            sres, tres = rng.uniform(0.5, 12.0, 2)
            bias0 = rng.choice([0.0, 1e-3, 0.02])
            known = region_decided(tt[0], planes[0], False, w, h, s, t, z, sres, tres, plane, bias0, bias0)
            u0, u1, v0, v1 = (int(x) for x in _texel_box(w, h, s, t, sres, tres))
            vv, uu = np.mgrid[v0:v1, u0:u1] + 0.5
            zs = np.array([plane_depth(plane, x, y, z) for x, y in zip(uu.ravel(), vv.ravel())])
            d = depth[0, v0:v1, u0:u1].ravel().astype(np.float64)
            if known == 0.0:
                assert np.all(zs <= d * DEPTH_REL_EPS + bias0)
                dmin, _ = tile_range(tt[0], v0 // 8, (v1 - 1) // 8, u0 // 8, (u1 - 1) // 8)
                decided_by_planes += max(zs.max(), z) > dmin * DEPTH_REL_EPS + bias0
            elif known == 1.0:
                assert np.all(zs > d * DEPTH_REL_EPS + bias0)
    assert decided_by_planes > 50


def test_tiles_search_region_holds_every_blocker():
    """The blocker search region narrowed by the tiles' nearest depths is
    inside the one at the face's nearest depth (no narrowing step) and still
    holds every texel that can block a ray from the receiver to the light
    (depth d nearer than the receiver, within the light's reach at d)."""
    from penumbra.core.methods.pcf.light_region import light_halfwidth, search_region
    from penumbra.core.methods.pcf.tiles import tile_minmax, tile_tables
    rng = np.random.default_rng(9)
    depth, _ = _slanted_map(rng, boxes=6)
    lo, hi = tile_minmax(depth)
    tt = tile_tables(lo, hi)
    h, w = depth.shape[1:]
    zmin = float(depth.min())
    lsize = np.array([40.0, 30.0, 0.0])
    for _ in range(300):
        s, t = rng.uniform(0, w), rng.uniform(0, h)
        z = float(depth[0, min(int(t), h - 1), min(int(s), w - 1)])
        if not np.isfinite(z):
            continue
        z *= 1.001
        ws, wt = search_region(tt[0], w, h, s, t, z, lsize, zmin, 2.0, 2.0, 64.0, 2)
        fs, ft = search_region(tt[0], w, h, s, t, z, lsize, zmin, 2.0, 2.0, 64.0, 0)
        assert ws <= fs and wt <= ft
        vv, uu = np.mgrid[0:h, 0:w] + 0.5
        d = depth[0].astype(np.float64)
        near = np.isfinite(d) & (d < z)
        reach = np.array([light_halfwidth(lsize, z, x) for x in d[near]])
        inside = ((np.abs(uu[near] - s) <= np.minimum(reach[:, 0], fs))
                  & (np.abs(vv[near] - t) <= np.minimum(reach[:, 1], ft)))
        blockers = np.flatnonzero(inside)
        assert np.all(np.abs(uu[near][blockers] - s) <= ws)
        assert np.all(np.abs(vv[near][blockers] - t) <= wt)


def test_pixel_step_copy_shares_a_blocks_first_pixel_on_one_surface_only():
    """pixel_step=2, step_fill="copy" (the Preview's): the first pixel of each 2 x 2 block has
    the full pass's V (the same bits: its own stream); another pixel of the
    block on the same object with a near normal has that V, one on another
    object (or whose block starts on empty sky) its own full-pass V. A step
    that does not divide the tile is an error."""
    from synthetic import box
    tris = quad(-10, 10, -10, 10, 0.0) + box(-0.7, 0.45, -0.3, 0.8, 0.0, 1.2)
    scene = make_scene(tris, [0, 0] + [1] * 12, [area_light(1.5, z=4.0)], res=62,
                       camera=persp_camera((0.5, -4.0, 3.5), (0.0, 0.0, 0.3)), names=("ground", "box"))
    full, fb = run_pcf(scene, pixel_step=1)
    step, _ = run_pcf(scene, pixel_step=2, step_fill="copy")
    a, b = full.passes["pcf"], step.passes["pcf"]
    g = fb.gbuffer
    np.testing.assert_array_equal(b[::2, ::2], a[::2, ::2])
    rows, cols = np.nonzero(g.hit)
    r0, c0 = rows - rows % 2, cols - cols % 2
    shared = g.hit[r0, c0] & (g.object_id[rows, cols] == g.object_id[r0, c0]) & (
        np.sum(g.normal[rows, cols] * g.normal[r0, c0], axis=1) >= 0.95)
    np.testing.assert_array_equal(b[rows[shared], cols[shared]], a[r0[shared], c0[shared]])
    np.testing.assert_array_equal(b[rows[~shared], cols[~shared]], a[rows[~shared], cols[~shared]])
    assert (~shared).sum() > 20 and ((rows % 2 + cols % 2) > 0)[shared].sum() > 1000
    assert ((a > 0.0) & (a < 1.0)).sum() > 200            # a shadow with a penumbra
    with pytest.raises(ValueError, match="pixel_step"):
        run_pcf(scene, pixel_step=3)


def _anchor_blend(a, g, step, tol, slope):
    """NumPy's account of step_fill="interpolate" over the pixel-centre pass
    ``a`` (every pixel filtered): per pixel, whether its anchors (the
    non-zero bilinear weights at ``step`` spacing) on its surface are at
    least 2 holding at least half the weight and span at most ``tol``, and
    their renormalised blend."""
    H, W = a.shape
    r, c = np.mgrid[0:H, 0:W]
    r0, c0 = r - r % step, c - c % step
    fr, fc = (r - r0) / step, (c - c0) / step
    r1, c1 = np.where(r > r0, r0 + step, r0), np.where(c > c0, c0 + step, c0)
    ok = g.hit & ((r % step + c % step) > 0) & (r1 < H) & (c1 < W)
    r1, c1 = np.minimum(r1, H - 1), np.minimum(c1, W - 1)
    lo, hi, blend = np.full(a.shape, np.inf), np.full(a.shape, -np.inf), np.zeros(a.shape)
    wsum, count = np.zeros(a.shape), np.zeros(a.shape, int)
    for rr, cc, wgt in ((r0, c0, (1 - fr) * (1 - fc)), (r0, c1, (1 - fr) * fc),
                        (r1, c0, fr * (1 - fc)), (r1, c1, fr * fc)):
        d = g.position - g.position[rr, cc]
        off = np.abs(np.sum(d * g.normal[rr, cc], axis=-1))
        same = (g.hit[rr, cc] & (g.object_id == g.object_id[rr, cc])
                & (np.sum(g.normal * g.normal[rr, cc], axis=-1) >= 0.95)
                & (off <= slope * np.linalg.norm(d, axis=-1)))
        used = (wgt > 0) & same
        v = a[rr, cc].astype(np.float64)
        lo = np.where(used, np.minimum(lo, v), lo)
        hi = np.where(used, np.maximum(hi, v), hi)
        blend += np.where(used, wgt * v, 0.0)
        wsum += np.where(used, wgt, 0.0)
        count += used
    ok &= (count >= 2) & (wsum >= 0.5)
    blend = blend / np.where(ok, wsum, 1.0)
    ok &= (hi - lo <= tol) & ((hi == lo) | ((lo > 0.0) & (hi < 1.0)))
    return ok, blend, ok & (wsum < 1.0 - 1e-9)


def _levels_blend(a, g, step, tol, slope):
    """NumPy's account of the levels (``step_levels``): the anchors (row
    and column multiples of ``step``) keep ``a``; then for s = step / 2,
    ..., 1 the pixels of the s-lattice off the 2s-lattice take the blend of
    their 2s-lattice anchors in the image so far where ``_anchor_blend``
    allows, else their own ``a``. Returns (the image, interpolated mask,
    mask of those blended from part of their anchors: beside a silhouette)."""
    H, W = a.shape
    r, c = np.mgrid[0:H, 0:W]
    img = a.astype(np.float64).copy()
    interp = np.zeros(a.shape, bool)
    part = np.zeros(a.shape, bool)
    s = step // 2
    while s >= 1:
        level = (r % s == 0) & (c % s == 0) & ~((r % (2 * s) == 0) & (c % (2 * s) == 0))
        ok, blend, some = _anchor_blend(img, g, 2 * s, tol, slope)
        take = level & ok
        img[take] = blend[take]
        interp |= take
        part |= level & some
        s //= 2
    return img, interp, part


def test_pixel_step_interpolates_between_anchors_on_their_surface_only():
    """The render's default (issue 15): step_fill="interpolate", pixel_step 0:
    2, and 4 from 1280 pixels across (``auto_pixel_step``), in levels
    (``step_levels``: 4, 2, 1). Anchors (row and column multiples of 4)
    keep the every-pixel pass's V bit for bit; a pixel of a finer level
    whose anchors on the coarser one lie on its surface (object, normal,
    tangent plane; at least 2 holding half the weight, renormalised) and
    span at most step_tolerance is their bilinear blend; every other pixel
    (an object's silhouette, a shadow edge sharper than the tolerance) has
    its own every-pixel V. pixel_step=2 is the one level of the same rule.
    The interpolated pass is no further from embree's than the every-pixel
    one."""
    from synthetic import box
    from penumbra.core.methods.pcf.anchors import PIXEL_STEP_SLOPE, auto_pixel_step, step_levels
    tris = quad(-10, 10, -10, 10, 0.0) + box(-0.7, 0.45, -0.3, 0.8, 0.0, 1.2)
    scene = make_scene(tris, [0, 0] + [1] * 12, [area_light(1.5, z=4.0)], res=62,
                       camera=persp_camera((0.5, -4.0, 3.5), (0.0, 0.0, 0.3)), names=("ground", "box"))
    full, fb = run_pcf(scene, pixel_step=1)
    step, _ = run_pcf(scene, pixel_step=4)
    two, _ = run_pcf(scene)
    assert PCFParams().pixel_step == 0 and PCFParams().step_fill == "interpolate"
    assert auto_pixel_step(62, 62) == 2 and auto_pixel_step(1279, 719) == 2
    assert auto_pixel_step(1280, 720) == 4 and auto_pixel_step(1920, 1080) == 4
    assert step_levels(4, True) == [4, 2, 1] and step_levels(4, False) == [0] and step_levels(1, True) == [0]
    a, b = full.passes["pcf"], step.passes["pcf"]
    g = fb.gbuffer
    np.testing.assert_array_equal(b[::4, ::4], a[::4, ::4])
    tol = PCFParams().step_tolerance
    for got, st in ((b, 4), (two.passes["pcf"], 2)):
        want, interp, _ = _levels_blend(a, g, st, tol, PIXEL_STEP_SLOPE)
        np.testing.assert_allclose(got[interp], want[interp], atol=1e-6)
        np.testing.assert_array_equal(got[~interp], a[~interp])
    want, interp, part = _levels_blend(a, g, 4, tol, PIXEL_STEP_SLOPE)
    rr, cc = np.mgrid[0:62, 0:62]
    coarse = (rr % 2 == 0) & (cc % 2 == 0) & ~((rr % 4 == 0) & (cc % 4 == 0))
    assert interp.sum() > 1500 and (interp & coarse).sum() > 200       # both levels blend
    assert part.sum() > 10                 # beside the box's silhouette: the anchors on the pixel's side
    assert ((~interp) & g.hit & (((rr % 4) + (cc % 4)) > 0)).sum() > 20
    # a shadow edge the tolerance keeps: pixels between anchors whose V differs by more than it
    edge = g.hit & ~interp & (a > 0.0) & (a < 1.0)
    assert edge.sum() > 10
    emb = producer_of("embree")
    ref = emb.run(fb, scene.lights[0], emb.make_params({"samples": 1024})).passes["embree"]
    m = g.hit
    assert _rmse(b[m], ref[m]) <= _rmse(a[m], ref[m]) + 0.002
    with pytest.raises(ValueError, match="step_fill"):
        run_pcf(scene, step_fill="nearest")
