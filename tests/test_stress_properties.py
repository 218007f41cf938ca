"""Property tests (hypothesis) on the numeric kernels: random
triangles, lights and receivers, float32 edge values included.

The scenes: a ground quad z = 0 (the receiver, it casts shadows too) seen
from above by an orthographic camera, random occluder triangles the camera
does not see (so adding one leaves the G-buffer unchanged), one light, and a
"frame" triangle that neither casts shadows nor is seen but fixes the
scene's bounds (so the ray offset, scaled by the scene's extent, is the same
with and without an added occluder).

Invariants, and for which methods they hold:
* V = 1 on the ground with no occluder, for every method: the ground must
  not shadow itself (the offset scheme of ``sampling.offset_origin``).
* Adding an occluder never increases V, per pixel, for ``embree`` and
  ``penumbra_casting`` (with its own sample sets and with the reference's):
  both test a fixed set of shadow rays per pixel chosen from the seed and the
  pixel only, and a ray blocked by a set of triangles stays blocked by a
  superset. It does not hold for the map-based methods (pcf, single_sample,
  layered, depth_raytrace): their light views are fitted to the receivers
  and their maps' texels change with what is rendered into them, and
  single_sample's penumbra search is not monotone in the blockers; nor for
  irregular, whose penumbra of separate silhouettes is additive and
  clamped (Johnson et al. 2.1), not a ray count.
* Translating the whole scene by up to 1e3 changes ``embree``'s V little:
  same samples per pixel, so only rays grazing an edge within the float32
  rounding of the moved vertices (1e3 * 2^-24 = 6e-5 units) may change.
* Random triangles with float32 edge values (tiny, huge, subnormal, zero,
  degenerate): every method returns finite V in [0, 1].
"""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from penumbra.core import methods as registry
from penumbra.core.scene import Light, ObjectInfo, Scene
from helpers import buffers_of, in_range, run_method
from synthetic import light_matrix, quad, top_ortho_camera

settings.register_profile("stress", derandomize=True, deadline=None, max_examples=20, database=None,
                          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
STRESS = settings.get_profile("stress")
RES = 20
F32 = np.float32

coord = st.floats(-3.0, 3.0, allow_nan=False, width=32)
height = st.floats(float(np.float32(0.05)), 3.5, allow_nan=False, width=32)
vertex = st.tuples(coord, coord, height)
triangle = st.tuples(vertex, vertex, vertex)
occluders = st.lists(triangle, min_size=0, max_size=8)

edge_value = st.sampled_from([0.0, -0.0, 1e-38, -1e-38, 1.4e-45, 1e-30, -1e-30, 1e-7, 1e20, -1e20,
                              3.0e38, -3.0e38, 1.0, -1.0, 2.0])
wild_vertex = st.tuples(st.one_of(coord, edge_value), st.one_of(coord, edge_value),
                        st.one_of(height, edge_value))
wild_triangle = st.one_of(st.tuples(wild_vertex, wild_vertex, wild_vertex),
                          wild_vertex.map(lambda v: (v, v, v)))          # a point: zero area


@st.composite
def lights(draw):
    kind = draw(st.sampled_from(["SQUARE", "RECTANGLE", "DISK", "ELLIPSE", "sphere", "spot", "sun"]))
    x, y = draw(st.floats(-1.5, 1.5, width=32)), draw(st.floats(-1.5, 1.5, width=32))
    size = draw(st.floats(0.0, 3.0, width=32))
    if kind == "sun":
        d = (draw(st.floats(-0.6, 0.6)), draw(st.floats(-0.6, 0.6)), -1.0)
        return Light("L", "sun", light_matrix((0, 0, 10), d), angle=min(size, 1.0))
    m = light_matrix((x, y, 4.0))
    if kind in ("sphere", "spot"):
        return Light("L", "sphere", m, radius=size / 2, spot_size=1.2 if kind == "spot" else np.pi)
    return Light("L", "area", m, shape=kind, size=size, size_y=draw(st.floats(0.0, 3.0, width=32)))


def scene_of(occ, light, offset=(0.0, 0.0, 0.0), res=RES, frame=True):
    """Ground + occluders + the bounds frame, the whole scene moved by ``offset``."""
    off = np.asarray(offset, np.float64)
    tris = quad(-10, 10, -10, 10, 0.0) + [list(map(list, t)) for t in occ]
    ids = [0, 0] + [1] * len(occ)
    if frame:
        tris.append([[-10, -10, 0.0], [10, 10, 6.0], [10, 10, 6.0]])
        ids.append(2)
    objs = [ObjectInfo("ground", 0), ObjectInfo("occ", 1, visible_camera=False),
            ObjectInfo("frame", 2, casts_shadow=False, visible_camera=False)]
    t = (np.asarray(tris, np.float64).reshape(-1, 3, 3) + off).astype(F32)
    cam = top_ortho_camera(2.5, height=0.02)
    cam.world_from_camera = cam.world_from_camera.copy()
    cam.world_from_camera[:3, 3] += off
    lm = light.world_from_light.copy()
    lm[:3, 3] += off
    lt = Light(light.name, light.kind, lm, shape=light.shape, size=light.size, size_y=light.size_y,
               radius=light.radius, spot_size=light.spot_size, angle=light.angle)
    return Scene(t, np.asarray(ids, np.int32), objs, cam, [lt], (res, res))


def run(scene, method, **params):
    fb = buffers_of(scene)
    return run_method(method, fb, scene.lights[0], **{"samples": 16, "seed": 3, **params}).passes[method], fb


MONOTONE = [("embree", {}), ("penumbra_casting", {}),
            ("penumbra_casting", {"shared_samples_with_reference": True})]


@pytest.mark.parametrize("method, extra", MONOTONE, ids=["embree", "penumbra_casting", "pc_shared"])
@STRESS
@given(occ=occluders, more=st.lists(triangle, min_size=1, max_size=3), light=lights())
def test_adding_an_occluder_never_increases_v(method, extra, occ, more, light):
    a, fa = run(scene_of(occ, light), method, **extra)
    b, fb = run(scene_of(occ + more, light), method, **extra)
    np.testing.assert_array_equal(fa.gbuffer.hit, fb.gbuffer.hit)
    assert (b <= a).all(), np.argwhere(b > a)[:5]


@pytest.mark.parametrize("method", list(registry.producers()))
@STRESS
@given(light=lights(), offset=st.tuples(st.floats(-50, 50), st.floats(-50, 50), st.floats(-50, 50)))
def test_v_is_one_without_occluders(method, light, offset):
    """Only the ground, which casts shadows on nothing but must not shadow
    itself: V = 1 wherever the light reaches (elsewhere V has no meaning)."""
    from penumbra.core.metrics import reach_mask
    sc = scene_of([], light, offset)
    v, fb = run(sc, method)
    mask = reach_mask(fb.gbuffer, sc.lights[0])
    assert np.isfinite(v).all()
    assert (v[mask] == 1.0).all(), (float(v[mask].min()), int((v[mask] < 1).sum()))


@STRESS
@given(occ=occluders, light=lights(),
       offset=st.tuples(st.floats(-1e3, 1e3), st.floats(-1e3, 1e3), st.floats(-1e3, 1e3)))
def test_translation_changes_embree_little(occ, light, offset):
    """Same per-pixel samples; only rays within float32 rounding of an edge
    (6e-5 units at 1e3) may flip, one ray of 16 is 1/16: on average over the
    image a change below 0.01, per pixel at most 2 rays."""
    from penumbra.core.metrics import reach_mask
    s0 = scene_of(occ, light)
    s1 = scene_of(occ, light, offset)
    a, f0 = run(s0, "embree")
    b, f1 = run(s1, "embree")
    m = reach_mask(f0.gbuffer, s0.lights[0]) & reach_mask(f1.gbuffer, s1.lights[0])
    d = np.abs(a.astype(np.float64) - b)[m]
    if d.size:
        assert d.mean() < 0.01 and d.max() <= 2 / 16 + 1e-6, (d.mean(), d.max())


@pytest.mark.parametrize("method", list(registry.producers()))
@STRESS
@given(occ=st.lists(wild_triangle, min_size=1, max_size=6), light=lights())
def test_float32_edge_values_no_nan_no_crash(method, occ, light):
    sc = scene_of(occ, light, frame=False)
    v, _ = run(sc, method)
    assert v.shape == (RES, RES) and in_range(v)
