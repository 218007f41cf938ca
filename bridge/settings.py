"""Reading Penumbra's settings (``light.penumbra``, ``scene.penumbra``, the
add-on preferences) into what the core takes: pass ids, ``Params``
overrides, seeds, thread counts.

The PropertyGroups themselves are made by ``addon/properties.py`` from each
method's ``Params`` dataclass; everything here works whether or not they are
registered (unregistered: the defaults, as the command line uses them). A
knob left at its default passes the dataclass's exact default (Blender
stores floats as float32), so unchanged settings give the same bits as the
command line.
"""
from __future__ import annotations

import dataclasses
from typing import Dict, List

import bpy

ROOT_PACKAGE = __package__.rsplit(".", 1)[0]      # "penumbra" or "bl_ext.<repo>.penumbra"
# fields set by the shared light / scene settings, not per method
COMMON_FIELDS = ("samples", "map_size", "seed")
AUTO = "auto"
AUTO_SUFFIX = "_auto"
REFERENCES = ("embree", "embree_irr", "cycles")


def light_settings(light_data):
    """``light.penumbra`` or None (add-on not registered, not a light)."""
    return getattr(light_data, "penumbra", None)


def scene_settings(scene):
    """``scene.penumbra`` or None (add-on not registered)."""
    return getattr(scene, "penumbra", None)


def references(scene) -> List[str]:
    """The reference passes the scene asks for beside each light's method."""
    s = scene_settings(scene)
    if s is None:
        return ["embree", "embree_irr"]
    return [r for r in REFERENCES if r in s.references]


def seed(scene) -> int:
    ss = scene_settings(scene)
    return int(ss.seed) if ss is not None else 0


def cycles_samples(scene) -> int:
    ss = scene_settings(scene)
    return int(ss.cycles_samples) if ss is not None else 64


def error_budget(scene) -> float:
    """The RMSE ``auto`` must meet (``scene.penumbra.error_budget``)."""
    from ..core.auto_choice import DEFAULT_BUDGET
    ss = scene_settings(scene) if scene is not None else None
    return float(getattr(ss, "error_budget", DEFAULT_BUDGET)) if ss is not None else DEFAULT_BUDGET


def visibility(scene) -> str:
    """Which V every method's pass is (``scene.penumbra.visibility``):
    ``irradiance`` (the default) or ``average``."""
    ss = scene_settings(scene) if scene is not None else None
    return str(getattr(ss, "visibility", "IRRADIANCE")).lower() if ss is not None else "irradiance"


def output_folder(scene) -> str:
    """The scene's Penumbra output folder ('' when unset)."""
    ss = scene_settings(scene)
    return ss.output_folder.strip() if ss is not None else ""


# --------------------------------------------------------------------------
# quality knobs
def knob_fields(method) -> List[dataclasses.Field]:
    """The dataclass fields of ``method.Params`` shown as knobs (the shared
    ones in ``COMMON_FIELDS`` are set elsewhere)."""
    return [f for f in dataclasses.fields(method.Params) if f.name not in COMMON_FIELDS]


def field_default(f: dataclasses.Field):
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:  # type: ignore[misc]
        return f.default_factory()  # type: ignore[misc]
    return None


def knob_names(group_class, method) -> List[str]:
    """Names of the knob properties of ``method`` that exist on its
    PropertyGroup class (fields of a type the UI cannot show have none)."""
    if group_class is None:
        return []
    ann = group_class.__annotations__
    return [f.name for f in knob_fields(method) if f.name in ann]


def knob_overrides(knobs_group, method) -> Dict[str, object]:
    """Params values for ``method`` from a light's knob group, only those
    that differ from the dataclass default (see the module doc)."""
    import numpy as np
    out: Dict[str, object] = {}
    if knobs_group is None:
        return out
    defaults = {f.name: field_default(f) for f in knob_fields(method)}
    ann = type(knobs_group).__annotations__
    for name in knob_names(type(knobs_group), method):
        default = defaults[name]
        auto_name = name + AUTO_SUFFIX
        if auto_name in ann and getattr(knobs_group, auto_name):
            continue                        # automatic: the dataclass default applies
        value = getattr(knobs_group, name)
        if isinstance(default, bool) or isinstance(value, bool):
            if bool(value) != default:
                out[name] = bool(value)
        elif isinstance(value, int):
            if default is None or int(value) != default:
                out[name] = int(value)
        elif isinstance(value, float):
            if default is None or np.float32(value) != np.float32(default):
                out[name] = float(value)
        elif isinstance(value, str):
            if value != default:
                out[name] = value
    return out


# --------------------------------------------------------------------------
# preferences
def addon_preferences():
    """The add-on's preferences, or None when it is registered as a plain
    package (``import penumbra; penumbra.register()``) or not at all."""
    addons = getattr(bpy.context, "preferences", None)
    entry = addons.addons.get(ROOT_PACKAGE) if addons is not None else None
    if entry is not None and entry.preferences is not None:
        return entry.preferences
    return None


def preferred_threads() -> int:
    """The preferences' thread count (0: all cores)."""
    prefs = addon_preferences()
    return int(getattr(prefs, "threads", 0) or 0)


def pixel_filter_spec(scene) -> str:
    """The scene's ``--pixel-filter`` spec (``scene.penumbra.pixel_filter``;
    ``scene``, the default, when the add-on is not registered)."""
    ss = scene_settings(scene) if scene is not None else None
    kind = str(getattr(ss, "pixel_filter", "SCENE")) if ss is not None else "SCENE"
    if kind in ("NONE", "SCENE"):
        return kind.lower()
    width = round(float(getattr(ss, "pixel_filter_width", 1.5)), 6)   # Blender stores float32
    return f"{kind.lower().replace('_', '-')}:{width:g}"


def render_pixel_filter(scene):
    """The pixel filter the scene renders with (``core.pixel_filter.from_render_settings``):
    Cycles' ``pixel_filter_type`` / ``filter_width``, EEVEE's ``render.filter_size``."""
    from ..core.pixel_filter import from_render_settings
    c = getattr(scene, "cycles", None)
    return from_render_settings(scene.render.engine, getattr(c, "pixel_filter_type", None),
                                float(getattr(c, "filter_width", 1.5)),
                                float(getattr(scene.render, "filter_size", 1.5)),
                                int(getattr(getattr(scene, "eevee", None), "taa_render_samples", 0)))


def pixel_filter(scene, spec=None):
    """``spec`` (None: the scene's setting) as a core PixelFilter; ``scene``
    resolves to the render's own filter. Raises ValueError for a bad spec."""
    from ..core.pixel_filter import parse
    spec = pixel_filter_spec(scene) if spec is None else spec
    wants_scene = spec.strip().lower().partition(":")[0] == "scene"
    return parse(spec, render_pixel_filter(scene) if wants_scene else None)
