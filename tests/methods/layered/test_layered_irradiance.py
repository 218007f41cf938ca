"""Layered attenuation maps' irradiance ratio: each layer's set of light
samples weighted at the receiver (Agrawala et al. equation 1 with / without
V), against the half plane's closed form; the average (equation 2) read from
the same sets is the paper's count / N."""
import dataclasses
import math

import numpy as np
import pytest

from penumbra.core.methods.layered import LayeredAttenuationMaps, display, precompute
from penumbra.core.methods.layered.ldi import seen_words
from penumbra.core.metrics import reach_mask
from helpers import buffers_of, half_plane_irradiance_ratio, in_range, rmse, run_method
from synthetic import area_light, half_plane_scene, leaf_cloud_scene, pixel_world_y, sphere_light

METHOD = LayeredAttenuationMaps()
# a light wide and near against the occluder: the samples' weights differ
# most (cos_r cos_l / d^2 over the light), so the ratio and the average part
SIZE, LIGHT_Z, OCCLUDER_Z = 4.0, 2.0, 1.0


def test_half_plane_irradiance_ratio_closed_form():
    """Ground pixels under a square light: V within a Monte Carlo tolerance
    of the closed-form irradiance ratio (Lambert's form factor of the part of
    the light past the edge over the whole light's), tol = 1 / sqrt(N), twice
    the largest standard deviation of an N-sample estimate; where the
    average differs from that ratio by more than 2 tol, the average pass is
    more than tol from it and the irradiance pass within tol. 256 samples
    (four words per layer's set), 128-texel maps."""
    n = 256
    scene = half_plane_scene(area_light(size=SIZE, z=LIGHT_Z), res=64, occluder_z=OCCLUDER_Z)
    fb = buffers_of(scene, 128)
    light = scene.lights[0]
    irr = run_method("layered", fb, light, map_size=128, samples=n).passes["layered"]
    avg = run_method("layered", fb, light, map_size=128, samples=n, visibility="average").passes["layered"]
    assert in_range(irr) and in_range(avg)
    ys = pixel_world_y(scene, np.arange(64))
    exact = np.array([half_plane_irradiance_ratio(y, SIZE, LIGHT_Z, OCCLUDER_Z) for y in ys])[:, None]
    # the average's closed form: the share of the light's side past the edge
    cut = ys * (1.0 - LIGHT_Z / OCCLUDER_Z)
    share = np.clip((0.5 * SIZE - cut) / SIZE, 0.0, 1.0)[:, None]
    tol = 1.0 / math.sqrt(n)
    assert np.abs(irr - exact).max() < tol
    assert np.abs(avg - share).max() < tol
    apart = np.abs(share - exact)[:, 0] > 2 * tol
    assert apart.sum() >= 4, "the scene must tell the two apart"
    assert (np.abs(avg[apart] - exact[apart]) > tol).all()
    assert np.abs(irr.mean(axis=1) - exact[:, 0]).max() < 0.03
    rms = lambda a: float(np.sqrt(np.mean((a - exact) ** 2)))
    assert rms(irr) < 0.3 * rms(avg)


def test_average_reads_only_the_counts():
    """``visibility="average"`` is the paper's count / N: its popcount-based
    display is bit for bit the same when every layer's set is replaced by
    the lowest samples of the same count; the irradiance display reads which
    samples saw a layer, so it changes. Leaves of one object over a ground
    (several layers per LDI pixel), N = 100: two words per set, the second
    partly used (no bit past N set)."""
    scene = leaf_cloud_scene(n_leaves=60, res=48)
    fb = buffers_of(scene)
    light = scene.lights[0]
    params = METHOD.make_params({"samples": 100})
    ldi = precompute(fb, light, params)
    assert ldi.seen.shape[2] == seen_words(100) == 2 and ldi.seen.dtype == np.uint64
    assert int(ldi.n_layers.max()) >= 3
    count = ldi.count
    filled = np.arange(ldi.seen.shape[1])[None, :] < ldi.n_layers[:, None]
    assert (count[filled] >= 1).all() and (count[filled] <= 100).all() and (count[~filled] == 0).all()
    assert not (ldi.seen[:, :, 1] >> np.uint64(36)).any()            # bits 100..127 unused
    # the same counts, the lowest samples
    low = np.zeros_like(ldi.seen)
    for word in range(2):
        k = np.clip(count - 64 * word, 0, 64).astype(np.uint64)
        full = k == 64
        low[:, :, word] = np.where(full, np.uint64(0xFFFFFFFFFFFFFFFF),
                                   (np.uint64(1) << np.where(full, np.uint64(0), k)) - np.uint64(1))
    relabelled = dataclasses.replace(ldi, seen=low)
    np.testing.assert_array_equal(relabelled.count, count)
    assert not np.array_equal(relabelled.seen, ldi.seen)
    g = fb.gbuffer
    P, N = g.position[g.hit], g.normal[g.hit]
    avg = METHOD.make_params({"samples": 100, "visibility": "average"})
    a = display(ldi, P, N, avg)
    np.testing.assert_array_equal(display(relabelled, P, N, avg), a)
    v = display(ldi, P, N, params)
    assert not np.array_equal(display(relabelled, P, N, params), v)
    assert in_range(v.astype(np.float32)) and in_range(a.astype(np.float32))
    assert (v[a == 0.0] == 0.0).all() and (a == 0.0).any()     # the umbra is the umbra in both



def test_large_sphere_light_weighs_its_samples_on_the_facing_disk():
    """A sphere light of radius 3.5 at height 4 over the half plane: its
    samples fill the ball, some of them near the ground, where weighted at
    their own distance they would outweigh the rest many times; weighted as
    their projections on the disk facing the point (the reference's
    samples), the irradiance pass is as close to the reference's irradiance
    ratio as the average pass is to the reference's average (the ball's
    perspective error, O((r / d)^2), is the rest)."""
    scene = half_plane_scene(sphere_light(3.5), res=48)
    fb = buffers_of(scene)
    light = scene.lights[0]
    refs = run_method("embree", fb, light, samples=256, seed=99).passes
    mask = reach_mask(fb.gbuffer, light)
    irr = run_method("layered", fb, light, samples=64, seed=5).passes["layered"]
    avg = run_method("layered", fb, light, samples=64, seed=5, visibility="average").passes["layered"]
    e_irr, e_avg = rmse(irr, refs["embree_irr"], mask), rmse(avg, refs["embree"], mask)
    assert e_irr < 0.12 and e_irr < e_avg + 0.01, (e_irr, e_avg)
