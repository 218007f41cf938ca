"""penumbra_casting's pass as the irradiance ratio (``visibility``): the
closed form of a half plane under a large square light, where it and the
average part, and alpha mattes weighted as the reference weighs them."""
import numpy as np
import pytest

from helpers import buffers_of, embree_pass, half_plane_irradiance_ratio, run_method
from penumbra.core.alpha import CLOSEST, EXTEND, LINEAR, REPEAT, AlphaMattes
from synthetic import area_light, half_plane_scene, leaf_cloud_scene, matte_layers_scene, pixel_world_y, \
    top_ortho_camera

#: a square light of side 4 at height 3 over an edge at height 1.5: the
#: weights cos_r cos_l / d^2 vary by a factor of about four over the light
SIZE, LIGHT_Z, OCCLUDER_Z = 4.0, 3.0, 1.5
#: per pixel: jittered strata in 8 sample sets of 256 samples
TOL = 0.035


def _pass(fb, light, **params):
    return run_method("penumbra_casting", fb, light, **params).passes["penumbra_casting"]


def test_half_plane_irradiance_ratio_closed_form():
    """Ground pixels on the two middle columns (x within half a pixel of 0,
    where the ratio is flat in x): V within TOL of
    ``helpers.half_plane_irradiance_ratio``; the average (eq. 2's share of the
    light past the edge) is further than TOL from it in the penumbra, and the
    average pass misses it there by more than TOL."""
    res = 64
    scene = half_plane_scene(area_light(SIZE, z=LIGHT_Z), res=res, occluder_z=OCCLUDER_Z)
    fb = buffers_of(scene)
    ys = pixel_world_y(scene, np.arange(res))
    exact = np.array([half_plane_irradiance_ratio(y, SIZE, LIGHT_Z, OCCLUDER_Z) for y in ys])
    h = 0.5 * SIZE
    average = (h - np.clip(ys * (1.0 - LIGHT_Z / OCCLUDER_Z), -h, h)) / SIZE
    assert np.abs(exact - average).max() > 3 * TOL
    mid = slice(res // 2 - 1, res // 2 + 1)
    v = _pass(fb, scene.lights[0], samples=256)[:, mid]
    assert np.abs(v - exact[:, None]).max() < TOL
    assert abs(float((v - exact[:, None]).mean())) < 0.004
    va = _pass(fb, scene.lights[0], samples=256, visibility="average")[:, mid]
    assert np.abs(va - average[:, None]).max() < TOL
    assert np.abs(va - exact[:, None]).max() > 2 * TOL


def _checker_card():
    """A checkerboard matte card at height 1 over the ground under a square
    light of side 2 at height 2.5 (large and low: the weights matter)."""
    checker = (np.add.outer(np.arange(8), np.arange(8)) % 2).astype(np.float32)
    return matte_layers_scene(area_light(size=2.0, z=2.5), [(1.0, checker, CLOSEST, REPEAT)], res=48,
                              ground=2.0, camera=top_ortho_camera(2.0, height=0.5))


def _matte_leaves():
    """``synthetic.leaf_cloud_scene`` (tilted receivers: leaves, ground) with a
    matte on every leaf: a binary checkerboard on half, a Linear gradient
    (fractional alpha) on the others."""
    scene = leaf_cloud_scene(n_leaves=60, res=40)
    n = (len(scene.triangles) - 2) // 2
    uv = np.zeros((len(scene.triangles), 3, 2), np.float32)
    uv[2:2 + n] = [[0, 0], [1, 0], [1, 1]]
    uv[2 + n:] = [[0, 0], [1, 1], [0, 1]]
    matte = np.full(len(scene.triangles), -1)
    matte[2:2 + n] = matte[2 + n:] = np.arange(n) % 2
    checker = (np.add.outer(np.arange(8), np.arange(8)) % 2).ravel()
    scene.alpha = AlphaMattes(matte, uv, np.concatenate([checker, np.linspace(0.0, 1.0, 16)]), [0, 64], [8, 4],
                              [8, 4], [CLOSEST, LINEAR], [REPEAT, EXTEND], ["leaf / checker", "leaf / gradient"])
    return scene


@pytest.mark.parametrize("alpha_fetch", [True, False])
@pytest.mark.parametrize("make", [_checker_card, _matte_leaves])
def test_matte_scene_with_shared_samples_equals_embree_irr(make, alpha_fetch):
    """Alpha mattes, the reference's own samples: the irradiance pass is
    ``embree_irr`` (the same relations and transmittances, the same weights)
    up to rays within rounding of a texel or triangle edge, with the paper's
    texture fetch and with Embree rays through the matte blockers; and it is
    not the average there."""
    scene = make()
    fb = buffers_of(scene)
    light = scene.lights[0]
    ref = embree_pass(fb, light, samples=64, pass_id="embree_irr")
    avg = embree_pass(fb, light, samples=64)
    v = _pass(fb, light, samples=64, shared_samples_with_reference=True, alpha_fetch=alpha_fetch)
    lit = fb.gbuffer.hit & (ref > 0)
    assert float(((ref[lit] > 0.05) & (ref[lit] < 0.95)).mean()) > 0.05      # mattes shadow part of the view
    assert np.abs(v - ref)[lit].mean() < 1e-3
    assert np.abs(v - ref)[lit].max() <= 4 / 64
    assert np.abs(v - avg)[lit].mean() > 5 * np.abs(v - ref)[lit].mean()
