"""Passes filtered like the render (``core/pixel_filter.py``,
``core/filtered_frame.py``): the filters against Cycles' own definitions,
a silhouette edge against the filter's integral, the pixel-centre pass kept
away from edges, the resolve against its formula."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from penumbra.core import filtered_frame, raycast
from penumbra.core import methods as registry
from penumbra.core.filtered_frame import render_filtered
from penumbra.core.frame import render_frame
from penumbra.core.pixel_filter import (DEPTH_JUMP, NORMAL_COS, PixelFilter, PixelFilterError, footprint_samples,
                                        from_render_settings, parse, refine_mask, resolve_pass)
from penumbra.core.scene import ObjectInfo, Scene
from helpers import rmse
from synthetic import area_light, box, make_scene, persp_camera, quad, sun_light, top_ortho_camera


# Cycles' intern/cycles/scene/film.cpp, transcribed: the functions and the
# width each is called with (filter_table: Gaussian width*3, Blackman-Harris width*2;
# the table spans [0, width/2]).
def cycles_gaussian(v, width):
    v = v * 6.0 / width
    return math.exp(-2.0 * v * v)


def cycles_blackman_harris(v, width):
    v = 2 * math.pi * (v / width + 0.5)
    return 0.35875 - 0.48829 * math.cos(v) + 0.14128 * math.cos(2 * v) - 0.01168 * math.cos(3 * v)


@pytest.mark.parametrize("w", [0.5, 1.0, 1.5, 3.0])
def test_filters_are_cycles_own(w):
    g, bh = PixelFilter("gaussian", w), PixelFilter("blackman-harris", w)
    assert g.radius == pytest.approx(3 * w / 2) and bh.radius == pytest.approx(2 * w / 2)
    for v in np.linspace(-0.999, 0.999, 37):
        assert g.profile(v * g.radius) == pytest.approx(cycles_gaussian(v * g.radius, 3 * w), abs=1e-12)
        assert bh.profile(v * bh.radius) == pytest.approx(cycles_blackman_harris(v * bh.radius, 2 * w),
                                                          abs=1e-12)
    assert g.profile(1.01 * g.radius) == 0.0 and bh.profile(1.01 * bh.radius) == 0.0
    assert bh.profile(0.0) == pytest.approx(1.0) and bh.profile(bh.radius) < 1e-4   # the window's ends
    # Gaussian: sigma = w / 4
    assert g.profile(w / 4) == pytest.approx(math.exp(-0.5))


def test_taps_are_the_separable_filter_normalised_over_the_footprint():
    f = PixelFilter("blackman-harris", 1.5, grid=4)
    m0, k = f.taps()
    assert k.shape == (12, 12) and m0 == -4          # 3 px of footprint at 4 samples per pixel
    d = (np.arange(m0, m0 + 12) + 0.5) / 4 - 0.5
    assert np.allclose(k, np.outer(f.profile(d), f.profile(d)))
    assert np.allclose(k, k.T) and np.allclose(k, k[::-1, ::-1])
    box = PixelFilter("box", 1.0, grid=4)
    m0, k = box.taps()
    assert m0 == 0 and k.shape == (4, 4) and np.all(k == 1.0)   # exactly the pixel's own samples
    assert PixelFilter("gaussian", 0.01).taps()[1].size == 0     # narrower than a sub-sample: the centre


def test_render_settings_and_specs():
    assert from_render_settings("CYCLES", "BLACKMAN_HARRIS", 1.5, 1.5) == PixelFilter("blackman-harris", 1.5)
    assert from_render_settings("CYCLES", "BOX", 0.01, 1.5) == PixelFilter("box", 1.0)   # Cycles ignores it
    assert from_render_settings("BLENDER_EEVEE_NEXT", "GAUSSIAN", 1.0, 2.0) == PixelFilter("eevee", 2.0)
    assert from_render_settings("BLENDER_EEVEE", "GAUSSIAN", 1.0, 2.0, 64) == PixelFilter("eevee", 2.0)
    # EEVEE's film: radius 0 at one render sample, whatever the filter size
    assert from_render_settings("BLENDER_EEVEE", "GAUSSIAN", 1.0, 2.0, 1).is_none
    assert from_render_settings("BLENDER_EEVEE", "GAUSSIAN", 1.0, 0.0, 64).is_none
    assert parse("none").is_none
    assert parse("Gaussian:0.75") == PixelFilter("gaussian", 0.75)
    assert parse("blackman-harris:1.5:8") == PixelFilter("blackman-harris", 1.5, grid=8)
    assert parse("scene", PixelFilter("box", 1.0)) == PixelFilter("box", 1.0)
    for bad in ("", "lanczos:2", "gaussian", "gaussian:", "gaussian:-1", "gaussian:nan", "box:1:0",
                "box:1:99", "box:1:2:3"):
        with pytest.raises(PixelFilterError):
            parse(bad, PixelFilter())
    with pytest.raises(PixelFilterError):
        parse("scene")


def test_resolve_is_the_weighted_ratio():
    """Refined pixels: sum w E0 V / sum w E0 over the in-image footprint, by brute force."""
    rng = np.random.default_rng(3)
    f = PixelFilter("gaussian", 1.0, grid=2)
    H, W, s = 5, 6, 2
    sub = rng.random((H * s, W * s))
    e0 = rng.random((H * s, W * s)) * (rng.random((H * s, W * s)) > 0.2)
    centre = rng.random((H, W))
    refine = rng.random((H, W)) > 0.4
    out = resolve_pass(f, refine, centre, sub, e0)
    ys, xs = (np.arange(H * s) + 0.5) / s, (np.arange(W * s) + 0.5) / s
    for r in range(H):
        for c in range(W):
            if not refine[r, c]:
                assert out[r, c] == np.float32(centre[r, c])
                continue
            w = f.weight(xs[None, :] - c - 0.5, ys[:, None] - r - 0.5) * e0
            want = (w * sub).sum() / w.sum() if w.sum() > 0 else 1.0
            assert out[r, c] == pytest.approx(want, abs=1e-6)


def test_subpixel_gbuffer_is_the_supersampled_view_bit_for_bit():
    sc = _edge_scene(16)
    W, H = 64, 64
    full = raycast.camera_gbuffer(sc, W, H)
    rows, cols = np.nonzero(np.ones((H, W), bool))
    part = raycast.camera_gbuffer_at(sc, W, H, cols[::3], rows[::3])
    sel = np.zeros(H * W, bool)
    sel[::3] = True
    sel = sel.reshape(H, W)
    for name in ("position", "normal", "depth", "object_id", "triangle_id", "hit"):
        a, b = getattr(full, name), getattr(part, name)
        assert np.array_equal(a[sel], b[sel]), name
    assert not part.hit[~sel].any()


RES, HALF = 32, 2.0
EDGE_PX = 18.25           # the silhouette's pixel coordinate: on a sub-sample boundary for grid 4


def _edge_scene(res=RES, ground=True):
    """Looking straight down: a plate (z = 0.2) over x < edge, in the shadow
    of a roof the camera does not see; the ground (z = 0) beyond the edge is
    lit by a vertical sun. The camera sees a straight silhouette between a
    shadowed plate (V = 0) and a lit plane (V = 1)."""
    edge = EDGE_PX * 2 * HALF / RES - HALF
    tris = quad(-10, edge, -10, 10, 0.2) + quad(-10, edge, -10, 10, 1.0)
    ids = [1, 1, 2, 2]
    if ground:
        tris = quad(-10, 10, -10, 10, 0.0) + tris
        ids = [0, 0] + ids
    objs = [ObjectInfo("ground", 0), ObjectInfo("plate", 1), ObjectInfo("roof", 2, visible_camera=False)]
    return Scene(np.array(tris, np.float32), np.array(ids), objs, top_ortho_camera(HALF, height=0.5),
                 [sun_light(0.0)], (res, res))


def _edge_integral(f: PixelFilter, col: int, inside_right: bool) -> float:
    """The filter's share of the footprint of pixel ``col`` beyond the edge."""
    x = np.linspace(-f.radius, f.radius, 200001)
    p = f.profile(x)
    beyond = (col + 0.5 + x > EDGE_PX) if inside_right else (col + 0.5 + x < EDGE_PX)
    return float((p * beyond).sum() / p.sum())


# the edge lies on a sub-sample boundary, so the grid is a midpoint rule of the smooth
# filter on each side: error O(h^2 f''), within the tolerance at 8 samples per pixel for
# Blackman-Harris 1.5 (not at 4), at 16 for the narrower Gaussian 1.0
@pytest.mark.parametrize("flt", [PixelFilter("blackman-harris", 1.5, grid=8),
                                 PixelFilter("gaussian", 1.0, grid=16),   # sigma 1/4 px: a finer grid
                                 PixelFilter("box", 1.0)])
def test_silhouette_edge_gives_the_filter_integral(flt):
    sc = _edge_scene()
    res = render_filtered(sc, ["embree", "embree_irr", "pcf"], overrides={"samples": 4}, pixel_filter=flt)
    lr = res.lights[0]
    cols = range(int(EDGE_PX - flt.radius) - 1, int(EDGE_PX + flt.radius) + 2)
    for c in cols:
        want = _edge_integral(flt, c, True)
        for pid in ("embree", "embree_irr"):
            assert lr.passes[pid][:, c] == pytest.approx(want, abs=2e-3), (pid, c)
    assert np.all(res.coverage == 1.0)
    rec = lr.record["embree_irr"]["pixel_filter"]
    assert rec["type"] == flt.kind and rec["refined_pixels"] > 0 and rec["subpixel_receivers"] > 0
    assert "subpixel" in lr.record["embree_irr"]["time_s"]


def test_coverage_is_the_filter_integral_over_the_surface():
    flt = PixelFilter("blackman-harris", 1.5, grid=8)
    res = render_filtered(_edge_scene(ground=False), ["embree"], overrides={"samples": 1}, pixel_filter=flt)
    for c in range(14, 23):
        assert res.coverage[:, c] == pytest.approx(_edge_integral(flt, c, False), abs=2e-3), c
    assert np.all(res.lights[0].passes["embree"][:, 20:] == 1.0)      # the world: V = 1


def test_filtered_and_pixel_centre_passes_agree_away_from_edges():
    sc = _edge_scene()
    passes = ["embree", "embree_irr", "pcf", "penumbra_casting"]
    centre = render_frame(sc, passes, overrides={"samples": 4}).lights[0].passes
    flt = PixelFilter("blackman-harris", 1.5)
    filtered = render_filtered(sc, passes, overrides={"samples": 4}, pixel_filter=flt).lights[0].passes
    far = np.abs(np.arange(RES) + 0.5 - EDGE_PX) > flt.radius + 1
    for pid in passes:
        assert np.array_equal(filtered[pid][:, far], centre[pid][:, far]), pid
        assert not np.array_equal(filtered[pid], centre[pid]), pid      # the edge was filtered


def test_none_is_the_pixel_centre_pass():
    sc = _edge_scene()
    a = render_frame(sc, ["embree", "embree_irr", "pcf"], overrides={"samples": 4})
    b = render_filtered(sc, ["embree", "embree_irr", "pcf"], overrides={"samples": 4}, pixel_filter=parse("none"))
    assert b.coverage is None and b.pixel_filter is None
    for pid in ("embree", "embree_irr", "pcf"):
        assert np.array_equal(a.lights[0].passes[pid], b.lights[0].passes[pid])


def test_footprint_samples_are_the_union_of_the_refined_footprints():
    rng = np.random.default_rng(1)
    for flt in (PixelFilter("blackman-harris", 1.5), PixelFilter("box", 1.0), PixelFilter("gaussian", 1.0, grid=3)):
        H, W, s = 7, 9, flt.grid
        refine = rng.random((H, W)) > 0.8
        m0, taps = flt.taps()
        k = taps.shape[0]
        want = np.zeros((s * H, s * W), bool)
        for r, c in zip(*np.nonzero(refine)):
            I = np.clip(np.arange(s * r + m0, s * r + m0 + k), 0, s * H - 1)
            J = np.clip(np.arange(s * c + m0, s * c + m0 + k), 0, s * W - 1)
            want[np.ix_(I, J)] = True
        rows, cols = footprint_samples(refine, s, m0, k)
        wr, wc = np.nonzero(want)
        assert np.array_equal(rows, wr) and np.array_equal(cols, wc), flt
        # pixels refined for V alone read the lattice's sub-rows and sub-columns of their own pixel
        full = refine & (rng.random((H, W)) > 0.5)
        for shade in (1, 2, s):
            lattice = dataclasses.replace(flt, shade_grid=shade).shade_lattice
            want = np.zeros((s * H, s * W), bool)
            for r, c in zip(*np.nonzero(refine)):
                if full[r, c]:
                    I = np.arange(s * r + m0, s * r + m0 + k)
                    J = np.arange(s * c + m0, s * c + m0 + k)
                else:
                    I, J = np.arange(s * r, s * r + s), np.arange(s * c, s * c + s)
                I, J = I[(I >= 0) & (I < s * H)], J[(J >= 0) & (J < s * W)]
                if not full[r, c]:
                    I, J = I[lattice[I % s]], J[lattice[J % s]]
                want[np.ix_(I, J)] = True
            rows, cols = footprint_samples(refine, s, m0, k, full, lattice)
            wr, wc = np.nonzero(want)
            assert np.array_equal(rows, wr) and np.array_equal(cols, wc), (flt, shade)


def test_reach_is_where_the_filter_tail_ends():
    """An edge further than ``reach`` pixel centres carries at most ``edge_tail``
    of the filter; ``edge_tail`` 0 reaches over the whole footprint."""
    for flt in (PixelFilter("blackman-harris", 1.5), PixelFilter("gaussian", 1.5), PixelFilter("box", 1.0),
                PixelFilter("blackman-harris", 2.0), PixelFilter("eevee", 1.5)):
        n = flt.reach
        x = np.linspace(0.0, flt.radius, 200001)
        p = np.exp(-0.5 * (x / (0.284 * flt.width)) ** 2) if flt.kind == "eevee" else flt.profile(x)
        assert (p[x > n].sum() / (2 * p.sum())) <= flt.edge_tail + 1e-4, flt
        if n > 1:
            assert p[x > n - 1].sum() / (2 * p.sum()) > flt.edge_tail, flt      # the smallest such n
        assert dataclasses.replace(flt, edge_tail=0.0).reach >= flt.radius
    assert PixelFilter("blackman-harris", 1.5).reach == 1 and PixelFilter("blackman-harris", 2.0).reach == 2


def _refined(values, threshold=0.02, reach=1):
    H, W = values.shape
    out, full = np.zeros((H, W), bool), np.ones((H, W), bool)
    refine_mask(np.ones((H, W), bool), np.zeros((H, W), np.int32), np.ones((H, W), np.float32),
                np.tile(np.array([0, 0, 1], np.float32), (H, W, 1)), values[None].astype(np.float32), reach,
                threshold, DEPTH_JUMP, NORMAL_COS, out, np.inf, full, 0.02)
    assert not full.any()                                  # one surface, no sharp edge: the shade grid
    return out


def test_curvature_test_refines_kinks_and_jumps_not_ramps():
    x = np.arange(24, dtype=np.float64)
    ramp = np.tile(0.04 * x, (6, 1))                       # a penumbra crossing 0.04 per pixel
    assert not _refined(ramp).any()                        # integrated exactly by the centre sample
    kink = np.tile(np.clip(0.1 * (x - 12), 0.0, 1.0), (6, 1))
    assert np.array_equal(np.nonzero(_refined(kink)[0])[0], [12, 22])          # where the slope changes
    jump = np.tile((x >= 12).astype(float), (6, 1))
    assert np.array_equal(np.nonzero(_refined(jump)[0])[0], [11, 12])          # both sides of the step


def _box_scene(res=40):
    """A box over a lit ground under an area light, seen from above at an
    angle: silhouettes, a crease and a soft shadow."""
    tris = quad(-3, 3, -3, 3, 0.0) + box(-0.5, 0.5, -0.5, 0.5, 0.4, 0.9)
    return make_scene(tris, [0, 0] + [1] * 12, [area_light(1.5, z=3.0)], res=res,
                      camera=persp_camera((2.0, -2.5, 3.0), (0.0, 0.0, 0.3)))


@pytest.mark.parametrize("visibility", ["irradiance", "average"])
def test_adaptive_pass_is_the_full_supersampled_pass(visibility):
    """The adaptive pass against 16 sub-pixel samples in every pixel (every
    pixel refined), each sub-pixel receiver with its share of the light
    samples: refining only where a footprint holds an edge adds at most
    0.005 RMSE over the covered pixels to the full pass's error, both
    against the full pass converged (16x the light samples)."""
    sc = _box_scene()
    flt = PixelFilter("blackman-harris", 1.5)
    everywhere = dataclasses.replace(flt, threshold=-1.0)
    passes = ["pcf", "penumbra_casting"]
    over = {"visibility": visibility}
    adaptive = render_filtered(sc, passes, pixel_filter=flt, overrides=over)
    full = render_filtered(sc, passes, pixel_filter=everywhere, overrides=over)
    converged = render_filtered(sc, passes, pixel_filter=everywhere, overrides=over, method_overrides={
        "pcf": {"BlockerSamples": 256, "PenumbraSamples": 1024}, "penumbra_casting": {"samples": 4096}})
    cov = full.coverage > 0
    st = adaptive.lights[0].record["pcf"]["pixel_filter"]
    assert 0 < st["refined_pixels"] < 0.8 * sc.resolution[0] * sc.resolution[1]
    assert full.lights[0].record["pcf"]["pixel_filter"]["refined_pixels"] == sc.resolution[0] * sc.resolution[1]
    for pid in passes:
        a, b, t = (r.lights[0].passes[pid] for r in (adaptive, full, converged))
        assert rmse(a, t, cov) <= rmse(b, t, cov) + 0.005, pid
        assert not np.array_equal(a, render_frame(sc, [pid], overrides=over).lights[0].passes[pid]), pid
    assert np.array_equal(adaptive.coverage[~cov], full.coverage[~cov])


PACKED = ["pcf", "embree", "penumbra_casting", "irregular", "layered", "depth_raytrace", "single_sample"]


def test_packed_receivers_give_the_supersampled_image_pass(monkeypatch):
    """Every method on the packed sub-pixel receivers (pcf's footprint and
    every seed at each receiver's own sub-pixel; layered's LDI and
    depth_raytrace's reference maps those of the pixel-centre stage) is the
    method on the supersampled image, bit for bit (single_sample without its
    adaptive image walk, which a packed list cannot take; pcf's
    ``pixel_step`` anchors and blends found among the listed receivers as
    in the image)."""
    sc = _box_scene(24)
    flt = PixelFilter("blackman-harris", 1.5)
    producers = registry.producers()
    assert {mid for mid, m in producers.items() if m.packed} == set(PACKED)
    opts = dict(overrides={"samples": 16}, method_overrides={"single_sample": {"adaptive": False}})
    packed = render_filtered(sc, PACKED, pixel_filter=flt, **opts)
    for m in producers.values():
        monkeypatch.setattr(m, "packed", False)
    dense = render_filtered(sc, PACKED, pixel_filter=flt, **opts)
    for pid in PACKED:
        assert np.array_equal(packed.lights[0].passes[pid], dense.lights[0].passes[pid]), pid
        assert packed.lights[0].record[pid]["pixel_filter"]["subpixel_samples"] > 0, pid
    assert np.array_equal(packed.coverage, dense.coverage)


def test_object_edges_and_hard_shadow_edges_get_the_full_grid():
    """refine_mask's ``full``: pixels beside another object (where V differs
    across it by more than ``geo_v``: an edge V does not see changes no
    filtered pass), or at a jump of V beyond ``sharp``, get the full
    sub-pixel grid; pixels flagged only for V's mild kinks (a soft
    penumbra's ends, noise) get the ``shade_grid`` lattice."""
    H, W = 5, 24
    obj = np.zeros((H, W), np.int32)
    obj[:, 20:] = 1
    x = np.arange(W, dtype=np.float32)
    v = np.clip(0.15 * (x - 4), 0.0, 0.6)                  # kinks of 0.15 at columns 4 and 8
    v[12:] = 0.0                                           # a hard edge: a jump of 0.6
    values = np.tile(v, (H, 1))[None].astype(np.float32)
    def mask(values, geo_v):
        out, full = np.zeros((H, W), bool), np.zeros((H, W), bool)
        refine_mask(np.ones((H, W), bool), obj, np.ones((H, W), np.float32),
                    np.tile(np.array([0, 0, 1], np.float32), (H, W, 1)), values, 1, 0.1, DEPTH_JUMP,
                    NORMAL_COS, out, 0.3, full, geo_v)
        return np.nonzero(out[2])[0].tolist(), np.nonzero(full[2])[0].tolist()
    # V = 0 on both sides of the object edge at 19 | 20: not refined
    assert mask(values, 0.02) == ([4, 8, 11, 12], [11, 12])
    lit = values.copy()
    lit[..., 20:] = 0.05                                   # V differs across the object edge (by less
                                                           # than the threshold: only geo_v sees it)
    assert mask(lit, 0.02) == ([4, 8, 11, 12, 19, 20], [11, 12, 19, 20])
    # the lattice: shade_grid sub-rows of the grid, symmetric about the pixel centre (its
    # samples' centroid is the centre: a linear V is integrated exactly)
    for grid, shade, want in ((4, 2, [1, 2]), (8, 2, [2, 5]), (8, 4, [1, 3, 4, 6]), (9, 3, [1, 4, 7]),
                              (4, 4, [0, 1, 2, 3]), (4, 3, [0, 1, 2, 3])):
        lat = PixelFilter("blackman-harris", 1.5, grid=grid, shade_grid=shade).shade_lattice
        assert np.flatnonzero(lat).tolist() == want, (grid, shade)
        offsets = (np.flatnonzero(lat) + 0.5) / grid - 0.5
        assert abs(offsets.sum()) < 1e-12


def test_each_light_and_method_gets_its_own_sub_pixel_samples():
    """Two lights whose penumbrae fall on different sides of a box: each
    light's method is refined where the geometry and its own passes need it,
    so its filtered pass is the one it gets when it is filtered alone (one
    light, one method), bit for bit (the sub-pixel receivers draw their
    samples by their own sub-pixel), and the JSON's counts are its own."""
    from synthetic import light_matrix
    west = dataclasses.replace(area_light(1.2, z=3.0, name="West"), world_from_light=light_matrix((-2.0, 0, 3.0)))
    east = dataclasses.replace(area_light(0.4, z=3.0, name="East"), world_from_light=light_matrix((2.0, 0, 3.0)))
    tris = quad(-3, 3, -3, 3, 0.0) + box(-0.5, 0.5, -0.5, 0.5, 0.4, 0.9)
    sc = make_scene(tris, [0, 0] + [1] * 12, [west, east], res=40,
                    camera=persp_camera((0.0, -3.0, 4.0), (0.0, 0.0, 0.3)))
    flt = PixelFilter("blackman-harris", 1.5)
    passes = ["pcf", "embree", "embree_irr"]
    both = render_filtered(sc, passes, overrides={"samples": 16}, pixel_filter=flt)
    stats = {}
    for lr in both.lights:
        for group in (["pcf"], ["embree", "embree_irr"]):
            alone = render_filtered(sc, group, [lr.name], overrides={"samples": 16}, pixel_filter=flt).lights[0]
            for pid in group:
                assert np.array_equal(lr.passes[pid], alone.passes[pid]), (lr.name, pid)
                assert lr.record[pid]["pixel_filter"] == alone.record[pid]["pixel_filter"], (lr.name, pid)
        stats[lr.name] = lr.record["pcf"]["pixel_filter"]
        assert stats[lr.name] != lr.record["embree"]["pixel_filter"]      # refined by its own V
    w, e = stats["West"], stats["East"]
    assert w["subpixel_samples"] != e["subpixel_samples"]
    geometry_only = render_filtered(sc, ["pcf"], ["West"], overrides={"samples": 16},
                                    pixel_filter=dataclasses.replace(flt, threshold=2.0)).lights[0]
    assert min(w["refined_pixels"], e["refined_pixels"]) > geometry_only.record["pcf"]["pixel_filter"]["refined_pixels"]


def test_hit_edges_are_the_full_grid_pixels_of_a_change_of_hit():
    """The coverage reads the pixels beside a change of hit: exactly those
    ``refine_mask`` puts on the full grid for one flat surface, whatever the
    producer's V (so every producer's list holds their whole footprints)."""
    rng = np.random.default_rng(3)
    for reach in (1, 2):
        H, W = 9, 13
        hit = rng.random((H, W)) > 0.4
        out, full = np.zeros((H, W), bool), np.zeros((H, W), bool)
        refine_mask(hit, np.zeros((H, W), np.int32), np.ones((H, W), np.float32),
                    np.tile(np.array([0, 0, 1], np.float32), (H, W, 1)),
                    rng.random((1, H, W)).astype(np.float32), reach, 0.1, DEPTH_JUMP, NORMAL_COS, out,
                    0.2, full, 0.02)
        edges = filtered_frame.hit_edges(hit, reach)
        assert np.array_equal(edges, full & _hit_change(hit, reach)) and np.array_equal(edges, _hit_change(hit, reach))


def _hit_change(hit, reach):
    H, W = hit.shape
    out = np.zeros_like(hit)
    for r in range(H):
        for c in range(W):
            win = hit[max(0, r - reach):r + reach + 1, max(0, c - reach):c + reach + 1]
            out[r, c] = (win != hit[r, c]).any()
    return out


def test_a_filtered_pass_does_not_depend_on_what_else_the_frame_computes():
    """A producer's sub-pixel receivers come from every pass it computes, not
    from the passes asked for: ``embree_irr`` alone and beside ``embree``
    and other methods are the same bits (leaves whose refined pixels differ
    between the average and the irradiance pass)."""
    from synthetic import leaf_cloud_scene
    sc = leaf_cloud_scene(res=64)
    flt = PixelFilter("blackman-harris", 1.5)
    alone = render_filtered(sc, ["embree_irr"], pixel_filter=flt, overrides={"samples": 16})
    with_others = render_filtered(sc, ["embree", "embree_irr", "pcf", "irregular"], pixel_filter=flt,
                                  overrides={"samples": 16})
    a, b = (r.lights[0].record["embree_irr"]["pixel_filter"] for r in (alone, with_others))
    assert a["refined_pixels"] == b["refined_pixels"] > 0
    np.testing.assert_array_equal(alone.lights[0].passes["embree_irr"], with_others.lights[0].passes["embree_irr"])
