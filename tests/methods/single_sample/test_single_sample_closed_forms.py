"""Single sample soft shadows against closed forms: a straight edge under
square, disk, sphere and sun lights, penumbra widths, lights of size zero,
the paper's radius knobs, the summed blockers, the horizon share (the
average pass) and the irradiance ratio (visibility="irradiance")."""
import math

import numpy as np
import pytest

from helpers import buffers_of, embree_pass
from penumbra.core.methods.single_sample import SingleSampleSoftShadows, single_sample_visibility
from penumbra.core.metrics import errors
from penumbra.core.scene import ObjectInfo, Scene
from single_sample_helpers import HL, PAPER, hard_edge_band, penumbra_width, run_ss
from synthetic import area_light, half_plane_scene, pixel_world_y, quad, sphere_light, sun_light


def test_square_light_matches_closed_form():
    """A square light of side a, straight edge at height HO: V(y) is exactly
    linear, clamp((a/2 + y (HL/HO - 1)) / a); the "slope" ramp in the light's
    1-norm reproduces it up to the map's texel quantization: the hard edge
    snaps to a texel boundary, half a texel of a 7.7-texel half ramp = 0.033
    at most."""
    a, HO = 1.0, 2.0
    scene = half_plane_scene(area_light(size=a, z=HL), res=64, occluder_z=HO)
    v, _, _ = run_ss(scene, adaptive=False, **PAPER)
    ys = pixel_world_y(scene, np.arange(64))
    expect = np.clip((a / 2 + ys * (HL / HO - 1)) / a, 0, 1)
    assert np.abs(v.mean(axis=1) - expect).max() < 0.04
    assert np.abs(v - expect[:, None]).max() < 0.07


def test_disk_light_close_to_closed_form():
    """Disk light: V is the circular segment's area; a linear ramp with the
    true slope at V = 1/2 departs from it by at most ~0.05 (at the ends)."""
    R, HO = 0.5, 2.0
    scene = half_plane_scene(area_light(size=2 * R, shape="DISK", z=HL), res=64, occluder_z=HO)
    v, _, _ = run_ss(scene, adaptive=False, **PAPER)
    ys = pixel_world_y(scene, np.arange(64))
    d = np.clip(ys * (1 - HL / HO) / R, -1, 1)
    expect = (np.arccos(d) - d * np.sqrt(1 - d * d)) / np.pi
    assert np.abs(v.mean(axis=1) - expect).max() < 0.07
    assert np.sqrt(np.mean((v.mean(axis=1) - expect) ** 2)) < 0.03


@pytest.mark.parametrize("auto", [True, False])
def test_penumbra_widens_with_receiver_occluder_distance(auto):
    """Section 3.2: the penumbra grows with the occluder-receiver distance.
    Occluder at height 1 then 2 under a light at 4: the true width
    a h / (HL - h) goes from a/3 to a. With the raw knobs (auto_radius off)
    only the growth is claimed; with the light's size the widths themselves."""
    a = 1.0
    widths = {}
    for h in (1.0, 2.0):
        scene = half_plane_scene(area_light(size=a, z=HL), res=64, occluder_z=h)
        v, _, _ = run_ss(scene, adaptive=False, auto_radius=auto, r_scale=3.0, r_shrink=0.5, **PAPER)
        widths[h] = penumbra_width(scene, v)
    assert widths[2.0] > 1.5 * widths[1.0] > 0
    if auto:      # the square light's ramp is exact: width a h / (HL - h)
        for h, w in widths.items():
            assert abs(w - a * h / (HL - h)) <= 0.05 * a, widths


@pytest.mark.parametrize("make", [lambda: sphere_light(0.5, z=HL), lambda: sun_light(0.25),
                                  lambda: area_light(1.0, shape="DISK", z=HL)])
def test_sphere_sun_and_disk_penumbrae_widen_like_the_reference(make):
    """Growth from occluder height 1 to 2 follows the reference's within
    15% (true ratio: 3 for the sphere and disk, 2 for the sun)."""
    w, wr = [], []
    for h in (1.0, 2.0):
        scene = half_plane_scene(make(), res=64, occluder_z=h)
        v, _, fb = run_ss(scene, adaptive=False, **PAPER)
        w.append(penumbra_width(scene, v))
        wr.append(penumbra_width(scene, embree_pass(fb, scene.lights[0], 256)))
    assert w[1] > 1.5 * w[0] > 0, (w, wr)
    assert abs((w[1] / w[0]) / (wr[1] / wr[0]) - 1) < 0.15, (w, wr)


@pytest.mark.parametrize("make", [lambda: area_light(0.0), lambda: sphere_light(0.0, z=HL),
                                  lambda: sun_light(0.0)])
def test_zero_size_light_is_the_hard_shadow(make):
    """DESIGN.md: a light of size zero equals the hard shadow. Exactly the
    hard test of the map (no search runs), and the ray-traced hard shadow
    everywhere but on the map's staircase along the edge."""
    light = make()
    scene = half_plane_scene(light, res=64)
    v, r, fb = run_ss(scene)
    hard, _ = single_sample_visibility(fb, light, SingleSampleSoftShadows().make_params({}), hard_only=True)
    np.testing.assert_array_equal(v, hard)
    assert set(np.unique(v)) == {0.0, 1.0}
    assert r.stats["searched"] == 0
    ref = embree_pass(fb, light, 4)          # size zero: one ray to the centre
    diff = v != ref
    assert not (diff & ~hard_edge_band(ref)).any()


def test_raw_knobs_follow_the_paper():
    """auto_radius off: r_max = r_scale |P'_z| + r_bias (texels) rescaled by
    r_shrink (P'_z - z_blocker); a larger r_scale gives a wider penumbra,
    r_scale = r_bias = 0 only the hard test."""
    scene = half_plane_scene(area_light(size=1.0, z=HL), res=64, occluder_z=2.0)
    fb = buffers_of(scene)
    w = []
    for rs in (1.0, 2.0):
        v, _, _ = run_ss(scene, fb, adaptive=False, auto_radius=False, r_scale=rs, r_shrink=0.5,
                         max_radius=80.0)
        w.append(penumbra_width(scene, v))
    assert w[1] > 1.5 * w[0] > 0
    v0, _, _ = run_ss(scene, fb, adaptive=False, auto_radius=False, r_scale=0.0, r_bias=0.0)
    hard, _ = single_sample_visibility(fb, scene.lights[0], SingleSampleSoftShadows().make_params({}),
                                       hard_only=True)
    np.testing.assert_array_equal(v0, hard)


def two_blocker_scene(gap=0.05, res=64):
    """Ground z=0; occluder A at z=2 covering x < -gap, occluder B at z=1
    covering x > gap (both unseen by the camera); a unit square light at
    z=HL. From the light's centre the ground between them is lit, but a
    ground point x sees the light's strip lx in (max(-x - 2 gap, -1/2),
    min(4 gap - 3 x, 1/2)) only: each occluder hides part of the light, on
    opposite sides."""
    tris = quad(-10, 10, -10, 10, 0.0) + quad(-10, -gap, -10, 10, 2.0) + quad(gap, 10, -10, 10, 1.0)
    objs = [ObjectInfo("ground", 0), ObjectInfo("A", 1, visible_camera=False),
            ObjectInfo("B", 2, visible_camera=False)]
    from synthetic import top_ortho_camera
    cam = top_ortho_camera(1.0, height=0.5)
    scene = Scene(np.array(tris, np.float32), np.array([0, 0, 1, 1, 2, 2]), objs, cam,
                  [area_light(1.0, z=HL)], (res, res))

    def closed_form(x):
        lo = np.maximum(-x - 2 * gap, -0.5)
        hi = np.minimum(4 * gap - 3 * x, 0.5)
        return np.clip(hi - lo, 0.0, 1.0)
    return scene, closed_form


def test_sum_adds_up_two_blockers_closed_form():
    """Section 3.4's limit: one blocker decides V. Where the ground sees the
    light's centre between two occluders that each hide a different part of
    the light (x in (-0.1, 0.067)), the paper's nearest-blocker ramp gives at
    least ``meet`` = 0.5 (the closed form: 0.4 at x = -0.05, 0.2 at x = 0.05,
    0 beyond x = 0.15); ``blocker="sum"`` adds up the light each blocker texel
    hides and follows the closed form, column means within 0.07 at the
    profile's kinks (the back-projection's texel quantization: occluder B's
    light footprint is 5 texels wide)."""
    scene, closed_form = two_blocker_scene()
    v_sum, r, fb = run_ss(scene, adaptive=False, blocker="sum")
    v_paper, _, _ = run_ss(scene, fb, adaptive=False, **PAPER)
    x = fb.gbuffer.position[..., 0]
    expect = closed_form(x)
    assert np.isfinite(v_sum).all() and v_sum.min() >= 0 and v_sum.max() <= 1
    assert np.abs(v_sum - expect).mean() < 0.03
    assert np.abs(v_sum.mean(axis=0) - expect.mean(axis=0)).max() < 0.07
    between = (x > -0.07) & (x < 0.035)         # lit from the light's centre, a texel in
    assert between.sum() > 150
    assert v_paper[between].min() >= 0.5 - 1e-6     # the paper: outer penumbra, >= meet
    assert expect[between].max() <= 0.47
    assert np.abs(v_sum[between] - expect[between]).mean() < 0.06
    ref = embree_pass(fb, scene.lights[0], 256)
    assert errors(v_sum, ref)["rmse"] < 0.04 and errors(v_paper, ref)["rmse"] > 0.08


def test_sum_matches_half_plane_closed_form():
    """One straight edge: the summed back-projection is the ramp
    clamp((a/2 + y (HL/HO - 1)) / a) (row means within 0.03)."""
    a, HO = 1.0, 2.0
    scene = half_plane_scene(area_light(size=a, z=HL), res=64, occluder_z=HO)
    v, _, _ = run_ss(scene, adaptive=False, blocker="sum")
    ys = pixel_world_y(scene, np.arange(64))
    expect = np.clip((a / 2 + ys * (HL / HO - 1)) / a, 0, 1)
    assert np.abs(v.mean(axis=1) - expect).max() < 0.03


@pytest.mark.parametrize("tilt", [60.0, 70.0])
def test_horizon_closed_form_on_a_lone_tilted_plane(tilt):
    """A lone plane tilted by ``tilt`` about x under an 8 x 8 square light 4
    above the origin: nothing else casts, and from a point P on the plane
    the light is hidden by the plane itself where q_y > P_y + cot(tilt)
    (4 - P_z), a line that is the same for every point (P_z = P_y
    tan(tilt)): the average V = (4 + 4 cot(tilt)) / 8 = 0.789 / 0.644
    everywhere. The reference agrees (rays into the plane hit it).
    horizon=False (the paper: the id test, no self-shadowing) gives 1;
    horizon gives the closed form. The irradiance ratio is 1: the light the
    plane hides lies below it and weighs nothing (cos_r = 0), so
    visibility="irradiance" applies no horizon share (the reference's
    ``embree_irr`` agrees)."""
    from synthetic import lone_tilted_plane
    t = math.radians(tilt)
    scene = lone_tilted_plane(tilt, area_light(size=8.0, z=4.0), res=32)
    exact = (4.0 + 4.0 / math.tan(t)) / 8.0
    v, _, fb = run_ss(scene)
    off, _, _ = run_ss(scene, fb, horizon=False)
    irr, _, _ = run_ss(scene, fb, visibility="irradiance")
    ref = embree_pass(fb, scene.lights[0], 256)
    ref_irr = embree_pass(fb, scene.lights[0], 256, pass_id="embree_irr")
    hit = fb.gbuffer.hit
    assert hit.all()
    assert abs(ref[hit].mean() - exact) < 0.01
    assert (off[hit] == 1.0).all()
    np.testing.assert_allclose(v[hit], exact, atol=1e-5)
    assert (irr[hit] == 1.0).all() and (ref_irr[hit] > 0.999).all()


@pytest.mark.parametrize("make", [lambda: area_light(2.0), lambda: area_light(3.0, 1.0, "RECTANGLE"),
                                  lambda: area_light(2.0, shape="DISK"), lambda: area_light(3.0, 1.0, "ELLIPSE"),
                                  lambda: sphere_light(0.8), lambda: sun_light(0.3), lambda: sun_light(2.0)])
def test_horizon_share_against_counted_light_points(make):
    """``horizon_share`` (closed forms) against the share of 40,000 points
    drawn uniformly over the light's domain (DESIGN.md: the area, the disk
    facing the point, the cone's solid angle) above random tangent planes."""
    from penumbra.core.methods.horizon import horizon_share
    light = make()
    rng = np.random.default_rng(3)
    n = 40
    P = rng.uniform(-1.5, 1.5, (n, 3)) * [1, 1, 0.5]
    N = rng.normal(size=(n, 3))
    N /= np.linalg.norm(N, axis=1, keepdims=True)
    got = horizon_share(light, P, N)
    k = 40000
    u, v = rng.uniform(-1, 1, k), rng.uniform(-1, 1, k)
    ex, ey, ez = light.axes
    want = np.empty(n)
    for i in range(n):
        if light.kind == "sun":
            ct = 1 - rng.uniform(0, 1, k) * (1 - math.cos(light.sun_half_angle))
            st = np.sqrt(1 - ct * ct)
            ph = rng.uniform(0, 2 * math.pi, k)
            w = np.outer(ct, -light.direction) + np.outer(st * np.cos(ph), ex) + np.outer(st * np.sin(ph), ey)
            want[i] = np.mean(w @ N[i] > 0)
            continue
        if light.kind == "sphere":
            d = light.position - P[i]
            d /= np.linalg.norm(d)
            a = np.cross(d, [1.0, 0, 0] if abs(d[0]) < 0.9 else [0, 1.0, 0])
            a /= np.linalg.norm(a)
            b = np.cross(d, a)
            inside = u * u + v * v <= 1
            q = light.position + light.radius * (np.outer(u[inside], a) + np.outer(v[inside], b))
        else:
            hx, hy = light.half_size
            inside = (u * u + v * v <= 1) if light.is_round else np.ones(k, bool)
            q = light.position + np.outer(hx * u[inside], ex) + np.outer(hy * v[inside], ey)
        want[i] = np.mean((q - P[i]) @ N[i] > 0)
    assert 0 < np.mean((want > 0.02) & (want < 0.98))          # some planes cut the light
    np.testing.assert_allclose(got, want, atol=0.012)


def test_irradiance_weights_meet_the_half_plane_irradiance_ratio():
    """A 2 x 2 square light 4 above the ground, the straight edge at height
    2: the average pass is the seen share of the light (its closed form, to
    the map's quantization); the irradiance ratio (Lambert's form factors,
    ``helpers.half_plane_irradiance_ratio``) leans towards the near part of
    the light by up to 0.03. visibility="irradiance" weighs each hidden part
    by the light's emission towards the receiver (cos_l / d^2; on this flat
    receiver cos_r, left out, would add as much again): the row means meet
    the ratio within 0.013 RMS over the penumbra, the average pass misses
    it by more than 0.018."""
    from helpers import half_plane_irradiance_ratio
    a = 2.0
    scene = half_plane_scene(area_light(size=a, z=HL), res=64, occluder_z=2.0)
    v_avg, _, fb = run_ss(scene, map_size=512)
    v_irr, _, _ = run_ss(scene, fb, map_size=512, visibility="irradiance")
    ys = pixel_world_y(scene, np.arange(64))
    ratio = np.array([half_plane_irradiance_ratio(y, a, HL, 2.0) for y in ys])
    share = np.clip(0.5 + ys / a, 0.0, 1.0)
    pen = (ratio > 0.02) & (ratio < 0.98)
    mid = slice(16, 48)                      # columns away from the map's border

    def rms(v, want):
        return float(np.sqrt(np.mean((v[pen, mid].mean(axis=1) - want[pen]) ** 2)))
    assert pen.sum() > 20
    assert rms(v_avg, share) < 0.002
    assert rms(v_irr, ratio) < 0.013 and rms(v_avg, ratio) > 0.018, (rms(v_irr, ratio), rms(v_avg, ratio))
