"""Settings -> work: what to compute for each captured light, and which
lights share one ``render_frame`` call.

Each light's pass list is its own method (``light.penumbra.method``; ``auto``
resolves per light in :func:`auto_choice_for`, from the accuracy study's
table under the scene's error budget, and the decision with its reason goes
into the frame's plan) plus the scene's references; its knobs, light samples
and depth-map size become ``render_frame``'s overrides. Lights with the same
settings share one step (one ``render_frame`` call and its buffers).
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field, replace
from typing import Dict, List, Optional, Sequence, Tuple

from . import settings
from .capture import light_kind_size, light_object

#: methods fast enough for the preview (others fall back to pcf there)
FAST_METHODS = ("pcf", "single_sample")
#: the preview's light views: this fraction of the default map's larger side (``views.default_map_size``)
#: (a quarter of the texels; a light's own Map Size wins). Preview quality:
#: pcf's MinSize region covers twice the surface, so its edges are softer.
PREVIEW_MAP_SCALE = 0.5
#: the preview's settings of the fast methods, under a light's own knobs (which
#: win): ``single_sample`` as the paper has it (the nearest blocker, object ids;
#: issue 17's ``blocker="sum"``, ``surfaces="mesh"`` defaults cost 20-80x at
#: 1080p; section 4.3's adaptive groups every 8th pixel instead of 4th: a
#: moved light's Preview at 1080p 0.52 -> 0.40 s, RMSE against embree within 0.002 of the
#: 4-pixel groups at 960x540 on four scenes), ``pcf`` with a quarter of the samples of its light-sized region,
#: V at one pixel in each 2 x 2 block (``pixel_step``, ``step_fill="copy"``: the block's other
#: pixels on the same surface share it, without the render's interpolation) and no pixel footprint (``ResFactor``
#: 0: the region's floor is MinSize texels; the light's extent sets it
#: anyway): issue 15, the filter's per-pixel cost was most of a moved light's
#: Preview at 1080p. The Compute keeps the accurate defaults. Said in the
#: Preview's report.
PREVIEW_PARAMS: Dict[str, Dict[str, object]] = {
    "single_sample": {"blocker": "nearest", "surfaces": "object", "block": 8},
    "pcf": {"BlockerSamples": 8, "PenumbraSamples": 16, "pixel_step": 2, "step_fill": "copy",
            "ResFactor": 0.0},
}


@dataclass
class LightJob:
    """What to compute for one captured light."""
    name: str
    passes: List[str]
    overrides: Dict[str, object]
    method_overrides: Dict[str, Dict[str, object]]
    map_size: Optional[int]
    auto: Optional[object] = None          # core.auto_choice.AutoChoice when the light asks for auto

    def key(self) -> str:
        return json.dumps([self.passes, self.overrides, self.method_overrides, self.map_size],
                          sort_keys=True, default=str)


@dataclass
class Step:
    """One ``render_frame`` call: lights ``names`` (None: every light) with
    the same passes and settings."""
    names: Optional[List[str]]
    passes: List[str]
    overrides: Dict[str, object]
    method_overrides: Dict[str, Dict[str, object]]
    map_size: Optional[int]
    auto: Dict[str, object] = field(default_factory=dict)   # light name -> AutoChoice
    error_budget: Optional[float] = None                      # for passes "auto" the planner resolves


def auto_choice_for(light_settings, light, scene):
    """``auto``'s decision (``core.auto_choice.AutoChoice``) for a light
    whose settings ask for it (or name no registered method), else None.
    ``light``: the captured light or the Blender light data; ``scene``: the
    Blender scene (its error budget)."""
    from ..core import auto_choice
    from ..core import methods as registry
    method = light_settings.method if light_settings is not None else settings.AUTO
    if method != settings.AUTO and method in registry.pass_ids(external=False):
        return None
    if light is None:
        return auto_choice.choose("area", 1.0, table=None)       # documented fallback
    kind, size = light_kind_size(light)
    return auto_choice.choose(kind, size, budget=settings.error_budget(scene))


def resolve_method(light_settings, light=None, scene=None) -> str:
    """The pass id a light's settings ask for; ``auto`` resolves per light
    (:func:`auto_choice_for`; without a light: the documented fallback)."""
    choice = auto_choice_for(light_settings, light, scene)
    return light_settings.method if choice is None else choice.method


def light_jobs(scene, captured, *, methods: Optional[Sequence[str]] = None,
               samples: Optional[int] = None, fast: bool = False,
               references: Optional[Sequence[str]] = None,
               only: Optional[Sequence[str]] = None,
               map_scale: float = 1.0) -> Tuple[List[LightJob], List[str]]:
    """One LightJob per captured light whose Penumbra setting is enabled.

    ``methods``: pass ids for every light instead of each light's method +
    references; ``samples``: light samples for every light; ``fast``: the
    light's method only if it is in FAST_METHODS, else pcf, with
    PREVIEW_PARAMS under the light's own knobs; ``references``:
    instead of the scene's; ``only``: names of Blender light objects;
    ``map_scale``: a light without its own map size gets light views of
    this fraction of ``views.default_map_size``'s side (1: that side).
    Returns (jobs, notes)."""
    from ..core import methods as registry
    from ..core.views import default_map_size
    seed = settings.seed(scene)
    refs = list(settings.references(scene) if references is None else references)
    jobs, notes = [], []
    for lt in captured.lights:
        ob = light_object(lt.name)
        if only is not None and (ob is None or ob.name not in only):
            continue
        s = settings.light_settings(ob.data) if ob is not None else None
        if s is not None and not s.enabled:
            notes.append(f"{lt.name}: Penumbra is off for this light")
            continue
        choice = None
        if methods:
            passes = list(methods)
        else:
            choice = auto_choice_for(s, lt, scene)
            m = s.method if choice is None else choice.method
            if fast and m not in FAST_METHODS:
                m = FAST_METHODS[0]
                if choice is not None:
                    choice = replace(choice, method=m, reason=f"{choice.reason}; the preview runs {m} "
                                                              f"instead (fast methods only)")
            passes = list(dict.fromkeys([m] + refs))
        ov = {"seed": seed}
        n = samples or (int(s.light_samples) if s is not None else None)
        if n:
            ov["samples"] = int(n)
        mo: Dict[str, Dict[str, object]] = {}
        for pid in passes:
            if registry.is_external(pid):
                continue
            m = registry.producer_of(pid)
            group = getattr(s.knobs, m.id, None) if s is not None else None
            knobs = settings.knob_overrides(group, m) if group is not None else {}
            if fast:
                knobs = {**PREVIEW_PARAMS.get(m.id, {}), **knobs}
            if knobs:
                mo[m.id] = knobs
        ms = int(s.map_size) if s is not None and s.map_size else None
        if ms is None and map_scale != 1.0:
            ms = max(1, int(round(default_map_size(*captured.resolution, lt.kind) * map_scale)))
        jobs.append(LightJob(lt.name, passes, ov, mo, ms, choice))
    return jobs, notes


def make_steps(jobs: Sequence[LightJob], per_light: bool) -> List[Step]:
    """Lights with the same settings share a step (one ``render_frame``
    call) unless ``per_light`` (one step per light, for the modal UI)."""
    steps: List[Step] = []
    by_key: Dict[str, Step] = {}
    for j in jobs:
        k = j.key()
        if not per_light and k in by_key:
            by_key[k].names.append(j.name)
            if j.auto is not None:
                by_key[k].auto[j.name] = j.auto
            continue
        st = Step([j.name], list(j.passes), dict(j.overrides), dict(j.method_overrides), j.map_size,
                  {j.name: j.auto} if j.auto is not None else {})
        steps.append(st)
        by_key[k] = st
    return steps
