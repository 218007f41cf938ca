"""The frame pipeline: one way from a Blender scene to a ``FrameResult``,
used by the command line, Compute Passes, Preview and the render handler.

    capture -> light jobs -> drop external passes that cannot run -> threads
            -> steps (``render_frame`` calls) -> merge

:func:`prepare_frame` captures the scene and plans the steps of a
:class:`FrameRequest` into a :class:`FrameJob`; ``job.step()`` runs one step
(the modal Compute Passes runs one per timer tick), ``job.run()`` all of
them, ``job.result()`` merges them. :func:`compute_frame` is the three in a
row. Nothing in ``bpy.data`` changes until the caller writes the result back
(:func:`write_back`, ``core.output.write_frame``), so a cancelled run leaves
no trace.

:class:`BackgroundFrameJob` runs a FrameJob's steps in a worker thread so
Blender's UI never waits on them: bpy is touched only on the main thread
(capture before the worker starts, :meth:`BackgroundFrameJob.collect` and
the write-back after it ends); the worker runs core only (Embree and the
heavy Numba kernels release the GIL). :func:`start_warm_up` compiles the
default method's kernels in a daemon thread when the add-on is enabled.
"""
from __future__ import annotations

import os
import threading
from dataclasses import dataclass
from typing import Callable, Dict, List, Optional, Sequence, Tuple

import bpy

from ..core.cancel import CancelToken, Cancelled, watching
from ..core.methods.base import IRRADIANCE
from . import buffer_cache, settings
from .capture import blend_stem, capture_scene, light_object, render_resolution
from .jobs import Step, light_jobs, make_steps

Progress = Callable[[str, float], None]


class NoCamera(ValueError):
    """The captured scene has no camera."""

    def __init__(self):
        super().__init__("the scene has no camera")


@dataclass
class FrameRequest:
    """What to compute for one frame of a scene. Made by one of two
    constructors: :meth:`from_command_line` (every light alike, the lights'
    own Penumbra settings do not apply) and :meth:`from_scene_settings`
    (each light's own method, knobs, samples and map size, the scene's
    references, seed and error budget: Compute Passes, the Preview, the
    render handler).

    Capture: ``frame`` (None: the current one), ``resolution`` (None: the
    scene's), ``depsgraph`` (a render's own) and its ``mode``.
    Work: ``methods`` (pass ids for every light; None: each light's own),
    ``lights`` (light object names; None: every light), ``samples``,
    ``seed``, ``map_size``, ``error_budget`` (the command line's; the scene
    settings' otherwise), ``references`` (None: the scene's), ``preview``
    (preview quality: ``bridge/jobs.py``; pixel centres unless
    ``pixel_filter`` names a filter; the last Preview's buffers while the
    camera and the geometry did not change: ``buffer_cache.py``),
    ``pixel_filter`` (a ``--pixel-filter`` spec; None: the scene's),
    ``visibility`` (which V every method's pass is, ``irradiance`` or
    ``average``; None: the scene's).
    Running: ``in_render`` (inside a render: no Cycles reference),
    ``threads`` (Numba threads, 0: all cores, None: unchanged),
    ``per_light`` (one step per light), ``catch_errors`` (a failed step ends
    the job with ``job.error`` instead of raising), ``skip_deleted`` (lights
    deleted between steps are skipped with a warning).
    """
    frame: Optional[int] = None
    resolution: Optional[Tuple[int, int]] = None
    depsgraph: object = None
    mode: str = "AUTO"
    light_settings: bool = True
    methods: Optional[Sequence[str]] = None
    lights: Optional[Sequence[str]] = None
    samples: Optional[int] = None
    seed: int = 0
    map_size: Optional[int] = None
    error_budget: Optional[float] = None
    references: Optional[Sequence[str]] = None
    preview: bool = False
    pixel_filter: Optional[str] = None
    visibility: Optional[str] = None
    in_render: bool = False
    threads: Optional[int] = None
    per_light: bool = False
    catch_errors: bool = False
    skip_deleted: bool = True

    @classmethod
    def from_command_line(cls, methods: Sequence[str], *, frame: Optional[int] = None,
                          resolution: Optional[Tuple[int, int]] = None, lights: Optional[Sequence[str]] = None,
                          samples: Optional[int] = None, seed: int = 0, map_size: Optional[int] = None,
                          error_budget: Optional[float] = None, pixel_filter: Optional[str] = None,
                          visibility: Optional[str] = None) -> "FrameRequest":
        """``penumbra render`` / ``plan``: ``methods`` (``auto`` among them
        resolved per light by the planner) for every light of ``lights``."""
        return cls(frame=frame, resolution=resolution, light_settings=False, methods=list(methods),
                   lights=lights, samples=samples, seed=seed, map_size=map_size, error_budget=error_budget,
                   pixel_filter=pixel_filter, visibility=visibility, skip_deleted=False)

    @classmethod
    def from_scene_settings(cls, *, preview: bool = False, methods: Optional[Sequence[str]] = None,
                            samples: Optional[int] = None, lights: Optional[Sequence[str]] = None,
                            references: Optional[Sequence[str]] = None,
                            resolution: Optional[Tuple[int, int]] = None, depsgraph=None, mode: str = "AUTO",
                            in_render: bool = False, per_light: bool = False, catch_errors: bool = False,
                            skip_deleted: bool = True, pixel_filter: Optional[str] = None) -> "FrameRequest":
        """The add-on's frames (Compute Passes, the Preview, the render
        handler): each light's own settings, the preferences' thread count."""
        return cls(resolution=resolution, depsgraph=depsgraph, mode=mode, methods=methods, lights=lights,
                   samples=samples, references=references, preview=preview, pixel_filter=pixel_filter,
                   in_render=in_render, threads=settings.preferred_threads(), per_light=per_light,
                   catch_errors=catch_errors, skip_deleted=skip_deleted)


# --------------------------------------------------------------------------
# running
def first_line(exc: BaseException) -> str:
    """The last line of an exception's text (Blender puts its report there)."""
    text = str(exc).strip()
    return text.splitlines()[-1] if text else type(exc).__name__


def set_threads(n: int) -> int:
    """Numba's thread count: ``n`` (at most the cores), 0 = all cores."""
    import numba
    top = numba.config.NUMBA_NUM_THREADS
    n = top if n <= 0 else min(n, top)
    numba.set_num_threads(n)
    return n


def run_step(captured, step: Step, external=None, progress=None, pixel_filter=None, previous=None):
    """``render_frame`` for the step's lights, filtered by ``pixel_filter``
    (a core PixelFilter; None: pixel centres, ``core.filtered_frame``);
    ``auto``'s decisions go into the result's plan (printed and stored in
    the JSON like the planner's). ``previous``: the cache of an earlier step
    or Preview for the same camera and geometry (``core/frame_cache.py``);
    the result keeps its own (``result.cache``)."""
    from ..core.filtered_frame import render_filtered
    from ..core.planner import record_auto
    passes = [p for p in step.passes if p != "cycles" or (external and "cycles" in external)]
    result = render_filtered(captured, passes, step.names, overrides=step.overrides,
                             method_overrides=step.method_overrides, map_size=step.map_size,
                             progress=progress, external=external, error_budget=step.error_budget,
                             pixel_filter=pixel_filter, previous=previous, keep=True)
    for lp in result.plan.lights:
        if lp.name in step.auto:
            record_auto(lp, step.auto[lp.name])
    return result


def merge_results(captured, results):
    """One FrameResult from the steps' results, lights in capture order,
    layer names unique across steps (as one planner call would make them)."""
    from ..core.frame import FrameResult
    from ..core.planner import Plan, unique_layers
    if len(results) == 1:
        return results[0]
    order = {lt.name: i for i, lt in enumerate(captured.lights)}
    lights = sorted((lr for r in results for lr in r.lights), key=lambda lr: order.get(lr.name, 0))
    plans = {lp.name: lp for r in results for lp in r.plan.lights}
    for lr, layer in zip(lights, unique_layers([lr.name for lr in lights])):
        lr.layer = plans[lr.name].layer = layer
    passes = list(dict.fromkeys(p for r in results for p in r.plan.passes))
    notes = list(dict.fromkeys(n for r in results for n in r.plan.notes))
    plan = Plan(passes, [plans[lr.name] for lr in lights if lr.name in plans], notes)
    times: Dict[str, float] = {}
    for r in results:
        for k, v in r.buffer_times.items():
            times[k] = times.get(k, 0.0) + v
    W, H = captured.resolution
    return FrameResult(captured.name, captured.frame, (W, H), plan, lights, times,
                       sum(r.total_s for r in results), sum(r.compile_s for r in results),
                       results[0].pixel_filter, next((r.coverage for r in results if r.coverage is not None),
                                                     None), visibility=results[0].visibility)


def empty_result(captured):
    from ..core.frame import FrameResult
    from ..core.planner import Plan
    return FrameResult(captured.name, captured.frame, tuple(captured.resolution),
                       Plan([], [], ["no light to compute"]), [], {}, 0.0)


class FrameJob:
    """The steps of one frame; ``step()`` runs the next one, ``result()``
    merges what ran. The steps share one frame cache (each takes over the
    last one's buffers: ``cache``, ``core/frame_cache.py``); a Preview's
    starts from the last Preview's (``bridge/buffer_cache.py``, ``ticket``)
    and is kept for the next."""

    def __init__(self, scene, captured, steps: List[Step], external=None, notes=(),
                 catch_errors: bool = True, skip_deleted: bool = True, pixel_filter=None,
                 cache=None, ticket=None):
        self.scene_name = scene.name
        self.pixel_filter = pixel_filter
        self.captured = captured
        self.steps = steps
        self.external = external or {}
        self.catch_errors = catch_errors
        self.skip_deleted = skip_deleted
        self.results = []
        self.index = 0
        self.notes: List[str] = list(notes)
        self.warnings: List[str] = []
        self.error: Optional[str] = None
        self.cache = cache                  # core FrameCache the next step takes over
        self.ticket = ticket                # buffer_cache.Ticket of a Preview (None: not kept)
        self.reused = cache is not None     # whether it started from a Preview's cache

    @property
    def done(self) -> bool:
        return self.error is not None or self.index >= len(self.steps)

    def step(self, progress: Optional[Progress] = None) -> bool:
        """Run the next step; False once there is nothing left (or it failed)."""
        if self.done:
            return False
        st = self.steps[self.index]
        self.index += 1
        if self.skip_deleted and st.names is not None:
            alive = [n for n in st.names if light_object(n) is not None]
            for n in st.names:
                if n not in alive:
                    self.warnings.append(f"light {n!r} was deleted during the run: skipped")
            if not alive:
                return not self.done
            st = Step(alive, st.passes, st.overrides, st.method_overrides, st.map_size,
                      {n: c for n, c in st.auto.items() if n in alive}, st.error_budget)
        try:
            res = run_step(self.captured, st, self.external, progress, self.pixel_filter, self.cache)
            self.cache, res.cache = res.cache, None
            self.results.append(res)
            if self.done and self.error is None:
                buffer_cache.store(self.ticket, self.cache)
        except Cancelled:
            raise
        except Exception as exc:           # a report, not a traceback
            if not self.catch_errors:
                raise
            self.error = f"{', '.join(st.names or ())}: {type(exc).__name__}: {exc}"
        return not self.done

    def run(self, progress: Optional[Progress] = None) -> "FrameJob":
        """Every remaining step; ``progress(message, fraction of the frame)``.
        One frame computes at a time in this process (:data:`COMPUTE_LOCK`)."""
        n = max(1, len(self.steps))
        with COMPUTE_LOCK:
            while not self.done:
                i = self.index
                self.step(None if progress is None else (lambda msg, f, i=i: progress(msg, (i + f) / n)))
        return self

    def drop_deleted_lights(self) -> None:
        """Main thread, after a run with ``skip_deleted=False`` in a worker:
        drop the results of lights deleted meanwhile, with a warning each."""
        kept = []
        for r in self.results:
            gone = {lr.name for lr in r.lights if light_object(lr.name) is None}
            for name in sorted(gone):
                self.warnings.append(f"light {name!r} was deleted during the run: skipped")
            r.lights = [lr for lr in r.lights if lr.name not in gone]
            r.plan.lights = [lp for lp in r.plan.lights if lp.name not in gone]
            if r.lights:
                kept.append(r)
        self.results = kept

    def result(self):
        """The merged FrameResult (an empty one when no step ran)."""
        if not self.results:
            return empty_result(self.captured)
        return merge_results(self.captured, self.results)


#: one frame computation at a time in this process (a cancelled worker that
#: has not reached its next check yet, the add-on's warm-up, a script's run)
COMPUTE_LOCK = threading.RLock()


class BackgroundFrameJob:
    """A FrameJob's steps in a daemon worker thread.

    ``start()`` returns at once; ``message`` / ``fraction`` follow the
    worker's progress (read them from a timer); ``cancel()`` stops it at
    the next light or method (the progress callback raises core's
    :class:`Cancelled`) or, inside a long method, at its next chunk of
    rows or rays (the worker's ``core.cancel`` token, checked by
    ``kernels.each_in_threads`` and ``pcf``); once ``done``, ``collect()``
    (main thread) drops lights deleted meanwhile and returns the FrameJob
    for the write-back. ``token``: the cancel token (tests pass their own).
    The worker never touches bpy: steps with external producers (the Cycles
    reference renders through bpy) cannot run here (``runs_in_background``).
    """

    def __init__(self, job: FrameJob, token: Optional[CancelToken] = None):
        self.job = job
        self.skip_deleted = job.skip_deleted
        job.skip_deleted = False              # light_object() reads bpy: checked in collect()
        self.message = "starting"
        self.fraction = 0.0
        self.cancelled = False
        self._cancel = token or CancelToken()
        self._thread: Optional[threading.Thread] = None

    @staticmethod
    def runs_in_background(job: FrameJob) -> bool:
        return not job.external

    def start(self) -> "BackgroundFrameJob":
        self._thread = threading.Thread(target=self._work, name="penumbra-frame", daemon=True)
        self._thread.start()
        return self

    def _progress(self, message: str, fraction: float) -> None:
        self._cancel.check()
        self.message, self.fraction = str(message), float(fraction)

    def _work(self) -> None:
        try:
            with watching(self._cancel):
                self.job.run(self._progress)
        except Cancelled:
            self.cancelled = True
        except Exception as exc:          # catch_errors=False: a report, not a traceback
            self.job.error = f"{type(exc).__name__}: {exc}"
        if self._cancel.cancelled:
            self.cancelled = True

    @property
    def done(self) -> bool:
        return self._thread is not None and not self._thread.is_alive()

    def cancel(self) -> None:
        self._cancel.cancel()

    def wait(self, timeout: Optional[float] = None) -> bool:
        """Block until the worker ends (tests, unregister); True when it has."""
        if self._thread is not None:
            self._thread.join(timeout)
        return self.done

    def collect(self) -> FrameJob:
        """Main thread, once done: the FrameJob, lights deleted meanwhile dropped."""
        if self.skip_deleted:
            self.job.drop_deleted_lights()
        return self.job


def default_methods() -> List[str]:
    """What a new light computes first: ``auto``'s pick for an area light of
    size 1 under the default budget, and the preview's fast method."""
    from ..core import auto_choice
    from .jobs import preview_methods
    return list(dict.fromkeys([auto_choice.choose("area", 1.0).method, preview_methods()[0]]))


def warm_up(methods: Optional[Sequence[str]] = None, stop: Optional[threading.Event] = None) -> None:
    """Compile ``methods``' kernels (default: :func:`default_methods`) for an
    area light at a light's default settings (``core.warmup``)."""
    import numpy as np
    from ..core import methods as registry
    from ..core.scene import Light
    from ..core.compile_ahead import plan_key, prefetch
    from ..core.warmup import ensure_compiled
    light = Light("warm-up", "area", np.eye(4), blender_type="AREA", size=1.0)
    methods = list(methods or default_methods())
    prefetch([plan_key(mid, "area", False) for mid in methods])    # helper processes compile from the end
    for mid in methods:
        if stop is not None and stop.is_set():
            return
        m = registry.producer_of(mid)
        with COMPUTE_LOCK:
            ensure_compiled(m, light, m.make_params({"seed": 0, "samples": 64}))


_warm_thread: Optional[threading.Thread] = None
_warm_stop = threading.Event()


def start_warm_up(methods: Optional[Sequence[str]] = None) -> threading.Thread:
    """:func:`warm_up` in a daemon thread (returns at once; never keeps
    Blender from exiting); a failure is printed, never raised."""
    global _warm_thread

    def work():
        try:
            warm_up(methods, _warm_stop)
        except Exception as exc:                 # the first real run reports it properly
            print(f"Penumbra: kernel warm-up failed: {type(exc).__name__}: {exc}")
    _warm_stop.clear()
    _warm_thread = threading.Thread(target=work, name="penumbra-warm-up", daemon=True)
    _warm_thread.start()
    return _warm_thread


def stop_warm_up() -> None:
    """Ask the warm-up to stop before its next method (unregister)."""
    _warm_stop.set()


# --------------------------------------------------------------------------
# planning
def external_producers(scene, captured, passes: Sequence[str], in_render: bool = False,
                       samples: Optional[int] = None, seed: Optional[int] = None, pixel_filter=None):
    """Producers for external passes (``cycles``: ``cycles_reference.py``)
    and notes for those that cannot run: (dict, notes); never inside a
    render. ``samples`` / ``seed``: the scene's Penumbra settings when None;
    ``pixel_filter``: the filter the reference renders with (None: pixel centres)."""
    wanted = [p for p in dict.fromkeys(passes) if p == "cycles"]
    if not wanted:
        return {}, []
    if in_render:
        return {}, ["cycles reference skipped: it needs its own render and cannot run inside one"]
    from .cycles_reference import make_cycles_producer
    samples = settings.cycles_samples(scene) if samples is None else samples
    seed = settings.seed(scene) if seed is None else seed
    return {"cycles": make_cycles_producer(scene, captured.resolution, samples, seed,
                                           pixel_filter=pixel_filter)}, []


def _uniform_step(request: FrameRequest) -> Step:
    """The command line's one step: the same passes and settings for every
    light (the lights' own Penumbra settings do not apply)."""
    overrides = {"seed": request.seed, "visibility": request.visibility or IRRADIANCE}
    if request.samples:
        overrides["samples"] = request.samples
    return Step(list(request.lights) if request.lights is not None else None, list(request.methods),
                overrides, {}, request.map_size, {}, request.error_budget)


def prepare_frame(scene, request: FrameRequest) -> FrameJob:
    """Capture ``scene`` and plan the request's steps. Raises ValueError /
    RuntimeError when the scene cannot be captured, :class:`NoCamera`
    when it has no camera. ``job.steps`` is empty when no light is to be
    computed (``job.notes`` says why for lights that were left out)."""
    captured = capture_scene(scene, depsgraph=request.depsgraph, frame=request.frame,
                             resolution=request.resolution, mode=request.mode)
    if captured.camera is None:
        raise NoCamera()
    # a Preview is preview quality: pixel centres, unless the request names a filter
    flt = settings.pixel_filter(scene, "none" if request.preview and request.pixel_filter is None
                                else request.pixel_filter)
    if not request.light_settings:
        step = _uniform_step(request)
        external, notes = external_producers(scene, captured, step.passes, request.in_render,
                                             samples=request.samples or 64, seed=request.seed,
                                             pixel_filter=flt)
        steps = [step]
    else:
        jobs, notes = light_jobs(scene, captured, methods=request.methods, samples=request.samples,
                                 preview=request.preview, references=request.references, lights=request.lights,
                                 visibility=request.visibility)
        all_passes = [p for j in jobs for p in j.passes]
        external, ext_notes = external_producers(scene, captured, all_passes, request.in_render,
                                                 pixel_filter=flt)
        notes = notes + ext_notes
        if "cycles" in all_passes and "cycles" not in external:
            from ..core.auto_choice import AVERAGE, FALLBACK
            for j in jobs:
                j.passes = [p for p in j.passes if p != "cycles"] or [FALLBACK[AVERAGE]]
        steps = make_steps(jobs, request.per_light)
    if request.threads is not None:
        set_threads(request.threads)
    ticket = cache = None
    if request.preview:                   # a Preview: start from the last one's cache
        buffer_cache.watch()
        ticket = buffer_cache.ticket(scene, captured)
        cache = buffer_cache.lookup(ticket)
    return FrameJob(scene, captured, steps, external, notes, request.catch_errors, request.skip_deleted,
                    flt, cache, ticket)


def compute_frame(scene, request: FrameRequest, progress: Optional[Progress] = None) -> FrameJob:
    """Capture, plan and run one frame: ``job.result()`` is its FrameResult,
    ``job.notes`` / ``job.warnings`` what was left out and why."""
    return prepare_frame(scene, request).run(progress)


def no_light_reason(job: FrameJob) -> str:
    """Why a job has no step: no lights at all, or none enabled."""
    return "the scene has no lights" if not job.captured.lights else "no light has Penumbra enabled"


# --------------------------------------------------------------------------
# write-back and output folders
def finish_frame(scene, job: FrameJob, out_dir: Optional[str] = None, *, store: bool = True,
                 build_nodes: bool = False, previews: bool = False):
    """The end of every frame, whoever computed it (the command line,
    Compute Passes, the render handler): merge the steps' results, store
    the passes as Blender images (``store``; with the compositor's nodes when
    ``build_nodes``) and write the EXR, the JSON (and the PNG previews when
    ``previews``) into ``out_dir`` when one is given. Returns (FrameResult,
    written paths or None); (None, None) when no step ran (``job.error``
    says why when one failed). A file that cannot be written is a warning in
    ``job.warnings``: nothing half-written is left."""
    from ..core.output import write_frame
    if job.error is not None or not job.results:
        return None, None
    result = job.result()
    if store:
        write_back(scene, result, build_nodes)
    written = None
    if out_dir:
        try:
            written = write_frame(result, out_dir, previews=previews)
        except (OSError, ValueError) as exc:
            job.warnings.append(f"could not write to {out_dir}: {exc}")
    return result, written


def write_back(scene, result, build_nodes: bool = False) -> List[str]:
    """Store the result's passes as images (and show them in the compositor
    when ``build_nodes``); returns the image names."""
    from . import compositor
    from .images import store_images
    names = store_images(result)
    if build_nodes and result.lights:
        passes = list(dict.fromkeys(p for lr in result.lights for p in lr.passes))
        compositor.build_side_by_side(scene, {lr.name: lr.layer for lr in result.lights}, passes)
    return names


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


def render_output_folder(scene, frame: int) -> str:
    """Where a render's frame files go: the scene's output folder if set, else
    the render output's folder (a ``penumbra`` sub-folder if the render's
    own file would have the name Penumbra's EXR has)."""
    from ..core.output import output_paths
    folder = settings.output_folder(scene)
    if folder:
        return folder
    frame_path = bpy.path.abspath(scene.render.frame_path(frame=frame))
    folder = os.path.dirname(frame_path) or os.getcwd()
    if os.path.abspath(output_paths(folder, blend_stem(scene), frame)["exr"]) == os.path.abspath(frame_path):
        folder = os.path.join(folder, "penumbra")
    return folder


def default_exr_path(scene) -> Optional[str]:
    """``<output folder>/<stem>.<frame:04d>.exr`` (DESIGN.md naming) when the
    scene has a Penumbra output folder."""
    from ..core.output import output_paths
    folder = settings.output_folder(scene)
    if not folder:
        return None
    return output_paths(bpy.path.abspath(folder), blend_stem(scene), scene.frame_current)["exr"]


def scaled_resolution(scene, scale: float = 1.0, max_side: int = 0) -> Tuple[int, int]:
    """The scene's render resolution times ``scale``, the larger side at
    most ``max_side`` (0: no limit)."""
    w, h = render_resolution(scene)
    s = float(scale)
    if max_side and max(w, h) * s > max_side:
        s = max_side / float(max(w, h))
    return max(1, int(round(w * s))), max(1, int(round(h * s)))
