"""The Preview re-uses the camera G-buffer while the camera and the
geometry do not change (the depsgraph says so: ``bridge/buffer_cache.py``),
so moving a light re-computes only its light view and the filter; Esc
cancels inside a long method and writes nothing back."""
import bpy
import numpy as np
import pytest

import penumbra
from penumbra.bridge import buffer_cache, jobs, pipeline
from penumbra.bridge.pipeline import FrameRequest, prepare_frame
from helpers import CancelAfter
from scenes import open_sample

RES = (96, 64)


@pytest.fixture
def scene():
    penumbra.register()                  # installs the depsgraph handler too
    sc = open_sample("sphere_plane")
    for lt in bpy.data.lights:
        lt.penumbra.method = "pcf"
    buffer_cache.invalidate()
    yield sc
    penumbra.unregister()
    assert not buffer_cache.watching()


def _preview(scene, **kw):
    job = prepare_frame(scene, FrameRequest.from_scene_settings(resolution=RES, preview=True, references=(), **kw))
    job.run()
    res = job.result()
    lr = res.lights[0]
    return job, lr.passes["pcf"], lr.record["pcf"]["time_s"]


def _light():
    return next(o for o in bpy.data.objects if o.type == "LIGHT")


def test_a_second_preview_reuses_every_buffer(scene):
    job, v, t = _preview(scene)
    assert not job.reused and t["gbuffer"] > 0.0 and buffer_cache.watching()
    job2, v2, t2 = _preview(scene)
    assert job2.reused
    assert t2["gbuffer"] == t2["light_view"] == 0.0
    np.testing.assert_array_equal(v, v2)


def test_moving_a_light_rebuilds_only_its_view(scene):
    _preview(scene)
    _light().location.x += 0.5
    bpy.context.view_layer.update()              # the depsgraph update a UI edit sends
    job, v, t = _preview(scene)
    assert job.reused and t["gbuffer"] == 0.0 and t["light_view"] > 0.0
    buffer_cache.invalidate()
    job_fresh, v_fresh, _ = _preview(scene)
    assert not job_fresh.reused
    np.testing.assert_array_equal(v, v_fresh)


def test_editing_geometry_or_moving_the_camera_rebuilds_the_gbuffer(scene):
    _preview(scene)
    mesh = next(o for o in bpy.data.objects if o.type == "MESH")
    mesh.location.z += 0.1
    bpy.context.view_layer.update()
    job, _, t = _preview(scene)
    assert not job.reused and t["gbuffer"] > 0.0
    scene.camera.location.x += 0.1               # no view_layer.update: the capture's own
    job, _, t = _preview(scene)                  # evaluation and the key both see it
    assert not job.reused and t["gbuffer"] > 0.0


def test_the_preview_map_is_half_the_default_map(scene):
    job, _, _ = _preview(scene)
    lr = job.result().lights[0]
    side = round((RES[0] * RES[1]) ** 0.5)          # views.default_map_size: texels ~ the output's pixels
    assert max(lr.record["pcf"]["stats"]["map"][1:]) == round(side * jobs.PREVIEW_MAP_SCALE)
    job = prepare_frame(scene, FrameRequest.from_scene_settings(resolution=RES, references=(), pixel_filter="none"))
    assert max(job.run().result().lights[0].record["pcf"]["stats"]["map"][1:]) == side   # Compute: the whole


def test_cancel_inside_a_method_writes_nothing_back(scene, monkeypatch):
    """The worker stops at the chunk after the cancel, inside the G-buffer's
    bands (one row each here, so 64 of them): at most one band per thread
    runs, nothing is kept or shown."""
    from penumbra.core import pixel_rays, raycast
    monkeypatch.setattr(raycast, "BAND_RAYS", RES[0])
    bands = []
    make_rays = pixel_rays.make_rays

    def counting(*args):
        bands.append(args[3])                     # row0: one call per band traced
        return make_rays(*args)

    monkeypatch.setattr(pixel_rays, "make_rays", counting)

    def run(token):
        job = prepare_frame(scene, FrameRequest.from_scene_settings(resolution=RES, preview=True, references=(), per_light=True))
        bg = pipeline.BackgroundFrameJob(job, token).start()
        assert bg.wait(300)
        return bg
    whole = run(CancelAfter(10 ** 9))          # counts its checks, never cancels
    assert not whole.cancelled and whole.job.results
    buffer_cache.invalidate()
    for img in [i for i in bpy.data.images if i.name.startswith("Penumbra ")]:
        bpy.data.images.remove(img)
    assert len(bands) > RES[1]                    # the G-buffer's 64 bands and the light view's
    bands.clear()
    bg = run(CancelAfter(1))                      # cancelled at its second check
    assert bg.cancelled and bg.job.error is None
    assert 1 <= len(bands) <= 2 < RES[1]          # a band on each of the two threads at most
    assert not bg.job.results and bg.job.cache is None
    assert buffer_cache.lookup(buffer_cache.ticket(scene, bg.job.captured)) is None
    assert not [i.name for i in bpy.data.images if i.name.startswith("Penumbra ")]


def test_an_unchanged_light_keeps_its_pass_a_moved_one_does_not(scene):
    """Two lights: moving one re-runs its method only; the other's pass is
    taken over (``"reused"``, 0 s); every pass equals a fresh compute, and a
    changed knob is not taken over."""
    key = _light()
    data = key.data.copy()
    fill = bpy.data.objects.new("Fill", data)
    fill.location = (key.location.x - 1.5, key.location.y + 1.0, key.location.z)
    scene.collection.objects.link(fill)
    bpy.context.view_layer.update()
    buffer_cache.invalidate()

    def run():
        job = prepare_frame(scene, FrameRequest.from_scene_settings(resolution=RES, preview=True, references=()))
        job.run()
        return job, {lr.name: lr for lr in job.result().lights}
    run()
    job, lights = run()
    assert job.reused and len(lights) == 2
    assert all(lr.record["pcf"].get("reused") and lr.record["pcf"]["time_s"]["total"] == 0.0
               for lr in lights.values())
    fill.location.x += 0.3
    bpy.context.view_layer.update()
    job, moved = run()
    assert job.reused and moved[key.name].record["pcf"].get("reused")
    assert "reused" not in moved["Fill"].record["pcf"] and moved["Fill"].record["pcf"]["time_s"]["filter"] > 0
    fill.data.penumbra.knobs.pcf.PenumbraSamples = 32      # Fill's own light data: Fill re-runs
    job, knob = run()
    assert knob[key.name].record["pcf"].get("reused") and "reused" not in knob["Fill"].record["pcf"]
    buffer_cache.invalidate()
    fresh_job, fresh = run()
    assert not fresh_job.reused
    for name, lr in knob.items():
        np.testing.assert_array_equal(lr.passes["pcf"], fresh[name].passes["pcf"])
    fill.data.penumbra.knobs.pcf.PenumbraSamples = 64
    buffer_cache.invalidate()
    _, fresh = run()
    for name, lr in moved.items():
        np.testing.assert_array_equal(lr.passes["pcf"], fresh[name].passes["pcf"])


def test_the_preview_runs_methods_at_their_preview_settings(scene):
    """single_sample previews with the paper's nearest blocker and object
    ids, pcf with fewer samples (``Method.preview_params``); a light's own
    knob wins; the Compute keeps the accurate defaults."""
    from penumbra.core.methods import producer_of
    PREVIEW_PARAMS = {m: producer_of(m).preview_params for m in ("pcf", "single_sample")}
    lt = _light()
    lt.data.penumbra.method = "single_sample"
    job = prepare_frame(scene, FrameRequest.from_scene_settings(resolution=RES, preview=True, references=()))
    job.run()
    params = job.result().lights[0].record["single_sample"]["params"]
    assert {k: params[k] for k in PREVIEW_PARAMS["single_sample"]} == PREVIEW_PARAMS["single_sample"]
    job = prepare_frame(scene, FrameRequest.from_scene_settings(resolution=RES, references=()))
    job.run()
    params = job.result().lights[0].record["single_sample"]["params"]
    assert (params["blocker"], params["surfaces"]) == ("sum", "mesh")
    lt.data.penumbra.method = "pcf"
    lt.data.penumbra.knobs.pcf.PenumbraSamples = 48
    job = prepare_frame(scene, FrameRequest.from_scene_settings(resolution=RES, preview=True, references=()))
    job.run()
    params = job.result().lights[0].record["pcf"]["params"]
    assert (params["PenumbraSamples"], params["BlockerSamples"]) == (48, PREVIEW_PARAMS["pcf"]["BlockerSamples"])


def test_the_preview_is_at_pixel_centres_and_compute_is_filtered(scene):
    """The scene's Pixel Filter is "Scene" by default, so Compute
    Passes is filtered like the render (an Alpha, the JSON's filter), while
    the Preview stays preview quality: pixel centres, unless its request
    names a filter."""
    assert scene.penumbra.pixel_filter == "SCENE"
    job, _, t = _preview(scene)
    assert job.result().pixel_filter is None and job.result().coverage is None and "subpixel" not in t
    job = prepare_frame(scene, FrameRequest.from_scene_settings(resolution=RES, references=()))
    res = job.run().result()
    assert res.pixel_filter["type"] == "blackman-harris" and res.coverage is not None
    assert "subpixel" in res.lights[0].record["pcf"]["time_s"]
    job = prepare_frame(scene, FrameRequest.from_scene_settings(resolution=RES, preview=True, references=(), pixel_filter="box:1"))
    assert job.run().result().pixel_filter["type"] == "box"


def test_a_scatter_is_compared_as_instances_and_never_flattened(tmp_path):
    """On an Instance on Points scatter the Preview's change check compares
    meshes and placements: a second Preview reuses the buffers, moving one
    point rebuilds them, and neither capture is flattened."""
    from test_capture import _scatter_file
    penumbra.register()
    try:
        bpy.ops.wm.open_mainfile(filepath=_scatter_file(tmp_path / "scatter.blend"))
        sc = bpy.context.scene
        for lt in bpy.data.lights:
            lt.penumbra.method = "pcf"
        buffer_cache.invalidate()
        job, v, t = _preview(sc)
        assert not job.captured.is_flattened and t["gbuffer"] > 0.0
        job2, v2, t2 = _preview(sc)
        assert job2.reused and t2["gbuffer"] == 0.0 and not job2.captured.is_flattened
        np.testing.assert_array_equal(v, v2)
        bpy.data.objects["Scatter"].data.vertices[0].co.x += 0.5
        bpy.context.view_layer.update()
        job3, _, t3 = _preview(sc)
        assert not job3.reused and t3["gbuffer"] > 0.0 and not job3.captured.is_flattened
    finally:
        penumbra.unregister()
