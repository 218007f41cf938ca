"""Set up compositor: the "Penumbra" node group in the scene's compositing
node group (``bridge/compositor.py`` builds it), fed by the stored pass
images or by a multilayer EXR written by ``penumbra render``."""
from __future__ import annotations

import os
from typing import Dict, List, Optional, Tuple

import bpy

from ..bridge import compositor, settings
from ..bridge.capture import light_object
from ..bridge.images import pass_image_name
from ..bridge.jobs import asks_for_auto, last_auto
from ..bridge.pipeline import default_exr_path


def exr_layers(path: str) -> Dict[str, List[str]]:
    """layer -> pass ids of a multilayer EXR written by ``penumbra render``
    (channel names ``layer.pass.V``); reads every part's header."""
    import OpenEXR
    out: Dict[str, List[str]] = {}
    with OpenEXR.File(path, header_only=True) as f:
        for part in f.parts:
            names = part.header.get("channels")
            names = [c.name for c in names] if names is not None else list(part.channels)
            for name in names:
                bits = name.split(".")
                if len(bits) >= 3:
                    out.setdefault(".".join(bits[:-2]), []).append(bits[-2])
    return out


def scene_lights(scene) -> List[Tuple[str, str]]:
    """(light object name, EXR layer) of the scene's rendered lights, in the
    planner's layer naming (dots -> underscores, repeats numbered)."""
    from ..core.planner import unique_layers
    names = sorted(o.name for o in scene.objects if o.type == "LIGHT" and not o.hide_render)
    return list(zip(names, unique_layers(names)))


def light_method(light_name: str, requested: str = "", scene=None) -> str:
    """The pass shown as "the method" for a light: ``requested``, else the
    light's Penumbra method (``auto``: what it last resolved to for this
    scene, ``bridge.jobs.last_auto``; '' when it never ran: then the light's
    first non-reference pass is shown)."""
    if requested:
        return requested
    ob = light_object(light_name)
    s = settings.light_settings(ob.data) if ob is not None else None
    if not asks_for_auto(s):
        return s.method
    choice = last_auto(scene.name, light_name) if scene is not None else None
    return choice.method if choice is not None else ""


def _fallback_method(method: str, available: List[str]) -> str:
    """``method`` when it has a pass, else the first non-reference pass."""
    if method in available or not available:
        return method
    refs = {"embree", "embree_irr", "cycles"}
    return next((p for p in available if p not in refs), method)


def plan_lights(scene, source: str, exr_path: Optional[str] = None,
                method: str = "") -> List[Tuple[str, str, str]]:
    """[(light name, layer, method)] for ``setup_compositor``. IMAGES: the
    scene's lights that have stored pass images; EXR: the EXR's layers."""
    from ..core import methods as registry
    known = registry.pass_ids()
    lights = []
    if source == "EXR":
        names = {layer: name for name, layer in scene_lights(scene)}
        for layer, passes in exr_layers(exr_path).items():
            name = names.get(layer, layer)
            lights.append((name, layer, _fallback_method(light_method(name, method, scene), passes)))
        return lights
    for name, layer in scene_lights(scene):
        have = [p for p in known if bpy.data.images.get(pass_image_name(layer, p))]
        if have:
            lights.append((name, layer, _fallback_method(light_method(name, method, scene), have)))
    return lights


class PENUMBRA_OT_setup_compositor(bpy.types.Operator):
    """Add the "Penumbra" node group to the compositor: per light, the method's
    shadow pass, the embree and cycles references and a false-colour error
    image, side by side. Rebuilding replaces only Penumbra's own nodes"""

    bl_idname = "penumbra.setup_compositor"
    bl_label = "Set up compositor"
    bl_options = {"REGISTER", "UNDO"}

    source: bpy.props.EnumProperty(
        name="Source", default="IMAGES",
        items=[("IMAGES", "Stored Images", "The pass images of Compute Passes / Render Cycles "
                                           "reference (\"Penumbra <layer> <pass>\")"),
               ("EXR", "EXR File", "A multilayer EXR written by penumbra render (one layer per light)")],
        description="Where the passes come from")
    filepath: bpy.props.StringProperty(
        name="EXR", subtype="FILE_PATH", default="",
        description="Multilayer EXR for the EXR source (empty: this frame's file in the scene's "
                    "Penumbra output folder)")
    method: bpy.props.StringProperty(
        name="Method", default="",
        description="Pass id shown as the method for every light (empty: each light's own method)")
    error_scale: bpy.props.FloatProperty(
        name="Error Scale", default=compositor.ERROR_SCALE, min=1e-4, max=1.0,
        description="Absolute error shown at full colour in the error image: smaller shows "
                    "smaller errors, larger ones saturate")

    def execute(self, context):
        scene = context.scene
        exr_path = None
        if self.source == "EXR":
            exr_path = bpy.path.abspath(self.filepath) if self.filepath else default_exr_path(scene)
            if not exr_path:
                self.report({"ERROR"}, "Penumbra: choose an EXR file (or set the scene's output folder)")
                return {"CANCELLED"}
            if not os.path.isfile(exr_path):
                self.report({"ERROR"}, f"Penumbra: no such EXR: {exr_path}")
                return {"CANCELLED"}
        if self.method:
            from ..core import methods as registry
            if self.method not in registry.pass_ids():
                self.report({"ERROR"}, f"Penumbra: unknown method {self.method!r}")
                return {"CANCELLED"}
        try:
            lights = plan_lights(scene, self.source, exr_path, self.method)
        except Exception as exc:          # unreadable EXR
            self.report({"ERROR"}, f"Penumbra: cannot read {exr_path}: {exc}")
            return {"CANCELLED"}
        if not lights:
            self.report({"ERROR"}, "Penumbra: no passes to show: run Compute Passes (or Render "
                                   "Cycles reference) first, or choose an EXR written by penumbra render"
                         if self.source == "IMAGES" else f"Penumbra: {exr_path} has no Penumbra layers")
            return {"CANCELLED"}
        vl = context.view_layer.name if context.view_layer is not None else None
        try:
            res = compositor.setup_compositor(scene, lights, exr_path, vl, self.error_scale)
        except (RuntimeError, ValueError) as exc:
            self.report({"ERROR"}, f"Penumbra: {exc}")
            return {"CANCELLED"}
        if res.unwired:
            self.report({"INFO"}, "Penumbra: connect each light's render with its shadow off (its light group's "
                                  "Combined pass) to " + ", ".join(res.unwired) + "; the group's "
                                  "'<layer>: shadowed' output is then that render with the shadow")
        if res.missing:
            self.report({"WARNING"}, "Penumbra: no source for " + ", ".join(res.missing)
                        + " (compute it first; its outputs stay empty)")
        self.report({"INFO"}, f"Penumbra: compositor set up for {len(lights)} light(s): "
                              + ", ".join(f"{n} ({m})" for n, _l, m in lights))
        return {"FINISHED"}


classes = (PENUMBRA_OT_setup_compositor,)
