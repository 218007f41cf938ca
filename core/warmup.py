"""Kernel compilation, kept apart from a method's own time (DESIGN.md "JSON
sidecar": ``compile_s``, never inside a method's ``time_s``).

Before a method runs on a light for the first time in a process,
:func:`ensure_compiled` runs it once on a tiny synthetic scene lit by a copy
of that light (same kind, shape, size, cone; the same parameters), so every
Numba kernel the real run calls is compiled (or loaded from Numba's on-disk
cache) there. Numba's compile time in it is the frame's compile time; the
real run then has no compilation in it. A scene with alpha mattes warms on
a warm-up scene with a matte (``warmup_scene(..., mattes=True)``), so the
matte kernels compile there too; :func:`ensure_buffers_compiled` compiles
the frame's buffer kernels (camera G-buffer, light views, the planner's
reach) before ``render_frame`` builds the real ones, and
:func:`ensure_filter_compiled` the pixel filter's (``filtered_frame``).

:func:`kernels_cached` says, before compiling, whether a method's kernels
are already in the on-disk cache (the CLI prints "compiling ... (first run
only)" when they are not): a warm-up writes a marker into ``NUMBA_CACHE_DIR``
(a folder keyed on a hash of every core source, ``core/__init__.py``; one
marker per Python) naming the dispatchers it compiled, and the check asks
each one's Numba cache index for entries of the current source.
"""
from __future__ import annotations

import json
import os
import sys
import threading
from dataclasses import replace
from typing import Callable, Dict, List, Optional, Sequence, Tuple

import numpy as np

from .alpha import LINEAR, REPEAT, AlphaMattes
from .compile_ahead import waited_s
from .motion import ShutterMotion
from .scene import Camera, Light, MeshInstances, ObjectInfo, Scene
from .views import look_rotation

#: side of the warm-up scene's camera view and light maps, pixels
WARMUP_SIZE = 8
MARKER_DIR = "penumbra-warm"

_lock = threading.RLock()         # one warm-up at a time (the add-on's and a job's)
_warm: set = set()                # keys warmed in this process
_busy: set = set()                # keys being warmed (``_warm_once``)


class CompileNotice(str):
    """The progress message sent before a method's kernels compile: a str
    (the UI shows it as is) that says which method (``method_id``)."""

    def __new__(cls, method_id: str):
        s = super().__new__(cls, f"compiling {method_id} kernels (first run only)...")
        s.method_id = method_id
        return s


def warmup_scene(light: Light, mattes: bool = False, instanced: bool = False, lens: bool = False,
                 moving: bool = False) -> Scene:
    """A tiny scene lit by a copy of ``light``: the light at height ``D`` shining
    down on a ground quad, an occluder quad halfway, the camera at the light
    looking down (so every pixel sees a receiver the light reaches). With
    ``mattes`` the occluder carries a 2x2 alpha matte (clear, opaque and
    partial texels: ``core/alpha.py``), so the matte kernels run. With
    ``instanced`` the two quads are instances of one quad mesh, not
    flattened (``MeshInstances``), so the kernels of rays on instances run.
    With ``lens`` the camera has depth of field (``camera_samples``); with
    ``moving`` the occluder slides over the shutter (``core/motion.py``)."""
    D = max(4.0 * light.extent, 1.0) if light.kind != "sun" else 1.0
    m = np.eye(4)
    m[:3, :3] = look_rotation(np.array([0.0, 0.0, -1.0]), np.array([0.0, 1.0, 0.0]))
    m[:3, 3] = (0.0, 0.0, D)
    lt = replace(light, world_from_light=m.copy(), energy=1.0, casts_shadow=True)
    g, o = 2.0 * D, 0.25 * D

    def quad(h, z):
        a, b, c, d = [-h, -h, z], [h, -h, z], [h, h, z], [-h, h, z]
        return [[a, b, c], [a, c, d]]
    tris = np.array(quad(g, 0.0) + quad(o, 0.5 * D), np.float32)
    cam_m = m.copy()
    cam_m[2, 3] = 0.9 * D
    cam = Camera(cam_m, kind="PERSP", lens=20.0, clip_start=1e-3 * D, clip_end=10.0 * D,
                 **(dict(aperture_radius=0.02 * D, focus_distance=0.5 * D) if lens else {}))
    objs = [ObjectInfo("ground", 0), ObjectInfo("occluder", 1)]
    alpha = None
    if mattes:
        uv = np.array([[[0, 0], [1, 0], [1, 1]], [[0, 0], [1, 1], [0, 1]]], np.float32)
        alpha = AlphaMattes(np.array([-1, -1, 0, 0], np.int32), np.concatenate([np.zeros_like(uv), uv]),
                            np.array([0.0, 1.0, 0.5, 1.0], np.float32), np.array([0], np.int64),
                            np.array([2], np.int32), np.array([2], np.int32), np.array([LINEAR], np.int8),
                            np.array([REPEAT], np.int8), ["warm-up"])
    if instanced and not mattes:
        unit = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], np.float64)
        place = [np.diag([g, g, 1.0, 1.0]), np.diag([o, o, 1.0, 1.0])]
        place[1][2, 3] = 0.5 * D
        ins = MeshInstances(vertices=[unit], faces=[np.array([[0, 1, 2], [0, 2, 3]], np.int32)],
                            mesh=[0, 0], object_id=[0, 1], world_from_mesh=place)
        return Scene(None, None, objs, cam, [lt], (WARMUP_SIZE, WARMUP_SIZE), name="warm-up", instances=ins,
                     motion=_sliding(o) if moving else None)
    return Scene(tris, np.array([0, 0, 1, 1], np.int32), objs, cam, [lt],
                 (WARMUP_SIZE, WARMUP_SIZE), name="warm-up", alpha=alpha, motion=_sliding(o) if moving else None)


def _sliding(distance: float) -> ShutterMotion:
    """The warm-up's occluder (object 1) sliding ``distance`` along x over the shutter."""
    delta = np.tile(np.eye(4), (3, 1, 1, 1))
    delta[:, 0, 0, 3] = (-0.5 * distance, 0.0, 0.5 * distance)
    return ShutterMotion([1], delta)


def has_mattes(scene: Scene) -> bool:
    """The scene has a triangle with an alpha matte (its kernels then run)."""
    return scene.alpha is not None and bool(np.any(scene.alpha.tri_matte >= 0))


def _key(method, light: Light, params, mattes: bool = False, instanced: bool = False) -> Tuple:
    from .methods.base import params_dict
    return (method.id, light.kind, light.shape, light.is_spot, light.is_zero_size, bool(mattes), bool(instanced),
            json.dumps(params_dict(params), sort_keys=True, default=str))


# --------------------------------------------------------------------------
# which Numba dispatchers exist, and which are in the on-disk cache
def _dispatchers() -> Dict[str, object]:
    """Every Numba dispatcher defined in ``penumbra.core``'s loaded modules,
    by ``module:qualname``."""
    from numba.core.dispatcher import Dispatcher
    root = __name__.rsplit(".", 1)[0]
    out = {}
    for name, mod in list(sys.modules.items()):
        if mod is None or not (name == root or name.startswith(root + ".")):
            continue
        for obj in list(vars(mod).values()):
            if isinstance(obj, Dispatcher) and getattr(obj, "__module__", None) == name:
                out[f"{name}:{obj.py_func.__qualname__}"] = obj
    return out


def _overload_counts() -> Dict[str, int]:
    return {k: len(d.overloads) for k, d in _dispatchers().items()}


def _in_disk_cache(disp) -> bool:
    """The dispatcher's Numba cache index holds entries for its current source."""
    try:
        return bool(disp._cache._cache_file._load_index())
    except Exception:        # no cache (cache=False) or an unreadable index
        return False


def _marker_path(method_id: str) -> str:
    """One marker per method and Python: Blender 5.0 (CPython 3.11) and 5.1+
    (3.13) share the cache folder, but Numba keeps an index per Python
    (``*.py311.nbi``), so what 3.13 compiled says nothing of 3.11's cache."""
    import numba
    tag = f"{sys.implementation.cache_tag}-numba{numba.__version__}"
    return os.path.join(numba.config.CACHE_DIR or os.environ.get("NUMBA_CACHE_DIR", ""),
                        MARKER_DIR, f"{method_id}.{tag}.json")


def kernels_cached(method_id: str) -> bool:
    """True when a warm-up of ``method_id`` left its kernels in the on-disk
    cache of the current core sources (and they are still there)."""
    try:
        with open(_marker_path(method_id)) as f:
            names = json.load(f)["dispatchers"]
    except (OSError, ValueError, KeyError, TypeError):
        return False
    disp = _dispatchers()
    return all(n in disp and _in_disk_cache(disp[n]) for n in names)


def _write_marker(method_id: str, names: List[str]) -> None:
    path = _marker_path(method_id)
    try:
        old = []
        if os.path.exists(path):
            with open(path) as f:
                old = json.load(f).get("dispatchers", [])
        os.makedirs(os.path.dirname(path), exist_ok=True)
        tmp = f"{path}.{os.getpid()}.{threading.get_ident()}.tmp"
        with open(tmp, "w") as f:
            json.dump({"dispatchers": sorted(set(old) | set(names))}, f)
        os.replace(tmp, path)
    except (OSError, ValueError):
        pass                 # a read-only cache folder: the next run prints the notice again


# --------------------------------------------------------------------------
def ensure_compiled(method, light: Light, params, notify: Optional[Callable[[str], None]] = None,
                    mattes: bool = False, instanced: bool = False) -> float:
    """Compile (or load from the cache) every kernel ``method.run`` calls for
    ``light`` with ``params``, once per process; returns the seconds Numba
    spent compiling (its ``numba:compile`` events: 0.0 when every kernel came
    from the on-disk cache or was compiled already; loading from the cache
    and the tiny run are in no figure but the frame's total).
    ``notify(CompileNotice)`` is called first when the kernels are not in the
    on-disk cache. ``mattes``: warm on a scene with an alpha matte (for a
    scene that has one, ``has_mattes``); ``instanced``: on instances (for a
    scene that is not flattened)."""
    key = _key(method, light, params, mattes, instanced)
    if key in _warm:
        return 0.0
    with _lock:
        if key in _warm:
            return 0.0
        if notify is not None and not kernels_cached(method.id):
            notify(CompileNotice(method.id))
        from numba.core.event import install_timer
        from .buffers import FrameBuffers
        before = _overload_counts()
        scene = warmup_scene(light, mattes, instanced)
        spent: List[float] = [-waited_s()]     # + the time spent waiting for helpers' kernels
        with install_timer("numba:compile", spent.append):
            buffers = FrameBuffers(scene, WARMUP_SIZE, WARMUP_SIZE, WARMUP_SIZE)
            with buffers.view(method.needs, method.id) as view:   # as render_frame runs it
                method.run(view, scene.lights[0], params)
        spent.append(waited_s())
        after = _overload_counts()
        _write_marker(method.id, [k for k, n in after.items() if n > before.get(k, 0)])
        _warm.add(key)
        return sum(spent)



def _warm_once(key: Tuple, marker: str, notify, work: Callable[[], None]) -> float:
    """Run ``work`` once per process under ``key`` with Numba's compile time
    measured (as ``ensure_compiled``; ``marker``: its name in the cache
    markers and the notice)."""
    if key in _warm:
        return 0.0
    with _lock:
        if key in _warm or key in _busy:      # _busy: the warm-up's own frame asks again
            return 0.0
        _busy.add(key)
        if notify is not None and not kernels_cached(marker):
            notify(CompileNotice(marker))
        from numba.core.event import install_timer
        before = _overload_counts()
        spent: List[float] = [-waited_s()]     # + the time spent waiting for helpers' kernels
        try:
            with install_timer("numba:compile", spent.append):
                work()
        finally:
            _busy.discard(key)
        spent.append(waited_s())
        after = _overload_counts()
        _write_marker(marker, [k for k, n in after.items() if n > before.get(k, 0)])
        _warm.add(key)
        return sum(spent)


def ensure_buffers_compiled(scene: Scene, notify: Optional[Callable[[str], None]] = None) -> float:
    """Compile the kernels of the frame's shared buffers (camera G-buffer,
    the planner's reach, each light kind's view), with the matte kernels
    when ``scene`` has mattes, on the warm-up scene, before ``render_frame``
    builds the real buffers (their build times are in the methods' times);
    returns the seconds Numba spent compiling."""
    from .buffers import FrameBuffers
    from .planner import plan_frame
    mattes, instanced = has_mattes(scene), not scene.is_flattened
    kinds = list({(lt.kind, lt.shape, lt.is_spot, lt.is_zero_size): lt for lt in scene.lights}.items())
    spent = 0.0
    for kind, light in kinds:
        def work(light=light):
            ws = warmup_scene(light, mattes, instanced)
            fb = FrameBuffers(ws, WARMUP_SIZE, WARMUP_SIZE, WARMUP_SIZE)
            plan_frame(ws, ["embree"], None, None, fb)
            fb.light_view(ws.lights[0])
        spent += _warm_once(("buffers", kind, mattes, instanced), "buffers", notify, work)
    return spent


def ensure_filter_compiled(scene: Scene, pixel_filter, render_filtered: Callable,
                           notify: Optional[Callable[[str], None]] = None,
                           passes: Sequence[str] = ("embree", "embree_irr")) -> float:
    """Compile the pixel filter's kernels (refine mask, sub-pixel G-buffer,
    resolve, the unshadowed irradiance of an irradiance pass, coverage) on
    the warm-up scene filtered by ``pixel_filter``, rendering ``passes``
    (the frame's own core passes: no method's kernels compiled that the
    frame does not need; an irradiance pass's E0 only when one is asked
    for), one run per light kind of ``scene``, with a matte when it has
    mattes, before the real frame is timed; returns the seconds Numba spent
    compiling. ``render_filtered``: ``filtered_frame.render_filtered``
    (handed in: that module imports this one)."""
    mattes, instanced = has_mattes(scene), not scene.is_flattened
    lens = scene.camera is not None and scene.camera.has_depth_of_field
    moving = scene.motion is not None and scene.motion.moves
    kinds = list({(lt.kind, lt.shape, lt.is_spot, lt.is_zero_size): lt for lt in scene.lights}.items())
    spec = json.dumps(pixel_filter.to_json(), sort_keys=True, default=str)
    passes = sorted(set(passes))
    # the warm-up frame's own notices (a method's kernels compiled inside it) reach the caller
    progress = None if notify is None else (lambda msg, frac: notify(msg) if isinstance(msg, CompileNotice) else None)
    spent = 0.0
    for kind, light in kinds:
        def work(light=light):
            render_filtered(warmup_scene(light, mattes, instanced, lens, moving), passes, None, pixel_filter,
                            overrides={"samples": 4, "seed": 0}, progress=progress)
        spent += _warm_once(("filter", kind, mattes, instanced, lens, moving, spec, tuple(passes)), "pixel_filter",
                            notify, work)
    return spent
