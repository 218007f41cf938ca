"""Panels where a Blender user looks: the light's Object Data properties
(its own settings and quality knobs) and the Render properties (scene-wide
settings and the operator buttons). Knobs are drawn from the generated
PropertyGroups, so a new method needs no UI code here."""
from __future__ import annotations

import importlib

import bpy

from ..bridge import settings
from ..bridge.jobs import asks_for_auto, last_auto
from . import properties as props

# operator modules whose buttons appear in the render panel, in this order
BUTTON_MODULES = ("preview", "compute", "cycles_reference", "compositor_ops", "clear")


def _operator_classes():
    pkg = __package__.rsplit(".", 1)[0] + ".operators"
    out = []
    for name in BUTTON_MODULES:
        try:
            mod = importlib.import_module(f"{pkg}.{name}")
        except ImportError:
            continue
        for cls in getattr(mod, "classes", ()):
            if getattr(cls, "is_registered", False) and getattr(cls, "bl_idname", ""):
                out.append(cls)
    return out


def draw_knobs(layout, settings, method_id: str):
    """The knobs of ``method_id``'s producer (Optional ones with their Auto)."""
    from ..core import methods as registry
    m = registry.producer_of(method_id)
    group = getattr(settings.knobs, m.id, None)
    if group is None:
        layout.label(text=f"{m.id}: no settings")
        return
    names = props.knob_names(m)
    if not names:
        layout.label(text=f"{m.id}: nothing to tune beyond samples and map size")
        return
    ann = props._knob_classes[m.id].__annotations__
    for name in names:
        auto = name + props.AUTO_SUFFIX
        if auto in ann:
            row = layout.row(align=True, heading=props.friendly_label(name))
            row.prop(group, auto, text="Auto", toggle=True)
            sub = row.row(align=True)
            sub.enabled = not getattr(group, auto)
            sub.prop(group, name, text="")
        else:
            layout.prop(group, name)


def _auto_choice(context):
    """``auto``'s last decision for the light being shown (its object:
    ``context.object`` when it holds this light, else the first that does)."""
    ob = getattr(context, "object", None)
    if ob is None or ob.data != context.light:
        ob = next((o for o in context.scene.objects if o.data == context.light), None)
    return last_auto(context.scene.name, ob.name) if ob is not None else None


class PENUMBRA_PT_light(bpy.types.Panel):
    bl_label = "Penumbra"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "data"
    bl_options = {"DEFAULT_CLOSED"}

    @classmethod
    def poll(cls, context):
        light = getattr(context, "light", None)
        return light is not None and settings.light_settings(light) is not None

    def draw_header(self, context):
        self.layout.prop(context.light.penumbra, "enabled", text="")

    def draw(self, context):
        s = context.light.penumbra
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        layout.active = s.enabled
        layout.prop(s, "method")
        layout.prop(s, "light_samples")
        layout.prop(s, "map_size")
        if s.method == settings.AUTO:
            choice = _auto_choice(context)
            layout.label(text=f"Auto: {choice.short}" if choice is not None
                         else "Auto: picked for the scene when computed", icon="INFO")
        op = layout.operator("penumbra.preview", text="Preview This Light", icon="IMAGE_RGB")
        op.only_active = True


class PENUMBRA_PT_light_quality(bpy.types.Panel):
    bl_label = "Quality"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "data"
    bl_parent_id = "PENUMBRA_PT_light"

    @classmethod
    def poll(cls, context):
        return PENUMBRA_PT_light.poll(context)

    def draw(self, context):
        s = context.light.penumbra
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        layout.active = s.enabled
        if not asks_for_auto(s):
            draw_knobs(layout, s, s.method)
            return
        choice = _auto_choice(context)
        if choice is None:
            layout.label(text="Auto: the picked method's defaults (compute once to see which)")
        else:
            draw_knobs(layout, s, choice.method)


class PENUMBRA_PT_render(bpy.types.Panel):
    bl_label = "Penumbra"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "render"
    bl_options = {"DEFAULT_CLOSED"}

    @classmethod
    def poll(cls, context):
        return context.scene is not None and settings.scene_settings(context.scene) is not None

    def draw(self, context):
        s = context.scene.penumbra
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        layout.prop(s, "render_passes")
        layout.prop(s, "output_folder")
        layout.prop(s, "seed")
        layout.prop(s, "error_budget")
        layout.prop(s, "visibility")
        layout.prop(s, "pixel_filter")
        sub = layout.row()
        sub.active = s.pixel_filter not in ("NONE", "SCENE")
        sub.prop(s, "pixel_filter_width")
        row = layout.row(heading="References")
        row.prop(s, "references")
        sub = layout.row()
        sub.active = "cycles" in s.references
        sub.prop(s, "cycles_samples")
        layout.prop(s, "preview_size")
        col = layout.column(align=True)
        for cls in _operator_classes():
            col.operator(cls.bl_idname)


classes = (PENUMBRA_PT_light, PENUMBRA_PT_light_quality, PENUMBRA_PT_render)


def register():
    for cls in classes:
        bpy.utils.register_class(cls)


def unregister():
    for cls in reversed(classes):
        if getattr(cls, "is_registered", False):
            bpy.utils.unregister_class(cls)
