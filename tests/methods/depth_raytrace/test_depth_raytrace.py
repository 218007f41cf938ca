"""Coherence-based ray tracing of depth images (Agrawala et al. 2000, section 5).

Against closed forms (half-plane occluder), against the ``embree`` reference
on the sample scenes (same light samples: the method draws the reference's
stratified jitter, so the difference is the depth-image approximation, not
Monte Carlo noise), the ablation switches, the coherent sampler's invariants
and the hard cases of DESIGN.md.
"""
import math

import numba
import numpy as np
import pytest

from penumbra.core import raycast, views
from penumbra.core.buffers import FrameBuffers
from penumbra.core.frame import render_frame
from penumbra.core.methods import producer_of
from penumbra.core.methods.depth_raytrace import DepthRaytraceParams, resolve_map_size
from penumbra.core.methods.depth_raytrace.benchmark import benchmark_table, format_table
from penumbra.core.methods.depth_raytrace.coherence import inv_concentric, project_to_light
from penumbra.core.methods.depth_raytrace.maps import FP_FOOT, build_reference_maps, fit_points, reference_eyes
from penumbra.core.methods.depth_raytrace.window import cone_envelope
from penumbra.core.metrics import errors, reach_mask
from penumbra.core.sampling import concentric_disk, light_sample, pack_light
from penumbra.core.scene import Camera, Light, ObjectInfo, Scene
from helpers import buffers_of, embree_pass, in_range, rmse, run_method
from synthetic import (area_light, box, half_plane_scene, light_matrix, pixel_world_y, quad, sphere_light,
                       sun_light, sun_pillars_scene, top_ortho_camera)

HL, HO = 4.0, 2.0     # light and occluder heights of half_plane_scene


def run(scene, fb=None, **over):
    """``depth_raytrace``'s MethodResult for the scene's light on ``fb`` (or
    the scene's own buffers), and the buffers."""
    fb = fb or buffers_of(scene)
    return run_method("depth_raytrace", fb, scene.lights[0], **over), fb


def run_embree(fb, light, samples):
    """The reference's MethodResult (both passes, ``embree`` and ``embree_irr``)."""
    return run_method("embree", fb, light, samples=samples)


# ---------------------------------------------------------------------------
# registration and the frame pipeline
def test_registered_with_both_passes():
    m = producer_of("depth_raytrace")
    assert m.passes == {"depth_raytrace": "irradiance", "depth_raytrace_irr": "irradiance"}
    assert m.visibility("depth_raytrace", m.make_params({"visibility": "average"})) == "average"
    assert m.visibility("depth_raytrace_irr", m.make_params({"visibility": "average"})) == "irradiance"
    assert producer_of("depth_raytrace_irr") is m
    assert m.physical
    p = m.make_params({"samples": 64, "seed": 3})
    assert p.samples == 64 and p.seed == 3


def test_render_frame_records_error_against_reference():
    scene = half_plane_scene(area_light(1.0), res=32)
    res = render_frame(scene, ["embree", "embree_irr", "depth_raytrace", "depth_raytrace_irr"],
                       overrides={"samples": 16, "visibility": "average"})
    rec = res.lights[0].record
    assert rec["depth_raytrace"]["error"]["reference"] == "embree"
    assert rec["depth_raytrace_irr"]["error"]["reference"] == "embree_irr"
    assert rec["depth_raytrace"]["error"]["rmse"] < 0.02
    st = rec["depth_raytrace"]["stats"]
    assert 0 < st["rays_per_pixel"] <= 16
    t = rec["depth_raytrace"]["time_s"]
    assert "reference_maps" in t and "trace" in t


# ---------------------------------------------------------------------------
# closed forms (tests/synthetic.py: light at height 4, occluder at 2 over y < 0)
def test_square_light_half_plane_closed_form():
    """V(y) = clamp((a/2 + y) / a, 0, 1) for a square light of side a. The
    depth-image answer can differ from the exact one only for rays passing
    within about a texel of the occluder's edge (one texel at the occluder is
    0.016 units here), so the row means stay within 0.02 of the closed form
    (the reference itself is within 0.01)."""
    a = 1.0
    scene = half_plane_scene(area_light(size=a, z=HL), res=64, occluder_z=HO)
    r, fb = run(scene, samples=256)
    v = r.passes["depth_raytrace"]
    ys = pixel_world_y(scene, np.arange(64))
    expect = np.clip((a / 2 + ys) / a, 0, 1)
    assert np.abs(v.mean(axis=1) - expect).max() < 0.02
    assert v[ys > a].min() == 1.0 and v[ys < -a].max() == 0.0
    e = embree_pass(fb, scene.lights[0], 256)
    assert rmse(v, e) < 0.012


def test_disk_light_closed_form():
    """Disk of radius R (4 boundary reference points): the visible fraction
    is the disk segment beyond ly = y (1 - HL/HO)."""
    R = 0.5
    scene = half_plane_scene(area_light(size=2 * R, shape="DISK", z=HL), res=64, occluder_z=HO)
    r, _ = run(scene, samples=256)
    v = r.passes["depth_raytrace"]
    ys = pixel_world_y(scene, np.arange(64))
    d = np.clip(ys * (1 - HL / HO) / R, -1, 1)
    expect = (np.arccos(d) - d * np.sqrt(1 - d * d)) / np.pi
    assert np.abs(v.mean(axis=1) - expect).max() < 0.02


def test_irradiance_pass_closed_form_sun():
    """A sun: V_irr = V_avg up to the cosine weights, and the penumbra width
    on the ground is 2 * HO * tan(angle / 2)."""
    ang = 0.2
    scene = half_plane_scene(sun_light(ang), res=64, occluder_z=HO)
    r, fb = run(scene, samples=256)
    va, vi = r.passes["depth_raytrace"], r.passes["depth_raytrace_irr"]
    ys = pixel_world_y(scene, np.arange(64))
    half = HO * math.tan(ang / 2)
    assert va[ys > half + 0.07].min() == 1.0 and va[ys < -half - 0.07].max() == 0.0
    e = run_embree(fb, scene.lights[0], 256)
    assert rmse(va, e.passes["embree"]) < 0.02
    assert rmse(vi, e.passes["embree_irr"]) < 0.02


def test_zero_size_light_is_the_hard_shadow():
    """A light of size zero: one sample at the centre. Rays from the ground
    graze the occluder edge only within a texel of it, so all but the texel
    row at the edge agree with the single Embree ray."""
    scene = half_plane_scene(area_light(0.0), res=48)
    r, fb = run(scene, samples=256)
    v = r.passes["depth_raytrace"]
    e = embree_pass(fb, scene.lights[0], 1)
    assert set(np.unique(v)) <= {0.0, 1.0}
    assert np.mean(v != e) < 0.03
    assert r.stats["samples"] == 1 and r.stats["reference_eyes"] == 1


# ---------------------------------------------------------------------------
# against the reference on the sample scenes
SAMPLE_CASES = {
    # name: (resolution, map size, RMSE bound for V_avg, for V_irr)
    # Bounds: the method and the reference shoot the same rays, so the
    # difference is the depth images' discretisation (rays passing within
    # about a texel of a silhouette, thin geometry narrower than a texel,
    # surfaces seen edge-on from the light): grids with the paper's 1024^2
    # maps (its 0.07-unit bars are 4 texels wide there), sphere_plane with
    # maps twice the image (the paper's ratio). The bounds sit at the level
    # of the reference's own Monte Carlo noise at 256 samples in a penumbra,
    # what the paper calls "no visible difference".
    "grids": (96, 1024, 0.04, 0.04),
    "sphere_plane": (96, None, 0.02, 0.03),
}


@pytest.fixture(scope="module")
def sample_runs():
    from scenes import load_sample
    out = {}
    for name, (res, ms, _, _) in SAMPLE_CASES.items():
        scene = load_sample(name, (res, res))
        fb = FrameBuffers(scene, res, res)
        light = scene.lights[0]
        e = run_embree(fb, light, 256)
        m = producer_of("depth_raytrace")
        over = {"samples": 256, "visibility": "average"}      # the paper's pass beside the irradiance ratio
        if ms:
            over["map_size"] = ms
        maps = m.build_maps(fb, light, m.make_params(over))
        coh = m.run(fb, light, m.make_params(over), maps=maps)
        nocoh = m.run(fb, light, m.make_params(dict(over, coherence=False)), maps=maps)
        out[name] = dict(fb=fb, light=light, embree=e, coh=coh, nocoh=nocoh,
                         mask=reach_mask(fb.gbuffer, light))
    return out


def test_default_pass_is_the_irradiance_ratio():
    scene = half_plane_scene(area_light(1.0), res=24)
    res = render_frame(scene, ["embree_irr", "depth_raytrace", "depth_raytrace_irr"], overrides={"samples": 16})
    lr = res.lights[0]
    assert np.array_equal(lr.passes["depth_raytrace"], lr.passes["depth_raytrace_irr"])
    assert lr.record["depth_raytrace"]["visibility"] == "irradiance"
    assert lr.record["depth_raytrace"]["error"]["reference"] == "embree_irr"
    avg = render_frame(scene, ["depth_raytrace"], overrides={"samples": 16, "visibility": "average"}).lights[0]
    assert not np.array_equal(avg.passes["depth_raytrace"], lr.passes["depth_raytrace"])


@pytest.mark.parametrize("name", list(SAMPLE_CASES))
def test_matches_embree_reference(sample_runs, name):
    _, _, bound_avg, bound_irr = SAMPLE_CASES[name]
    d = sample_runs[name]
    for res in (d["coh"], d["nocoh"]):
        ea = errors(res.passes["depth_raytrace"], d["embree"].passes["embree"], d["mask"])
        ei = errors(res.passes["depth_raytrace_irr"], d["embree"].passes["embree_irr"], d["mask"])
        assert ea["rmse"] < bound_avg, ea
        assert ei["rmse"] < bound_irr, ei
        assert abs(ea["mean_signed"]) < 0.01, ea      # no systematic darkening / light leaks
        for v in res.passes.values():
            assert in_range(v)
        bg = ~d["fb"].gbuffer.hit
        assert (res.passes["depth_raytrace"][bg] == 1).all()


@pytest.mark.parametrize("name", list(SAMPLE_CASES))
def test_coherence_traces_fewer_rays_and_changes_little(sample_runs, name):
    d = sample_runs[name]
    coh, nocoh = d["coh"], d["nocoh"]
    ref = d["embree"].passes["embree"]
    m = d["mask"]
    assert coh.stats["rays_per_pixel"] < 0.75 * nocoh.stats["rays_per_pixel"]
    assert rmse(coh.passes["depth_raytrace"], nocoh.passes["depth_raytrace"], m) < 0.02
    assert abs(rmse(coh.passes["depth_raytrace"], ref, m) - rmse(nocoh.passes["depth_raytrace"], ref, m)) < 0.005
    assert coh.stats["precompute_s"] >= 0 and coh.stats["trace_s"] > 0


def test_coherent_sampler_driving_embree():
    """The same sampler on real triangles (the paper: a geometric ray tracer
    can use it): close to brute force with fewer rays; without coherence it
    shoots the reference's rays (only rays into the point's own surface,
    which the method settles as blocked without tracing, can differ: at the
    sphere's terminator the reference's offset origin lets a few escape)."""
    from scenes import load_sample
    scene = load_sample("sphere_plane", (64, 64))
    fb = FrameBuffers(scene, 64, 64)
    light = scene.lights[0]
    e = embree_pass(fb, light, 256, pass_id="embree_irr")
    mask = reach_mask(fb.gbuffer, light)
    coh, _ = run(scene, fb, samples=256, tracer="embree")
    plain, _ = run(scene, fb, samples=256, tracer="embree", coherence=False)
    d = plain.passes["depth_raytrace"] - e
    assert np.mean(d[mask] != 0) < 0.02 and rmse(d, 0, mask) < 0.01
    assert rmse(coh.passes["depth_raytrace"], e, mask) < 0.01
    assert coh.stats["rays_per_pixel"] < 0.5 * 256


def test_fully_lit_points_trace_only_the_border_cells():
    """No occluder: every prediction is "unblocked", so only the light's
    border cells (4N - 4 of N x N) are traced, apart from the first point of
    each tile (section 5.2, figure 8)."""
    tris = quad(-10, 10, -10, 10, 0.0)
    scene = Scene(np.array(tris, np.float32), np.zeros(2, np.int32), [ObjectInfo("ground", 0)],
                  top_ortho_camera(2.0), [area_light(1.0)], (32, 32))
    r, _ = run(scene, samples=256, tile=16)
    assert (r.passes["depth_raytrace"] == 1.0).all()
    n_tiles = 4
    expect = (60 * (32 * 32 - n_tiles) + 256 * n_tiles) / (32 * 32)
    assert r.stats["rays_per_pixel"] == pytest.approx(expect)
    # the sampler's own account of where the rays went
    st = r.stats
    assert st["full_trace_points"] == n_tiles
    assert st["full_trace_rays_per_pixel"] == pytest.approx(256 * n_tiles / (32 * 32))
    assert st["predicted_rays_per_pixel"] == pytest.approx(60 * (32 * 32 - n_tiles) / (32 * 32))
    assert st["flood_fill_rays_per_pixel"] == 0 and st["prediction_errors_per_pixel"] == 0
    assert st["blockers_per_pixel"] == 0


def test_sampler_ray_account(sample_runs):
    """Every traced ray was queued exactly once: by a full trace (no
    prediction), by Predict (edge and border cells) or by the flood fill."""
    st = sample_runs["grids"]["coh"].stats
    parts = st["full_trace_rays_per_pixel"] + st["predicted_rays_per_pixel"] + st["flood_fill_rays_per_pixel"]
    assert parts == pytest.approx(st["rays_per_pixel"], rel=1e-12)
    assert 0 < st["prediction_errors_per_pixel"] < st["rays_per_pixel"]
    assert st["flood_fill_rays_per_pixel"] > 0 and st["blockers_per_pixel"] > 0
    assert 1 <= st["full_trace_points"] < st["pixels"]


# ---------------------------------------------------------------------------
# the acceleration switches (sections 5.1.1, 5.1.2)
@pytest.fixture(scope="module")
def ablation():
    from scenes import load_sample
    scene = load_sample("sphere_plane", (64, 64))
    fb = FrameBuffers(scene, 64, 64)
    light = scene.lights[0]
    m = producer_of("depth_raytrace")
    base = {"samples": 64, "coherence": False}
    maps = m.build_maps(fb, light, m.make_params(base))

    def go(**over):
        return m.run(fb, light, m.make_params(dict(base, **over)), maps=maps).passes["depth_raytrace"]
    return go, go(), reach_mask(fb.gbuffer, light), embree_pass(fb, light, 64)


def test_hierarchical_connectedness_is_exact(ablation):
    """A connected node spanned by the epipolar depth interval must be
    crossed: stopping there gives the same verdict as descending."""
    go, full, _, _ = ablation
    np.testing.assert_array_equal(go(hierarchical_connectedness=False), full)
    np.testing.assert_array_equal(go(hierarchical_connectedness=False, occlusion_intervals=False,
                                     clear_miss=False, rank_images=False, minmax_clipping=False),
                                  go(occlusion_intervals=False, clear_miss=False, rank_images=False,
                                     minmax_clipping=False))


def test_minmax_clipping_is_exact(ablation):
    """Clipping only skips parts of the ray in front of / behind every floor
    of a node. Tracing each image whole, the verdicts are identical; with
    occlusion intervals the intervals' end points are computed at other
    places, so a ray exactly at a tie may flip (at most a few rays)."""
    go, full, _, _ = ablation
    whole = dict(occlusion_intervals=False, clear_miss=False)
    np.testing.assert_array_equal(go(minmax_clipping=False, **whole), go(**whole))
    d = np.abs(go(minmax_clipping=False) - full)
    assert d.max() <= 2 / 64 and np.count_nonzero(d) <= 3


def test_image_combination_switches_change_little(ablation):
    """Ranking, the clear miss and occlusion intervals change which reference
    image decides a ray, and the images disagree by up to their
    discretisation (here 128^2 maps: a few per cent of the pixels differ
    between settings). None of them is less accurate: every setting stays
    within 0.005 of the full method's RMSE against the reference."""
    go, full, mask, ref = ablation
    base_err = rmse(full, ref, mask)
    for over in ({"rank_images": False}, {"occlusion_intervals": False},
                 {"occlusion_intervals": False, "clear_miss": False},
                 {"hierarchical_connectedness": False, "minmax_clipping": False, "rank_images": False,
                  "clear_miss": False, "occlusion_intervals": False}):
        v = go(**over)
        assert rmse(v, full, mask) < 0.03, over
        assert np.mean(v != full) < 0.1, over
        assert abs(rmse(v, ref, mask) - base_err) < 0.005, over
    # with occlusion intervals, the clear miss is implied (an empty interval list ends the ray)
    np.testing.assert_array_equal(go(clear_miss=False), full)


# ---------------------------------------------------------------------------
# a sun's windows and maps (thin pillars under a 4-degree sun)
def test_cone_envelope_is_the_chessboard_upper_envelope():
    """window.cone_envelope = max_q R(q) - step * chessboard distance, brute force."""
    rng = np.random.default_rng(4)
    R = rng.uniform(0, 10, (9, 13))
    R[rng.uniform(size=R.shape) < 0.6] = -np.inf
    ii, jj = np.indices(R.shape)
    step = 0.7
    F = cone_envelope(R, step)
    for i in range(R.shape[0]):
        for j in range(R.shape[1]):
            d = np.maximum(np.abs(ii - i), np.abs(jj - j))
            assert F[i, j] == pytest.approx(np.max(R - step * d))


@pytest.fixture(scope="module")
def sun_pillars():
    """Thin pillars (6 cm) under a 4-degree sun at 20 degrees, the camera seeing
    the ground far beyond their shadows: a window holding every receiver is
    about 40 m wide, a texel of 128^2 maps over it 20 cm, several pillar
    widths."""
    scene = sun_pillars_scene(64)
    fb = FrameBuffers(scene, 64, 64)
    light = scene.lights[0]
    e = embree_pass(fb, light, 64)
    mask = reach_mask(fb.gbuffer, light)
    m = producer_of("depth_raytrace")
    p = m.make_params({"samples": 64})
    return scene, fb, light, e, mask, m.run(fb, light, p).passes["depth_raytrace"], m.build_maps(fb, light, p)


def test_sun_thin_pillars_match_embree(sun_pillars):
    """Fitted to what can block, the windows hold the pillars at a texel of a
    few cm and the method matches the reference's rays (same samples) on the
    ground and in the pillars' penumbrae; a window fitted to every receiver
    would give the same maps texels of 20 cm and more, wider than a pillar,
    which falls between texel centres."""
    _, fb, light, e, mask, vb, mb = sun_pillars
    ground = mask & (fb.gbuffer.object_id == 0)
    pen = ground & (e > 0.02) & (e < 0.98)
    assert pen.sum() > 100
    assert rmse(vb, e, ground) < 0.02 and rmse(vb, e, pen) < 0.07
    assert rmse(vb, e, mask) < 0.04           # the pillars' own faces, a few pixels each
    assert abs(np.mean((vb - e)[mask])) < 0.005
    # the texels: the receivers' windows (at 128^2) 30 cm, the blockers' a few cm
    casters = fb.shadow_triangles[0].reshape(-1, 3).astype(np.float64)
    pts = fit_points(fb, light, casters)
    receivers = [f for _, lt in reference_eyes(light, 4)
                 for f in views.light_view_faces(lt, pts, fb.scene.bounds(), 128)]
    foot = [0.5 * ((f.bounds[1] - f.bounds[0]) / f.width + (f.bounds[3] - f.bounds[2]) / f.height)
            for f in receivers]
    assert min(foot) > 0.2 and mb.faces[:, FP_FOOT].max() < 0.05


def test_sun_maps_are_at_least_the_papers_size(sun_pillars):
    """With the windows fitted to the blockers, the texel follows the
    pillars' extent, not the output's pixels, and at 64 px maps of
    map_scale x 64 = 128 quantise the pillars' silhouettes into their
    penumbrae. A sun's maps are at least ``SUN_MIN_MAP`` (the paper's 1024)
    on a side, at most ``SUN_MIN_MAP_REACH`` x the map_scale side (here 512):
    against the reference's own rays (same samples, so its noise cancels)
    the ground penumbra's error falls with the texel. Other lights keep
    map_scale alone, and so does a tiny output (8 px: 64^2 maps, not
    1024^2)."""
    scene, fb, light, e, mask, v_default, _ = sun_pillars
    assert resolve_map_size(DepthRaytraceParams(), 256, 256, light) == 1024
    assert resolve_map_size(DepthRaytraceParams(), 64, 64, light) == 512
    assert resolve_map_size(DepthRaytraceParams(), 8, 8, light) == 64
    assert resolve_map_size(DepthRaytraceParams(map_size=96), 64, 64, light) == 96
    assert resolve_map_size(DepthRaytraceParams(), 64, 64, area_light(1.0)) == 128
    assert resolve_map_size(DepthRaytraceParams(), 1024, 512, light) == 2048
    pen = mask & (fb.gbuffer.object_id == 0) & (e > 0.02) & (e < 0.98)
    err = {}
    for side in (128, 256, 512):
        v, _ = run(scene, fb, samples=64, map_size=side)
        err[side] = rmse(v.passes["depth_raytrace"], e, pen)
        if side == 512:                       # the default's maps at 64 px
            np.testing.assert_array_equal(v.passes["depth_raytrace"], v_default)
    assert err[512] < 0.02 and err[512] < 0.5 * err[128] and err[256] < err[128], err


# ---------------------------------------------------------------------------
# gap bias (section 5.1): walls only between connected texels
def test_gap_bias_keeps_separate_objects_apart():
    """The occluder plate (height 2) and the ground (height 0) are separate
    surfaces: with the default gap bias a ray passing under the plate's edge
    goes through the silhouette gap and is decided by another reference
    image; connecting everything (a gap bias larger than the scene) builds
    a wall from the plate's edge down to the ground, which blocks those rays:
    the lit side of the penumbra darkens."""
    a = 1.0
    scene = half_plane_scene(area_light(size=a, z=HL), res=48, occluder_z=HO)
    ys = pixel_world_y(scene, np.arange(48))
    expect = np.clip((a / 2 + ys) / a, 0, 1)
    r, fb = run(scene, samples=64, map_size=256)
    walls, _ = run(scene, fb, samples=64, map_size=256, gap_bias=100.0)
    v, w = r.passes["depth_raytrace"].mean(axis=1), walls.passes["depth_raytrace"].mean(axis=1)
    pen = (ys > 0.1) & (ys < a / 2)
    assert np.abs(v - expect)[np.abs(ys) < a / 2].max() < 0.02
    assert (w[pen] < expect[pen] - 0.1).all()       # walls darken the lit half of the penumbra


# ---------------------------------------------------------------------------
# coherent sampler pieces
def test_projection_onto_the_light_inverts_the_light_sampling():
    """Predict maps a blocker point back to the light's unit square: for a
    point on the segment from p to light_sample(u, v), it returns (u, v)."""
    rng = np.random.default_rng(1)
    lights = [area_light(1.0, 0.6, "RECTANGLE"), area_light(1.0, 0.5, "ELLIPSE"),
              sphere_light(0.4), sun_light(0.3)]
    for lt in lights:
        lp = pack_light(lt)
        for _ in range(200):
            p = rng.uniform(-1, 1, 3) * [1, 1, 0.2]
            u, v = rng.uniform(0.01, 0.99, 2)
            x, y, z, is_dir, _ = light_sample(lp, p[0], p[1], p[2], u, v)
            q = np.array([x, y, z])
            b = p + 0.37 * (q if is_dir else q - p)
            ok, uu, vv = project_to_light(lp, p[0], p[1], p[2], *b)
            assert ok
            assert uu == pytest.approx(u, abs=1e-6) and vv == pytest.approx(v, abs=1e-6)
        # a blocker beyond the light (or outside its shape) projects nowhere
        if lt.kind == "area":
            ok, _, _ = project_to_light(lp, 0.0, 0.0, 0.0, 5.0, 5.0, 2.0)
            assert not ok


def test_inverse_concentric_map():
    for u, v in np.random.default_rng(2).uniform(0, 1, (500, 2)):
        x, y = concentric_disk(u, v)
        uu, vv = inv_concentric(x, y)
        assert uu == pytest.approx(u, abs=1e-9) and vv == pytest.approx(v, abs=1e-9)


def test_reference_points_on_the_light():
    sq = area_light(2.0)
    pts = np.array([e for e, _ in reference_eyes(sq)])
    assert len(pts) == 4 and np.allclose(np.abs(pts[:, :2]), 1.0) and np.allclose(pts[:, 2], 4.0)
    disk = area_light(2.0, shape="DISK")
    pts = np.array([e for e, _ in reference_eyes(disk, 6)])
    assert len(pts) == 6 and np.allclose(np.linalg.norm(pts[:, :2], axis=1), 1.0)
    assert len(reference_eyes(sphere_light(0.5))) == 6
    suns = reference_eyes(sun_light(0.2), 4)
    for _, lt in suns:   # views along the cone's boundary
        assert math.acos(np.clip(-lt.direction @ np.array([0, 0, 1.0]), -1, 1)) == pytest.approx(0.1)


# ---------------------------------------------------------------------------
# robustness (DESIGN.md hard cases)
def _scaled(scene, s):
    cam = scene.camera
    m = cam.world_from_camera.copy()
    m[:3, 3] *= s
    cam2 = Camera(m, kind=cam.kind, ortho_scale=cam.ortho_scale * s, clip_start=cam.clip_start * s,
                  clip_end=cam.clip_end * s)
    lts = []
    for lt in scene.lights:
        lm = lt.world_from_light.copy()
        lm[:3, 3] *= s
        lts.append(Light(lt.name, lt.kind, lm, shape=lt.shape, size=lt.size * s, size_y=lt.size_y * s,
                         radius=lt.radius * s, angle=lt.angle, spot_size=lt.spot_size))
    return Scene(scene.triangles * s, scene.tri_object, scene.objects, cam2, lts, scene.resolution)


def _scene(tris, ids, lights, res=32, cam=None, names=("ground", "occ")):
    objs = [ObjectInfo(n, i) for i, n in enumerate(names)]
    return Scene(np.array(tris, np.float32), np.array(ids, np.int32), objs,
                 cam or top_ortho_camera(2.0), lights, (res, res))


def hard_cases():
    g = quad(-10, 10, -10, 10, 0.0)
    yield "grazing", _scene(g + box(-0.5, 0.5, -0.5, 0.5, 0.0, 0.5), [0, 0] + [1] * 12,
                            [Light("A", "area", light_matrix((10, 0, 0.4), (-1, 0, -0.02)), size=1.0, size_y=1.0)])
    yield "contact", _scene(g + box(-0.5, 0.5, -0.5, 0.5, 0.0, 1.0), [0, 0] + [1] * 12, [area_light(1.0)])
    yield "coplanar", _scene(g + quad(-1, 1, -1, 1, 0.0), [0, 0, 1, 1], [area_light(1.0)])
    yield "behind_light", _scene(g + quad(-1, 1, -1, 1, 6.0), [0, 0, 1, 1], [area_light(1.0)])
    yield "light_in_box", _scene(g + box(-1, 1, -1, 1, 3.0, 5.0), [0, 0] + [1] * 12, [area_light(1.0)])
    yield "huge_light", half_plane_scene(area_light(50.0), res=32)
    yield "tiny_scene", _scaled(half_plane_scene(area_light(1.0), res=32), 1e-3)
    yield "huge_scene", _scaled(half_plane_scene(area_light(1.0), res=32), 1e4)
    yield "sphere", half_plane_scene(sphere_light(0.5), res=32)
    yield "spot", half_plane_scene(sphere_light(0.3, spot_size=1.0), res=32)
    yield "point_zero", half_plane_scene(sphere_light(0.0), res=32)
    yield "sun", half_plane_scene(sun_light(0.3), res=32)
    yield "ellipse", half_plane_scene(area_light(1.5, 0.5, "ELLIPSE"), res=32)
    yield "facing_away", _scene(g, [0, 0], [Light("A", "area", light_matrix((0, 0, 4), (0, 0, 1)),
                                                  size=1.0, size_y=1.0)], names=("ground",))
    cam_inside = Camera(light_matrix((0, 0, 0.5)), kind="PERSP", clip_start=1e-3, clip_end=100)
    yield "camera_inside", _scene(g + box(-1, 1, -1, 1, 0.0, 1.0), [0, 0] + [1] * 12, [area_light(1.0)],
                                  cam=cam_inside)


@pytest.mark.parametrize("name,scene", list(hard_cases()), ids=[n for n, _ in hard_cases()])
def test_hard_cases_finite_and_in_range(name, scene):
    r, fb = run(scene, samples=16)
    for v in r.passes.values():
        assert in_range(v)
        assert (v[~fb.gbuffer.hit] == 1).all()
    if name == "light_in_box":   # a closed box around the light: (almost) everything blocked
        v = r.passes["depth_raytrace"][fb.gbuffer.hit]
        assert v.max() <= 2 / 16 and v.mean() < 0.005
    # accuracy too, except where depth images from the light's boundary sample
    # the scene poorly (section 6.1, "Sampling"): grazing light (a 2-degree
    # ground is off by 0.1) and a light 50 times the scene's occluder height
    # (its corners see the occluder edge-on: rays leak, +0.19)
    if name in ("contact", "coplanar", "behind_light", "tiny_scene", "huge_scene", "sphere",
                "sun", "ellipse", "spot"):
        e = embree_pass(fb, scene.lights[0], 16)
        m = reach_mask(fb.gbuffer, scene.lights[0])
        assert rmse(r.passes["depth_raytrace"], e, m) < 0.08, name


# ---------------------------------------------------------------------------
# determinism, threads, the benchmark helper
def test_deterministic_and_thread_count_independent():
    scene = half_plane_scene(area_light(1.0), res=40)
    a, fb = run(scene, samples=64)
    b, _ = run(scene, fb, samples=64)
    old = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        c, _ = run(scene, fb, samples=64)
    finally:
        numba.set_num_threads(old)
    for k in a.passes:
        np.testing.assert_array_equal(a.passes[k], b.passes[k])
        np.testing.assert_array_equal(a.passes[k], c.passes[k])
    d, _ = run(scene, fb, samples=64, seed=5)
    assert not np.array_equal(a.passes["depth_raytrace"], d.passes["depth_raytrace"])


def test_tile_workers_do_not_change_the_result(monkeypatch):
    """The tracer's tiles run on worker threads (serial ``nogil`` kernels,
    ``tiles.trace_tiles``): 1 and 3 workers give the same bits."""
    scene = half_plane_scene(area_light(1.0), res=40)
    monkeypatch.setattr(numba, "get_num_threads", lambda: 1)
    a, fb = run(scene, samples=64)
    monkeypatch.setattr(numba, "get_num_threads", lambda: 3)
    b, _ = run(scene, fb, samples=64)
    for k in a.passes:
        np.testing.assert_array_equal(a.passes[k], b.passes[k])


def test_borrowed_arrays_share_the_data():
    """``kernels.borrowed``: the same data, shape and strides (reads and
    writes go to the caller's arrays), through (named) tuples too."""
    from numba import njit
    from penumbra.core.kernels import borrowed
    from penumbra.core.methods.depth_raytrace.trace import TraceScratch

    @njit
    def use(a, t):
        b = borrowed(a)
        u = borrowed(t)
        b[1, 2] = 7.0
        u.U[0, 1] = b.sum()
        return b.shape[0] * 10 + b.shape[1], u.line.strides[0]

    a = np.zeros((3, 4))[:, ::-1]
    t = TraceScratch(np.zeros((2, 5)), np.zeros(2, np.int64), np.zeros(2), np.zeros((4, 2)), np.zeros((4, 2)))
    shape, stride = use(a, t)
    assert (shape, stride) == (34, 40)
    assert a[1, 2] == 7.0 and a.sum() == 7.0
    assert t.U[0, 1] == 7.0


def test_benchmark_table_rows():
    scene = half_plane_scene(area_light(1.0), res=24)
    fb = FrameBuffers(scene, 24, 24)
    rows = benchmark_table(fb, scene.lights[0], (16, 64))
    assert [r["samples"] for r in rows] == [16, 64]
    for r in rows:
        for k in ("no_accel_s", "accel_s", "accel_coherence_s", "embree_s", "precompute_s",
                  "accel_coherence_rays_per_pixel", "accel_coherence_rmse"):
            assert np.isfinite(r[k]) and r[k] >= 0, k
        assert r["accel_coherence_rays_per_pixel"] < r["samples"]
    assert "| 64 |" in format_table(rows)


def test_a_sun_window_of_one_depth_still_blocks():
    # receivers under the inside of a flat occluder only: the sun's window is fitted to their
    # blockers, every texel holds the occluder's one depth, and a ray crossing it is blocked (a
    # root key range of zero width used to let every ray through)
    scene = half_plane_scene(sun_light(0.0), res=64)
    scene.triangles = scene.triangles.copy()
    scene.triangles[2:4, :, 1] -= 0.1667                   # the occluder's edge off the texel grid
    b = FrameBuffers(scene, 64, 64)
    render_frame(scene, ["pcf"], buffers=b)
    sub_scene = scene.at_resolution(256, 256)
    rows = np.arange(139, 148)
    g = raycast.camera_gbuffer_at(sub_scene, 256, 256, np.full(9, 22), rows, b.camera_scene, packed=True)
    y = g.position[0, :, 1]
    assert (y < -0.17).all()                                # every receiver lies under the occluder
    m = producer_of("depth_raytrace")
    view = b.supersampled(sub_scene, 256, 256, g, 0.0).view(m.needs)
    p = m.make_params({})
    maps = build_reference_maps(view, scene.lights[0], 1024, p.ref_points, p.shadow_bias, p.bias_texels,
                                p.slope_bias, p.gap_bias, p.gap_texels)
    depth = maps.raw_depth[0][np.isfinite(maps.raw_depth[0])]
    assert depth.size and depth.min() == depth.max()         # the window holds the occluder's one depth
    V = m.run(view, scene.lights[0], p, maps=maps).passes["depth_raytrace"]
    assert np.array_equal(V.reshape(-1), np.zeros(9, np.float32))

