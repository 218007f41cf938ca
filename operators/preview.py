"""Preview: a fast method at reduced resolution, shown in the image
"Penumbra Preview" (updated in place, so an Image Editor showing it refreshes).

Each enabled light uses its own method when that has preview settings
(``Method.preview_params``), else pcf, with no references. Several lights
combine as their energy-weighted mean visibility (1 = every light fully
visible). In the UI it computes in a worker thread (``modal_job.py``);
headless, at once. Preview quality (``FrameRequest.preview``): light views at
``jobs.PREVIEW_MAP_SCALE`` of the default map's side, the methods at their
preview settings (said in the report), and the last Preview's camera
G-buffer, and the views and passes of the lights that did not change, while
the camera and the geometry do not change (``bridge/buffer_cache.py``).
"""
from __future__ import annotations

import bpy

from ..bridge import settings
from ..bridge.images import combine, show_preview
from ..bridge.pipeline import FrameRequest, scaled_resolution
from .modal_job import ModalFrameJob


def preview_label(pass_id: str) -> str:
    """A pass id with the preview's own settings of it (``Method.preview_params``),
    for the report: "single_sample (preview settings: blocker nearest, ...)"."""
    from ..core import methods as registry
    ps = registry.producer_of(pass_id).preview_params if pass_id in registry.pass_ids(external=False) else None
    if not ps:
        return pass_id
    return f"{pass_id} (preview settings: {', '.join(f'{k} {v}' for k, v in ps.items())})"


def _show_in_image_editors(context, img) -> int:
    n = 0
    screen = getattr(context, "screen", None)
    if screen is None:
        return 0
    for area in screen.areas:
        if area.type == "IMAGE_EDITOR":
            area.spaces.active.image = img
            area.tag_redraw()
            n += 1
    return n


class PENUMBRA_OT_preview(ModalFrameJob, bpy.types.Operator):
    """Quick look at the soft shadows: each light's method at its preview
    settings (pcf for a method without them) and reduced resolution, shown
    in the "Penumbra Preview" image"""

    bl_idname = "penumbra.preview"
    bl_label = "Preview Shadows"
    bl_options = {"REGISTER", "UNDO"}
    _label = "preview"

    only_active: bpy.props.BoolProperty(
        name="Active Light Only", default=False,
        description="Preview only the active light (else every enabled light)")
    max_size: bpy.props.IntProperty(
        name="Size", default=0, min=0, max=4096,
        description="Larger side of the preview in pixels; 0: the scene's Preview Size")

    @classmethod
    def poll(cls, context):
        return context.scene is not None

    def _prepare(self, context, per_light: bool = False):
        scene = context.scene
        only = None
        if self.only_active:
            ob = context.object
            if ob is None or ob.type != "LIGHT":
                self.report({"ERROR"}, "Penumbra: the active object is not a light")
                return None
            only = [ob.name]
        ss = settings.scene_settings(scene)
        side = self.max_size or (int(ss.preview_size) if ss is not None else 256)
        request = FrameRequest.from_scene_settings(resolution=scaled_resolution(scene, 1.0, side), preview=True,
                                                   references=(), lights=only, per_light=per_light)
        return self._plan_job(scene, request)

    def _conclude(self, context, job):
        if job.error is not None:
            self.report({"ERROR"}, f"Penumbra: preview failed: {job.error}")
            return {"CANCELLED"}
        if not job.results:
            self.report({"ERROR"}, "Penumbra: no light left to preview")
            return {"CANCELLED"}
        result = job.result()
        img = show_preview(combine(result, job.captured))
        shown = _show_in_image_editors(context, img)
        methods = [preview_label(p) for p in sorted({p for lr in result.lights for p in lr.passes})]
        where = "" if shown or bpy.app.background else " (open an Image Editor to see it)"
        res = job.captured.resolution
        self.report({"INFO"}, f"Penumbra: preview {res[0]}x{res[1]}, {len(result.lights)} light(s), "
                              f"{', '.join(methods)}, {result.total_s:.2f} s -> image "
                              f"'{img.name}'{where}")
        return {"FINISHED"}


classes = (PENUMBRA_OT_preview,)
