"""Settings -> work: what to compute for each captured light, and which
lights share one ``render_frame`` call.

Each light's pass list is its own method (``light.penumbra.method``; ``auto``
resolves per light with the planner's scene-aware resolver,
``core.planner.auto_choice_for``, under the scene's error budget, and the
decision with its reason goes into the frame's plan) plus the scene's
references; its knobs, light samples and depth-map size become
``render_frame``'s overrides. Lights with the same settings share one step
(one ``render_frame`` call and its buffers).

The Preview runs a light's method when the method has preview settings
(``Method.preview_params``), else the first such method (``pcf``), with
those settings under the light's own knobs, and light views at
``PREVIEW_MAP_SCALE`` of the default map's side.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field, replace
from typing import Dict, List, Optional, Sequence, Tuple

from . import settings
from .capture import light_object

#: the Preview's light views: this fraction of the default map's larger side
#: (``views.default_map_size``; a light's own Map Size wins)
PREVIEW_MAP_SCALE = 0.5

#: the last ``auto`` decision per (scene name, light name): what the light's
#: panel shows (the pick depends on the captured scene, so it is known once a
#: frame was computed)
_last_auto: Dict[Tuple[str, str], object] = {}


def preview_methods() -> List[str]:
    """The methods the Preview runs as they are (those with preview
    settings), in registry order: the first stands in for the others."""
    from ..core import methods as registry
    return [mid for mid, m in registry.producers().items() if m.preview_params is not None]


def asks_for_auto(light_settings) -> bool:
    """Whether a light's settings ask for ``auto`` (or name no registered
    method, which is read as ``auto``)."""
    from ..core import methods as registry
    method = light_settings.method if light_settings is not None else settings.AUTO
    return method == settings.AUTO or method not in registry.pass_ids(external=False)


def last_auto(scene_name: str, light_name: str):
    """``auto``'s last decision (``core.auto_choice.AutoChoice``) for the light
    object ``light_name`` of the scene, or None when none was computed yet."""
    return _last_auto.get((scene_name, light_name))


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


def light_jobs(scene, captured, *, methods: Optional[Sequence[str]] = None,
               samples: Optional[int] = None, preview: bool = False,
               references: Optional[Sequence[str]] = None,
               lights: Optional[Sequence[str]] = None,
               visibility: Optional[str] = None) -> Tuple[List[LightJob], List[str]]:
    """One LightJob per captured light whose Penumbra setting is enabled.

    ``methods``: pass ids for every light instead of each light's method +
    references; ``samples``: light samples for every light; ``preview``: the
    light's method only if it has preview settings (``preview_methods``),
    else the first that has, with those settings under the light's own
    knobs, light views at ``PREVIEW_MAP_SCALE`` of the default map's side;
    ``references``: instead of the scene's; ``lights``: names of Blender
    light objects (None: every light); ``visibility``: which V every pass
    is (None: the scene's). Returns (jobs, notes)."""
    from ..core import methods as registry
    from ..core.planner import auto_choice_for
    from ..core.views import default_map_size
    seed = settings.seed(scene)
    visibility = visibility or settings.visibility(scene)
    refs = list(settings.references(scene) if references is None else references)
    fast = preview_methods() if preview else []
    jobs, notes = [], []
    for lt in captured.lights:
        ob = light_object(lt.name)
        if lights is not None and (ob is None or ob.name not in lights):
            continue
        s = settings.light_settings(ob.data) if ob is not None else None
        if s is not None and not s.enabled:
            notes.append(f"{lt.name}: Penumbra is off for this light")
            continue
        choice = None
        if methods:
            passes = list(methods)
        else:
            if asks_for_auto(s):
                choice = auto_choice_for(captured, lt, settings.error_budget(scene), visibility)
                _last_auto[(scene.name, lt.name)] = choice
            m = s.method if choice is None else choice.method
            if preview and m not in fast:
                m = fast[0]
                if choice is not None:
                    choice = replace(choice, method=m, reason=f"{choice.reason}; the preview runs {m} "
                                                              f"instead (methods with preview settings only)")
            passes = list(dict.fromkeys([m] + refs))
        ov = {"seed": seed, "visibility": visibility}
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
            if preview:
                knobs = {**(m.preview_params or {}), **knobs}
            if knobs:
                mo[m.id] = knobs
        ms = int(s.map_size) if s is not None and s.map_size else None
        if ms is None and preview:
            ms = max(1, int(round(default_map_size(*captured.resolution, lt.kind) * PREVIEW_MAP_SCALE)))
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
