"""What the scene calls for (DESIGN.md ``planner.py``): which lights need
work, which methods run for each, and which buffers those methods need.
Every decision carries its reason in words.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Dict, List, Optional, Sequence

import numpy as np

from . import auto_choice
from . import methods as method_registry
from .alpha import CLIP, CLOSEST, EXTEND, LINEAR, REPEAT
from .scene import Light, Scene

#: the request "pick per light" (``core/auto_choice.py``): never a pass name;
#: a light's pass is written under the method id ``auto`` resolved to
AUTO = "auto"


def layer_name(light_name: str) -> str:
    """The light's EXR layer name: dots (EXR's layer separator) -> underscores."""
    return light_name.replace(".", "_") or "_"


def unique_layers(light_names: Sequence[str]) -> List[str]:
    """The EXR layers of lights in this order: ``layer_name``, a second light
    of the same layer name gets ``_2``, and so on."""
    used: Dict[str, int] = {}
    out = []
    for name in light_names:
        layer = layer_name(name)
        if layer in used:
            used[layer] += 1
            layer = f"{layer}_{used[layer]}"
        used.setdefault(layer, 1)
        out.append(layer)
    return out


@dataclass
class LightPlan:
    name: str
    layer: str
    action: str                    # "compute" | "hard" | "skip"
    reason: str
    producers: List[str] = field(default_factory=list)
    buffers: List[str] = field(default_factory=list)
    decisions: List[str] = field(default_factory=list)   # further choices, with reasons
    passes: List[str] = field(default_factory=list)      # this light's pass ids (``auto`` resolved)
    auto: Optional[dict] = None                          # AutoChoice.to_json() when ``auto`` was asked
    #: on a scene kept as instances, when a producer needs world-space
    #: triangles: what the frame expands (``FrameBuffers.expansion_counts``)
    expanded: Optional[dict] = None


@dataclass
class Plan:
    passes: List[str]
    lights: List[LightPlan]
    notes: List[str] = field(default_factory=list)

    def to_json(self) -> dict:
        lights = [{k: v for k, v in asdict(lp).items() if k != "expanded" or v is not None}
                  for lp in self.lights]
        return {"passes": list(self.passes), "lights": lights, "notes": list(self.notes)}

    def describe(self) -> str:
        lines = [f"passes: {', '.join(self.passes)}"]
        for lp in self.lights:
            lines.append(f"light {lp.name!r} -> layer {lp.layer!r}: {lp.action} ({lp.reason})")
            if lp.producers:
                lines.append(f"    methods: {', '.join(lp.producers)}; buffers: {', '.join(lp.buffers) or 'none'}")
            lines.extend(f"    {d}" for d in lp.decisions)
        lines.extend(f"note: {n}" for n in self.notes)
        return "\n".join(lines)


class PlanError(ValueError):
    """Bad request (unknown method or light): the CLI turns it into exit 2."""


def resolve_passes(spec: str | Sequence[str] | None, external: Sequence[str] = (),
                   allow_auto: bool = False) -> List[str]:
    """Method ids from ``spec`` ("all" or a comma list). ``external`` names the
    external passes the caller can produce (``cycles`` needs Blender): "all"
    includes those, and asking for one the caller cannot produce is an error.
    ``allow_auto``: ``auto`` may be asked for (kept as is; ``make_plan``
    resolves it per light)."""
    known = method_registry.pass_ids(external=False) + [e for e in method_registry.EXTERNAL_PASSES
                                                        if e in external]
    if spec is None or spec == "all" or spec == ["all"]:
        return known
    items = [s.strip() for s in (spec.split(",") if isinstance(spec, str) else spec) if s.strip()]
    if not items:
        raise PlanError("no methods given")
    bad = [s for s in items if s not in known and s != AUTO and s != "all"
           and not method_registry.is_external(s)]
    if bad:
        raise PlanError(f"unknown method {bad[0]!r} (known: {', '.join(known)})")
    for s in items:
        if method_registry.is_external(s) and s not in external:
            raise PlanError(f"method {s!r} needs Blender (the bpy module) and cannot run here")
    if AUTO in items and not allow_auto:
        raise PlanError("method 'auto' is not available here: give method ids "
                        "(`penumbra plan --methods auto` shows what auto picks per light)")
    if "all" in items:
        return known
    return list(dict.fromkeys(items))


def producers_for(passes: Sequence[str]) -> List[str]:
    """Producer ids (external passes as themselves) of ``passes``, in order."""
    out: List[str] = []
    for pid in passes:
        p = pid if method_registry.is_external(pid) else method_registry.producer_of(pid).id
        if p not in out:
            out.append(p)
    return out


def buffers_for(producers: Sequence[str]) -> List[str]:
    registry = method_registry.producers()
    return sorted({b for pid in producers if pid in registry for b in registry[pid].needs})


def record_auto(lp: LightPlan, choice: "auto_choice.AutoChoice") -> None:
    """Put ``auto``'s decision for this light in the plan (its reason first
    among the decisions)."""
    lp.auto = choice.to_json()
    if choice.reason not in lp.decisions:
        lp.decisions.insert(0, choice.reason)


_INTERPOLATION_NAMES = {CLOSEST: "Closest", LINEAR: "Linear"}
_EXTENSION_NAMES = {REPEAT: "Repeat", EXTEND: "Extend", CLIP: "Clip"}


def alpha_notes(scene: Scene) -> List[str]:
    """The plan's words on alpha mattes: the mattes captured
    (``scene.alpha``) and the materials treated as opaque because the capture
    could not read their transparency (``scene.alpha_opaque``, filled by
    ``bridge/capture.py``). Empty for a scene without either."""
    notes = []
    m = scene.alpha
    if m is not None and m.count:
        notes.append("alpha mattes: " + ", ".join(
            f"{m.names[i]} ({int(m.width[i])}x{int(m.height[i])}, "
            f"{_INTERPOLATION_NAMES.get(int(m.interpolation[i]), '?')}, "
            f"{_EXTENSION_NAMES.get(int(m.extension[i]), '?')})" for i in range(m.count)))
    opaque = list(scene.alpha_opaque)
    if opaque:
        notes.append("treated as opaque (transparency not read): " + "; ".join(opaque))
    return notes


def auto_choice_for(scene: Scene, light: Light, error_budget: Optional[float] = None,
                    visibility: str = auto_choice.IRRADIANCE, auto_table=auto_choice.PACKAGED,
                    expanded: Optional[int] = None):
    """``auto``'s decision (``core.auto_choice.AutoChoice``) for ``light`` of
    the captured ``scene``, whose shape (shadow-casting triangles, instances,
    pixels, light size) scales the measured times (``auto_choice`` rule 5):
    the one resolver of the command line, ``plan``, Compute Passes, the
    Preview and the render handler. ``error_budget``: RMSE (default
    ``auto_choice.DEFAULT_BUDGET``); a bad one is a PlanError. ``expanded``:
    on a scene kept as instances, the shadow-casting triangles a method that
    needs world-space triangles would expand (None: all of them)."""
    budget = auto_choice.DEFAULT_BUDGET if error_budget is None else float(error_budget)
    try:
        return auto_choice.choose_for_light(light, visibility, budget, auto_table, scene=scene,
                                            expanded=expanded)
    except ValueError as exc:                # bad budget / definition
        raise PlanError(str(exc))


def make_plan(scene: Scene, passes: Sequence[str], light_names: Optional[Sequence[str]] = None,
              error_budget: Optional[float] = None, visibility: str = auto_choice.IRRADIANCE,
              auto_table=auto_choice.PACKAGED, expanded: Optional[int] = None) -> Plan:
    """Per light: skip, hard or compute, with the reason; the light's passes
    and the producers and buffers they need. ``auto`` among ``passes`` is
    resolved per light (``core/auto_choice.py``) under ``error_budget``
    (RMSE; default ``auto_choice.DEFAULT_BUDGET``) for the ``visibility``
    definition, from ``auto_table`` (the packaged table by default; a path,
    an AutoTable, or None for none); ``expanded``: ``auto_choice_for``'s."""
    notes = []
    lights = list(scene.lights)
    if light_names:
        names = {lt.name for lt in lights}
        for n in light_names:
            if n not in names:
                raise PlanError(f"unknown light {n!r} (scene has: {', '.join(sorted(names)) or 'none'})")
        lights = [lt for lt in lights if lt.name in set(light_names)]
    out = []
    for lt, layer in zip(lights, unique_layers([lt.name for lt in lights])):
        choice = None
        mine = list(passes)
        if AUTO in passes:
            choice = auto_choice_for(scene, lt, error_budget, visibility, auto_table, expanded)
            mine = list(dict.fromkeys(choice.method if p == AUTO else p for p in passes))
        producers = producers_for(mine)
        buffers = buffers_for(producers)
        if not lt.casts_shadow:
            lp = LightPlan(lt.name, layer, "skip", "the light's shadow is off (use_shadow): V = 1")
        elif lt.energy <= 0:
            lp = LightPlan(lt.name, layer, "skip", "the light has no energy: V = 1")
        elif not scene.casts_any_shadow():
            lp = LightPlan(lt.name, layer, "skip", "no object casts shadows: V = 1")
        elif lt.is_zero_size:
            lp = LightPlan(lt.name, layer, "hard", "the light has size zero: hard shadows only, one sample",
                           producers, buffers)
        else:
            lp = LightPlan(lt.name, layer, "compute", f"{lt.kind} light of size {lt.extent:g}",
                           producers, buffers)
        lp.passes = mine
        if choice is not None:
            record_auto(lp, choice)
        out.append(lp)
    if not out:
        notes.append("the scene has no lights: nothing to compute")
    elif all(lp.action == "skip" for lp in out):
        notes.append("no light casts shadows: every pass is V = 1")
    notes.extend(alpha_notes(scene))
    return Plan(list(passes), out, notes)


def refine_with_receivers(plan: Plan, scene: Scene, reach: Dict[str, np.ndarray]) -> None:
    """Second stage, once the camera G-buffer exists: a light that reaches no
    visible receiver (every visible point outside its spot cone, behind it,
    or facing away) is skipped. ``reach[name]`` is ``metrics.reach_mask``."""
    for lp in plan.lights:
        if lp.action in ("compute", "hard") and lp.name in reach and not reach[lp.name].any():
            lp.action = "skip"
            lp.reason = ("the light reaches no visible receiver (outside its cone, behind it "
                         "or facing away): V = 1")
            lp.producers, lp.buffers = [], []
    if plan.lights and all(lp.action == "skip" for lp in plan.lights) and not any(
            "every pass is V = 1" in n for n in plan.notes):
        plan.notes.append("no light casts a shadow on what the camera sees: every pass is V = 1")


def plan_frame(scene: Scene, passes: Sequence[str], light_names: Optional[Sequence[str]] = None,
               error_budget: Optional[float] = None, buffers=None,
               visibility: str = auto_choice.IRRADIANCE):
    """The plan ``render`` follows: :func:`make_plan` (``auto`` judged for
    the frame's ``visibility``), then
    :func:`refine_with_receivers` with the reach masks (``metrics.reach_mask``)
    of the camera G-buffer of ``buffers`` (a ``core.buffers.FrameBuffers``,
    built only when some light is not skipped already; ``FrameBuffers.reach``).
    Returns (plan, reach)."""
    counts = None
    if buffers is not None and buffers.instanced and scene.casts_any_shadow() and any(
            lt.casts_shadow and lt.energy > 0 for lt in scene.lights):
        counts = buffers.expansion_counts()
    plan = make_plan(scene, passes, light_names, error_budget=error_budget, visibility=visibility,
                     expanded=None if counts is None else counts["shadow_triangles"])
    reach: Dict[str, np.ndarray] = {}
    if buffers is not None and any(lp.action != "skip" for lp in plan.lights):
        reach = {lp.name: buffers.reach(scene.light(lp.name)) for lp in plan.lights if lp.action != "skip"}
        refine_with_receivers(plan, scene, reach)
    if counts is not None:
        record_expansion(plan, counts)
    return plan, reach


def expands_instances(producer: str) -> bool:
    """Whether ``producer`` needs world-space triangles: on a scene kept as
    instances it reads the frame's expanded instances (not
    ``Method.runs_on_instances``; external producers never do)."""
    registry = method_registry.producers()
    return producer in registry and not registry[producer].runs_on_instances


def record_expansion(plan: Plan, counts: dict) -> None:
    """Put what the frame expands (``FrameBuffers.expansion_counts``) in the
    plan of each light that is computed by a producer needing world-space
    triangles."""
    for lp in plan.lights:
        users = [p for p in lp.producers if expands_instances(p)]
        if lp.action == "skip" or not users:
            continue
        lp.expanded = dict(counts)
        lp.decisions.append(
            f"{', '.join(users)} expand{'s' if len(users) == 1 else ''} {counts['instances']:,} of "
            f"{counts['of_instances']:,} instances into world-space triangles ({counts['triangles']:,} of "
            f"{counts['of_triangles']:,}): those whose box meets the region between the visible receivers "
            f"and a light that can shadow them")
