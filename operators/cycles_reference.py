"""Render Cycles reference: the ``cycles`` pass of every shadow-casting
light (``bridge/cycles_reference.py`` renders it), stored as images."""
from __future__ import annotations

import bpy

from ..bridge import compositor, settings
from ..bridge.capture import capture_scene, object_named
from ..bridge.cycles_reference import PASS_ID, CyclesReferenceError, make_cycles_producer
from ..bridge.images import store_pass_image
from ..bridge.pipeline import scaled_resolution


def _penumbra_enabled(light_name: str) -> bool:
    """The light's Penumbra setting (``light.penumbra.enabled``; True when the
    settings are not registered or the light is an instance)."""
    ob = object_named(light_name)
    s = settings.light_settings(ob.data) if ob is not None and ob.type == "LIGHT" else None
    return bool(getattr(s, "enabled", True))


class PENUMBRA_OT_render_cycles_reference(bpy.types.Operator):
    """Render the Cycles shadow reference (Diffuse Direct with / without the
    light's shadow) of every shadow-casting light and store it as an image"""

    bl_idname = "penumbra.render_cycles_reference"
    bl_label = "Render Cycles reference"
    bl_options = {"REGISTER"}

    samples: bpy.props.IntProperty(
        name="Samples", default=0, min=0, max=1 << 20,
        description="Cycles samples per pixel (0: the scene's Penumbra Cycles Samples). More "
                    "samples, less noise (it falls as 1/sqrt(samples)); two renders per light")
    seed: bpy.props.IntProperty(
        name="Seed", default=-1, min=-1,
        description="Cycles seed (-1: the scene's Penumbra seed); the same seed gives the same image")
    resolution_scale: bpy.props.FloatProperty(
        name="Resolution Scale", default=1.0, min=0.01, max=1.0,
        description="Fraction of the scene's render resolution: the pass costs the square of it")
    build_nodes: bpy.props.BoolProperty(
        name="Build Compositor Nodes", default=False,
        description="Also show the reference images in the compositor")

    def _settings(self, scene):
        samples = self.samples or settings.cycles_samples(scene)
        seed = self.seed if self.seed >= 0 else settings.seed(scene)
        return samples, seed

    def execute(self, context):
        from ..core.frame import render_frame
        scene = context.scene
        if scene.camera is None:
            self.report({"ERROR"}, "Penumbra: the scene has no camera")
            return {"CANCELLED"}
        samples, seed = self._settings(scene)
        res = scaled_resolution(scene, self.resolution_scale)
        view_layer = context.view_layer
        wm = context.window_manager
        wm.progress_begin(0.0, 1.0)
        try:
            captured = capture_scene(scene, depsgraph=context.evaluated_depsgraph_get(), resolution=res)
            producer = make_cycles_producer(scene, res, samples, seed, view_layer,
                                            pixel_filter=settings.pixel_filter(scene))
            names = [lt.name for lt in captured.lights if _penumbra_enabled(lt.name)]
            if not names:
                self.report({"WARNING"}, "Penumbra: no light to render (none, or Penumbra is off "
                                         "for every light)")
                return {"CANCELLED"}
            result = render_frame(captured, [PASS_ID], names, external={PASS_ID: producer},
                                  progress=lambda _msg, f: wm.progress_update(f))
        except (CyclesReferenceError, ValueError) as exc:
            self.report({"ERROR"}, f"Penumbra: {exc}")
            return {"CANCELLED"}
        except RuntimeError as exc:       # Blender's render reported an error
            msg = str(exc).strip().splitlines()[-1] if str(exc).strip() else "the render failed"
            self.report({"ERROR"}, f"Penumbra: {msg}")
            return {"CANCELLED"}
        finally:
            wm.progress_end()
        done = [lr for lr in result.lights if not lr.record[PASS_ID].get("skipped")]
        for lp in result.plan.lights:
            if lp.action == "skip":
                self.report({"INFO"}, f"Penumbra: {lp.name}: skipped, {lp.reason}")
        if not done:
            self.report({"WARNING"}, "Penumbra: no light casts shadows; nothing to render")
            return {"CANCELLED"}
        for lr in done:
            store_pass_image(lr.layer, PASS_ID, lr.passes[PASS_ID])
        if self.build_nodes:
            compositor.build_side_by_side(scene, {lr.name: lr.layer for lr in done}, (PASS_ID,))
        total = sum(lr.record[PASS_ID]["time_s"]["total"] for lr in done)
        self.report({"INFO"}, f"Penumbra: Cycles reference of {len(done)} light(s) at "
                              f"{res[0]}x{res[1]}, {samples} samples, in {total:.2f} s")
        return {"FINISHED"}


classes = (PENUMBRA_OT_render_cycles_reference,)
