"""The planner's rules, each on a scene built for it, and that skipping or
culling changes no pixel of the final pass; pass ids and EXR layer names."""
import numpy as np
import pytest

from penumbra.core.buffers import FrameBuffers
from penumbra.core.frame import render_frame
from penumbra.core.methods.embree_ref import trace_visibility
from penumbra.core.metrics import reach_mask
from penumbra.core.planner import PlanError, layer_name, make_plan, resolve_passes
from penumbra.core.scene import ObjectInfo
from helpers import embree_pass
from synthetic import area_light, half_plane_scene, light_matrix, quad, sphere_light


def test_spot_cone_missing_every_receiver_is_skipped_and_equal():
    sc = half_plane_scene(area_light(1.0), res=24)
    spot = sphere_light(0.2, z=4.0, name="Spot", spot_size=np.radians(20))
    spot.world_from_light = light_matrix((30.0, 0, 4.0))          # its cone lands far away
    sc.lights = [spot]
    res = render_frame(sc, ["pcf", "embree"], overrides={"samples": 8})
    lp = res.plan.lights[0]
    assert lp.action == "skip" and "reaches no visible receiver" in lp.reason
    # what computing it would have given, after the same unreached -> 1 rule
    fb = FrameBuffers(sc, 24, 24)
    v = np.where(reach_mask(fb.gbuffer, spot), embree_pass(fb, spot, 8), 1.0)
    np.testing.assert_array_equal(res.lights[0].passes["embree"], v)


def test_occluder_culling_changes_no_pixel():
    """Add far-away clutter that cannot shadow anything visible: it is culled
    from the light's BVH and every pixel stays bit-identical."""
    sc = half_plane_scene(area_light(1.0), res=32)
    clutter = []
    for k in range(40):
        clutter += quad(50 + k, 51 + k, 50, 51, 1.0)
    sc.triangles = np.concatenate([sc.triangles, np.array(clutter, np.float32)])
    sc.tri_object = np.concatenate([sc.tri_object, np.full(len(clutter), 2, np.int32)])
    sc.objects.append(ObjectInfo("clutter", 2))
    fb = FrameBuffers(sc, 32, 32)
    light = sc.lights[0]
    culled = fb.shadow_scene_for(light)
    assert culled.count == 4 and fb.culling["Area"] == {"casters": 84, "kept": 4}
    g = fb.gbuffer
    idx = np.flatnonzero(g.hit.reshape(-1))
    P = g.position.reshape(-1, 3)[idx]
    N = g.normal.reshape(-1, 3)[idx].astype(np.float64)
    a = trace_visibility(culled, P, N, idx, light, 64, 0, fb.scale)
    b = trace_visibility(fb.shadow_scene, P, N, idx, light, 64, 0, fb.scale)
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])
    res = render_frame(sc, ["embree"], overrides={"samples": 16})
    assert any("occluders: 4 of 84" in d for d in res.plan.lights[0].decisions)


def test_zero_size_light_plans_hard_shadows_with_one_sample():
    sc = half_plane_scene(area_light(0.0), res=16)
    res = render_frame(sc, ["embree"], overrides={"samples": 64})
    assert res.plan.lights[0].action == "hard"
    assert res.lights[0].record["embree"]["stats"]["samples"] == 1


def test_plan_json_carries_reasons():
    sc = half_plane_scene(area_light(1.0), res=16)
    rec = render_frame(sc, ["pcf"]).to_json()["plan"]
    (lp,) = rec["lights"]
    assert lp["action"] == "compute" and lp["reason"] and lp["decisions"]
    assert lp["buffers"] == ["gbuffer", "light_view"]


def test_materials_treated_as_opaque_survive_a_scene_copy_and_reach_the_plan():
    """``Scene.alpha_opaque`` is a field: ``dataclasses.replace`` (the
    filtered frame's supersampled scene, the CLI's resolution override) keeps
    it, and the plan names each material in one note; a scene without any has
    no such note."""
    import dataclasses
    sc = half_plane_scene(area_light(1.0), res=16)
    assert sc.alpha_opaque == [] and not any("opaque" in n for n in make_plan(sc, ["pcf"]).notes)
    sc.alpha_opaque = ["Bark: Math node on Alpha", "Moss: image 'moss.png' missing"]
    copy = dataclasses.replace(sc, resolution=(8, 8))
    notes = [n for n in make_plan(copy, ["pcf"]).notes if "opaque" in n]
    assert len(notes) == 1 and "Bark: Math node" in notes[0] and "moss.png" in notes[0]


def test_layer_names_are_exr_safe():
    assert layer_name("Key.Light.001") == "Key_Light_001"


def test_resolve_passes():
    assert resolve_passes("pcf,embree") == ["pcf", "embree"]
    assert {"pcf", "embree", "embree_irr"} <= set(resolve_passes("all"))
    with pytest.raises(PlanError, match="unknown method 'nope'"):
        resolve_passes("pcf,nope")


def test_plan_rules():
    sc = half_plane_scene(area_light(1.0), res=8)
    off = area_light(1.0, name="Off")
    off.casts_shadow = False
    dark = area_light(1.0, name="Dark")
    dark.energy = 0.0
    tiny = sphere_light(0.0, name="Tiny.Point")
    sc.lights += [off, dark, tiny]
    plan = make_plan(sc, ["pcf", "embree"])
    by = {lp.name: lp for lp in plan.lights}
    assert by["Area"].action == "compute"
    assert by["Off"].action == "skip" and "shadow is off" in by["Off"].reason
    assert by["Dark"].action == "skip" and "energy" in by["Dark"].reason
    assert by["Tiny.Point"].action == "hard" and by["Tiny.Point"].layer == "Tiny_Point"
    assert by["Area"].buffers == ["gbuffer", "light_view", "shadow_geometry"]
    with pytest.raises(PlanError, match="unknown light"):
        make_plan(sc, ["pcf"], ["Nope"])
