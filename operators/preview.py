"""Preview: a fast method at reduced resolution, shown in the image
"Penumbra Preview" (updated in place, so an Image Editor showing it refreshes).

Each enabled light uses its own method when that is fast (``FAST_METHODS``),
else pcf, with no references. Several lights combine as their
energy-weighted mean visibility (1 = every light fully visible).
"""
from __future__ import annotations

import numpy as np

import bpy

from ..addon import properties as props
from ..addon.compositor import fill_grey
from .capture import capture_scene
from .compute import (_first_line, light_jobs, light_object, make_steps, merge_results, run_step,
                      scaled_resolution)

PREVIEW_IMAGE = "Penumbra Preview"


def combine(result, captured) -> np.ndarray:
    """Energy-weighted mean of the lights' passes (float32[H,W])."""
    W, H = captured.resolution
    energy = {lt.name: max(float(lt.energy), 0.0) for lt in captured.lights}
    acc = np.zeros((H, W), np.float64)
    total = 0.0
    for lr in result.lights:
        v = next(iter(lr.passes.values()), None)
        if v is None:
            continue
        w = energy.get(lr.name, 0.0) or 1e-12
        acc += w * v
        total += w
    if total <= 0.0:
        return np.ones((H, W), np.float32)
    return (acc / total).astype(np.float32)


def show_preview(v: np.ndarray) -> bpy.types.Image:
    """Write ``v`` (row 0 at the top) into the "Penumbra Preview" image,
    resizing it in place rather than making a new one."""
    h, w = v.shape
    img = bpy.data.images.get(PREVIEW_IMAGE)
    if img is None:
        img = bpy.data.images.new(PREVIEW_IMAGE, w, h, alpha=False, float_buffer=True)
    elif tuple(img.size) != (w, h):
        img.scale(w, h)
    fill_grey(img, v)
    return img


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


class PENUMBRA_OT_preview(bpy.types.Operator):
    """Quick look at the soft shadows: a fast method at reduced resolution,
    shown in the "Penumbra Preview" image"""

    bl_idname = "penumbra.preview"
    bl_label = "Preview Shadows"
    bl_options = {"REGISTER", "UNDO"}

    only_active: bpy.props.BoolProperty(
        name="Active Light Only", default=False,
        description="Preview only the active light (else every enabled light)")
    max_size: bpy.props.IntProperty(
        name="Size", default=0, min=0, max=4096,
        description="Larger side of the preview in pixels; 0: the scene's Preview Size")

    @classmethod
    def poll(cls, context):
        return context.scene is not None

    def execute(self, context):
        scene = context.scene
        if scene.camera is None:
            self.report({"ERROR"}, "Penumbra: the scene has no camera")
            return {"CANCELLED"}
        only = None
        if self.only_active:
            ob = context.object
            if ob is None or ob.type != "LIGHT":
                self.report({"ERROR"}, "Penumbra: the active object is not a light")
                return {"CANCELLED"}
            only = [ob.name]
        ss = props.scene_settings(scene)
        side = self.max_size or (int(ss.preview_size) if ss is not None else 256)
        res = scaled_resolution(scene, 1.0, side)
        try:
            captured = capture_scene(scene, resolution=res)
        except (ValueError, RuntimeError) as exc:
            self.report({"ERROR"}, f"Penumbra: {_first_line(exc)}")
            return {"CANCELLED"}
        jobs, _notes = light_jobs(scene, captured, fast=True, references=(), only=only)
        if not jobs:
            why = "the scene has no lights" if not captured.lights else "no light has Penumbra enabled"
            self.report({"ERROR"}, f"Penumbra: {why}")
            return {"CANCELLED"}
        from ..addon.preferences import apply_threads
        apply_threads()
        wm = context.window_manager
        steps = make_steps(jobs, per_light=False)
        results = []
        wm.progress_begin(0.0, 1.0)
        try:
            for i, st in enumerate(steps):
                st.names = [n for n in st.names if light_object(n) is not None]
                if not st.names:
                    continue
                results.append(run_step(captured, st, None,
                                        lambda _m, f, i=i: wm.progress_update((i + f) / len(steps))))
        except Exception as exc:          # a report, not a traceback
            self.report({"ERROR"}, f"Penumbra: preview failed: {type(exc).__name__}: {_first_line(exc)}")
            return {"CANCELLED"}
        finally:
            wm.progress_end()
        if not results:
            self.report({"ERROR"}, "Penumbra: no light left to preview")
            return {"CANCELLED"}
        result = merge_results(captured, results)
        img = show_preview(combine(result, captured))
        shown = _show_in_image_editors(context, img)
        methods = sorted({p for lr in result.lights for p in lr.passes})
        where = "" if shown or bpy.app.background else " (open an Image Editor to see it)"
        self.report({"INFO"}, f"Penumbra: preview {res[0]}x{res[1]}, {len(result.lights)} light(s), "
                              f"{', '.join(methods)}, {result.total_s:.2f} s -> image "
                              f"'{img.name}'{where}")
        return {"FINISHED"}


classes = (PENUMBRA_OT_preview,)
