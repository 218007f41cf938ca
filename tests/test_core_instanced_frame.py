"""A scene captured as instances renders without flattening: the G-buffer,
light views and shadow rays go through Embree's two-level BVH
(``raycast.InstanceScene``) and agree with the same scene flattened."""
import numpy as np

from helpers import instanced_grove, leaf_cluster, placement
from penumbra.core.buffers import FrameBuffers
from penumbra.core.filtered_frame import render_filtered
from penumbra.core.frame import render_frame
from penumbra.core.pixel_filter import parse
from penumbra.core.scene import Light
from synthetic import light_matrix, persp_camera


def _grove(res=48, casts=True):
    """A ground and 12 instances of one 60-leaf cluster (one object each,
    rotated and scaled), under an area light, seen obliquely."""
    rng = np.random.default_rng(5)
    verts, leaves = leaf_cluster(rng, 60, 0.25, (0, 0, 0.9), 0.08)
    n = 12
    xf = [placement((s, s, s), ang, (x, y, 0)) for s, ang, x, y in
          zip(0.8 + 0.4 * rng.random(n), 6.3 * rng.random(n), *(rng.random((2, n)) * 3 - 1.5))]
    light = Light("Area", "area", light_matrix((0.5, -0.4, 3.5), (-0.5, 0.4, -3.5)), blender_type="AREA",
                  shape="SQUARE", size=1.2)
    cam = persp_camera((3.2, -3.6, 2.6), (0, 0, 0.5), lens=30.0)
    return instanced_grove(verts, leaves, 4.0, xf, light, cam, res, casts)


def test_the_instanced_gbuffer_is_the_flattened_one():
    lazy, flat = _grove()
    gi = FrameBuffers(lazy, 48, 48).gbuffer
    gf = FrameBuffers(flat, 48, 48).gbuffer
    assert not lazy.is_flattened
    assert gi.hit.mean() > 0.5 and (gf.object_id > 0).mean() > 0.1
    assert np.mean(gi.hit != gf.hit) < 1e-3
    both = gi.hit & gf.hit
    assert np.mean(gi.triangle_id[both] == gf.triangle_id[both]) > 0.999
    assert np.mean(gi.object_id[both] == gf.object_id[both]) > 0.999
    same = gi.triangle_id == gf.triangle_id
    np.testing.assert_allclose(gi.position[both & same], gf.position[both & same], atol=1e-5)
    np.testing.assert_allclose(gi.normal[both & same], gf.normal[both & same], atol=1e-5)
    np.testing.assert_allclose(gi.depth[both & same], gf.depth[both & same], rtol=1e-5)


def test_passes_on_instances_match_the_flattened_scene_without_flattening():
    """embree_irr and pcf (shadow rays, a light view) on the instances equal
    the flattened scene's passes up to float32 rounding of the leaves, and
    the scene is never flattened; a method that needs the triangles
    (penumbra_casting) expands the instances that can shadow a visible
    receiver (here every one) and leaves the scene as instances."""
    lazy, flat = _grove()
    opts = {"overrides": {"samples": 64}}
    for passes in (["embree_irr"], ["pcf"]):
        a = render_filtered(lazy, passes, pixel_filter=parse("box:1.5"), **opts).lights[0].passes[passes[0]]
        b = render_filtered(flat, passes, pixel_filter=parse("box:1.5"), **opts).lights[0].passes[passes[0]]
        assert a.min() < 0.5                                   # the grove shadows the ground
        assert np.mean(np.abs(a - b)) < 2e-3 and np.mean(np.abs(a - b) > 0.05) < 5e-3, passes
    assert not lazy.is_flattened
    light = render_frame(lazy, ["penumbra_casting"], overrides={"samples": 64}).lights[0]
    assert not lazy.is_flattened and np.isfinite(light.passes["penumbra_casting"]).all()
    assert light.record["penumbra_casting"]["expanded"]["instances"] == 13


def test_instances_that_cast_no_shadow_are_left_out_of_the_shadow_rays():
    """Trees whose objects cast no shadow (Cycles' ``visible_shadow`` off)
    leave the ground lit: the pass is the flattened scene's, not the
    casting grove's."""
    lit, lit_flat = _grove(casts=False)
    shading, _ = _grove()
    v = {name: render_frame(s, ["embree_irr"], overrides={"samples": 16}).lights[0].passes["embree_irr"]
         for name, s in (("lit", lit), ("flat", lit_flat), ("shading", shading))}
    assert not lit.is_flattened
    assert np.mean(np.abs(v["lit"] - v["flat"])) < 1e-3
    assert np.mean(v["lit"] < 0.9) < 0.01 < np.mean(v["shading"] < 0.9)


def test_auto_keeps_to_methods_that_run_on_instances_when_flattening_cannot_fit(monkeypatch):
    """When the flattened soup would not fit in memory, ``auto`` picks only
    among the methods that run on instances, and its frame never flattens;
    otherwise its candidates are every measured method."""
    from penumbra.core import scene as core_scene
    from penumbra.core.auto_choice import scene_shape
    from penumbra.core.methods import producer_of
    from penumbra.core.planner import auto_choice_for

    lazy, _ = _grove()
    light = lazy.lights[0]
    assert not scene_shape(lazy, light).instanced_only
    monkeypatch.setattr(core_scene, "physical_memory", lambda: 1000)
    shape = scene_shape(lazy, light)
    assert shape.instanced_only and shape.triangles == 12 * 120 + 2      # the trees and the ground
    for budget in (0.001, 0.02, 0.5):
        choice = auto_choice_for(lazy, light, budget)
        assert producer_of(choice.method).runs_on_instances, (budget, choice.method)
    frame = render_frame(lazy, ["auto"], overrides={"samples": 16}, error_budget=0.02)
    (pid,) = frame.lights[0].passes
    assert producer_of(pid).runs_on_instances and not lazy.is_flattened
