"""Alpha mattes against Cycles.

1. Each wiring the capture reads, on a card that shadows the ground under a
   small light: Cycles multiplies (1 - alpha) along a shadow ray (with
   ``transparent_max_bounces`` high enough), so under the card's umbra the
   shadowed / unshadowed ratio is exactly 1 - alpha, the alpha the capture
   read; the reference render leaves the scene as it was.
2. The accuracy on ``leaf_cards``: ``embree_irr`` (and ``embree``) with the
   mattes within Monte Carlo noise of the Cycles ratio
   (``helpers.mc_noise_bound``, as in test_cycles_reference.py), on ground
   pixels the camera sees directly (a camera ray through a card mixes two
   receivers in Cycles' ratio).
"""
import dataclasses
import math

import bpy
import numpy as np
import pytest

from penumbra.bridge import compat
from penumbra.bridge import cycles_reference as cr
from penumbra.bridge.capture import capture_scene
from penumbra.core.buffers import FrameBuffers
from penumbra.core.frame import render_frame
from penumbra.core.metrics import reach_mask
from helpers import fully_facing, mc_noise_bound, rmse
from scenes import open_sample, render_state

RES = (16, 16)


def _uniform_image(name, value, byte=False, channel="alpha"):
    img = bpy.data.images.new(name, 4, 4, alpha=True, float_buffer=not byte)
    px = np.ones((4, 4, 4), np.float32)
    if channel == "alpha":
        px[..., 3] = value
    else:
        px[..., :3] = value
    img.pixels.foreach_set(px.ravel())
    return img


def _wired(kind):
    """(material, the alpha the wiring stands for)."""
    mat = bpy.data.materials.new(kind)
    nt = mat.node_tree
    bsdf, out = nt.nodes["Principled BSDF"], nt.nodes["Material Output"]
    if kind == "constant":
        bsdf.inputs["Alpha"].default_value = 0.5
        return mat, 0.5
    tex = nt.nodes.new("ShaderNodeTexImage")
    if kind == "image_alpha":
        tex.image = _uniform_image("a", 0.25)
        nt.links.new(tex.outputs["Alpha"], bsdf.inputs["Alpha"])
        return mat, 0.25
    if kind == "image_color_srgb":
        tex.image = _uniform_image("c", 0.5, byte=True, channel="rgb")
        assert tex.image.colorspace_settings.name == "sRGB"
        nt.links.new(tex.outputs["Color"], bsdf.inputs["Alpha"])
        q = round(0.5 * 255) / 255                     # 8 bits, then sRGB -> linear
        return mat, ((q + 0.055) / 1.055) ** 2.4
    if kind.startswith("image_color_premultiplied"):
        # Color = (0.8, 0.8, 0.8), alpha 0.5: Cycles premultiplies the Color output
        # unless the Alpha output is linked too (here to Roughness, which does
        # not change the shadow); a byte image in 8 bits, before sRGB -> linear
        byte = kind.endswith("byte")
        img = bpy.data.images.new("p", 4, 4, alpha=True, float_buffer=not byte)
        px = np.full((4, 4, 4), 0.8, np.float32)
        px[..., 3] = 0.5
        img.pixels.foreach_set(px.ravel())
        tex.image = img
        nt.links.new(tex.outputs["Color"], bsdf.inputs["Alpha"])
        if not byte:        # 5.0: a float buffer is stored premultiplied (compat)
            return mat, 0.8 if compat.float_pixels_premultiplied() else 0.4
        q = round(0.8 * 255 * round(0.5 * 255) / 255) / 255
        return mat, ((q + 0.055) / 1.055) ** 2.4
    if kind == "image_color_unassociated_float":
        img = bpy.data.images.new("u", 4, 4, alpha=True, float_buffer=True)
        px = np.full((4, 4, 4), 0.3, np.float32)
        px[..., 3] = 0.5
        img.pixels.foreach_set(px.ravel())
        tex.image = img
        nt.links.new(tex.outputs["Color"], bsdf.inputs["Alpha"])
        nt.links.new(tex.outputs["Alpha"], bsdf.inputs["Roughness"])
        return mat, 0.6 if compat.float_pixels_premultiplied() else 0.3   # 0.3 / alpha 0.5 in 5.0
    assert kind == "mix_shader"
    tex.image = _uniform_image("m", 0.3)
    clear = nt.nodes.new("ShaderNodeBsdfTransparent")
    mix = nt.nodes.new("ShaderNodeMixShader")
    nt.links.new(tex.outputs["Alpha"], mix.inputs[0])
    nt.links.new(clear.outputs["BSDF"], mix.inputs[1])
    nt.links.new(bsdf.outputs["BSDF"], mix.inputs[2])
    nt.links.new(mix.outputs["Shader"], out.inputs["Surface"])
    return mat, 0.3


def _card_over_ground(kind):
    """A ground, a 4 x 4 card with the wiring ``kind`` at height 1 (hidden
    from the camera), a small area light above; returns (scene, alpha)."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    material, alpha = _wired(kind)
    scene.render.engine = "CYCLES"

    def quad(name, h, z, mat):
        me = bpy.data.meshes.new(name)
        me.from_pydata([(-h, -h, z), (h, -h, z), (h, h, z), (-h, h, z)], [], [[0, 1, 2, 3]])
        me.uv_layers.new(name="UVMap")
        if mat is not None:
            me.materials.append(mat)
        ob = bpy.data.objects.new(name, me)
        scene.collection.objects.link(ob)
        return ob
    quad("Ground", 6.0, 0.0, bpy.data.materials.new("Ground"))
    card = quad("Card", 2.0, 1.0, material)
    card.visible_camera = False                 # the camera sees the ground
    twin = bpy.data.objects.new("Twin", card.data)      # a linked duplicate, out of view
    twin.location = (9.0, 0.0, 0.0)
    scene.collection.objects.link(twin)
    cam = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    cam.data.type, cam.data.ortho_scale = "ORTHO", 4.0
    cam.location = (0, 0, 12)
    scene.collection.objects.link(cam)
    scene.camera = cam
    light = bpy.data.objects.new("Light", bpy.data.lights.new("Light", "AREA"))
    light.data.size, light.data.energy = 0.2, 500.0
    light.location = (0, 0, 4)
    scene.collection.objects.link(light)
    return scene, alpha


@pytest.mark.parametrize("kind", ["constant", "image_alpha", "image_color_srgb",
                                  "image_color_premultiplied_float", "image_color_premultiplied_byte",
                                  "image_color_unassociated_float", "mix_shader"])
def test_reference_sees_each_wiring_as_the_capture_reads_it(kind):
    scene, alpha = _card_over_ground(kind)
    captured = capture_scene(scene, resolution=RES)
    m = captured.alpha
    assert m is not None and m.count == 1
    assert np.allclose(m.texels, alpha, atol=2e-3), (m.texels, alpha)
    before = render_state(scene)
    slots = [(ob.name, [s.material for s in ob.material_slots]) for ob in scene.objects]
    v, _ = cr.render_light_reference(scene, "Light", RES, samples=16)
    assert render_state(scene) == before
    assert [(ob.name, [s.material for s in ob.material_slots]) for ob in scene.objects] == slots
    umbra = v[4:12, 4:12]                       # ground under the card's middle (|x|, |y| < 1)
    assert np.allclose(umbra, 1.0 - float(m.texels.mean()), atol=2e-3), (kind, umbra.mean())


CYCLES_SAMPLES = 128
EMBREE_SAMPLES = 1024
ACCURACY_RES = (64, 64)


def test_embree_matches_cycles_on_leaf_cards():
    scene = open_sample("leaf_cards")
    captured = capture_scene(scene, resolution=ACCURACY_RES)
    assert captured.alpha is not None
    producer = cr.make_cycles_producer(scene, ACCURACY_RES, samples=CYCLES_SAMPLES, seed=0)
    result = render_frame(captured, ["embree", "embree_irr", "cycles"],
                          overrides={"samples": EMBREE_SAMPLES, "seed": 1},
                          external={"cycles": producer})
    lr = result.lights[0]
    c, e, e_vis = lr.passes["cycles"], lr.passes["embree_irr"], lr.passes["embree"]
    light = captured.lights[0]
    # ground pixels no card's quad covers: Cycles' ratio there is one receiver's
    opaque = FrameBuffers(dataclasses.replace(captured, alpha=None), *ACCURACY_RES, None).gbuffer
    ground = next(o.id for o in captured.objects if o.name == "Ground")
    core = reach_mask(opaque, light) & fully_facing(opaque, light) & (opaque.object_id == ground)
    shadowed = core & (e < 0.98)
    assert shadowed.sum() >= 100, "the leaf cards must shadow the ground"
    sigma_mc = mc_noise_bound(e[core], CYCLES_SAMPLES, EMBREE_SAMPLES)
    err = rmse(c, e, core)
    mean_signed = float(np.mean((c - e.astype(np.float64))[core]))
    print(f"\nleaf_cards: embree_irr vs Cycles RMSE {err:.4f} on {core.sum()} ground px "
          f"(MC bound {sigma_mc:.4f}; {shadowed.sum()} shadowed), mean signed {mean_signed:+.5f}; "
          f"embree (visibility) vs Cycles {rmse(c, e_vis, core):.4f}")
    assert err <= sigma_mc
    # ``embree`` (the visibility average) too: its definition differs from the
    # irradiance ratio only in the light-sample weights, below the noise here
    assert rmse(c, e_vis, core) <= sigma_mc
    assert abs(mean_signed) <= 4.0 * sigma_mc / math.sqrt(core.sum()) + 1e-4
    # the mattes matter: opaque cards are far off
    opaque_v = render_frame(dataclasses.replace(captured, alpha=None), ["embree_irr"],
                            overrides={"samples": 64, "seed": 1}).lights[0].passes["embree_irr"]
    assert rmse(c, opaque_v, shadowed) > 3.0 * sigma_mc
