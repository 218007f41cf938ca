"""One frame, end to end in core: plan -> shared buffers -> methods -> errors.

``render_frame`` returns every pass of every planned light plus the JSON
record DESIGN.md's contract describes; writing files is ``core/output.py``.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable, Dict, List, Mapping, Optional, Sequence

import numpy as np

from . import methods as method_registry
from .buffers import EXPAND_PHASE, FrameBuffers
from .camera_effects import describe_effects
from .data_passes import frame_data_passes
from .frame_cache import FrameCache
from .compile_ahead import frame_keys, prefetch
from .methods.base import AVERAGE, IRRADIANCE, VISIBILITIES, params_dict
from .metrics import errors
from .planner import Plan, plan_frame
from .scene import Scene
from .warmup import ensure_buffers_compiled, ensure_compiled, has_mattes

REFERENCE_FOR = {AVERAGE: "embree", IRRADIANCE: "embree_irr"}


@dataclass
class LightResult:
    name: str
    layer: str
    passes: Dict[str, np.ndarray] = field(default_factory=dict)
    record: Dict[str, dict] = field(default_factory=dict)
    stats: Dict[str, dict] = field(default_factory=dict)
    #: every pass the light's producers computed (those not asked for too), as
    #: its passes are: what a filtered frame refines on, whatever was asked
    computed: Dict[str, np.ndarray] = field(default_factory=dict, repr=False)


@dataclass
class FrameResult:
    scene_name: str
    frame: int
    resolution: tuple
    plan: Plan
    lights: List[LightResult]
    buffer_times: Dict[str, float]
    total_s: float
    compile_s: float = 0.0          # kernel compilation (``core/warmup.py``), in no method's time
    pixel_filter: Optional[dict] = None     # ``core/pixel_filter.py``: recorded when a filter was asked for
    coverage: Optional[np.ndarray] = None   # float32[H,W] alpha of a filtered frame (None: pixel centres)
    cache: Optional[FrameCache] = field(default=None, repr=False, compare=False)  # for a later ``previous``
    visibility: str = IRRADIANCE            # the frame's definition of V (each pass's: its record)
    camera_effects: Optional[dict] = None   # ``camera_effects.describe_effects``: None for a pinhole
    #: the Z and vector passes (``core/data_passes.py``), written into every layer
    data_passes: Dict[str, np.ndarray] = field(default_factory=dict, repr=False)

    def to_json(self) -> dict:
        return {
            "scene": self.scene_name,
            "frame": int(self.frame),
            "resolution": [int(self.resolution[0]), int(self.resolution[1])],
            "plan": self.plan.to_json(),
            "buffers_time_s": {k: round(v, 6) for k, v in self.buffer_times.items()},
            "total_time_s": round(self.total_s, 6),
            "compile_s": round(self.compile_s, 6),
            "visibility": self.visibility,
            **({"pixel_filter": self.pixel_filter} if self.pixel_filter is not None else {}),
            **({"camera_effects": self.camera_effects} if self.camera_effects is not None else {}),
            **({"data_passes": sorted(self.data_passes)} if self.data_passes else {}),
            "lights": [{"name": lr.name, "layer": lr.layer, "methods": lr.record} for lr in self.lights],
        }


def frame_visibility(overrides: Optional[Mapping[str, object]]) -> str:
    """The frame's definition of V (``overrides["visibility"]``, applied to
    every method that has the field): IRRADIANCE unless AVERAGE is asked for."""
    v = (overrides or {}).get("visibility") or IRRADIANCE
    if v not in VISIBILITIES:
        raise ValueError(f"visibility must be one of {', '.join(VISIBILITIES)}, not {v!r}")
    return v


def _visibility(pid: str, overrides) -> str:
    """Which V pass ``pid`` is in a frame with ``overrides``."""
    if method_registry.is_external(pid):
        return method_registry.visibility_of(pid)
    m = method_registry.producer_of(pid)
    return m.visibility(pid, m.make_params(overrides))


def _finite_pass(v: np.ndarray, unreached: np.ndarray) -> np.ndarray:
    """A method's pass as the frame writes it: float32 in [0, 1], NaN as 1,
    and 1 where the light cannot reach (no light there, so no shadow: the
    same as skipping the light)."""
    v = np.clip(np.nan_to_num(v, nan=1.0, posinf=1.0, neginf=0.0), 0.0, 1.0).astype(np.float32)
    v[unreached] = 1.0
    return v


def _params(m, overrides, method_overrides):
    ov = dict(overrides or {})
    ov.update((method_overrides or {}).get(m.id, {}))
    return m.make_params(ov)


def _compile(plan: Plan, scene: Scene, overrides, method_overrides, progress) -> float:
    """Compile the kernels of every planned (light, method) before anything
    is timed (``core/warmup.py``); returns the seconds that took."""
    registry = method_registry.producers()
    spent = 0.0
    mattes, instanced = has_mattes(scene), not scene.is_flattened
    for lp in plan.lights:
        for prod_id in lp.producers if lp.action != "skip" else ():
            if prod_id in registry:
                m = registry[prod_id]
                notify = None if progress is None else (lambda msg: progress(msg, 0.0))
                spent += ensure_compiled(m, scene.light(lp.name), _params(m, overrides, method_overrides),
                                         notify, mattes, instanced)
    return spent


def render_frame(scene: Scene, passes: Sequence[str], light_names: Optional[Sequence[str]] = None,
                 overrides: Optional[Mapping[str, object]] = None,
                 method_overrides: Optional[Mapping[str, Mapping[str, object]]] = None,
                 map_size: Optional[int] = None,
                 progress: Optional[Callable[[str, float], None]] = None,
                 external: Optional[Mapping[str, Callable]] = None,
                 error_budget: Optional[float] = None,
                 buffers: Optional[FrameBuffers] = None,
                 previous: Optional[FrameCache] = None, keep: bool = False) -> FrameResult:
    """Compute ``passes`` for every planned light of ``scene``. ``auto`` among
    them becomes, per light, the method the planner chose under
    ``error_budget`` (``core/auto_choice.py``): the pass is written under that
    method's id.

    ``overrides`` apply to every method's Params where the field exists
    (``samples``, ``seed``); ``method_overrides[producer_id]`` to one method.
    ``external[pass_id](light) -> MethodResult`` produces passes core cannot
    (``cycles``); its ``params`` field is recorded as the method's params.
    ``buffers``: the frame's buffers when the caller built (or seeded) them
    (``pixel_filter``'s stages); by default new ones at the scene's resolution.
    ``previous``: an earlier frame's cache (``result.cache``) for the same
    camera and geometry (the caller vouches for it): its buffers are taken
    over and its results for a light, method and parameters that did not
    change are used instead of running the method again (billed 0 s,
    ``"reused": true`` in the record; ``core/frame_cache.py``). ``keep``:
    the result holds this frame's cache (``result.cache``, else None).
    """
    t0 = time.perf_counter()
    W, H = scene.resolution
    if buffers is None:
        buffers = FrameBuffers(scene, W, H, map_size)
    cache = FrameCache.following(previous, buffers) if previous is not None or keep else None
    notify = None if progress is None else (lambda msg: progress(msg, 0.0))
    prefetch(frame_keys(scene, passes, False))            # helper processes compile from the end
    compile_s = ensure_buffers_compiled(scene, notify)   # before the real buffers are built (and timed)
    visibility = frame_visibility(overrides)
    plan, reach = plan_frame(scene, passes, light_names, error_budget, buffers, visibility)
    if "auto" in passes:                                 # auto's methods, now chosen
        prefetch(frame_keys(scene, [p for lp in plan.lights if lp.action != "skip" for p in lp.passes], False))
    compile_s += _compile(plan, scene, overrides, method_overrides, progress)
    registry = method_registry.producers()
    results = []
    n_lights = max(1, len(plan.lights))
    for li, lp in enumerate(plan.lights):
        light = scene.light(lp.name)
        lr = LightResult(lp.name, lp.layer)
        if lp.action == "skip":
            for pid in lp.passes:
                lr.passes[pid] = np.ones(buffers.shape, np.float32)
                lr.record[pid] = {"time_s": {"total": 0.0}, "visibility": _visibility(pid, overrides),
                                  "params": {}, "skipped": lp.reason}
            results.append(lr)
            continue
        done = {}
        reused = set()                        # producers whose result an adopted frame kept
        for k, prod_id in enumerate(lp.producers):
            if progress:
                progress(f"{lp.name}: {prod_id}", (li + k / max(1, len(lp.producers))) / n_lights)
            if method_registry.is_external(prod_id):
                if not external or prod_id not in external:
                    raise ValueError(f"no producer given for external pass {prod_id!r}")
                res = external[prod_id](light)
                phases = {k2: round(v, 6) for k2, v in res.time_s.items() if k2 != "total"}
                phases["total"] = round(sum(phases.values()), 6)
                done[prod_id] = (None, res.params or {}, res, phases)
                continue
            m = registry[prod_id]
            params = _params(m, overrides, method_overrides)
            key = cache.key(light, m.id, params_dict(params)) if cache is not None else None
            res = cache.get(key) if cache is not None else None
            if res is not None:               # the previous frame's result for this very light: nothing to do
                reused.add(prod_id)
                phases = buffers.billed((), m.needs)
                phases.update({k2: 0.0 for k2 in res.time_s if k2 != "total"})
            else:
                with buffers.view(m.needs, m.id) as view:   # run() sees only what it declared
                    res = m.run(view, light, params)
                phases = view.phase_times()   # the buffers it used, whoever built them
                phases.update({k2: v for k2, v in res.time_s.items() if k2 != "total"})
                if cache is not None:
                    cache.put(key, res)
            phases = {k2: round(v, 6) for k2, v in phases.items()}
            phases["total"] = round(sum(phases.values()), 6)
            done[prod_id] = (m, params, res, phases)
        mask = reach[lp.name]
        if light.name in buffers.culling:
            c = buffers.culling[light.name]
            lp.decisions.append(f"occluders: {c['kept']} of {c['casters']} shadow-casting triangles can lie "
                                f"between the light and a visible receiver")
        lp.decisions.append(f"{int(mask.sum())} of {int(buffers.gbuffer.hit.sum())} visible pixels can be "
                            f"lit by this light; the others get V = 1")
        unreached = ~mask
        for m, _p, res, _t in done.values():
            for pid, v in (res.passes.items() if m is not None else ()):
                lr.computed[pid] = _finite_pass(v, unreached)
        for pid in lp.passes:
            ext = method_registry.is_external(pid)
            m, params, res, phases = done[pid if ext else method_registry.producer_of(pid).id]
            lr.passes[pid] = _finite_pass(res.passes[pid], unreached) if ext else lr.computed[pid]
            rec = {"time_s": phases,
                   "visibility": method_registry.visibility_of(pid) if ext else m.visibility(pid, params),
                   "params": dict(params) if ext else params_dict(params)}
            if m is not None and len(m.passes) > 1:
                rec["computed_with"] = [q for q in m.passes if q != pid]
            if res.stats:
                rec["stats"] = res.stats
            if m is not None and EXPAND_PHASE in phases:   # it read instances expanded into triangles
                rec["expanded"] = buffers.expansion_counts()
            if m is not None and m.id in reused:
                rec["reused"] = True
            lr.record[pid] = rec
        for pid in lp.passes:
            ref = REFERENCE_FOR[lr.record[pid]["visibility"]]
            if ref in lr.passes and ref != pid:
                lr.record[pid]["error"] = {"reference": ref, **errors(lr.passes[pid], lr.passes[ref], mask)}
        results.append(lr)
    if progress:
        progress("done", 1.0)
    data = frame_data_passes(scene, buffers.gbuffer) if scene.data_passes and not buffers.subpixel else {}
    return FrameResult(scene.name, scene.frame, (W, H), plan, results, dict(buffers.build_times),
                       time.perf_counter() - t0, compile_s, cache=cache if keep else None,
                       visibility=visibility, camera_effects=describe_effects(scene, sampled=False),
                       data_passes=data)
