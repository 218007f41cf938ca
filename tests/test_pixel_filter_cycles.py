"""Filtered passes against an anti-aliased Cycles render: with the
scene's own pixel filter (Blackman-Harris 1.5 px, Cycles' default), the
ratio of Cycles' shadowed / unshadowed Diffuse Direct (the factor a
compositor multiplies the unshadowed render by) equals the filtered
``embree_irr`` pass within the Monte Carlo noise, on the silhouette pixels
too, where the pixel-centre pass is far off.

Noise bound as in test_cycles_reference.py (``helpers.mc_noise_bound``):
sigma_MC = sqrt(mean(V(1-V)) (1/N_cycles + 1/N_embree)). A filtered pixel
averages many samples of several sub-pixel receivers, so this bound
(per-sample variance) is loose only upward. The sub-pixel grid (8 x 8 per pixel here) resolves an edge to
1/8 px: on an edge pixel the quadrature adds at most the filter's mass in
one grid column (BH 1.5: 0.11 at the centre column / 2 = 0.06, much less on
curved silhouettes, which cut many columns): QUADRATURE allows for it on
silhouette pixels only.
"""
import math

import bpy  # noqa: F401  (the module needs bpy: tests/conftest.py)
import numpy as np
import pytest

from penumbra.bridge import cycles_reference as cr
from penumbra.bridge import settings
from penumbra.bridge.capture import capture_scene
from penumbra.core.buffers import FrameBuffers
from penumbra.core.filtered_frame import render_filtered
from penumbra.core.frame import render_frame
from penumbra.core.metrics import reach_mask
from helpers import mc_noise_bound, rmse
from scenes import open_sample

RES = (48, 48)
CYCLES_SAMPLES = 512
EMBREE_SAMPLES = 256
QUADRATURE = 0.02


def _neighbourhood_all(mask: np.ndarray, reach: int) -> np.ndarray:
    out = mask.copy()
    for dy in range(-reach, reach + 1):
        for dx in range(-reach, reach + 1):
            out &= np.roll(mask, (dy, dx), axis=(0, 1))
    out[:reach], out[-reach:], out[:, :reach], out[:, -reach:] = False, False, False, False
    return out


@pytest.mark.parametrize("name", ["torus_plane"])
def test_unshadowed_times_filtered_pass_is_the_shadowed_render(name):
    scene = open_sample(name)
    scene.render.engine = "CYCLES"
    scene.cycles.pixel_filter_type = "BLACKMAN_HARRIS"
    scene.cycles.filter_width = 1.5
    flt = settings.pixel_filter(scene, "scene:8")
    assert (flt.kind, flt.width, flt.grid) == ("blackman-harris", 1.5, 8)
    captured = capture_scene(scene, resolution=RES)
    producer = cr.make_cycles_producer(scene, RES, samples=CYCLES_SAMPLES, seed=0, pixel_filter=flt)
    over = {"samples": EMBREE_SAMPLES, "seed": 1}
    result = render_filtered(captured, ["embree_irr", "cycles"], overrides=over,
                             external={"cycles": producer}, pixel_filter=flt)
    centre = render_frame(captured, ["embree_irr"], overrides=over).lights[0].passes["embree_irr"]
    lr = result.lights[0]
    assert lr.record["cycles"]["params"]["filter"] == {"type": "BLACKMAN_HARRIS", "width_px": 1.5}
    assert lr.record["embree_irr"]["pixel_filter"]["type"] == "blackman-harris"
    c, e = lr.passes["cycles"], lr.passes["embree_irr"]

    light = captured.lights[0]
    g = FrameBuffers(captured, *RES, None).gbuffer
    # pixels whose neighbours' centres all see a surface the light reaches (where it
    # cannot, Cycles' ratio is 0 / 0 and the pass holds V = 1)
    ok = _neighbourhood_all(reach_mask(g, light), 1)
    ids = g.object_id
    edge = np.zeros_like(ok)
    for dy, dx in ((0, 1), (0, -1), (1, 0), (-1, 0), (1, 1), (-1, -1), (1, -1), (-1, 1)):
        edge |= ids != np.roll(ids, (dy, dx), axis=(0, 1))
    silhouette = ok & edge
    assert silhouette.sum() >= 20, "the scene must have silhouette pixels to compare"
    sigma = mc_noise_bound(e[ok], CYCLES_SAMPLES, EMBREE_SAMPLES)
    err_all, err_sil = rmse(c, e, ok), rmse(c, e, silhouette)
    err_centre_sil = rmse(c, centre, silhouette)
    print(f"\n{name}: filtered embree_irr vs Cycles BH 1.5: RMSE {err_all:.4f} on {ok.sum()} px "
          f"(MC bound {sigma:.4f}), {err_sil:.4f} on {silhouette.sum()} silhouette px; "
          f"pixel-centre pass {err_centre_sil:.4f} there")
    assert err_all <= sigma + QUADRATURE * math.sqrt(silhouette.sum() / ok.sum())
    assert err_sil <= sigma + QUADRATURE
    assert err_centre_sil > 2 * err_sil          # what filtering fixes
