"""Operators: thin wrappers, capture -> core -> write back."""
from __future__ import annotations

import bpy

from ..addon import compositor
from .capture import capture_scene

DEFAULT_PASSES = ("pcf", "embree", "embree_irr")


class PENUMBRA_OT_compute_passes(bpy.types.Operator):
    """Compute Penumbra's shadow passes for the current frame, store each as an
    image and show them in the compositor beside the ray-traced reference"""

    bl_idname = "penumbra.compute_passes"
    bl_label = "Compute Shadow Passes"
    bl_options = {"REGISTER"}

    methods: bpy.props.StringProperty(name="Methods", default=",".join(DEFAULT_PASSES),
                                      description="Comma-separated method ids, or 'all'")
    samples: bpy.props.IntProperty(name="Samples", default=64, min=1, max=65536,
                                   description="Light samples per pixel for sampling methods")
    resolution_scale: bpy.props.FloatProperty(name="Resolution Scale", default=1.0, min=0.01, max=1.0)
    build_nodes: bpy.props.BoolProperty(name="Build Compositor Nodes", default=True)

    def execute(self, context):
        from ..core.frame import render_frame
        from ..core.planner import PlanError, resolve_passes
        scene = context.scene
        try:
            passes = resolve_passes(self.methods)
        except PlanError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        if scene.camera is None:
            self.report({"ERROR"}, "Penumbra: the scene has no camera")
            return {"CANCELLED"}
        r = scene.render
        pct = r.resolution_percentage / 100.0 * self.resolution_scale
        res = (max(1, int(r.resolution_x * pct)), max(1, int(r.resolution_y * pct)))
        try:
            captured = capture_scene(scene, depsgraph=context.evaluated_depsgraph_get(), resolution=res)
        except ValueError as exc:
            self.report({"ERROR"}, f"Penumbra: {exc}")
            return {"CANCELLED"}
        wm = context.window_manager
        wm.progress_begin(0.0, 1.0)
        try:
            result = render_frame(captured, passes, overrides={"samples": self.samples},
                                  progress=lambda _msg, f: wm.progress_update(f))
        finally:
            wm.progress_end()
        for lr in result.lights:
            for pid, v in lr.passes.items():
                compositor.store_pass_image(lr.layer, pid, v)
        if self.build_nodes:
            compositor.build_side_by_side(scene, {lr.name: lr.layer for lr in result.lights}, passes)
        for n in result.plan.notes:
            self.report({"INFO"}, f"Penumbra: {n}")
        self.report({"INFO"}, f"Penumbra: {len(result.lights)} light(s), {len(passes)} pass(es) "
                              f"in {result.total_s:.2f} s")
        return {"FINISHED"}


classes = (PENUMBRA_OT_compute_passes,)
