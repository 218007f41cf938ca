"""Compute Shadow Passes: the current frame's passes for every enabled
light (its own method and settings, plus the scene's references), through
``bridge.pipeline``.

In the UI the operator is modal (``modal_job.py``): the steps (one per
light) run in a worker thread while the status bar and the window manager
show the progress, and Esc cancels; in background mode (and when called
from a script) it runs every step at once. Nothing in ``bpy.data`` changes
until the last step is done, so a cancelled run leaves no trace and a
finished one is a single undo step.
"""
from __future__ import annotations

from typing import Optional

import bpy

from ..bridge import settings
from ..bridge.pipeline import FrameJob, FrameRequest, check_out_dir, finish_frame, scaled_resolution
from .modal_job import ModalFrameJob


class PENUMBRA_OT_compute_passes(ModalFrameJob, bpy.types.Operator):
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

    _label = "computing shadow passes"
    _modal_per_light = True
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
        self._out_dir = None
        if settings.output_folder(scene):
            self._out_dir, err = check_out_dir(settings.output_folder(scene))
            if err:
                self.report({"ERROR"}, f"Penumbra: {err}")
                return None
        request = FrameRequest.from_scene_settings(resolution=scaled_resolution(scene, self.resolution_scale),
                                                   methods=methods, samples=self.samples or None,
                                                   per_light=per_light, catch_errors=True)
        return self._plan_job(scene, request)

    def _conclude(self, context, job: FrameJob):
        if job.error is not None:
            for w in job.warnings:
                self.report({"WARNING"}, f"Penumbra: {w}")
            self.report({"ERROR"}, f"Penumbra: computing failed: {job.error}")
            return {"CANCELLED"}
        scene = bpy.data.scenes.get(job.scene_name) or context.scene
        result, written = finish_frame(scene, job, self._out_dir, build_nodes=self.build_nodes)
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

    # execute (headless, scripts: every step at once) and the modal invoke: ModalFrameJob


classes = (PENUMBRA_OT_compute_passes,)
