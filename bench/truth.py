"""The compositing truth of a sample scene, and Cycles' own pair beside it.

A shadow pass is right when the unshadowed render times the pass is the
shadowed render, pixel by pixel: the truth is Cycles' Diffuse Direct with the
light's shadow over the same without it, rendered with the scene's own pixel
filter at ``TRUTH_SAMPLES`` samples (``bridge/cycles_reference.py``), one
light at a time. It is cached on disk (``<cache>/penumbra/truth``, keyed on the
scene file's contents, the size, the samples, the seed and the Blender
version), since it is the slowest part of the study and does not depend on
Penumbra's code. ``cycles_pair`` renders the same pair at fewer samples, timed
in the run that uses it: the workflow a pass replaces.

The ``..._of`` / ``..._file`` forms take an open bpy scene or any .blend (the
instancing benchmark's scatter scenes, ``bench/instancing.py``) and the
light's object name, so a scene with millions of instanced triangles is not
captured just to learn its light.
"""
from __future__ import annotations

import hashlib
import os
import time
from typing import Optional, Tuple

import numpy as np

from .harness import ROOT, cache_dir, open_sample

TRUTH_SAMPLES = 1024
TRUTH_SEED = 4242


def _file_hash(path: str) -> str:
    with open(path, "rb") as f:
        return hashlib.sha256(f.read()).hexdigest()[:16]


def _blend_hash(name: str) -> str:
    return _file_hash(os.path.join(ROOT, "sample_blends", f"{name}.blend"))


def cycles_pair_of(scene, light_name: str, res: Tuple[int, int], samples: int,
                   seed: int = 0, renders: Optional[dict] = None) -> Tuple[np.ndarray, float]:
    """(V, wall seconds of both renders): Cycles' shadow ratio of the light
    object ``light_name`` of the open bpy ``scene`` at ``res`` and
    ``samples``, filtered like the scene renders. ``renders`` (a dict) gets
    each render's own seconds (``render_shadowed``, ``render_unshadowed``)."""
    from ..bridge import settings
    from ..bridge.cycles_reference import render_light_reference
    t = time.perf_counter()
    v, times = render_light_reference(scene, light_name, tuple(res), int(samples), int(seed),
                                      pixel_filter=settings.pixel_filter(scene, "scene"))
    if renders is not None:
        renders.update(times)
    return v, time.perf_counter() - t


def cycles_pair(name: str, res: Tuple[int, int], samples: int, seed: int = 0) -> Tuple[np.ndarray, float]:
    """(V, wall seconds): Cycles' shadow ratio of sample ``name``'s first
    light at ``res`` and ``samples``, filtered like the scene renders."""
    from ..bridge.capture import capture_scene
    scene = open_sample(name)
    light = capture_scene(scene, resolution=tuple(res)).lights[0]
    return cycles_pair_of(scene, light.name, res, samples, seed)


def _cached(key: str, make) -> np.ndarray:
    path = os.path.join(cache_dir("truth"), key + ".npy")
    if os.path.exists(path):
        return np.load(path)
    v = make()
    os.makedirs(os.path.dirname(path), exist_ok=True)
    tmp = path + f".{os.getpid()}.tmp.npy"
    np.save(tmp, v)
    os.replace(tmp, path)
    return v


def _blender() -> str:
    import bpy
    return bpy.app.version_string.split()[0]


def cycles_truth(name: str, res: Tuple[int, int], samples: int = TRUTH_SAMPLES) -> np.ndarray:
    """Cycles' shadow ratio at ``samples`` (the study's truth), from the
    cache when it holds it."""
    key = f"{name}_{res[0]}x{res[1]}_{samples}_{TRUTH_SEED}_{_blender()}_{_blend_hash(name)}"
    return _cached(key, lambda: cycles_pair(name, res, samples, TRUTH_SEED)[0])


def truth_file_key(path: str, light_name: str, res: Tuple[int, int], samples: int = TRUTH_SAMPLES) -> str:
    """The cache key of ``cycles_truth_file`` (the .blend's contents among it)."""
    stem = os.path.splitext(os.path.basename(path))[0]
    return (f"{stem}_{light_name}_{res[0]}x{res[1]}_{samples}_{TRUTH_SEED}_{_blender()}_"
            f"{_file_hash(path)}")


def truth_file_cached(path: str, light_name: str, res: Tuple[int, int], samples: int = TRUTH_SAMPLES) -> bool:
    return os.path.exists(os.path.join(cache_dir("truth"), truth_file_key(path, light_name, res, samples) + ".npy"))


def cycles_truth_file(scene, path: str, light_name: str, res: Tuple[int, int],
                      samples: int = TRUTH_SAMPLES) -> np.ndarray:
    """``cycles_truth`` of the open bpy ``scene`` loaded from ``path`` (any
    .blend) for its light object ``light_name``, cached the same way."""
    return _cached(truth_file_key(path, light_name, res, samples),
                   lambda: cycles_pair_of(scene, light_name, res, samples, TRUTH_SEED)[0])
