"""Compute Passes and Preview off the UI thread (``operators/modal_job.py``):
the modal step returns at once while the worker computes, Esc leaves no
trace, and a finished run writes back what the synchronous path writes.
The operators' modal() is driven with fake TIMER / ESC events (bpy runs
headless here, so there is no window to post real ones)."""
import os
import time
from types import SimpleNamespace

import bpy
import numpy as np

from penumbra.bridge import pipeline
from penumbra.bridge.images import pass_image_name
from penumbra.operators.compute import PENUMBRA_OT_compute_passes
from penumbra.operators.modal_job import ModalFrameJob
from penumbra.operators.preview import PENUMBRA_OT_preview
from scenes import image_rgba, open_sample

TIMER, ESC = SimpleNamespace(type="TIMER"), SimpleNamespace(type="ESC")


def _open(w, h, method="embree", samples=64):
    scene = open_sample("sphere_plane", (w, h))
    scene.penumbra.references = set()
    for lt in bpy.data.lights:
        lt.penumbra.method = method
        lt.penumbra.light_samples = samples
    return scene


def _fake(op_cls, **props):
    """The operator's own functions on a plain object (a registered bpy
    Operator cannot be made outside an operator call)."""
    body = {k: v for k, v in vars(op_cls).items() if callable(v) and not k.startswith("__")}
    op = type("Fake" + op_cls.__name__, (ModalFrameJob,), body)()
    op.reports = []
    op.report = lambda kind, msg: op.reports.append((next(iter(kind)), msg))
    for k, v in props.items():
        setattr(op, k, v)
    return op


def _context(scene):
    return SimpleNamespace(scene=scene, window_manager=bpy.context.window_manager, window=None,
                           workspace=None, screen=None, object=bpy.context.object)


def _drive(op, ctx):
    """TIMER events until the operator ends: (result, slowest modal() call,
    ticks seen while the worker was still computing)."""
    slowest, busy = 0.0, 0
    while True:
        t = time.perf_counter()
        r = op.modal(ctx, TIMER)
        slowest = max(slowest, time.perf_counter() - t)
        if r != {"RUNNING_MODAL"}:
            return r, slowest, busy
        busy += 1
        time.sleep(0.02)


def _compute_op():
    return _fake(PENUMBRA_OT_compute_passes, methods="", samples=0, resolution_scale=1.0, build_nodes=True)


def test_modal_compute_stays_responsive_and_writes_what_execute_writes(registered):
    scene = _open(160, 120, samples=512)
    op, ctx = _compute_op(), _context(scene)
    job = op._prepare(ctx, per_light=True)
    assert op._begin(ctx, job) == {"RUNNING_MODAL"} and op._bg is not None
    assert not bpy.data.images.get(pass_image_name("Key_Light", "embree"))   # nothing before the end
    result, slowest, busy = _drive(op, ctx)
    assert result == {"FINISHED"}, op.reports
    assert busy >= 1 and slowest < 0.2            # the UI thread never waited on the worker
    modal = image_rgba(bpy.data.images[pass_image_name("Key_Light", "embree")])
    bpy.data.images.remove(bpy.data.images[pass_image_name("Key_Light", "embree")])
    assert bpy.ops.penumbra.compute_passes() == {"FINISHED"}        # headless: execute()
    np.testing.assert_array_equal(modal, image_rgba(bpy.data.images[pass_image_name("Key_Light", "embree")]))


def test_escape_cancels_and_leaves_no_trace(registered, tmp_path):
    scene = _open(160, 120, samples=2048)
    scene.penumbra.output_folder = str(tmp_path / "out")
    op, ctx = _compute_op(), _context(scene)
    job = op._prepare(ctx, per_light=True)
    op._begin(ctx, job)
    assert op.modal(ctx, TIMER) == {"RUNNING_MODAL"}
    t = time.perf_counter()
    assert op.modal(ctx, ESC) == {"CANCELLED"}
    assert time.perf_counter() - t < 0.2
    assert op._bg.wait(120) and op._bg.cancelled
    assert any("cancelled" in msg and "nothing was changed" in msg for _, msg in op.reports)
    assert not [i.name for i in bpy.data.images if i.name.startswith("Penumbra ")]
    assert os.listdir(tmp_path / "out") == []


def test_modal_preview_shows_what_execute_shows(registered):
    scene = _open(96, 64, method="pcf")
    scene.penumbra.preview_size = 64
    op, ctx = _fake(PENUMBRA_OT_preview, only_active=False, max_size=0), _context(scene)
    op._begin(ctx, op._prepare(ctx))
    result, slowest, _busy = _drive(op, ctx)
    assert result == {"FINISHED"}, op.reports
    modal = image_rgba(bpy.data.images["Penumbra Preview"]).copy()
    bpy.data.images.remove(bpy.data.images["Penumbra Preview"])
    assert bpy.ops.penumbra.preview() == {"FINISHED"}
    np.testing.assert_array_equal(modal, image_rgba(bpy.data.images["Penumbra Preview"]))


def test_light_deleted_while_the_worker_runs(registered):
    scene = _open(48, 32, method="pcf")
    bpy.ops.object.light_add(type="SPOT", location=(1, -1, 4))
    spot = bpy.context.object
    spot.name = "Second"
    spot.data.penumbra.method = "pcf"
    op, ctx = _compute_op(), _context(scene)
    bg = pipeline.BackgroundFrameJob(op._prepare(ctx, per_light=True)).start()
    assert bg.wait(120)
    bpy.data.objects.remove(spot)
    job = bg.collect()
    assert job.warnings == ["light 'Second' was deleted during the run: skipped"]
    assert [lr.name for r in job.results for lr in r.lights] == ["Key.Light"]
