"""Bad input at the core level (scenes far from the origin, degenerate and
NaN triangles, no geometry, no lights, huge and tiny lights): never a
traceback, never NaN. Through the CLI and the operators: test_cli.py,
test_addon_operators.py."""
import numpy as np
import pytest

from penumbra.core.frame import render_frame
from penumbra.core.scene import finite_triangles
from helpers import in_range
from synthetic import area_light, half_plane_scene, pixel_world_y, sphere_light, sun_light

PASSES = ["pcf", "embree", "embree_irr"]


def check(res):
    for lr in res.lights:
        for v in lr.passes.values():
            assert in_range(v)


def translated(scene, offset):
    off = np.asarray(offset, np.float64)
    scene.triangles = (scene.triangles.astype(np.float64) + off).astype(np.float32)
    scene.camera.world_from_camera = scene.camera.world_from_camera.copy()
    scene.camera.world_from_camera[:3, 3] += off
    for lt in scene.lights:
        lt.world_from_light = lt.world_from_light.copy()
        lt.world_from_light[:3, 3] += off
    return scene


def test_scene_far_from_origin_keeps_the_closed_form():
    """The half-plane closed form V = clamp(0.5 + y, 0, 1) at 1e4 from the origin."""
    sc = translated(half_plane_scene(area_light(1.0), res=48), (1e4, -1e4, 1e4))
    res = render_frame(sc, PASSES, overrides={"samples": 256})
    check(res)
    ys = pixel_world_y(sc, np.arange(48))
    v = res.lights[0].passes["embree"]
    assert np.abs(v.mean(axis=1) - np.clip(0.5 + ys, 0, 1)).max() < 0.02
    assert res.lights[0].record["pcf"]["error"]["rmse"] < 0.1


def test_degenerate_and_nan_triangles():
    sc = half_plane_scene(area_light(1.0), res=32)
    bad = np.array([[[0, 0, 1], [0, 0, 1], [0, 0, 1]],              # zero area
                    [[0, 0, 1], [1, 1, 1], [2, 2, 1]],              # collinear
                    [[np.nan, 0, 1], [1, 0, 1], [0, 1, 1]]], np.float32)
    tris = np.concatenate([sc.triangles, bad])
    ids = np.concatenate([sc.tri_object, [1, 1, 1]]).astype(np.int32)
    tris, ids, dropped = finite_triangles(tris, ids)
    assert dropped == 1
    sc.triangles, sc.tri_object = tris, ids
    check(render_frame(sc, PASSES, overrides={"samples": 16}))


def test_empty_scene_and_no_lights():
    sc = half_plane_scene(area_light(1.0), res=16)
    sc.triangles = np.zeros((0, 3, 3), np.float32)
    sc.tri_object = np.zeros(0, np.int32)
    res = render_frame(sc, PASSES)
    check(res)
    assert all((v == 1).all() for v in res.lights[0].passes.values())
    sc2 = half_plane_scene(area_light(1.0), res=16)
    sc2.lights = []
    res2 = render_frame(sc2, PASSES)
    assert res2.lights == [] and "no lights" in res2.plan.notes[0]


@pytest.mark.parametrize("make", [lambda: area_light(50.0), lambda: sphere_light(30.0), lambda: sun_light(3.0),
                                  lambda: area_light(1e-7)])
def test_huge_and_tiny_lights(make):
    check(render_frame(half_plane_scene(make(), res=24), PASSES, overrides={"samples": 16}))
