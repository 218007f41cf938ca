"""Motion blur (``core/motion.py``, the shutter times of
``core/camera_samples.py``, Embree's moving instances): a hard shadow edge
whose occluder, or whose camera, moves over the shutter against the closed
form of its time average; the instanced and flattened forms of the same
scene; what ``auto`` and the JSON say."""
from __future__ import annotations

import numpy as np
import pytest

from penumbra.core import camera_effects, camera_samples, raycast
from penumbra.core.auto_choice import choose, scene_shape
from penumbra.core.buffers import FrameBuffers
from penumbra.core.filtered_frame import render_filtered
from penumbra.core.frame import render_frame
from penumbra.core.motion import ShutterMotion, blend, frame_offsets
from penumbra.core.pixel_filter import PixelFilter
from penumbra.core.scene import MeshInstances, Scene
from synthetic import box, half_plane_scene, light_matrix, make_scene, quad, sun_light, top_ortho_camera

FLT = PixelFilter("blackman-harris", 1.5, 4)


def _sliding(dy: float, steps: int = 3) -> np.ndarray:
    """float64[steps, 4, 4]: a translation along y from -dy/2 to +dy/2 over the shutter."""
    out = np.tile(np.eye(4), (steps, 1, 1))
    out[:, 1, 3] = np.linspace(-dy / 2, dy / 2, steps)
    return out


def _ramp_truth(scene: Scene, lit_share) -> np.ndarray:
    """Per pixel row: the filtered time average of a ground point's lit share
    ``lit_share(y)`` (the top orthographic camera's rows, Blackman-Harris)."""
    W, H = scene.resolution
    d = np.linspace(-FLT.radius, FLT.radius, 4001)
    w = FLT.profile(d)
    half = scene.camera.ortho_scale / 2
    y = half - (np.arange(H)[:, None] + 0.5 + d[None]) / H * 2 * half
    return (lit_share(y) * w).sum(1) / w.sum()


def _rmse(V, truth):
    return float(np.sqrt(np.mean((V - truth[:, None]) ** 2)))


def test_a_moving_occluder_blurs_its_shadow_as_the_shutter_averages_it():
    # the occluder covers y < 0 at the frame and slides by dy over the shutter: a ground point at
    # y is lit while the edge is below it, for a share (y + dy/2) / dy of the shutter
    dy = 0.5
    scene = half_plane_scene(sun_light(0.0), res=64)
    scene.motion = ShutterMotion([1], _sliding(dy)[:, None])
    truth = _ramp_truth(scene, lambda y: np.clip((y + dy / 2) / dy, 0.0, 1.0))
    res = render_filtered(scene, ["embree_irr", "pcf"], pixel_filter=FLT)
    V = res.lights[0].passes["embree_irr"]
    assert ((truth > 0.05) & (truth < 0.95)).sum() >= 8
    assert _rmse(V, truth) < 0.02 and np.abs(V.mean(1) - truth).max() < 0.02
    eff = res.to_json()["camera_effects"]
    assert eff["motion_blur"]["moving_objects"] == 1 and eff["sampled"] == "per sub-pixel receiver"
    rec = res.lights[0].record
    assert rec["embree_irr"]["shutter"] == "occluders at the receiver's time"
    assert rec["pcf"]["shutter"] == "occluders at 3 time slices"


MAP_AND_TRIANGLE_METHODS = ["pcf", "single_sample", "layered", "depth_raytrace", "penumbra_casting", "irregular"]


def test_the_other_methods_take_the_moving_occluder_at_time_slices():
    # with K slices a method sees the occluder where it is at each slice's middle, t_k = (k + 1/2) / K:
    # the edge at dy (t_k - 1/2), a staircase of K steps whose filtered form is a closed form too;
    # with one slice (at the frame) the edge stays sharp, as the record says
    dy = 0.5
    scene = half_plane_scene(sun_light(0.0), res=64)
    scene.motion = ShutterMotion([1], _sliding(dy)[:, None])
    truth = _ramp_truth(scene, lambda y: np.clip((y + dy / 2) / dy, 0.0, 1.0))
    stairs = _ramp_truth(scene, lambda y: np.mean([y > dy * ((k + 0.5) / 3 - 0.5) for k in range(3)], 0))
    still = _ramp_truth(scene, lambda y: (y > 0).astype(float))
    three = render_filtered(scene, MAP_AND_TRIANGLE_METHODS, pixel_filter=FLT).lights[0]
    one = render_filtered(scene, MAP_AND_TRIANGLE_METHODS, pixel_filter=FLT, time_slices=1).lights[0]
    for m in MAP_AND_TRIANGLE_METHODS:
        assert three.record[m]["shutter"] == "occluders at 3 time slices"
        assert one.record[m]["shutter"] == "occluders at the frame"
        assert _rmse(one.passes[m], still) < 0.02 < 0.08 < _rmse(one.passes[m], truth)
        assert _rmse(three.passes[m], stairs) < 0.03      # the map methods: the edge on their texels
        assert _rmse(three.passes[m], truth) < 0.035


def test_time_slices_move_instances_and_triangles_alike():
    dy = 0.5
    flat = half_plane_scene(sun_light(0.0), res=32)
    kept = _kept_as_instances(flat)
    for s in (flat, kept):
        s.motion = ShutterMotion([1], _sliding(dy)[:, None])
    methods = ["pcf", "penumbra_casting"]
    a = render_filtered(flat, methods, pixel_filter=FLT).lights[0].passes
    b = render_filtered(kept, methods, pixel_filter=FLT).lights[0].passes
    assert not kept.is_flattened
    for m in methods:
        assert np.abs(a[m] - b[m]).max() < 1e-3


def test_only_the_pixels_a_moving_object_can_change_are_refined():
    # a small box sliding over a large sun-lit ground. Only the pixels its image can reach are
    # refined on the full grid: a still receiver's pixel centre stands for the shutter (the
    # reference spreads its shadow rays over it, pcf averages its time slices), and the
    # moving shadow's edges are refined as any edge is. Within noise of the pass refined everywhere
    tris = quad(-4, 4, -4, 4, 0.0) + box(-0.2, 0.2, -0.2, 0.2, 0.3, 0.7)
    sun = sun_light(0.0)
    sun.world_from_light = light_matrix((0, 0, 10.0), forward=(0.8, 0.0, -1.0))   # the shadow falls beside it
    scene = make_scene(tris, [0, 0] + [1] * 12, [sun], res=64, camera=top_ortho_camera(2.0, height=2.0))
    scene.motion = ShutterMotion([1], _sliding(0.6)[:, None])
    methods = ["embree_irr", "pcf"]
    adaptive = render_filtered(scene, methods, pixel_filter=FLT).lights[0]
    everywhere = render_filtered(scene, methods, pixel_filter=PixelFilter("blackman-harris", 1.5, 4,
                                                                          threshold=-1.0)).lights[0]
    for m in methods:
        a, e = adaptive.passes[m], everywhere.passes[m]
        assert 0 < adaptive.record[m]["pixel_filter"]["refined_pixels"] < 0.1 * 64 * 64
        assert ((a > 0.05) & (a < 0.95)).sum() > 20              # the blurred shadow and silhouette are there
        assert np.sqrt(np.mean((a - e) ** 2)) < 0.005 and np.abs(a - e).max() < 0.08
    assert adaptive.record["pcf"]["time_s"]["time_slices"] > 0


@pytest.mark.parametrize("slices", [1, 3])
def test_a_moving_receiver_is_shaded_where_the_slices_occluders_are(slices):
    # a box rising and sliding under a sun: its lit top, taken at each sub-sample's own time, is shaded with
    # the occluders of its time slice (or the frame); it must not shadow itself for being taken
    # at another time than they are
    tris = quad(-4, 4, -4, 4, 0.0) + box(-0.8, 0.8, -0.8, 0.8, 0.3, 0.7)
    sun = sun_light(0.02)
    sun.world_from_light = light_matrix((0, 0, 10.0), forward=(0.3, 0.0, -1.0))
    scene = make_scene(tris, [0, 0] + [1] * 12, [sun], res=48, camera=top_ortho_camera(2.0, height=2.0))
    rising = _sliding(0.6)
    rising[:, 2, 3] = rising[:, 1, 3] / 2                   # up 0.3 while it slides: its top moves off itself
    scene.motion = ShutterMotion([1], rising[:, None])
    methods = ["pcf", "single_sample", "penumbra_casting", "irregular"]
    res = render_filtered(scene, methods, pixel_filter=FLT, time_slices=slices).lights[0]
    g = FrameBuffers(scene, 48, 48).gbuffer
    top = (g.object_id == 1) & (np.abs(g.position[..., 2] - 0.7) < 1e-4)   # the box's top at the frame
    inner = top.copy()                    # ... and under every sub-sample of the pixel all shutter long
    for d in range(1, 7):
        inner &= np.roll(top, d, 0) & np.roll(top, -d, 0)
    for d in (1, 2):
        inner &= np.roll(top, d, 1) & np.roll(top, -d, 1)
    assert inner.sum() > 20
    for m in methods:
        assert res.passes[m][inner].min() > 0.95, m


def test_a_moving_camera_blurs_a_still_shadow_edge():
    # the camera slides by dy along y: the image of a ground point moves, so a pixel sees the
    # edge y = 0 pass through it over the shutter; a pixel whose frame point is y sees y - s(t)
    dy = 0.4
    scene = half_plane_scene(sun_light(0.0), res=64)
    scene.motion = ShutterMotion(np.zeros(0, np.int32), np.zeros((3, 0, 4, 4)), camera=_sliding(dy))
    truth = _ramp_truth(scene, lambda y: np.clip((y + dy / 2) / dy, 0.0, 1.0))
    V = render_filtered(scene, ["embree_irr"], pixel_filter=FLT).lights[0].passes["embree_irr"]
    assert _rmse(V, truth) < 0.02


def _kept_as_instances(flat: Scene) -> Scene:
    """``half_plane_scene``'s ground and occluder as two instances of two meshes."""
    tris = flat.triangles.astype(np.float64)
    quads = [tris[0:2], tris[2:4]]
    ins = MeshInstances(vertices=[q.reshape(-1, 3) for q in quads],
                        faces=[np.arange(6, dtype=np.int32).reshape(2, 3)] * 2,
                        mesh=[0, 1], object_id=[0, 1], world_from_mesh=[np.eye(4), np.eye(4)])
    kept = Scene(None, None, flat.objects, flat.camera, flat.lights, flat.resolution, instances=ins)
    assert not kept.is_flattened
    return kept


def test_instanced_and_flattened_forms_move_alike():
    dy = 0.5
    flat = half_plane_scene(sun_light(0.0), res=48)
    kept = _kept_as_instances(flat)
    for s in (flat, kept):
        s.motion = ShutterMotion([1], _sliding(dy)[:, None])
    a = render_filtered(flat, ["embree_irr"], pixel_filter=FLT).lights[0].passes["embree_irr"]
    b = render_filtered(kept, ["embree_irr"], pixel_filter=FLT).lights[0].passes["embree_irr"]
    assert not kept.is_flattened
    assert np.abs(a - b).max() < 1e-3


def test_rays_find_moving_triangles_where_they_are_at_their_time():
    scene = half_plane_scene(sun_light(0.0), res=8)
    scene.motion = ShutterMotion([1], _sliding(2.0)[:, None])
    bvh = raycast.TriangleScene.from_scene(scene, scene.tri_casts_shadow)
    # a ray straight up from the ground at y = 0.5, towards the occluder at z = 2 (covering y < 0 at
    # the frame, y < -1 + 2 t over the shutter): blocked once the edge passed it, at t > 0.75
    org = np.array([[0.0, 0.5, 0.01]] * 4, np.float32)
    up = np.array([[0.0, 0.0, 1.0]] * 4, np.float32)
    t = np.array([0.0, 0.5, 0.74, 0.9], np.float32)
    hit = bvh.occluded(org, up, np.full(4, 10.0, np.float32), t)
    assert hit.tolist() == [False, False, False, True]
    assert not bvh.occluded(org, up, np.full(4, 10.0, np.float32)).any()    # no time: the frame (edge y = 0)


def test_blend_and_offsets_follow_the_shutter():
    steps = _sliding(1.0, 5)
    m = blend(steps, np.array([0.0, 0.125, 0.5, 1.0]))
    assert np.allclose(m[:, 1, 3], [-0.5, -0.375, 0.0, 0.5])
    assert np.allclose(frame_offsets(3, 0.5, "CENTER"), [-0.25, 0.0, 0.25])
    assert np.allclose(frame_offsets(3, 1.0, "START"), [0.0, 0.5, 1.0])
    assert np.allclose(frame_offsets(5, 0.5, "END"), [-0.5, -0.375, -0.25, -0.125, 0.0])


def test_shutter_times_are_stratified_per_pixel():
    grid, W, H = 4, 8, 8
    SW = grid * W
    flat = np.arange(SW * grid * H)
    t = camera_samples.shutter_times(flat, SW, grid, seed=2)
    rows, cols = np.divmod(flat, SW)
    pixel = (rows // grid) * W + cols // grid
    for p in range(W * H):
        strata = np.sort(np.floor(t[pixel == p] * grid * grid).astype(int))
        assert strata.tolist() == list(range(grid * grid))       # one sample in each stratum
    assert np.array_equal(camera_samples.shutter_times(flat[[3, 99]], SW, grid, seed=2), t[[3, 99]])


def test_a_still_receivers_shadow_rays_take_every_stratum_of_the_shutter():
    ns = 64
    t = camera_samples.ray_times(np.arange(50), ns, seed=3).reshape(50, ns).astype(np.float64)
    strata = np.floor(t * ns).astype(int)
    assert all(sorted(row) == list(range(ns)) for row in strata)      # one ray in each stratum
    assert len({tuple(row) for row in strata}) == 50                   # each pixel its own order
    assert np.array_equal(camera_samples.ray_times(np.array([7]), ns, seed=3), t[7].astype(np.float32))


def test_auto_runs_the_reference_when_something_moves():
    scene = half_plane_scene(sun_light(0.05), res=16)
    still = choose("sun", 0.05, shape=scene_shape(scene, scene.lights[0]))
    scene.motion = ShutterMotion([1], _sliding(0.5)[:, None])
    moving = choose("sun", 0.05, shape=scene_shape(scene, scene.lights[0]))
    assert moving.method == "embree_irr" and moving.rule == "moving"
    assert still.rule != "moving"
    hard = choose("sun", 0.0, shape=scene_shape(scene, scene.lights[0]))
    assert hard.method == "embree_irr"            # a moving hard shadow is not hard


def test_pixel_centres_stay_at_the_frame():
    scene = half_plane_scene(sun_light(0.0), res=16)
    ref = render_frame(scene, ["embree_irr"]).lights[0].passes["embree_irr"]
    scene.motion = ShutterMotion([1], _sliding(0.5)[:, None])
    res = render_frame(scene, ["embree_irr"])
    assert np.array_equal(res.lights[0].passes["embree_irr"], ref)
    assert res.to_json()["camera_effects"]["sampled"].startswith("no")
    assert "motion blur over 0.5 frame(s) (1 moving object(s), 3 steps)" in camera_effects.effects_line(scene, True)


@pytest.mark.parametrize("bad", [np.zeros((3, 2, 4, 4)), np.zeros((3, 4, 4))])
def test_motion_arrays_must_match_the_moving_objects(bad):
    with pytest.raises(ValueError):
        ShutterMotion([1], bad)
