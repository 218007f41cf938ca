"""Every method's default pass composites: on the foliage sample scene (3,000
single-sided leaves at random orientations, so the unshadowed irradiance
varies within a pixel's footprint), the filtered irradiance pass of each
method is close to Cycles' own shadow ratio (shadowed / unshadowed Diffuse
Direct, the scene's Blackman-Harris 1.5 px filter), and closer than the same
method's average pass (equation 2, resolved by the filter weights alone),
which mixes receivers that face the light differently as if they were
equally lit. ``layered`` is the exception: its LDI misses the light's samples
that graze a leaf's plane, and the irradiance weights make those decide the
pass, so on leaves its weighted pass is further from Cycles than its average
(its bound says how far)."""
import bpy  # noqa: F401  (the module needs bpy: tests/conftest.py)
import numpy as np
import pytest

from penumbra.bridge import cycles_reference as cr
from penumbra.bridge import settings
from penumbra.bridge.capture import capture_scene
from penumbra.core.buffers import FrameBuffers
from penumbra.core.filtered_frame import render_filtered
from penumbra.core.metrics import reach_mask
from helpers import rmse
from scenes import open_sample

RES = (96, 96)
CYCLES_SAMPLES = 512
#: the default pass's RMSE to Cycles' ratio over lit pixels may not exceed this
#: (the Monte Carlo noise of both at these samples is about 0.01)
BOUND = {"embree_irr": 0.02, "penumbra_casting": 0.02, "irregular": 0.02, "depth_raytrace": 0.026,
         "single_sample": 0.055, "pcf": 0.055, "layered": 0.09}
#: the weighted pass is further from Cycles than the average on leaves (module docstring)
WORSE_WEIGHTED = ("layered",)


@pytest.fixture(scope="module")
def foliage():
    scene = open_sample("foliage")
    flt = settings.pixel_filter(scene, "scene")
    assert (flt.kind, flt.width) == ("blackman-harris", 1.5)
    captured = capture_scene(scene, resolution=RES)
    light = captured.lights[0]
    producer = cr.make_cycles_producer(scene, RES, samples=CYCLES_SAMPLES, seed=3, pixel_filter=flt)
    truth = producer(light).passes["cycles"]
    lit = reach_mask(FrameBuffers(captured, *RES).gbuffer, light)
    assert lit.sum() > 0.5 * RES[0] * RES[1]
    return captured, flt, truth, lit


@pytest.mark.parametrize("pid", sorted(BOUND))
def test_the_default_pass_is_cycles_shadow_ratio(foliage, pid):
    captured, flt, truth, lit = foliage

    def frame(visibility):
        return render_filtered(captured, [pid], pixel_filter=flt,
                               overrides={"samples": 64, "seed": 1, "visibility": visibility})
    default = frame("irradiance").lights[0]
    assert default.record[pid]["visibility"] == "irradiance"
    err = rmse(default.passes[pid], truth, lit)
    assert err <= BOUND[pid], (pid, err)
    if pid != "embree_irr":                   # the reference's irradiance pass has no average twin
        average = frame("average").lights[0]
        assert average.record[pid]["visibility"] == "average"
        closer = err < rmse(average.passes[pid], truth, lit) - 0.005
        assert closer != (pid in WORSE_WEIGHTED), pid
