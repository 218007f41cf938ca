"""Single sample soft shadows, its parts: registration, parameters, the
hard test over pixel ranges against the per-pixel warp, and the depth-range
tiles that must not change a pixel."""
import math

import numpy as np
import pytest

from helpers import buffers_of
from penumbra.core.methods import pass_ids, producer_of
from penumbra.core.methods.single_sample import SingleSampleSoftShadows
from single_sample_helpers import HL, PAPER, run_ss, with_light
from synthetic import area_light, half_plane_scene, sphere_light, sun_light


def test_registered_with_its_pass():
    assert "single_sample" in pass_ids()
    m = producer_of("single_sample")
    assert m.passes == {"single_sample": "irradiance"}
    assert m.visibility("single_sample", m.make_params({"visibility": "average"})) == "average"
    assert {"gbuffer", "light_view"} <= set(m.needs)


def test_adaptive_follows_the_blocker_rule():
    """adaptive=None: section 4.3's interpolation for the paper's ramp, not
    for the sum (its V is not linear between a group's ends)."""
    from penumbra.core.methods.single_sample import resolved_adaptive
    P = SingleSampleSoftShadows().make_params
    assert resolved_adaptive(P({})) is False
    assert resolved_adaptive(P(PAPER)) is True
    assert resolved_adaptive(P({"auto_radius": False})) is True     # the paper's knobs: nearest
    assert resolved_adaptive(P({"adaptive": True})) is True
    scene = half_plane_scene(area_light(1.0, z=HL), res=32)
    _, r, _ = run_ss(scene)
    assert r.stats["adaptive"] is False and r.stats["searched"] == r.stats["pixels"]


def test_unknown_blocker_and_surfaces_rejected():
    scene = half_plane_scene(area_light(1.0, z=HL), res=16)
    for over in ({"blocker": "max"}, {"blocker": "ratio"}, {"surfaces": "faces"}, {"layer": "bogus"}):
        with pytest.raises(ValueError):
            run_ss(scene, **over)


def test_adaptive_from_text_is_a_boolean():
    P = SingleSampleSoftShadows().make_params
    assert P({"adaptive": "false"}).adaptive is False and P({"adaptive": "on"}).adaptive is True
    with pytest.raises(ValueError):
        P({"adaptive": "maybe"})


def _leaf_scene(make):
    from synthetic import leaf_cloud_scene
    scene = leaf_cloud_scene(n_leaves=120, res=48)
    return scene if make is None else with_light(scene, make())


LEAF_LIGHTS = [None, lambda: sphere_light(0.3, z=3.0), lambda: sun_light(0.2)]   # rectangle, cube faces, sun


@pytest.mark.parametrize("make", LEAF_LIGHTS)
def test_the_hard_test_over_pixel_ranges_is_the_warp_of_each_pixel(make):
    """``hard_all`` (``_hard_range``, ``_warp`` inlined, ranges of
    pixels on any thread count) gives every pixel the face, hard result and
    id of the out-of-line ``_warp`` called on that pixel alone."""
    from penumbra.core.methods import single_sample as ss
    from penumbra.core.methods.single_sample.packed import pack_params
    from penumbra.core.methods.single_sample.shade import hard_all
    from penumbra.core.methods.single_sample.warp import _warp
    scene = _leaf_scene(make)
    light = scene.lights[0]
    fb = buffers_of(scene)
    g = fb.gbuffer
    lv = fb.light_view(light, None)
    P = np.ascontiguousarray(g.position.reshape(-1, 3), np.float64)
    Nrm = np.ascontiguousarray(g.normal.reshape(-1, 3))
    hit = np.ascontiguousarray(g.hit.reshape(-1))
    faces = lv.packed_faces()
    depth = np.ascontiguousarray(lv.depth, np.float32)
    ids = np.ascontiguousarray(lv.object_id, np.int32)
    pid = np.ascontiguousarray(g.object_id.reshape(-1), np.int32)
    prm = pack_params(SingleSampleSoftShadows().make_params({}), light, False, ss._coord_mag(scene.bounds(), light))
    n = P.shape[0]
    got = []
    for threads in (1, 2):
        arrs = np.empty(n, np.int32), np.empty(n, np.int8), np.empty(n, np.int32)
        hard_all(P, Nrm, hit, faces, depth, ids, prm, *arrs, pid, threads=threads)
        got.append(arrs)
    for a, b in zip(*got):
        np.testing.assert_array_equal(a, b)
    hface, hinner, hid = got[0]
    assert (hinner[hit] == 1).any() and (hinner[hit] == 0).any()
    assert (hface[~hit] == -2).all() and (hid[~hit] == -1).all()
    for i in np.flatnonzero(hit):
        f, u, v, zr, inner = _warp(P, Nrm, i, faces, depth, prm)[:5]
        assert hface[i] == f and hinner[i] == (1 if inner else 0), i
        if f >= 0 and inner:
            assert hid[i] == ids[f, min(int(math.floor(v)), lv.depth.shape[1] - 1),
                                 min(int(math.floor(u)), lv.depth.shape[2] - 1)]
        else:
            assert hid[i] == pid[i]


@pytest.mark.parametrize("make", LEAF_LIGHTS)
def test_passing_over_hopeless_tiles_changes_no_pixel(make, monkeypatch):
    """The search skips boxes and ring texels of tiles whose depth range and
    id rule out a candidate (``_tile_range``, ``_tile_hopeless``); V is the
    same as with tiles that rule out nothing (every texel read), for the
    nearest-blocker search, adaptive or not, with jitter, with the paper's
    radius knobs, and for the sum; fewer texels are read."""
    import penumbra.core.methods.single_sample as ss
    scene = _leaf_scene(make)
    fb = buffers_of(scene)
    real = ss.tile_depth_range

    def open_tiles(depth, ids):         # every tile may hold every depth and several ids
        t = real(depth, ids)
        t[..., 0], t[..., 1], t[..., 2] = -np.inf, np.inf, -2.0
        return t
    for over in (dict(blocker="nearest", surfaces="object"), dict(blocker="nearest", jitter=0.5, adaptive=False),
                 dict(blocker="nearest", auto_radius=False, adaptive=False), dict(adaptive=False)):
        on, r_on, _ = run_ss(scene, fb, **over)
        with monkeypatch.context() as mp:
            mp.setattr(ss, "tile_depth_range", open_tiles)
            off, r_off, _ = run_ss(scene, fb, **over)
        np.testing.assert_array_equal(on, off)
        assert r_on.stats["searched"] == r_off.stats["searched"] > 0
        assert r_on.stats["texels_read"] < r_off.stats["texels_read"], over
