"""Motion blur against Cycles: a box sliding over a sun-lit ground, the
render's motion blur on (shutter 0.5 frames, centred on the frame), seen
from above at 48 x 48; Cycles renders the shadow on / off pair with the
scene's filter (Blackman-Harris 1.5 px). The filtered ``embree_irr`` pass,
whose sub-pixel receivers each take a shutter time and trace their shadow
rays against the box where it is then (``core/motion.py``), equals Cycles'
ratio within the Monte Carlo noise (``helpers.mc_noise_bound``) plus
TIME_NOISE, the shutter's own sampling error at 8 x 8 times per pixel (the
closed form in test_motion_blur.py measures about 0.01); the same scene
captured still does not."""
import bpy  # noqa: F401  (the module needs bpy: tests/conftest.py)
import numpy as np

from penumbra.bridge import cycles_reference as cr
from penumbra.bridge import settings
from penumbra.bridge.capture import capture_scene
from penumbra.core.buffers import FrameBuffers
from penumbra.core.filtered_frame import render_filtered
from penumbra.core.metrics import reach_mask
from helpers import mc_noise_bound, rmse
from scenes import sliding_box_scene

RES = (48, 48)
CYCLES_SAMPLES = 512
EMBREE_SAMPLES = 256
TIME_NOISE = 0.015


def test_a_moving_occluders_shadow_pass_is_the_blurred_render_ratio(factory_scene):
    sc = sliding_box_scene(factory_scene, RES)
    flt = settings.pixel_filter(sc, "scene:8")
    captured = capture_scene(sc, resolution=RES)
    assert captured.motion is not None and len(captured.motion.objects) == 1
    producer = cr.make_cycles_producer(sc, RES, samples=CYCLES_SAMPLES, seed=0, pixel_filter=flt)
    over = {"samples": EMBREE_SAMPLES, "seed": 1}
    result = render_filtered(captured, ["embree_irr", "cycles"], overrides=over,
                             external={"cycles": producer}, pixel_filter=flt)
    assert sc.render.use_motion_blur and sc.frame_current == 2     # the reference left the scene as it was
    still = capture_scene(sc, resolution=RES)
    still.motion = None
    sharp = render_filtered(still, ["embree_irr"], overrides=over, pixel_filter=flt).lights[0].passes["embree_irr"]
    lr = result.lights[0]
    c, e = lr.passes["cycles"], lr.passes["embree_irr"]
    g = FrameBuffers(captured, *RES, None).gbuffer
    ok = reach_mask(g, captured.lights[0]) & (g.object_id == g.object_id[0, 0])   # the ground, box excluded
    ok[:2], ok[-2:], ok[:, :2], ok[:, -2:] = False, False, False, False
    sigma = mc_noise_bound(e[ok], CYCLES_SAMPLES, EMBREE_SAMPLES)
    err, err_sharp = rmse(c, e, ok), rmse(c, sharp, ok)
    blurred = ok & (c > 0.1) & (c < 0.9)
    print(f"\nsliding box: embree_irr vs Cycles {err:.4f} on {ok.sum()} px (MC bound {sigma:.4f}); "
          f"captured still {err_sharp:.4f}; {blurred.sum()} px in the blurred shadow")
    assert blurred.sum() >= 30
    assert err <= sigma + TIME_NOISE
    assert err_sharp > 2 * err
    assert lr.record["embree_irr"]["shutter"] == "occluders at the receiver's time"
