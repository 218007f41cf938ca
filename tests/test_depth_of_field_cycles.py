"""Depth of field against Cycles: the sun-lit pillars seen through an f/0.2
lens focused at a tenth of the distance to them (a blur disk of several
pixels on their hard shadows at 48 x 48), rendered by Cycles with
the scene's filter (Blackman-Harris 1.5 px), shadow on / off. The filtered
``embree_irr`` pass, whose sub-pixel receivers lie on thin-lens rays
(``core/camera_samples.py``), equals Cycles' ratio within the Monte Carlo
noise; the same pass through a pinhole does not.

Noise bound: ``helpers.mc_noise_bound`` (per-sample variance; a filtered
pixel averages many samples, so it is loose only upward) plus LENS_NOISE,
the lens' own sampling error at 8 x 8 lens samples per pixel (the thin-lens
closed form in test_depth_of_field.py measures it at about 0.01 RMSE)."""
import math

import bpy  # noqa: F401  (the module needs bpy: tests/conftest.py)
import numpy as np

from penumbra.bridge import cycles_reference as cr
from penumbra.bridge import settings
from penumbra.bridge.capture import capture_scene
from penumbra.core.buffers import FrameBuffers
from penumbra.core.filtered_frame import render_filtered
from penumbra.core.metrics import reach_mask
from helpers import mc_noise_bound, rmse
from scenes import open_sample

RES = (48, 48)
CYCLES_SAMPLES = 512
EMBREE_SAMPLES = 256
LENS_NOISE = 0.015
SCENE = "sun_pillars"


def test_a_defocused_shadow_pass_is_the_defocused_render_ratio():
    scene = open_sample(SCENE)
    scene.render.engine = "CYCLES"
    scene.cycles.pixel_filter_type = "BLACKMAN_HARRIS"
    scene.cycles.filter_width = 1.5
    cam = scene.camera
    target = np.zeros(3)
    distance = float(np.dot(np.array(cam.matrix_world.to_3x3().col[2]), np.array(cam.location) - target))
    cam.data.dof.use_dof = True
    cam.data.dof.focus_distance = 0.1 * distance
    cam.data.dof.aperture_fstop = 0.2
    flt = settings.pixel_filter(scene, "scene:8")
    captured = capture_scene(scene, resolution=RES)
    assert captured.camera.aperture_radius > 0
    producer = cr.make_cycles_producer(scene, RES, samples=CYCLES_SAMPLES, seed=0, pixel_filter=flt)
    over = {"samples": EMBREE_SAMPLES, "seed": 1}
    result = render_filtered(captured, ["embree_irr", "cycles"], overrides=over,
                             external={"cycles": producer}, pixel_filter=flt)
    assert cam.data.dof.use_dof                        # the reference left the user's camera as it was
    pinhole = capture_scene(scene, resolution=RES)
    pinhole.camera.aperture_radius = 0.0
    sharp = render_filtered(pinhole, ["embree_irr"], overrides=over, pixel_filter=flt).lights[0].passes["embree_irr"]
    lr = result.lights[0]
    c, e = lr.passes["cycles"], lr.passes["embree_irr"]
    g = FrameBuffers(captured, *RES, None).gbuffer
    ok = reach_mask(g, captured.lights[0])
    ok[:2], ok[-2:], ok[:, :2], ok[:, -2:] = False, False, False, False   # Cycles traces beyond the frame
    sigma = mc_noise_bound(e[ok], CYCLES_SAMPLES, EMBREE_SAMPLES)
    err, err_sharp = rmse(c, e, ok), rmse(c, sharp, ok)
    print(f"\ndefocused {SCENE}: embree_irr vs Cycles {err:.4f} on {ok.sum()} px (MC bound {sigma:.4f}); "
          f"through a pinhole {err_sharp:.4f}")
    assert err <= sigma + LENS_NOISE
    assert err_sharp > 2 * err
