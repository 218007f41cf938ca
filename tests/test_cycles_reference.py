"""The ``cycles`` reference (bridge/cycles_reference.py) against
``embree_irr``, and that it leaves the scene exactly as it found it.

Both references estimate the same ratio V = sum_i w_i v_i / sum_i w_i per
pixel, independently (Cycles renders shadowed and unshadowed with one seed,
so numerator and denominator share their samples, as embree_irr's do):
their RMSE is asserted within the Monte Carlo noise bound
(``helpers.mc_noise_bound``, with V taken from embree_irr) on pixels that
see the whole light above their tangent plane (``helpers.fully_facing``: at
the terminator Cycles shades with the smooth-shading normal and Penumbra
with the geometric one, a different, legitimate answer, counted separately
and allowed to be rare). A one-pixel misalignment would add the image
gradient: several times the bound on these scenes, which the shifted
comparisons check.
"""
import glob
import math
import os
import tempfile

import bpy
import numpy as np
import pytest

from penumbra.core.buffers import FrameBuffers
from penumbra.core.frame import render_frame
from penumbra.core.metrics import reach_mask
from penumbra.bridge import cycles_reference as cr
from penumbra.bridge.capture import capture_scene
from helpers import fully_facing, mc_noise_bound, rmse
from scenes import image_rgba, open_sample, render_state, sample_path

RES = (64, 64)
CYCLES_SAMPLES = 128
EMBREE_SAMPLES = 1024


# --------------------------------------------------------------------------
# the ratio itself
def test_shadow_ratio_is_finite_and_clamped():
    sh = np.array([[[0.2, 0.2, 0.2], [0.0, 0.0, 0.0], [np.nan, 0, 0], [2.0, 2.0, 2.0], [0.0, 0.3, 0.0]]])
    un = np.array([[[0.4, 0.4, 0.4], [0.0, 0.0, 0.0], [1.0, 1, 1], [1.0, 1.0, 1.0], [0.0, 0.6, 0.0]]])
    v = cr.shadow_ratio(sh, un)
    assert v.dtype == np.float32 and v.shape == (1, 5)
    assert np.isfinite(v).all()
    # half; 0/0 -> 0; NaN -> 0; above 1 -> 1; a green light: ratio of the channel sums
    np.testing.assert_allclose(v[0], [0.5, 0.0, 0.0, 1.0, 0.5], atol=1e-6)


@pytest.mark.parametrize("name", ["sphere_plane", "torus_plane"])
def test_cycles_reference_matches_embree_irr(name):
    scene = open_sample(name)
    blend_mtime = os.path.getmtime(sample_path(name))
    captured = capture_scene(scene, resolution=RES)
    before = render_state(scene)
    tmp_before = set(glob.glob(os.path.join(tempfile.gettempdir(), "penumbra_cycles_*")))
    producer = cr.make_cycles_producer(scene, RES, samples=CYCLES_SAMPLES, seed=0)
    result = render_frame(captured, ["embree", "embree_irr", "cycles"],
                          overrides={"samples": EMBREE_SAMPLES, "seed": 1},
                          external={"cycles": producer})
    # the scene is exactly as it was, the file untouched, no temporary files left
    assert render_state(scene) == before
    assert os.path.getmtime(sample_path(name)) == blend_mtime
    assert set(glob.glob(os.path.join(tempfile.gettempdir(), "penumbra_cycles_*"))) == tmp_before
    assert not cr.is_rendering()

    lr = result.lights[0]
    rec = lr.record["cycles"]
    assert rec["visibility"] == "irradiance"
    assert set(rec["time_s"]) == {"render_shadowed", "render_unshadowed", "total"}
    assert all(t > 0 for t in rec["time_s"].values())
    assert rec["params"]["samples"] == CYCLES_SAMPLES and rec["params"]["seed"] == 0
    assert rec["params"]["filter"] == {"type": "GAUSSIAN", "width_px": 0.01}
    assert rec["error"]["reference"] == "embree_irr"

    c, e = lr.passes["cycles"], lr.passes["embree_irr"]
    assert c.shape == (RES[1], RES[0]) and c.dtype == np.float32
    assert np.isfinite(c).all() and c.min() >= 0.0 and c.max() <= 1.0
    light = captured.lights[0]
    g = FrameBuffers(captured, *RES, None).gbuffer
    reach = reach_mask(g, light)
    core = reach & fully_facing(g, light)
    assert core.sum() > 0.5 * reach.sum()
    penumbra_px = core & (e > 0.02) & (e < 0.98)
    assert penumbra_px.sum() >= 20, "the scene must have a penumbra to compare"
    assert (e[core] < 0.5).sum() >= 20, "and a shadow"

    sigma_mc = mc_noise_bound(e[core], CYCLES_SAMPLES, EMBREE_SAMPLES)
    err_core = rmse(c, e, core)
    mean_signed = float(np.mean((c - e.astype(np.float64))[core]))
    big = reach & (np.abs(c - e) > 0.25)
    print(f"\n{name}: Cycles {CYCLES_SAMPLES} spp renders {rec['time_s']['render_shadowed']:.2f} s + "
          f"{rec['time_s']['render_unshadowed']:.2f} s; RMSE vs embree_irr ({EMBREE_SAMPLES} spp): "
          f"{err_core:.4f} on {core.sum()} fully lit-facing px (MC bound {sigma_mc:.4f}), "
          f"{rec['error']['rmse']:.4f} on all {reach.sum()} reachable px; penumbra RMSE "
          f"{rmse(c, e, penumbra_px):.4f} on {penumbra_px.sum()} px; mean signed {mean_signed:+.5f}; "
          f"|diff| > 0.25 on {big.sum()} px")
    assert err_core <= sigma_mc
    # no systematic offset: the mean of the per-pixel noise has std sigma_mc / sqrt(n)
    assert abs(mean_signed) <= 4.0 * sigma_mc / math.sqrt(core.sum()) + 1e-4
    # terminator / silhouette disagreements are rare
    assert big.sum() <= max(2, 0.002 * reach.sum())
    # aligned with pixel centres: any one-pixel shift of the reference is clearly worse
    inner = np.zeros_like(core)
    inner[1:-1, 1:-1] = True
    for dy, dx in ((0, 1), (0, -1), (1, 0), (-1, 0)):
        shifted = np.roll(e, (dy, dx), axis=(0, 1))
        m = core & np.roll(core, (dy, dx), axis=(0, 1)) & inner
        assert rmse(c, shifted, m) > 2.0 * rmse(c, e, m), (dy, dx)


# --------------------------------------------------------------------------
# one light at a time, no world, restored settings, on a scene built for it
def _mesh(scene, name, verts, faces):
    me = bpy.data.meshes.new(name)
    me.from_pydata(verts, [], faces)
    ob = bpy.data.objects.new(name, me)
    scene.collection.objects.link(ob)
    return ob


def _box_scene():
    """A ground, a floating square occluder (not seen by the camera), area
    light A straight above it, light B low at the side (lights A's umbra), a
    bright world, a hidden light, a user material override and unusual
    render settings."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.engine = "BLENDER_WORKBENCH"
    scene.render.resolution_x, scene.render.resolution_y = 48, 48
    scene.cycles.samples = 7
    scene.cycles.pixel_filter_type = "BOX"
    scene.cycles.max_bounces = 5
    _mesh(scene, "Ground", [(-6, -6, 0), (6, -6, 0), (6, 6, 0), (-6, 6, 0)], [(0, 1, 2, 3)])
    occ = _mesh(scene, "Occluder", [(-1, -1, 1), (1, -1, 1), (1, 1, 1), (-1, 1, 1)], [(0, 1, 2, 3)])
    occ.visible_camera = False          # the camera sees the ground under it
    cam = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    scene.collection.objects.link(cam)
    cam.location = (0, 0, 12)
    scene.camera = cam
    a = bpy.data.objects.new("A", bpy.data.lights.new("A", "AREA"))
    a.data.size, a.data.energy = 0.2, 500.0
    a.location = (0, 0, 4)
    b = bpy.data.objects.new("B", bpy.data.lights.new("B", "POINT"))
    b.data.energy, b.data.use_shadow = 2000.0, False
    b.location = (5, 0, 0.5)
    hidden = bpy.data.objects.new("Hidden", bpy.data.lights.new("Hidden", "POINT"))
    hidden.hide_render = True
    for ob in (a, b, hidden):
        scene.collection.objects.link(ob)
    world = bpy.data.worlds.new("Bright")
    bg = world.node_tree.nodes.get("Background")
    bg.inputs["Strength"].default_value = 5.0
    scene.world = world
    user_mat = bpy.data.materials.new("UserOverride")
    scene.view_layers[0].material_override = user_mat
    return scene


def test_one_light_at_a_time_without_the_world():
    scene = _box_scene()
    before = render_state(scene)
    res = (24, 24)
    v_a, times = cr.render_light_reference(scene, "A", res, samples=16, seed=3)
    assert render_state(scene) == before
    assert set(times) == {"render_shadowed", "render_unshadowed"}
    # the camera looks straight down: the centre is A's umbra under the
    # occluder, the corners are open ground. B and the world light the umbra
    # too, so only with them off is it 0.
    assert v_a.shape == (24, 24)
    assert v_a[10:14, 10:14].max() == 0.0
    assert v_a[:3, :3].min() > 0.99 and v_a[-3:, -3:].min() > 0.99
    # B's own shadow is off in the file: its reference renders it on, then restores it
    v_b, _ = cr.render_light_reference(scene, "B", res, samples=16, seed=3)
    assert render_state(scene) == before and not scene.objects["B"].data.use_shadow
    assert np.isfinite(v_b).all() and 0.0 <= v_b.min() and v_b.max() <= 1.0
    # the same seed gives the same image
    v_a2, _ = cr.render_light_reference(scene, "A", res, samples=16, seed=3)
    np.testing.assert_array_equal(v_a, v_a2)


def test_scene_restored_when_the_render_fails(monkeypatch):
    scene = _box_scene()
    before = render_state(scene)
    calls = []
    real = cr._render_once

    def failing(*args):
        calls.append(1)
        if len(calls) == 2:
            raise RuntimeError("Error: simulated render failure")
        return real(*args)

    monkeypatch.setattr(cr, "_render_once", failing)
    with pytest.raises(RuntimeError, match="simulated"):
        cr.render_light_reference(scene, "A", (8, 8), samples=1)
    assert len(calls) == 2
    assert render_state(scene) == before
    assert cr.WHITE_MATERIAL not in bpy.data.materials
    assert not cr.is_rendering()


def test_bad_input_is_a_clear_error():
    scene = _box_scene()
    with pytest.raises(cr.CyclesReferenceError, match="no light object"):
        cr.render_light_reference(scene, "Nope", (8, 8))
    with pytest.raises(cr.CyclesReferenceError, match="instance"):
        cr.render_light_reference(scene, "Empty/Lamp#1", (8, 8))
    with pytest.raises(cr.CyclesReferenceError, match="not a light"):
        cr.render_light_reference(scene, "Ground", (8, 8))
    scene.camera = None
    with pytest.raises(cr.CyclesReferenceError, match="no camera"):
        cr.render_light_reference(scene, "A", (8, 8))


# --------------------------------------------------------------------------
# the operator
def test_operator_stores_reference_images(registered):
    from penumbra.bridge import compositor
    scene = open_sample("sphere_plane")
    scene.render.resolution_x, scene.render.resolution_y = 40, 30
    scene.penumbra.render_passes = True       # switched off for the reference renders, then back
    before = render_state(scene)
    assert before["penumbra.render_passes"] is True
    assert bpy.ops.penumbra.render_cycles_reference(samples=16, seed=2) == {"FINISHED"}
    assert render_state(scene) == before
    img = bpy.data.images[compositor.pass_image_name("Key_Light", "cycles")]
    assert tuple(img.size) == (40, 30)
    v = image_rgba(img)[..., 0]
    assert np.isfinite(v).all() and v.min() == 0.0 and v.max() > 0.99
    # a resolution scale renders smaller
    assert bpy.ops.penumbra.render_cycles_reference(samples=4, resolution_scale=0.5) == {"FINISHED"}
    img = bpy.data.images[compositor.pass_image_name("Key_Light", "cycles")]   # remade at the new size
    assert tuple(img.size) == (20, 15)


def test_operator_reports_missing_camera(registered):
    scene = _box_scene()
    scene.camera = None
    with pytest.raises(RuntimeError, match="no camera"):
        bpy.ops.penumbra.render_cycles_reference(samples=1)
