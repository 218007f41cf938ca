"""A frame's buffers (``core/buffers.py``). ``needs`` is a contract: a
method's ``run()`` sees only the buffers it declared, every need has a
builder, and the buffer phases billed to a method do not depend on which
method ran first. Buffers taken over from an earlier frame give the passes
of fresh ones; the default light-map size, the frame memo and the
receivers' subsample."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from penumbra.core import buffers as buffers_mod
from penumbra.core import ledger as ledger_mod
from penumbra.core import methods as registry
from penumbra.core.buffers import NEED_BUILDERS, NEED_PHASE, FrameBuffers, UndeclaredBufferError
from penumbra.core.frame import render_frame
from penumbra.core.methods import base
from penumbra.core.methods.base import GBUFFER, LIGHT_VIEW, SHADOW_GEOMETRY, SHADOW_TRIANGLES
from helpers import run_declared
from synthetic import area_light, half_plane_scene, sphere_light, sun_light

RES = 20
FAST = {"samples": 4, "seed": 3}
METHODS = sorted(registry.producers())
LIGHTS = {"area": lambda: area_light(1.0), "spot": lambda: sphere_light(0.4, spot_size=1.2),
          "sun": lambda: sun_light(0.2)}
NEEDS = {v for k, v in vars(base).items() if k.isupper() and isinstance(v, str)} - {base.AVERAGE, base.IRRADIANCE}


def _half_plane(light="area"):
    return half_plane_scene(LIGHTS[light](), res=RES)


def _run(fb, m, light):
    return run_declared(m, fb, light, **FAST)


def test_every_need_has_a_builder_and_a_phase():
    assert NEEDS == {GBUFFER, LIGHT_VIEW, SHADOW_GEOMETRY, SHADOW_TRIANGLES, base.LIGHT_SAMPLE_VIEWS,
                     base.MESH_PIECES, base.PRECOMPUTE}
    # a method's own precompute is billed in its own phases: every other need has one
    assert set(NEED_BUILDERS) == NEEDS and set(NEED_PHASE) == NEEDS - {base.PRECOMPUTE}
    for need, members in NEED_BUILDERS.items():
        assert members, need
        for name in members:
            assert hasattr(FrameBuffers, name), f"{need}: FrameBuffers has no {name}"
    for m in registry.producers().values():
        assert m.needs <= NEEDS, m.id


@pytest.mark.parametrize("kind", sorted(LIGHTS))
@pytest.mark.parametrize("method", METHODS)
def test_every_method_runs_on_its_declared_buffers(method, kind):
    """A method touching a buffer it did not declare fails here."""
    scene = _half_plane(kind)
    fb = FrameBuffers(scene, RES, RES)
    m = registry.producers()[method]
    res, phases = _run(fb, m, scene.lights[0])
    for pid in m.passes:
        v = res.passes[pid]
        assert v.shape == (RES, RES) and np.isfinite(v).all()
        assert v.min() >= 0.0 and v.max() <= 1.0
        assert v.min() < 0.5, "the occluder casts no shadow"
    assert set(phases) == {NEED_PHASE[n] for n in buffers_mod._with_sources(m.needs) if n in NEED_PHASE}


def test_undeclared_access_raises():
    fb = FrameBuffers(_half_plane(), RES, RES)
    view = fb.view({GBUFFER}, "probe")
    assert view.gbuffer.shape == (RES, RES)
    assert view.scale == fb.scale and view.camera is fb.scene.camera
    for name in ("shadow_scene", "shadow_scene_for", "light_view", "shadow_triangles", "sample_view",
                 "mesh_pieces", "matte_casters", "precomputed"):
        with pytest.raises(UndeclaredBufferError, match=f"probe uses FrameBuffers.{name} without declaring"):
            getattr(view, name)
    for name in ("build_times", "scene", "ledger"):       # the frame itself is not a method's input
        with pytest.raises(UndeclaredBufferError, match="no need exposes"):
            getattr(view, name)
    with pytest.raises(ValueError, match="no buffer builds"):
        fb.view({"no_such_buffer"})


def test_a_method_with_too_few_needs_fails():
    pc = registry.producers()["penumbra_casting"]
    short = type("Short", (type(pc),), {"needs": frozenset({GBUFFER})})()
    fb = FrameBuffers(_half_plane(), RES, RES)
    with pytest.raises(UndeclaredBufferError, match="shadow_triangles"):
        _run(fb, short, fb.scene.lights[0])


def test_penumbra_casting_builds_no_bvh():
    fb = FrameBuffers(_half_plane(), RES, RES)
    _, phases = _run(fb, registry.producers()["penumbra_casting"], fb.scene.lights[0])
    assert "bvh" not in phases and "shadow_triangles" in phases
    assert "bvh_shadow" not in fb.build_times and not any(k.startswith("bvh_culled") for k in fb.build_times)


class _Clock:
    """perf_counter for buffers.py: every build takes exactly one second."""

    def __init__(self):
        self.t = 0.0

    def perf_counter(self):
        self.t += 1.0
        return self.t


@pytest.mark.parametrize("method", METHODS)
def test_buffer_phases_do_not_depend_on_the_order(method, monkeypatch):
    """Billed build times: the same whether the method runs first or last."""
    monkeypatch.setattr(ledger_mod, "time", _Clock())
    light_kind = "area"
    m = registry.producers()[method]
    fb = FrameBuffers(_half_plane(light_kind), RES, RES)
    _, first = _run(fb, m, fb.scene.lights[0])
    fb = FrameBuffers(_half_plane(light_kind), RES, RES)
    for other in METHODS:
        if other != method:
            _run(fb, registry.producers()[other], fb.scene.lights[0])
    _, last = _run(fb, m, fb.scene.lights[0])
    assert first == last
    # one second per buffer used: the camera BVH + G-buffer, one shadow BVH, one view, the
    # shadow-casting triangles (and the matte casters split from them), the mesh pieces
    expect = {"gbuffer": 2.0, "bvh": 1.0, "light_view": 1.0, "mesh_pieces": 1.0,
              "shadow_triangles": 2.0 if method in ("irregular", "penumbra_casting") else 1.0}
    assert first == {k: expect[k] for k in first}


def test_render_frame_bills_phases_by_use():
    scene = _half_plane()
    out = render_frame(scene, ["penumbra_casting", "pcf", "embree"], overrides=FAST).to_json()
    rec = out["lights"][0]["methods"]
    assert set(rec["penumbra_casting"]["time_s"]) >= {"gbuffer", "shadow_triangles", "total"}
    assert "bvh" not in rec["penumbra_casting"]["time_s"]
    for mid in ("pcf", "embree"):
        t = rec[mid]["time_s"]
        assert t["bvh"] > 0.0, mid
        assert t["total"] == pytest.approx(sum(v for k, v in t.items() if k != "total"), abs=1e-5)


def _moved(scene, dx):
    """The same geometry and camera, the light moved by ``dx`` across the
    occluder's edge (along y)."""
    from dataclasses import replace
    lt = scene.lights[0]
    m = lt.world_from_light.copy()
    m[1, 3] += dx
    return replace(scene, lights=[replace(lt, world_from_light=m)])


def test_a_frame_cache_gives_the_passes_of_fresh_buffers():
    """A frame may start from an earlier frame's cache (``FrameCache``: same
    camera and geometry): its G-buffer and BVHs, the views of unchanged
    lights and their methods' results; a moved light gets a new view. Passes
    are those of a fresh frame; what was taken over is billed 0 s, an
    unchanged light's pass included (its method does not run again);
    another parameter runs it."""
    scene = _half_plane()
    first = render_frame(scene, ["pcf"], keep=True)
    assert first.cache is not None and render_frame(scene, ["pcf"]).cache is None
    again = render_frame(scene, ["pcf"], previous=first.cache, keep=True)
    np.testing.assert_array_equal(again.lights[0].passes["pcf"], first.lights[0].passes["pcf"])
    rec = again.lights[0].record["pcf"]
    assert rec["reused"] and all(v == 0.0 for v in rec["time_s"].values()) and "filter" in rec["time_s"]
    other = render_frame(scene, ["pcf"], previous=first.cache, method_overrides={"pcf": {"PenumbraSamples": 32}},
                         keep=True)
    t = other.lights[0].record["pcf"]["time_s"]
    assert "reused" not in other.lights[0].record["pcf"]
    assert t["gbuffer"] == t["light_view"] == t["bvh"] == 0.0 and t["filter"] > 0.0
    assert again.cache.buffers._views and again.cache.buffers._gbuffer is first.cache.buffers._gbuffer
    moved = _moved(scene, 0.3)
    reused = render_frame(moved, ["pcf"], previous=again.cache)
    fresh = render_frame(moved, ["pcf"])
    np.testing.assert_array_equal(reused.lights[0].passes["pcf"], fresh.lights[0].passes["pcf"])
    assert not np.array_equal(fresh.lights[0].passes["pcf"], first.lights[0].passes["pcf"])
    t = reused.lights[0].record["pcf"]["time_s"]
    assert t["gbuffer"] == 0.0 and t["light_view"] > 0.0


def test_buffers_of_another_camera_or_resolution_are_refused():
    from dataclasses import replace
    scene = _half_plane()
    first = render_frame(scene, ["pcf"], keep=True)
    cam = scene.camera
    m = cam.world_from_camera.copy()
    m[0, 3] += 0.1
    other = replace(scene, camera=replace(cam, world_from_camera=m))
    with pytest.raises(ValueError, match="camera"):
        render_frame(other, ["pcf"], previous=first.cache)
    with pytest.raises(ValueError, match="resolution"):
        FrameBuffers(scene, RES + 1, RES).adopt(first.cache.buffers)


def test_a_precompute_is_kept_only_when_a_filtered_frame_shares_it():
    """``precomputed`` (layered's LDI, depth_raytrace's maps) builds every
    call on plain buffers, so runs timed on one set of buffers (the study,
    the benchmark) each pay their precompute; after ``share_precomputed``
    (``render_filtered``) it builds once per light and params, and the
    sub-pixel stage's buffers (``supersampled``) see the same one."""
    sc = _half_plane()
    light = sc.lights[0]
    fb = FrameBuffers(sc, *sc.resolution)
    builds = []
    build = lambda: builds.append(1) or len(builds)
    params = registry.producers()["layered"].make_params({})
    assert fb.precomputed("layered.ldi", light, params, build) == 1
    assert fb.precomputed("layered.ldi", light, params, build) == 2
    fb.share_precomputed()
    assert fb.precomputed("layered.ldi", light, params, build) == 3
    assert fb.precomputed("layered.ldi", light, params, build) == 3
    sub = fb.supersampled(sc, 2 * sc.resolution[0], 2 * sc.resolution[1], fb.gbuffer, 0.0)
    assert sub.precomputed("layered.ldi", light, params, build) == 3
    other = registry.producers()["layered"].make_params({"samples": 16})
    assert fb.precomputed("layered.ldi", light, other, build) == 4


@pytest.mark.parametrize("light", sorted(LIGHTS))
def test_the_default_light_map_holds_no_more_texels_than_the_output_has_pixels(light):
    """``views.default_map_size``: an area or spot light's map's larger side
    is sqrt(W x H), so a 16:9 frame's light view holds at most its pixel
    count (not more texels to render than the camera has rays); a sun's
    keeps the output's larger side (its orthographic view
    spreads over the receivers' box); a square output keeps its side; a map
    size given wins for every light, and a sub-pixel stage keeps the
    pixel-centre view's sizes."""
    from penumbra.core.views import default_map_size
    assert default_map_size(1920, 1080) == 1440 and default_map_size(256, 256) == 256
    assert default_map_size(1920, 1080, "sun") == 1920 and default_map_size(1, 1) == 1
    scene = _half_plane(light)
    lt = scene.lights[0]
    W, H = 64, 36
    side = 64 if light == "sun" else 48
    fb = FrameBuffers(scene, W, H)
    lv = fb.light_view(lt)
    assert fb.map_size_for(lt) == side
    assert max(max(f.width, f.height) for f in lv.faces) == side
    assert light == "sun" or all(f.width * f.height <= W * H for f in lv.faces)
    assert max(lv.depth.shape[1:]) == side
    sub = fb.supersampled(scene, 4 * W, 4 * H, fb.gbuffer, 0.0)
    assert sub.map_size_for(lt) == side
    given = FrameBuffers(scene, W, H, 80)
    assert given.map_size_for(lt) == 80


def test_receiver_points_are_the_hits_subsample_and_box(monkeypatch):
    """``FrameBuffers.receivers`` / the receivers' box (one pass of
    ``kernels.hit_box``, only the subsample gathered): the box is NumPy's
    min / max over every hit, the points every k-th hit (k = ceil(hits /
    _FIT_POINTS)) and the first and last."""
    monkeypatch.setattr(buffers_mod, "_FIT_POINTS", 37)
    scene = _half_plane()
    fb = FrameBuffers(scene, 48, 40)
    g = fb.gbuffer
    hit = g.hit.copy()
    hit[::3, ::2] = False                                  # misses (sky) are left out
    hit[:5] = False
    fb._gbuffer = dataclasses.replace(g, hit=hit)
    hits = g.position[hit]
    assert 0 < len(hits) < 48 * 40
    pts, lo, hi = fb._receiver_points()
    np.testing.assert_array_equal(lo, hits.min(0))
    np.testing.assert_array_equal(hi, hits.max(0))
    k = int(np.ceil(len(hits) / 37))
    np.testing.assert_array_equal(pts, np.concatenate([hits[::k], hits[[0, -1]]]))
    from penumbra.core.kernels import hit_box
    assert hit_box(np.zeros((4, 3)), np.zeros(4, bool)) == (np.inf,) * 3 + (-np.inf,) * 3
