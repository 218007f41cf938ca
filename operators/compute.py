"""Compute Shadow Passes: capture -> core -> write back, per-light settings.

Each light's pass list is its own method (``light.penumbra.method``; ``auto``
resolves per light in :func:`auto_choice_for`, from the accuracy study's
table under the scene's error budget, and the decision with its reason goes
into the frame's plan) plus the scene's references; its knobs,
light samples and depth-map size become ``render_frame``'s overrides. Lights
with the same settings share one ``render_frame`` call (and its buffers).

The work is a :class:`ComputeJob` of steps: in the UI the operator is modal
and runs one step (one light) per timer tick, reports progress through the
window manager and stops on Esc; in background mode (and when called from a
script) it runs every step at once. Nothing in ``bpy.data`` changes until the
last step is done, so a cancelled run leaves no trace and a finished one is a
single undo step. The helpers here are shared by the preview operator and the
render handler.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass, field, replace
from typing import Callable, Dict, List, Optional, Sequence, Tuple

import bpy

from ..addon import compositor
from ..addon import properties as props
from .capture import capture_scene, render_resolution

#: methods fast enough for the preview (others fall back to pcf there)
FAST_METHODS = ("pcf", "single_sample")
IMAGE_PREFIX = "Penumbra "


# --------------------------------------------------------------------------
# settings -> work
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
    names: List[str]
    passes: List[str]
    overrides: Dict[str, object]
    method_overrides: Dict[str, Dict[str, object]]
    map_size: Optional[int]
    auto: Dict[str, object] = field(default_factory=dict)   # light name -> AutoChoice


def light_object(captured_name: str):
    """The Blender object of a captured light (instances are named
    ``parent/object#id``), or None when it no longer exists."""
    ob = bpy.data.objects.get(captured_name)
    if ob is None and "/" in captured_name:
        ob = bpy.data.objects.get(captured_name.split("/", 1)[1].rsplit("#", 1)[0])
    if ob is None or ob.type != "LIGHT":
        return None
    return ob


def light_kind_size(light) -> Tuple[str, float]:
    """(kind, size) of a captured ``core.scene.Light`` or of Blender light
    data (as ``operators/capture.py`` reads it, without the object's scale:
    ``auto`` only tells zero from non-zero sizes)."""
    if hasattr(light, "extent"):
        return light.kind, float(light.extent)
    t = getattr(light, "type", "")
    if t == "AREA":
        wide = str(light.shape) in ("RECTANGLE", "ELLIPSE")
        return "area", float(max(light.size, light.size_y if wide else light.size))
    if t in ("POINT", "SPOT"):
        return "sphere", 2.0 * float(light.shadow_soft_size)
    if t == "SUN":
        return "sun", float(light.angle)
    raise ValueError(f"not a light: {light!r}")


def error_budget(scene) -> float:
    from ..core.auto_choice import DEFAULT_BUDGET
    ss = props.scene_settings(scene) if scene is not None else None
    return float(getattr(ss, "error_budget", DEFAULT_BUDGET)) if ss is not None else DEFAULT_BUDGET


def auto_choice_for(settings, light, scene):
    """``auto``'s decision (``core.auto_choice.AutoChoice``) for a light
    whose settings ask for it (or name no registered method), else None.
    ``light``: the captured light or the Blender light data; ``scene``: the
    Blender scene (its error budget)."""
    from ..core import auto_choice
    from ..core import methods as registry
    method = settings.method if settings is not None else props.AUTO
    if method != props.AUTO and method in registry.pass_ids(external=False):
        return None
    if light is None:
        return auto_choice.choose("area", 1.0, table=None)       # documented fallback
    kind, size = light_kind_size(light)
    return auto_choice.choose(kind, size, budget=error_budget(scene))


def resolve_method(settings, light=None, scene=None) -> str:
    """The pass id a light's settings ask for; ``auto`` resolves per light
    (:func:`auto_choice_for`; without a light: the documented fallback)."""
    choice = auto_choice_for(settings, light, scene)
    return settings.method if choice is None else choice.method


def light_jobs(scene, captured, *, methods: Optional[Sequence[str]] = None,
               samples: Optional[int] = None, fast: bool = False,
               references: Optional[Sequence[str]] = None,
               only: Optional[Sequence[str]] = None) -> Tuple[List[LightJob], List[str]]:
    """One LightJob per captured light whose Penumbra setting is enabled.

    ``methods``: pass ids for every light instead of each light's method +
    references; ``samples``: light samples for every light; ``fast``: the
    light's method only if it is in FAST_METHODS, else pcf; ``references``:
    instead of the scene's; ``only``: names of Blender light objects.
    Returns (jobs, notes)."""
    from ..core import methods as registry
    ss = props.scene_settings(scene)
    seed = int(ss.seed) if ss is not None else 0
    refs = list(props.references(scene) if references is None else references)
    jobs, notes = [], []
    for lt in captured.lights:
        ob = light_object(lt.name)
        if only is not None and (ob is None or ob.name not in only):
            continue
        s = props.light_settings(ob.data) if ob is not None else None
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
        if s is not None:
            for pid in passes:
                if registry.is_external(pid):
                    continue
                m = registry.producer_of(pid)
                group = getattr(s.knobs, m.id, None)
                knobs = props.knob_overrides(group, m) if group is not None else {}
                if knobs:
                    mo[m.id] = knobs
        ms = int(s.map_size) if s is not None and s.map_size else None
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


def external_producers(scene, captured, passes: Sequence[str], in_render: bool = False):
    """Producers for external passes (``cycles``) and notes for those that
    cannot run: (dict, notes). The Cycles reference comes from
    ``operators/cycles_reference.py``'s ``external_producers(scene, captured,
    samples=, seed=)`` when that module provides it; never inside a render."""
    wanted = [p for p in dict.fromkeys(passes) if p == "cycles"]
    if not wanted:
        return {}, []
    if in_render:
        return {}, ["cycles reference skipped: it needs its own render and cannot run inside one"]
    try:
        from . import cycles_reference
        make = getattr(cycles_reference, "external_producers")
    except (ImportError, AttributeError):
        return {}, ["cycles reference skipped: the Cycles reference is not available"]
    ss = props.scene_settings(scene)
    samples = int(ss.cycles_samples) if ss is not None else 64
    seed = int(ss.seed) if ss is not None else 0
    return dict(make(scene, captured, samples=samples, seed=seed)), []


def check_out_dir(path: str) -> Tuple[Optional[str], Optional[str]]:
    """(absolute folder, None) when ``path`` can be written to (created if
    needed), else (None, a one-line reason)."""
    if path.startswith("//") and not bpy.data.filepath:
        return None, f"output folder {path!r} is relative to an unsaved file: save it or use an absolute path"
    out = os.path.abspath(bpy.path.abspath(path))
    try:
        os.makedirs(out, exist_ok=True)
    except OSError as exc:
        return None, f"cannot create output folder {out}: {exc.strerror or exc}"
    if not os.path.isdir(out) or not os.access(out, os.W_OK):
        return None, f"output folder is not writable: {out}"
    return out, None


# --------------------------------------------------------------------------
# running
def run_step(captured, step: Step, external=None, progress=None):
    """``render_frame`` for the step's lights; ``auto``'s decisions go into
    the result's plan (printed and stored in the JSON like the planner's)."""
    from ..core.frame import render_frame
    from ..core.planner import record_auto
    passes = [p for p in step.passes if p != "cycles" or (external and "cycles" in external)]
    result = render_frame(captured, passes, step.names, overrides=step.overrides,
                          method_overrides=step.method_overrides, map_size=step.map_size,
                          progress=progress, external=external)
    for lp in result.plan.lights:
        if lp.name in step.auto:
            record_auto(lp, step.auto[lp.name])
    return result


def merge_results(captured, results):
    """One FrameResult from the steps' results, lights in capture order,
    layer names unique across steps (as one planner call would make them)."""
    from ..core.frame import FrameResult
    from ..core.planner import Plan
    if len(results) == 1:
        return results[0]
    order = {lt.name: i for i, lt in enumerate(captured.lights)}
    lights = sorted((lr for r in results for lr in r.lights), key=lambda lr: order.get(lr.name, 0))
    plans = {lp.name: lp for r in results for lp in r.plan.lights}
    used: Dict[str, int] = {}
    for lr in lights:
        layer = lr.layer
        if layer in used:
            used[layer] += 1
            layer = f"{layer}_{used[layer]}"
            lr.layer = layer
            plans[lr.name].layer = layer
        used.setdefault(layer, 1)
    passes = list(dict.fromkeys(p for r in results for p in r.plan.passes))
    notes = list(dict.fromkeys(n for r in results for n in r.plan.notes))
    plan = Plan(passes, [plans[lr.name] for lr in lights if lr.name in plans], notes)
    times: Dict[str, float] = {}
    for r in results:
        for k, v in r.buffer_times.items():
            times[k] = times.get(k, 0.0) + v
    W, H = captured.resolution
    return FrameResult(captured.name, captured.frame, (W, H), plan, lights, times,
                       sum(r.total_s for r in results))


def empty_result(captured):
    from ..core.frame import FrameResult
    from ..core.planner import Plan
    return FrameResult(captured.name, captured.frame, tuple(captured.resolution),
                       Plan([], [], ["no light to compute"]), [], {}, 0.0)


def store_images(result) -> List[str]:
    """Each light's passes as ``Penumbra <layer> <pass>`` images, updated in
    place. Images of other passes (an earlier run's reference, the Cycles
    reference operator's) are kept. Returns the names."""
    names = []
    for lr in result.lights:
        for pid, v in lr.passes.items():
            names.append(compositor.store_pass_image(lr.layer, pid, v).name)
    return names


def scaled_resolution(scene, scale: float = 1.0, max_side: int = 0) -> Tuple[int, int]:
    w, h = render_resolution(scene)
    s = float(scale)
    if max_side and max(w, h) * s > max_side:
        s = max_side / float(max(w, h))
    return max(1, int(round(w * s))), max(1, int(round(h * s)))


class ComputeJob:
    """The steps of one Compute Passes run; ``step()`` runs the next one,
    ``finish()`` writes everything back at the end."""

    def __init__(self, scene, captured, steps: List[Step], external=None,
                 out_dir: Optional[str] = None, build_nodes: bool = True, notes=()):
        self.scene_name = scene.name
        self.captured = captured
        self.steps = steps
        self.external = external or {}
        self.out_dir = out_dir
        self.build_nodes = build_nodes
        self.results = []
        self.index = 0
        self.notes: List[str] = list(notes)
        self.warnings: List[str] = []
        self.error: Optional[str] = None
        self.written: Optional[Dict[str, str]] = None

    @property
    def done(self) -> bool:
        return self.error is not None or self.index >= len(self.steps)

    def step(self, progress: Optional[Callable[[str, float], None]] = None) -> bool:
        """Run the next step; False once there is nothing left (or it failed)."""
        if self.done:
            return False
        st = self.steps[self.index]
        self.index += 1
        alive = [n for n in st.names if light_object(n) is not None]
        for n in st.names:
            if n not in alive:
                self.warnings.append(f"light {n!r} was deleted during the run: skipped")
        if not alive:
            return not self.done
        st = Step(alive, st.passes, st.overrides, st.method_overrides, st.map_size,
                  {n: c for n, c in st.auto.items() if n in alive})
        try:
            self.results.append(run_step(self.captured, st, self.external, progress))
        except Exception as exc:           # a report, not a traceback
            self.error = f"{', '.join(alive)}: {type(exc).__name__}: {exc}"
        return not self.done

    def finish(self, context):
        """Merge, store images, build the compositor nodes and write files.
        Returns the FrameResult (None when nothing was computed)."""
        if self.error is not None or not self.results:
            return None
        result = merge_results(self.captured, self.results)
        scene = bpy.data.scenes.get(self.scene_name) or context.scene
        store_images(result)
        if self.build_nodes and result.lights:
            passes = list(dict.fromkeys(p for lr in result.lights for p in lr.passes))
            compositor.build_side_by_side(scene, {lr.name: lr.layer for lr in result.lights}, passes)
        if self.out_dir:
            from ..core.output import write_frame
            try:
                if result.lights:
                    self.written = write_frame(result, self.out_dir, previews=False)
            except (OSError, ValueError) as exc:
                self.warnings.append(f"could not write to {self.out_dir}: {exc}")
        return result


# --------------------------------------------------------------------------
# the operator
def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[-1] if text else type(exc).__name__


class PENUMBRA_OT_compute_passes(bpy.types.Operator):
    """Compute Penumbra's shadow passes of the current frame for every enabled
    light (its own method and settings, plus the scene's references), store
    them as images and show them in the compositor. Esc cancels"""

    bl_idname = "penumbra.compute_passes"
    bl_label = "Compute Shadow Passes"
    bl_options = {"REGISTER", "UNDO"}

    methods: bpy.props.StringProperty(
        name="Methods", default="",
        description="Comma-separated method ids (or 'all') for every light; empty: each light's "
                    "own method plus the scene's references")
    samples: bpy.props.IntProperty(
        name="Samples", default=0, min=0, max=65536,
        description="Light samples per pixel for every light; 0: each light's own setting")
    resolution_scale: bpy.props.FloatProperty(name="Resolution Scale", default=1.0, min=0.01, max=1.0)
    build_nodes: bpy.props.BoolProperty(name="Build Compositor Nodes", default=True)

    _timer = None
    _job: Optional[ComputeJob] = None

    @classmethod
    def poll(cls, context):
        return context.scene is not None

    # -- shared set-up ------------------------------------------------------
    def _prepare(self, context, per_light: bool) -> Optional[ComputeJob]:
        from ..core.planner import PlanError, resolve_passes
        scene = context.scene
        methods = None
        if self.methods.strip():
            try:
                methods = resolve_passes(self.methods, external=("cycles",))
            except PlanError as exc:
                self.report({"ERROR"}, f"Penumbra: {exc}")
                return None
        if scene.camera is None:
            self.report({"ERROR"}, "Penumbra: the scene has no camera")
            return None
        ss = props.scene_settings(scene)
        out_dir = None
        if ss is not None and ss.output_folder.strip():
            out_dir, err = check_out_dir(ss.output_folder.strip())
            if err:
                self.report({"ERROR"}, f"Penumbra: {err}")
                return None
        try:
            captured = capture_scene(scene, resolution=scaled_resolution(scene, self.resolution_scale))
        except (ValueError, RuntimeError) as exc:
            self.report({"ERROR"}, f"Penumbra: {_first_line(exc)}")
            return None
        jobs, notes = light_jobs(scene, captured, methods=methods, samples=self.samples or None)
        if not jobs:
            why = "the scene has no lights" if not captured.lights else "no light has Penumbra enabled"
            self.report({"ERROR"}, f"Penumbra: {why}")
            return None
        all_passes = [p for j in jobs for p in j.passes]
        external, ext_notes = external_producers(scene, captured, all_passes)
        if "cycles" in all_passes and "cycles" not in external:
            for j in jobs:
                j.passes = [p for p in j.passes if p != "cycles"] or [resolve_method(None)]
        from ..addon.preferences import apply_threads
        apply_threads()
        return ComputeJob(scene, captured, make_steps(jobs, per_light), external, out_dir,
                          self.build_nodes, notes + ext_notes)

    def _conclude(self, context, job: ComputeJob):
        if job.error is not None:
            for w in job.warnings:
                self.report({"WARNING"}, f"Penumbra: {w}")
            self.report({"ERROR"}, f"Penumbra: computing failed: {job.error}")
            return {"CANCELLED"}
        result = job.finish(context)
        for w in job.warnings:
            self.report({"WARNING"}, f"Penumbra: {w}")
        if result is None:
            self.report({"ERROR"}, "Penumbra: no light was computed")
            return {"CANCELLED"}
        for n in list(job.notes) + list(result.plan.notes):
            self.report({"INFO"}, f"Penumbra: {n}")
        n_pass = len({p for lr in result.lights for p in lr.passes})
        msg = f"Penumbra: {len(result.lights)} light(s), {n_pass} pass(es) in {result.total_s:.2f} s"
        written = job.written
        if written:
            msg += f"; wrote {written.get('exr', written['json'])}"
        self.report({"INFO"}, msg)
        return {"FINISHED"}

    # -- synchronous (background, scripts) ----------------------------------
    def execute(self, context):
        job = self._prepare(context, per_light=False)
        if job is None:
            return {"CANCELLED"}
        wm = context.window_manager
        n = max(1, len(job.steps))
        wm.progress_begin(0.0, 1.0)
        try:
            while not job.done:
                i = job.index
                job.step(lambda _msg, f, i=i: wm.progress_update((i + f) / n))
        finally:
            wm.progress_end()
        return self._conclude(context, job)

    # -- modal (UI): one step per timer tick, Esc cancels --------------------
    def invoke(self, context, event):
        if bpy.app.background or context.window is None:
            return self.execute(context)
        job = self._prepare(context, per_light=True)
        if job is None:
            return {"CANCELLED"}
        self._job = job
        wm = context.window_manager
        wm.progress_begin(0.0, float(max(1, len(job.steps))))
        self._timer = wm.event_timer_add(0.05, window=context.window)
        wm.modal_handler_add(self)
        context.workspace.status_text_set("Penumbra: computing shadow passes (Esc to cancel)")
        return {"RUNNING_MODAL"}

    def _stop(self, context):
        wm = context.window_manager
        if self._timer is not None:
            wm.event_timer_remove(self._timer)
            self._timer = None
        wm.progress_end()
        if context.workspace is not None:
            context.workspace.status_text_set(None)

    def modal(self, context, event):
        job = self._job
        if event.type == "ESC":
            self._stop(context)
            self.report({"WARNING"}, f"Penumbra: cancelled after {job.index} of {len(job.steps)} "
                                     "step(s); nothing was changed")
            return {"CANCELLED"}
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        if not job.done:
            job.step()
            context.window_manager.progress_update(float(job.index))
        if job.done:
            self._stop(context)
            return self._conclude(context, job)
        return {"RUNNING_MODAL"}

    def cancel(self, context):
        self._stop(context)


classes = (PENUMBRA_OT_compute_passes,)
