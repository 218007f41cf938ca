"""pcf's kernels against closed forms and brute force: figure 4's samples,
the light's reach, the receiver's plane and its division-free form, the
camera's ray terms and pixel footprint, the tile tables, planes and test,
and the blocker search region."""
import numpy as np
import pytest

from penumbra.core import views
from penumbra.core.kernels import face_project, finite_bbox
from penumbra.core.methods.pcf.footprint import pixel_footprint, pixel_ray_terms
from penumbra.core.methods.pcf.light_region import light_halfwidth, light_reach, search_region
from penumbra.core.methods.pcf.receiver import DEPTH_REL_EPS, NO_PLANE, _receiver_form, plane_depth
from penumbra.core.methods.pcf.samples import sample_shadow
from penumbra.core.methods.pcf.tiles import (TILE, _texel_box, region_decided, tile_minmax, tile_planes, tile_range,
                                            tile_tables)
from penumbra.core.methods.pcf.weight import NO_WEIGHTS

from helpers import buffers_of
from synthetic import area_light, half_plane_scene, make_scene, persp_camera, quad, sphere_light, sun_light


def test_region_outside_map_bbox_is_lit():
    """sample_shadow returns 0 (not in shadow) when the region misses the map's
    bounding box of finite depths, and for points behind the light."""
    depth = np.full((8, 8), np.inf, np.float32)
    depth[2:4, 2:4] = 1.0
    bbox = finite_bbox(depth[None])[0]
    assert list(bbox) == [2, 3, 2, 3]
    assert sample_shadow(depth, bbox, 6.5, 6.5, 5.0, 0.5, 0.5, 16, 1, 0.0, 0.0, 0, 0, NO_PLANE, NO_WEIGHTS) == 0.0
    assert sample_shadow(depth, bbox, 3.0, 3.0, -1.0, 1.0, 1.0, 16, 1, 0.0, 0.0, 0, 0, NO_PLANE, NO_WEIGHTS) == 0.0
    assert sample_shadow(depth, bbox, 3.0, 3.0, 5.0, 0.9, 0.9, 16, 1, 0.0, 0.0, 0, 0, NO_PLANE, NO_WEIGHTS) == 1.0


def test_sample_counts_follow_figure_4():
    """A large region takes about NumSamples samples; a small one at least
    MinSamples per axis: count the distinct outcomes' denominators."""
    depth = np.zeros((64, 64), np.float32)
    bbox = np.array([0, 63, 0, 63])
    # half the map in shadow: fraction is a multiple of 1/(ns nt)
    depth[:, 32:] = 10.0
    f = sample_shadow(depth, bbox, 32.0, 32.0, 5.0, 16.0, 16.0, 16, 2, 0.0, 0.0, 0, 0, NO_PLANE, NO_WEIGHTS)
    assert f == pytest.approx(0.5)
    f1 = sample_shadow(depth, bbox, 20.0, 20.0, 5.0, 0.0, 0.0, 16, 3, 0.0, 0.0, 0, 0, NO_PLANE, NO_WEIGHTS)
    assert f1 == 1.0


def test_light_reach_closed_forms():
    """light_reach: an area light along the view's axes gives its half
    sides over the texel size; a sphere light its radius; a sun tan(half
    angle) on an orthographic face; zero size: zero."""
    for light, half in ((area_light(1.0, size_y=0.5, shape="RECTANGLE"), (0.5, 0.25)),
                        (sphere_light(0.3), (0.3, 0.3)), (sun_light(0.1), (np.tan(0.05),) * 2)):
        fb = buffers_of(half_plane_scene(light, res=16))
        face = fb.light_view(light).faces[0]
        l, r, b, t = face.bounds
        k = light_reach(light, [face])[0]
        np.testing.assert_allclose(k[:2], [half[0] * face.width / (r - l), half[1] * face.height / (t - b)],
                                   rtol=1e-9)
        assert k[2] == (1.0 if face.ortho else 0.0)


@pytest.mark.parametrize("ortho", [False, True])
def test_receiver_form_compares_as_plane_depth(ortho):
    """The sampler's division-free test (``_receiver_form``) says
    "behind" exactly where ``plane_depth`` does, texel by texel, for
    tangent planes of random slopes (perspective and orthographic faces),
    over boxes where the form holds (mode 1 / 2), and falls back (mode 3)
    where ``plane_depth``'s own fallback is reached."""
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
                    form = fk > thr * (fa * u + fb * v + fc) if mode == 2 else fa * u + fb * v + fc > thr
                    assert form == (zs > thr)
                    checked += 1
    assert checked > 1000 and fallback > 10


@pytest.mark.parametrize("camera", [None, persp_camera((0.3, -3.0, 2.5), (0.0, 0.0, 0.0))])
def test_pixel_ray_terms_meet_the_gbuffer_hits(camera):
    """The affine camera rays pcf carries pixel corners along pass, at pixel
    centres, through the G-buffer's hit points on the ground z = 0."""
    scene = make_scene(quad(-20, 20, -20, 20, 0.0), [0, 0], [area_light(1.0)], res=40, camera=camera,
                       names=("ground",))
    fb = buffers_of(scene)
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
    fb = buffers_of(scene)
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
    u, v, _ = face_project(face, p[0], p[1], p[2])
    return u, v


def test_tile_tables_give_the_min_and_max_of_any_block_of_tiles():
    """The tile test's sparse tables: the min / max over any block of tiles
    in four lookups equal a loop over the tiles, on maps of odd sizes with
    empty (+inf) texels, one and several faces; with ``span``, over any
    block of at most that many tiles a side."""
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
