"""Compute Shadow Passes: the current frame's passes for every enabled
light (its own method and settings, plus the scene's references), through
``bridge.pipeline``.

In the UI the operator is modal and runs one step (one light) per timer tick,
reports progress through the window manager and stops on Esc; in background
mode (and when called from a script) it runs every step at once. Nothing in
``bpy.data`` changes until the last step is done, so a cancelled run leaves
no trace and a finished one is a single undo step.
"""
from __future__ import annotations

from typing import Optional

import bpy

from ..bridge import settings
from ..bridge.pipeline import (FrameJob, FrameRequest, check_out_dir, first_line,
                               no_light_reason, prepare_frame, scaled_resolution, write_back)


def finish(job: FrameJob, scene, out_dir: Optional[str], build_nodes: bool):
    """Merge, store images, build the compositor nodes and write files.
    Returns (FrameResult or None when nothing was computed, written paths)."""
    if job.error is not None or not job.results:
        return None, None
    from ..core.output import write_frame
    result = job.result()
    write_back(scene, result, build_nodes)
    written = None
    if out_dir and result.lights:
        try:
            written = write_frame(result, out_dir, previews=False)
        except (OSError, ValueError) as exc:
            job.warnings.append(f"could not write to {out_dir}: {exc}")
    return result, written


class PENUMBRA_OT_compute_passes(bpy.types.Operator):
    """Compute Penumbra's shadow passes of the current frame for every enabled
    light (its own method and settings, plus the scene's references), store
    them as images and show them in the compositor. Esc cancels"""

    bl_idname = "penumbra.compute_passes"
    bl_label = "Compute Shadow Passes"
    bl_options = {"REGISTER", "UNDO"}

    methods: bpy.props.StringProperty(
        name="Methods", default="",
        description="Comma-separated method ids (or 'all') for every light; empty: each light's "
                    "own method plus the scene's references")
    samples: bpy.props.IntProperty(
        name="Samples", default=0, min=0, max=65536,
        description="Light samples per pixel for every light; 0: each light's own setting")
    resolution_scale: bpy.props.FloatProperty(name="Resolution Scale", default=1.0, min=0.01, max=1.0)
    build_nodes: bpy.props.BoolProperty(name="Build Compositor Nodes", default=True)

    _timer = None
    _job: Optional[FrameJob] = None
    _out_dir: Optional[str] = None

    @classmethod
    def poll(cls, context):
        return context.scene is not None

    # -- shared set-up ------------------------------------------------------
    def _prepare(self, context, per_light: bool) -> Optional[FrameJob]:
        from ..core.planner import PlanError, resolve_passes
        scene = context.scene
        methods = None
        if self.methods.strip():
            try:
                methods = resolve_passes(self.methods, external=("cycles",))
            except PlanError as exc:
                self.report({"ERROR"}, f"Penumbra: {exc}")
                return None
        if scene.camera is None:
            self.report({"ERROR"}, "Penumbra: the scene has no camera")
            return None
        self._out_dir = None
        if settings.output_folder(scene):
            self._out_dir, err = check_out_dir(settings.output_folder(scene))
            if err:
                self.report({"ERROR"}, f"Penumbra: {err}")
                return None
        request = FrameRequest(resolution=scaled_resolution(scene, self.resolution_scale),
                               methods=methods, samples=self.samples or None, per_light=per_light,
                               threads=settings.preferred_threads(), catch_errors=True)
        try:
            job = prepare_frame(scene, request)
        except (ValueError, RuntimeError) as exc:
            self.report({"ERROR"}, f"Penumbra: {first_line(exc)}")
            return None
        if not job.steps:
            self.report({"ERROR"}, f"Penumbra: {no_light_reason(job)}")
            return None
        return job

    def _conclude(self, context, job: FrameJob):
        if job.error is not None:
            for w in job.warnings:
                self.report({"WARNING"}, f"Penumbra: {w}")
            self.report({"ERROR"}, f"Penumbra: computing failed: {job.error}")
            return {"CANCELLED"}
        scene = bpy.data.scenes.get(job.scene_name) or context.scene
        result, written = finish(job, scene, self._out_dir, self.build_nodes)
        for w in job.warnings:
            self.report({"WARNING"}, f"Penumbra: {w}")
        if result is None:
            self.report({"ERROR"}, "Penumbra: no light was computed")
            return {"CANCELLED"}
        for n in list(job.notes) + list(result.plan.notes):
            self.report({"INFO"}, f"Penumbra: {n}")
        n_pass = len({p for lr in result.lights for p in lr.passes})
        msg = f"Penumbra: {len(result.lights)} light(s), {n_pass} pass(es) in {result.total_s:.2f} s"
        if written:
            msg += f"; wrote {written.get('exr', written['json'])}"
        self.report({"INFO"}, msg)
        return {"FINISHED"}

    # -- synchronous (background, scripts) ----------------------------------
    def execute(self, context):
        job = self._prepare(context, per_light=False)
        if job is None:
            return {"CANCELLED"}
        wm = context.window_manager
        wm.progress_begin(0.0, 1.0)
        try:
            job.run(lambda _msg, f: wm.progress_update(f))
        finally:
            wm.progress_end()
        return self._conclude(context, job)

    # -- modal (UI): one step per timer tick, Esc cancels --------------------
    def invoke(self, context, event):
        if bpy.app.background or context.window is None:
            return self.execute(context)
        job = self._prepare(context, per_light=True)
        if job is None:
            return {"CANCELLED"}
        self._job = job
        wm = context.window_manager
        wm.progress_begin(0.0, float(max(1, len(job.steps))))
        self._timer = wm.event_timer_add(0.05, window=context.window)
        wm.modal_handler_add(self)
        context.workspace.status_text_set("Penumbra: computing shadow passes (Esc to cancel)")
        return {"RUNNING_MODAL"}

    def _stop(self, context):
        wm = context.window_manager
        if self._timer is not None:
            wm.event_timer_remove(self._timer)
            self._timer = None
        wm.progress_end()
        if context.workspace is not None:
            context.workspace.status_text_set(None)

    def modal(self, context, event):
        job = self._job
        if event.type == "ESC":
            self._stop(context)
            self.report({"WARNING"}, f"Penumbra: cancelled after {job.index} of {len(job.steps)} "
                                     "step(s); nothing was changed")
            return {"CANCELLED"}
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        if not job.done:
            job.step()
            context.window_manager.progress_update(float(job.index))
        if job.done:
            self._stop(context)
            return self._conclude(context, job)
        return {"RUNNING_MODAL"}

    def cancel(self, context):
        self._stop(context)


classes = (PENUMBRA_OT_compute_passes,)
