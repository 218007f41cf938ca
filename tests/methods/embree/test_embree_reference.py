"""The ray-traced references ``embree`` / ``embree_irr`` against closed
forms (no bpy)."""
import numpy as np
import pytest

from helpers import buffers_of, in_range, run_method
from synthetic import area_light, half_plane_scene, pixel_world_y, sphere_light, sun_light

HL, HO = 4.0, 2.0   # light and occluder heights used by half_plane_scene


def run_embree(scene, samples=256, seed=0):
    """The reference's MethodResult (both passes) on the scene's own buffers."""
    return run_method("embree", buffers_of(scene), scene.lights[0], samples=samples, seed=seed)


def row_means(img):
    return img.mean(axis=1)


def test_square_light_half_plane_closed_form():
    """Square light of side a at height 4, straight-edged occluder at height 2
    covering y < 0: a ground point at y sees the part of the light with
    ly > y (1 - HL/HO), so V = clamp((a/2 + y) / a, 0, 1)."""
    a = 1.0
    scene = half_plane_scene(area_light(size=a, z=HL), res=64, occluder_z=HO)
    r = run_embree(scene, samples=256)
    v = r.passes["embree"]
    ys = pixel_world_y(scene, np.arange(64))
    expect = np.clip((a / 2 + ys) / a, 0, 1)
    assert np.abs(row_means(v) - expect).max() < 0.01
    assert np.abs(v - expect[:, None]).max() < 0.06
    # on the line under the edge (y = 0) exactly half the light is visible
    rows_at_edge = np.argsort(np.abs(ys))[:2]
    assert abs(v[rows_at_edge].mean() - 0.5) < 0.04
    assert v[ys > a].min() == 1.0        # unoccluded: every ray gets through
    assert v[ys < -a].max() == 0.0       # full umbra


def test_disk_light_closed_form():
    """Disk light of radius R: visible fraction = segment area of the disk
    beyond the line ly = y* = y (1 - HL/HO): (acos d - d sqrt(1 - d^2)) / pi."""
    R = 0.5
    scene = half_plane_scene(area_light(size=2 * R, shape="DISK", z=HL), res=64, occluder_z=HO)
    v = run_embree(scene, samples=256).passes["embree"]
    ys = pixel_world_y(scene, np.arange(64))
    d = np.clip(ys * (1 - HL / HO) / R, -1, 1)
    expect = (np.arccos(d) - d * np.sqrt(1 - d * d)) / np.pi
    assert np.abs(row_means(v) - expect).max() < 0.01


def test_ellipse_and_rectangle_follow_their_y_extent():
    """Only the light's extent across the edge matters: a rectangle 3 x 1
    (long side along x) has the same V(y) as a 1 x 1 square."""
    scene = half_plane_scene(area_light(size=3.0, size_y=1.0, shape="RECTANGLE", z=HL), res=48)
    v = run_embree(scene, samples=256).passes["embree"]
    ys = pixel_world_y(scene, np.arange(48))
    assert np.abs(row_means(v) - np.clip(0.5 + ys, 0, 1)).max() < 0.01


def test_irradiance_ratio_against_quadrature():
    """V_irr = int_visible cos cos / d^2 / int_all cos cos / d^2, integrated
    on a fine grid over the square light, for ground points under it."""
    a = 1.0
    scene = half_plane_scene(area_light(size=a, z=HL), res=32, occluder_z=HO)
    vi = run_embree(scene, samples=1024).passes["embree_irr"]
    ys = pixel_world_y(scene, np.arange(32))
    g = (np.arange(400) + 0.5) / 400 * a - a / 2
    LX, LY = np.meshgrid(g, g)
    for row in (10, 14, 16, 18, 22):
        y = ys[row]
        w = HL * HL / (LX ** 2 + (LY - y) ** 2 + HL ** 2) ** 2
        vis = LY > y * (1 - HL / HO)
        expect = (w * vis).sum() / w.sum()
        assert abs(vi[row].mean() - expect) < 0.01, (row, vi[row].mean(), expect)


@pytest.mark.parametrize("make", [lambda: sphere_light(0.5, z=HL), lambda: sun_light(0.2)])
def test_sphere_and_sun_half_covered_is_half(make):
    scene = half_plane_scene(make(), res=64, occluder_z=HO)
    v = run_embree(scene, samples=256).passes["embree"]
    ys = pixel_world_y(scene, np.arange(64))
    rows_at_edge = np.argsort(np.abs(ys))[:2]
    # ground points on the line under the edge, near x = 0
    assert abs(v[rows_at_edge, 24:40].mean() - 0.5) < 0.03
    assert v[ys > 1.0].min() == 1.0
    assert v[ys < -1.0].max() == 0.0
    # V does not decrease moving out of the shadow (y grows)
    rm = row_means(v)[::-1]
    assert np.all(np.diff(rm) >= -0.02)


def test_zero_size_light_is_hard_shadow():
    scene = half_plane_scene(area_light(size=0.0, z=HL), res=32)
    r = run_embree(scene, samples=64)
    v = r.passes["embree"]
    ys = pixel_world_y(scene, np.arange(32))
    assert r.stats["samples"] == 1
    assert set(np.unique(v)) <= {0.0, 1.0}
    np.testing.assert_array_equal(v, np.where(ys > 0, 1.0, 0.0)[:, None] * np.ones((1, 32)))


def test_seeded_and_deterministic():
    scene = half_plane_scene(area_light(size=1.0), res=32)
    a = run_embree(scene, samples=16, seed=3).passes["embree"]
    b = run_embree(scene, samples=16, seed=3).passes["embree"]
    c = run_embree(scene, samples=16, seed=4).passes["embree"]
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def test_values_finite_and_in_range():
    scene = half_plane_scene(area_light(size=2.0, shape="ELLIPSE", size_y=0.5), res=32)
    r = run_embree(scene, samples=32)
    for v in r.passes.values():
        assert in_range(v)


@pytest.mark.parametrize("shape", ["SQUARE", "RECTANGLE", "DISK", "ELLIPSE"])
def test_unshadowed_irradiance_of_an_area_light_is_the_reference_weights_mean(shape):
    """E0 of an area light in closed form (Lambert's form factor of the part
    of the light above the tangent plane, 0 behind its emitting side) is the
    mean of the reference's own weights cos cos / d^2 over the light, as
    many light samples give it (random receivers around, under and behind
    the light, grazing ones among them)."""
    from penumbra.core import sampling
    from penumbra.core.methods import embree_ref as er
    from synthetic import area_light
    rng = np.random.default_rng(7)
    n = 300
    light = area_light(size=1.5, size_y=0.7, shape=shape, z=2.0)
    P = np.c_[rng.uniform(-3, 3, n), rng.uniform(-3, 3, n), rng.uniform(-0.5, 2.5, n)]
    N = rng.normal(size=(n, 3))
    N /= np.linalg.norm(N, axis=1)[:, None]
    pix = np.arange(n, dtype=np.int64)
    mc = np.zeros(n)
    er.unshadowed_range(0, n, P, N, pix, sampling.pack_light(light), 16384, 0, 1.0, mc)
    exact = er.unshadowed_irradiance(P, N, pix, light, 16, 0, 1.0)
    assert (mc == 0).sum() > 20 and (exact[mc == 0] < 1e-3 * mc.max()).all()   # behind it, below the horizon
    assert (mc[exact == 0] < 1e-3 * mc.max()).all()
    lit = mc > 1e-3 * mc.max()
    assert np.median(np.abs(exact[lit] / mc[lit] - 1.0)) < 2e-4
    assert np.abs(exact - mc).max() < (0.05 if shape == "DISK" else 2e-3) * mc.max()
