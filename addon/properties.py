"""Penumbra's settings: ``light.penumbra`` (per light data) and
``scene.penumbra`` (per scene).

The quality knobs are generated from each registered method's ``Params``
dataclass (``core.methods``), so a method that lands later gets its settings
and its panel with no new UI code: one PropertyGroup per method
(``light.penumbra.knobs.<method id>``), one property per dataclass field
(bool, int, float, str, ``Optional[int]`` / ``Optional[float]``; an Optional
field gets a companion ``<name>_auto`` toggle meaning "None: the method
picks"). Labels are the paper's names made readable; tooltips come from
``TOOLTIPS`` (what each knob trades) with a generic fallback. A dataclass
field's ``metadata`` may give ``label``, ``description``, ``min``, ``max``
and ``choices`` (a str field with choices becomes a drop-down).

Fields every method shares are set once per light or scene, not per method:
``samples`` (light samples), ``map_size`` (depth-map resolution), ``seed``
(scene). Reading them back into core requests is ``bridge/settings.py``'s.
"""
from __future__ import annotations

import re
import typing
import zlib
from typing import Dict, List, Optional, Tuple

import bpy

from ..bridge.settings import AUTO, AUTO_SUFFIX, field_default, knob_fields
from ..bridge.settings import knob_names as _knob_names_of

# what each knob trades: field name, or "<method id>.<field>" for one method;
# (tooltip, min, max) with None for no bound
TOOLTIPS: Dict[str, Tuple[str, Optional[float], Optional[float]]] = {
    "NumSamples": ("Depth-map samples per pixel (Reeves et al.): more gives smoother, less noisy "
                   "penumbrae at proportional cost", 1, 4096),
    "ResFactor": ("Enlarges each pixel's filter region (Reeves et al., 2 to 4): softer edges and "
                  "less aliasing, but shadows blur beyond the real penumbra", 0.0, None),
    "MinSamples": ("Fewest samples per axis of a filter region: fewer is faster but noisier "
                   "where regions are small", 1, 64),
    "MinSize": ("Smallest filter region, in texels: larger hides aliasing, smaller keeps "
                "contact shadows crisp", 0.0, None),
    "MaxSize": ("Largest filter region (half size, texels): bounds the cost at grazing views, "
                "at the price of too-sharp shadows there", 0.5, None),
    "Bias0": ("Lower depth bias (scene units): larger removes shadow acne but detaches shadows "
              "from their contact points (peter-panning)", 0.0, None),
    "Bias1": ("Upper depth bias (scene units): the random bias range hides acne as noise instead "
              "of bands; larger detaches shadows from contacts", 0.0, None),
    "receiver_plane": ("Compare with the receiver's tangent plane at each texel: no acne on flat "
                       "receivers without a large bias (off: the paper's constant depth)", None, None),
    "r_scale": ("Penumbra search radius per unit of receiver depth (Brabec & Seidel): wider "
                "penumbrae, and more texels searched", 0.0, None),
    "r_bias": ("Smallest penumbra search radius, texels: softens every edge a little, "
               "at some cost", 0.0, None),
    "r_shrink": ("Shrinks the radius with blocker-receiver distance: sharper contact shadows, "
                 "but penumbrae can end too early", 0.0, None),
    "max_radius": ("Cap on the search box half size, texels: bounds the cost, but clips "
                   "very wide penumbrae", 1.0, None),
    "meet": ("Visibility where the inner and outer penumbra meet (paper: 0.5): moves the "
             "shadow edge towards the umbra or the lit side", 0.0, 1.0),
    "auto_radius": ("Derive the search radius from the light's real size: physically sized "
                    "penumbrae (off: r_scale and r_bias alone)", None, None),
    "adaptive": ("Interpolate over small blocks where neighbours agree (paper 4.3): much faster, "
                 "may miss very thin shadows", None, None),
    "block": ("Block size for adaptive interpolation: larger is faster, coarser", 1, 64),
    "jitter": ("Jitter of blocker texels (texels): trades banding for noise (0: off)", 0.0, None),
    "edge_distance": ("Measure distance to a texel's square rather than its centre: smoother "
                      "penumbrae at the same cost", None, None),
    "layer": ("Receiver depth used for the penumbra search: constant (the paper) or plane (the "
              "receiver's tangent plane: a tilted receiver does not shadow itself without the ID test)",
              None, None),
    "id_test": ("Blockers must belong to another object (paper 3.2): no self-shadowing, but an "
                "object cannot shadow itself", None, None),
    "bias_texels": ("Hard-shadow test tolerance, in texels of receiver slope: larger removes "
                    "acne but shrinks shadows", 0.0, None),
    "blocker": ("What sets the penumbra: sum (every blocker texel's share of the light) or nearest "
                "(the paper's one nearest blocker: faster, wrong where shadows overlap)", None, None),
    "epsilon": ("Depth tolerance when merging light-sample layers (scene units): larger merges "
                "nearby surfaces (fewer layers, light leaks), smaller keeps duplicates", 0.0, None),
    "bilinear": ("Filter the four neighbouring attenuations (paper figure 11): smoother edges, "
                 "slightly blurred contacts", None, None),
    "plane_depth": ("Compare depths at layer pixel centres on the receiver's plane: fewer "
                    "artefacts on flat receivers", None, None),
    "warp": ("How light-sample views are warped into the central view: auto (a shift for "
             "planar lights, else projective) or projective (general, slower)", None, None),
}

# str knobs that take one of a few values: "<method id>.<field>" or field name
CHOICES: Dict[str, Tuple[str, ...]] = {
    "surfaces": ("mesh", "object"),
    "pcf.region": ("light", "figure4"),
    "pcf.step_fill": ("interpolate", "copy"),
    "single_sample.layer": ("constant", "plane"),
    "single_sample.blocker": ("sum", "nearest"),
    "layered.warp": ("auto", "projective"),
    "layered.splat": ("footprint", "neighbours"),
    "depth_raytrace.tracer": ("depth", "embree"),
    "irregular.silhouette_from": ("centre", "light"),
    "irregular.overlap": ("sampled", "zero"),
}

# acronyms and paper names kept as written in labels
_LABEL_WORDS = {"id": "ID", "irr": "Irr", "ldi": "LDI", "r": "r"}

# names a PropertyGroup already has
_RESERVED = frozenset({"name", "rna_type", "bl_rna", "id_data", "method_id"})

# classes made by register(); one knob group per producer id
_generated: List[type] = []
_knob_classes: Dict[str, type] = {}


# --------------------------------------------------------------------------
# names and tooltips
def friendly_label(name: str) -> str:
    """``NumSamples`` -> ``Num Samples``, ``Bias0`` -> ``Bias 0``,
    ``r_scale`` -> ``r Scale``: the paper's name, readable."""
    words = []
    for part in name.split("_"):
        words.extend(re.findall(r"[A-Z]+(?![a-z])|[A-Z]?[a-z]+|\d+", part) or [part])
    out = []
    for i, w in enumerate(words):
        low = w.lower()
        if low in _LABEL_WORDS:
            out.append(_LABEL_WORDS[low])
        elif w.isupper() and len(w) > 1:
            out.append(w)
        else:
            out.append(w[:1].upper() + w[1:])
    return " ".join(out) or name


def knob_tooltip(method_id: str, name: str, default) -> Tuple[str, Optional[float], Optional[float]]:
    entry = TOOLTIPS.get(f"{method_id}.{name}") or TOOLTIPS.get(name)
    shown = "automatic" if default is None else repr(default)
    if entry is None:
        return (f"{name} ({method_id}): the paper's parameter; default {shown}. "
                "Raising quality settings usually costs time", None, None)
    text, lo, hi = entry
    return (f"{name}: {text}. Default {shown}", lo, hi)


def _base_type(tp):
    """(python type, optional?) of a dataclass field annotation."""
    origin = typing.get_origin(tp)
    if origin is typing.Union:
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if len(args) == 1:
            return args[0], True
        return None, True
    return tp, False


def _enum_number(ident: str, used: set) -> int:
    """A stable enum value per id (Blender saves an enum's number), so adding
    a method never changes what a saved file's lights use."""
    n = zlib.crc32(ident.encode()) & 0x3FFFFFFF
    while n in used:
        n = (n + 1) & 0x3FFFFFFF
    used.add(n)
    return n


# --------------------------------------------------------------------------
# knob groups generated from the Params dataclasses
def _knob_properties(method) -> Dict[str, object]:
    hints = typing.get_type_hints(method.Params)
    props: Dict[str, object] = {}
    for f in knob_fields(method):
        if f.name in _RESERVED or f.name.startswith("_") or len(f.name) + len(AUTO_SUFFIX) > 63:
            continue            # not a valid Blender property name: the default applies
        tp, optional = _base_type(hints.get(f.name, type(None)))
        default = field_default(f)
        meta = dict(f.metadata or {})
        label = meta.get("label") or friendly_label(f.name)
        tip, lo, hi = knob_tooltip(method.id, f.name, default)
        tip = meta.get("description", tip)
        lo = meta.get("min", lo)
        hi = meta.get("max", hi)
        bounds = {}
        if lo is not None:
            bounds["min"] = lo
        if hi is not None:
            bounds["max"] = hi
        if tp is bool:
            props[f.name] = bpy.props.BoolProperty(name=label, description=tip, default=bool(default))
        elif tp is int:
            bounds = {k: int(v) for k, v in bounds.items()}
            d = int(default) if default is not None else max(int(bounds.get("min", 0)), 0)
            props[f.name] = bpy.props.IntProperty(name=label, description=tip, default=d, **bounds)
        elif tp is float:
            bounds = {k: float(v) for k, v in bounds.items()}
            d = float(default) if default is not None else float(bounds.get("min", 0.0))
            props[f.name] = bpy.props.FloatProperty(name=label, description=tip, default=d,
                                                    precision=4, **bounds)
        elif tp is str:
            choices = meta.get("choices") or CHOICES.get(f"{method.id}.{f.name}") or CHOICES.get(f.name)
            if choices and default in choices:
                items = [(c, friendly_label(c), f"{f.name} = {c!r}") for c in choices]
                props[f.name] = bpy.props.EnumProperty(name=label, description=tip, items=items,
                                                       default=str(default))
            else:
                props[f.name] = bpy.props.StringProperty(name=label, description=tip,
                                                         default="" if default is None else str(default))
        else:
            continue            # a type the UI cannot show: the method's default applies
        if optional:
            props[f.name + AUTO_SUFFIX] = bpy.props.BoolProperty(
                name="Auto", default=default is None,
                description=f"Let {method.id} choose {f.name} (from the scene's size or the output)")
    return props


def _make_knob_group(method) -> type:
    props = _knob_properties(method)
    cls = type(f"PENUMBRA_PG_knobs_{method.id}", (bpy.types.PropertyGroup,),
               {"__annotations__": props, "__doc__": f"Quality settings of {method.id}",
                "method_id": method.id})
    return cls


def knob_names(method) -> List[str]:
    """Names of the knob properties of ``method`` that exist on its group."""
    return _knob_names_of(_knob_classes.get(method.id), method)


# --------------------------------------------------------------------------
# enum items
def method_items():
    from ..core import methods as registry
    used: set = set()
    items = [(AUTO, "Auto", "Pick per light the cheapest method whose error measured by the accuracy "
              "study meets the scene's error budget (Render properties > Penumbra)", "AUTO",
              _enum_number(AUTO, used))]
    for pid in registry.pass_ids(external=False):
        m = registry.producer_of(pid)
        paper = getattr(m, "paper", "") or ""
        desc = f"{pid}: {paper}" if paper else pid
        if registry.visibility_of(pid) == "irradiance":
            desc += " (irradiance ratio)"
        items.append((pid, pid, desc, "NONE", _enum_number(pid, used)))
    return items


def _reference_items():
    return [
        ("embree", "Embree", "Ray-traced reference: average visibility (compared with most methods)", 1),
        ("embree_irr", "Embree Irradiance", "Ray-traced reference: irradiance ratio", 2),
        ("cycles", "Cycles", "Cycles render with / without each light's shadow (irradiance ratio); "
                             "not computed inside a render", 4),
    ]


def _on_render_passes(self, context):
    scene = self.id_data
    if self.render_passes:
        scene.render.use_lock_interface = True


# --------------------------------------------------------------------------
# groups
def _make_classes():
    from ..core import methods as registry
    from ..core.auto_choice import DEFAULT_BUDGET
    from ..core.methods.base import DEFAULT_LIGHT_SAMPLES
    knob_classes = {}
    for mid, m in registry.producers().items():
        knob_classes[mid] = _make_knob_group(m)
    knobs = type("PENUMBRA_PG_knobs", (bpy.types.PropertyGroup,), {
        "__annotations__": {mid: bpy.props.PointerProperty(type=cls, name=mid)
                            for mid, cls in knob_classes.items()},
        "__doc__": "Quality settings of every method, one group per method id"})

    light_ann = {
        "enabled": bpy.props.BoolProperty(
            name="Penumbra", default=True,
            description="Compute Penumbra's shadow passes for this light"),
        "method": bpy.props.EnumProperty(
            name="Method", items=method_items(), default=AUTO,
            description="Soft-shadow method for this light's pass"),
        "light_samples": bpy.props.IntProperty(
            name="Light Samples", default=DEFAULT_LIGHT_SAMPLES, min=1, max=65536,
            description="Points sampled on the light per pixel (references and sampling methods): "
                        "more means less noise at proportional cost"),
        "map_size": bpy.props.IntProperty(
            name="Depth Map Size", default=0, min=0, max=16384,
            description="Resolution (larger side) of the light's depth maps; 0 = as many texels as "
                        "the output has pixels. Larger maps give finer shadow detail at more memory and time"),
        "knobs": bpy.props.PointerProperty(type=knobs, name="Quality"),
    }
    light = type("PENUMBRA_PG_light", (bpy.types.PropertyGroup,),
                 {"__annotations__": light_ann, "__doc__": "Penumbra settings of one light"})

    scene_ann = {
        "output_folder": bpy.props.StringProperty(
            name="Output Folder", subtype="DIR_PATH", default="",
            description="Where Compute Passes and renders write each frame's EXR + JSON; empty: "
                        "renders write beside the render output, Compute Passes writes no files"),
        "seed": bpy.props.IntProperty(
            name="Seed", default=0, min=0, max=2 ** 31 - 1,
            description="Random seed of every sampled method and reference (same seed, same bits)"),
        "references": bpy.props.EnumProperty(
            name="References", items=_reference_items(), options={"ENUM_FLAG"},
            default={"embree", "embree_irr"},
            description="Reference passes computed beside each light's method"),
        "error_budget": bpy.props.FloatProperty(
            name="Error Budget", default=DEFAULT_BUDGET, min=0.001, max=1.0, precision=3, step=0.5,
            description="RMSE against the ray-traced reference that a light's Auto method must meet: "
                        "Auto picks the cheapest method the accuracy study measured within it "
                        "(smaller: more accurate, slower methods)"),
        "cycles_samples": bpy.props.IntProperty(
            name="Cycles Samples", default=64, min=1, max=1 << 16,
            description="Samples of the Cycles shadow reference: less noise at proportional cost"),
        "visibility": bpy.props.EnumProperty(
            name="Visibility", default="IRRADIANCE",
            items=[("IRRADIANCE", "Irradiance Ratio", "The light's shadowed / unshadowed irradiance: the "
                    "unshadowed render x the pass = the shadowed render", 0),
                   ("AVERAGE", "Average", "The share of the light each point sees, unweighted", 1)],
            description="Which V every method's pass is"),
        "pixel_filter": bpy.props.EnumProperty(
            name="Pixel Filter", default="SCENE",
            items=[("NONE", "Pixel Centres", "One receiver at each pixel centre (no anti-aliasing)", 0),
                   ("SCENE", "Scene", "Filtered like the scene's render: Cycles' pixel filter type and "
                    "width, or EEVEE's filter size", 1),
                   ("BOX", "Box", "Box filter of the width below", 2),
                   ("GAUSSIAN", "Gaussian", "Cycles' Gaussian filter of the width below", 3),
                   ("BLACKMAN_HARRIS", "Blackman-Harris", "Cycles' Blackman-Harris filter of the width "
                    "below", 4)],
            description="How a pass is filtered over each pixel's footprint, so it lines up with an "
                        "anti-aliased render (sub-pixel receivers only where the footprint holds an "
                        "edge)"),
        "pixel_filter_width": bpy.props.FloatProperty(
            name="Filter Width", default=1.5, min=0.01, max=64.0, precision=2, subtype="PIXEL",
            description="Width of the Box, Gaussian or Blackman-Harris pixel filter, in pixels "
                        "(as Cycles' Film > Pixel Filter width)"),
        "render_passes": bpy.props.BoolProperty(
            name="Passes in Every Render", default=False, update=_on_render_passes,
            description="Compute the passes for every rendered frame (F12, animations, background "
                        "renders) before compositing and write them beside the output. Locks "
                        "the interface while rendering"),
        "preview_size": bpy.props.IntProperty(
            name="Preview Size", default=256, min=16, max=4096,
            description="Larger side of the preview image, in pixels"),
    }
    scene = type("PENUMBRA_PG_scene", (bpy.types.PropertyGroup,),
                 {"__annotations__": scene_ann, "__doc__": "Penumbra settings of one scene"})
    return knob_classes, [*knob_classes.values(), knobs, light, scene]


def register():
    global _generated, _knob_classes
    knob_classes, classes = _make_classes()
    for cls in classes:
        bpy.utils.register_class(cls)
    _generated = classes
    _knob_classes = knob_classes
    bpy.types.Light.penumbra = bpy.props.PointerProperty(type=classes[-2], name="Penumbra")
    bpy.types.Scene.penumbra = bpy.props.PointerProperty(type=classes[-1], name="Penumbra")


def unregister():
    global _generated, _knob_classes
    for attr, owner in (("penumbra", bpy.types.Scene), ("penumbra", bpy.types.Light)):
        if hasattr(owner, attr):
            delattr(owner, attr)
    for cls in reversed(_generated):
        if getattr(cls, "is_registered", False):
            bpy.utils.unregister_class(cls)
    _generated = []
    _knob_classes = {}
