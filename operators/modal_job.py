"""The modal side of a frame computed off the UI thread, shared by Compute
Passes and Preview (``bridge.pipeline.BackgroundFrameJob``).

``invoke`` captures and plans on the main thread (``_prepare``), starts the
worker and a window timer; each TIMER event only reads the worker's
progress into the status bar and the window manager's progress, so it
returns at once; Esc cancels (nothing in ``bpy.data`` has changed: the
write-back, ``_conclude``, runs on the main thread once the worker is done).
A job with external producers (the Cycles reference renders through bpy)
runs one step per timer tick on the main thread instead.
"""
from __future__ import annotations

from typing import Optional

import bpy

from ..bridge.pipeline import BackgroundFrameJob, FrameJob, first_line, no_light_reason, prepare_frame

#: seconds between two looks at the worker
TICK = 0.1


class ModalFrameJob:
    """Mixin for a bpy Operator: subclasses give ``_prepare(context,
    per_light) -> FrameJob or None``, ``_conclude(context, job) -> set``
    (the write-back and the report) and ``_label`` (the status bar's words)."""

    _label = "computing"
    _modal_per_light = False              # one step per light (finer progress and cancel)
    _timer = None
    _job: Optional[FrameJob] = None
    _bg: Optional[BackgroundFrameJob] = None

    def execute(self, context):
        """Headless and from scripts: every step at once, on this thread."""
        job = self._prepare(context, per_light=False)
        if job is None:
            return {"CANCELLED"}
        wm = context.window_manager
        wm.progress_begin(0.0, 1.0)
        try:
            job.run(lambda _msg, f: wm.progress_update(f))
        except Exception as exc:          # a report, not a traceback
            job.error = f"{type(exc).__name__}: {first_line(exc)}"
        finally:
            wm.progress_end()
        return self._conclude(context, job)

    def _plan_job(self, scene, request) -> Optional[FrameJob]:
        """``prepare_frame(scene, request)``, or None with the reason
        reported (a bad scene, or no light to compute)."""
        try:
            job = prepare_frame(scene, request)
        except (ValueError, RuntimeError) as exc:
            self.report({"ERROR"}, f"Penumbra: {first_line(exc)}")
            return None
        if not job.steps:
            self.report({"ERROR"}, f"Penumbra: {no_light_reason(job)}")
            return None
        return job

    def invoke(self, context, event):
        if bpy.app.background or context.window is None:
            return self.execute(context)
        job = self._prepare(context, per_light=self._modal_per_light)
        if job is None:
            return {"CANCELLED"}
        return self._begin(context, job)

    def _begin(self, context, job: FrameJob):
        """Start ``job`` in the worker (or step it per tick when it needs bpy)."""
        self._job = job
        self._bg = BackgroundFrameJob(job).start() if BackgroundFrameJob.runs_in_background(job) else None
        wm = context.window_manager
        wm.progress_begin(0.0, 1.0)
        if getattr(context, "window", None) is not None:
            self._timer = wm.event_timer_add(TICK, window=context.window)
            wm.modal_handler_add(self)
        self._status(context, "starting")
        return {"RUNNING_MODAL"}

    def _status(self, context, message: str) -> None:
        if getattr(context, "workspace", None) is not None:
            context.workspace.status_text_set(f"Penumbra: {self._label}: {message} (Esc to cancel)")

    def _stop(self, context):
        wm = context.window_manager
        if self._timer is not None:
            wm.event_timer_remove(self._timer)
            self._timer = None
        wm.progress_end()
        if getattr(context, "workspace", None) is not None:
            context.workspace.status_text_set(None)

    def modal(self, context, event):
        job = self._job
        if event.type == "ESC":
            if self._bg is not None:
                self._bg.cancel()
            self._stop(context)
            self.report({"WARNING"}, f"Penumbra: cancelled after {job.index} of {len(job.steps)} "
                                     "step(s); nothing was changed")
            return {"CANCELLED"}
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        if self._bg is not None:
            if not self._bg.done:
                context.window_manager.progress_update(self._bg.fraction)
                self._status(context, f"{self._bg.message} ({100 * self._bg.fraction:.0f}%)")
                return {"RUNNING_MODAL"}
            job = self._bg.collect()
        elif not job.done:
            job.step()
            context.window_manager.progress_update(job.index / max(1, len(job.steps)))
            self._status(context, f"{job.index} of {len(job.steps)} step(s)")
        if job.done:
            self._stop(context)
            return self._conclude(context, job)
        return {"RUNNING_MODAL"}

    def cancel(self, context):
        if self._bg is not None:
            self._bg.cancel()
        self._stop(context)
