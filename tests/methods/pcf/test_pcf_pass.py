"""pcf's pass: figure 4's region shrunk to nothing is Williams' hard test,
the soft edge is monotone, the receiver's plane removes self-shadowing, the
tile test changes nothing, region="light" is the square light's exact
penumbra on a straight edge (the average pass) and widens with the light,
and visibility="irradiance" weighs the samples towards the irradiance ratio
of a square and of a disk light."""
import numpy as np
import pytest

from penumbra.core.methods import producer_of
from penumbra.core.methods.pcf import resolved_bias
from penumbra.core.methods.pcf.samples import hard_shadow_kernel
from penumbra.core.scene import ObjectInfo, Scene

from helpers import buffers_of, rmse, run_method
from synthetic import area_light, half_plane_scene, pixel_world_y, sphere_light, sun_light, top_ortho_camera


def run_pcf(scene, **over):
    """pcf's result for the scene's first light, with its buffers: the
    average pass (equation 2, the closed forms below) unless ``visibility``
    is given."""
    fb = buffers_of(scene)
    over.setdefault("visibility", "average")
    return run_method("pcf", fb, scene.lights[0], **over), fb


def hard(fb, light, bias):
    """Williams' hard test (``hard_shadow_kernel``) at the G-buffer's hits."""
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


def test_bias_scales_with_scene_size():
    scene = half_plane_scene(area_light(1.0), res=8)
    p = producer_of("pcf").make_params({})
    b0, b1 = resolved_bias(p, scene.extent())
    assert b0 == pytest.approx(0.003 * 20) and b1 == pytest.approx(0.004 * 20)


def test_receiver_plane_removes_self_shadowing_on_a_tilted_plane():
    """A lone plane tilted 60 degrees to a light above: with the paper's
    constant z and zero bias the large regions shadow the plane itself
    (section 4.2's Moire); comparing with the tangent-plane depth per texel
    leaves it fully lit with zero bias."""
    c, s = np.cos(np.radians(60)), np.sin(np.radians(60))
    tris = np.array([[[-5 * c, -5, -5 * s], [5 * c, -5, 5 * s], [5 * c, 5, 5 * s]],
                     [[-5 * c, -5, -5 * s], [5 * c, 5, 5 * s], [-5 * c, 5, -5 * s]]], np.float32)
    cam = top_ortho_camera(1.5, height=8.0)
    sc = Scene(tris, np.zeros(2, np.int32), [ObjectInfo("p", 0)], cam, [area_light(1.0, z=10.0)], (48, 48))
    on, _ = run_pcf(sc, Bias0=0.0, Bias1=0.0, ResFactor=4.0)
    off, _ = run_pcf(sc, Bias0=0.0, Bias1=0.0, ResFactor=4.0, receiver_plane=False)
    assert on.passes["pcf"].min() == 1.0
    assert off.passes["pcf"].mean() < 0.95


@pytest.mark.parametrize("visibility", ["average", "irradiance"])
@pytest.mark.parametrize("region", ["light", "figure4"])
def test_tile_early_out_changes_nothing(region, visibility):
    """Reeves et al. 3.3's tiles only skip regions whose result they decide:
    the pass is bit-identical with them off (region="light": the tiles test
    the blocker search's region, which holds the filter's), weighted or not."""
    for make in (lambda: area_light(1.0), lambda: sphere_light(0.3), lambda: sun_light(0.1)):
        scene = half_plane_scene(make(), res=48)
        a, _ = run_pcf(scene, tiles=True, region=region, visibility=visibility)
        b, _ = run_pcf(scene, tiles=False, region=region, visibility=visibility)
        np.testing.assert_array_equal(a.passes["pcf"], b.passes["pcf"])


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
    assert rmse(v, exact) < 0.03, rmse(v, exact)
    assert rmse(paper, exact) > 0.1
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


def _rms_over_penumbra(v, want, pen):
    """RMS over the rows ``pen`` of the row means of ``v``'s middle columns
    (away from the map's border) against ``want``."""
    return float(np.sqrt(np.mean((v[pen, 16:48].mean(axis=1) - want[pen]) ** 2)))


def test_irradiance_weights_meet_the_half_plane_irradiance_ratio():
    """A 2 x 2 square light 4 above the ground, the straight edge at height
    2, region="light" with many samples and a region large enough for the
    light: the average pass is the seen share of the light (its closed
    form); the irradiance ratio (Lambert's form factors,
    ``helpers.half_plane_irradiance_ratio``) leans towards the near part of
    the light by up to 0.03. visibility="irradiance" weighs each sample by
    the light's emission towards the receiver at its light point (cos_l /
    d^2; on this flat receiver cos_r, left out, would add as much again):
    it meets the ratio within 0.013 RMS over the penumbra, the average pass
    misses it by more than 0.018."""
    from helpers import half_plane_irradiance_ratio
    a = 2.0
    scene = half_plane_scene(area_light(a), res=64)
    kw = dict(PenumbraSamples=1024, MaxSize=512.0, map_size=512)
    v_avg = run_pcf(scene, **kw)[0].passes["pcf"]
    v_irr = run_pcf(scene, visibility="irradiance", **kw)[0].passes["pcf"]
    ys = pixel_world_y(scene, np.arange(64))
    ratio = np.array([half_plane_irradiance_ratio(y, a) for y in ys])
    pen = (ratio > 0.02) & (ratio < 0.98)
    assert pen.sum() > 20
    assert _rms_over_penumbra(v_avg, np.clip(0.5 + ys / a, 0.0, 1.0), pen) < 0.008
    e_irr, e_avg = _rms_over_penumbra(v_irr, ratio, pen), _rms_over_penumbra(v_avg, ratio, pen)
    assert e_irr < 0.013 and e_avg > 0.018, (e_irr, e_avg)


def _disk_irradiance_ratio(y, R, zl=4.0, zo=2.0, n=801):
    """The irradiance ratio at ground point (0, y, 0) of the half-plane scene
    under a disk light of radius R at height zl (the edge at height zo):
    the light's weight cos_r cos_l / d^2 = zl^2 / d^4 over the part seen
    past the edge (y_l >= y - y zl / zo) over the whole disk, by midpoint
    integration on an n x n grid."""
    c = -R + 2.0 * R * (np.arange(n) + 0.5) / n
    X, Y = np.meshgrid(c, c)
    d2 = X * X + (Y - y) ** 2 + zl * zl
    w = np.where(X * X + Y * Y <= R * R, zl * zl / (d2 * d2), 0.0)
    return float((w * (Y >= y - y * zl / zo)).sum() / w.sum())


def test_irradiance_samples_past_the_light_weigh_nothing():
    """A disk light of diameter 1: region="light" is its bounding square, so
    the average pass ramps linearly like a square light's (0.05 from the
    disk's circular-segment profile). visibility="irradiance": the samples
    whose light point misses the disk weigh nothing, and V follows the
    disk's irradiance ratio within 0.008 (row means, RMS over the penumbra)."""
    R = 0.5
    scene = half_plane_scene(area_light(2.0 * R, shape="DISK"), res=64)
    v_avg = run_pcf(scene, PenumbraSamples=1024)[0].passes["pcf"]
    v_irr = run_pcf(scene, PenumbraSamples=1024, visibility="irradiance")[0].passes["pcf"]
    ratio = np.array([_disk_irradiance_ratio(y, R) for y in pixel_world_y(scene, np.arange(64))])
    pen = (ratio > 0.02) & (ratio < 0.98)
    assert pen.sum() > 10
    e_irr, e_avg = _rms_over_penumbra(v_irr, ratio, pen), _rms_over_penumbra(v_avg, ratio, pen)
    assert e_irr < 0.008 and e_avg > 0.03, (e_irr, e_avg)


def test_unknown_region_is_an_error():
    with pytest.raises(ValueError, match="region"):
        run_pcf(half_plane_scene(area_light(1.0), res=8), region="pcss")
