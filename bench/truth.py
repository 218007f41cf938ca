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
"""
from __future__ import annotations

import hashlib
import os
import time
from typing import Tuple

import numpy as np

from .harness import ROOT, open_sample

TRUTH_SAMPLES = 1024
TRUTH_SEED = 4242


def _cache_dir() -> str:
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "penumbra", "truth")


def _blend_hash(name: str) -> str:
    with open(os.path.join(ROOT, "sample_blends", f"{name}.blend"), "rb") as f:
        return hashlib.sha256(f.read()).hexdigest()[:16]


def cycles_pair(name: str, res: Tuple[int, int], samples: int, seed: int = 0) -> Tuple[np.ndarray, float]:
    """(V, wall seconds): Cycles' shadow ratio of sample ``name``'s first
    light at ``res`` and ``samples``, filtered like the scene renders."""
    import bpy
    from ..bridge import settings
    from ..bridge.capture import capture_scene
    from ..bridge.cycles_reference import render_light_reference
    scene = open_sample(name)
    light = capture_scene(scene, resolution=tuple(res)).lights[0]
    t = time.perf_counter()
    v, _ = render_light_reference(scene, light.name, tuple(res), int(samples), int(seed),
                                  pixel_filter=settings.pixel_filter(scene, "scene"))
    seconds = time.perf_counter() - t
    return v, seconds


def cycles_truth(name: str, res: Tuple[int, int], samples: int = TRUTH_SAMPLES) -> np.ndarray:
    """Cycles' shadow ratio at ``samples`` (the study's truth), from the
    cache when it holds it."""
    import bpy
    key = f"{name}_{res[0]}x{res[1]}_{samples}_{TRUTH_SEED}_{bpy.app.version_string.split()[0]}_{_blend_hash(name)}"
    path = os.path.join(_cache_dir(), key + ".npy")
    if os.path.exists(path):
        return np.load(path)
    v, _ = cycles_pair(name, res, samples, TRUTH_SEED)
    os.makedirs(os.path.dirname(path), exist_ok=True)
    tmp = path + f".{os.getpid()}.tmp.npy"
    np.save(tmp, v)
    os.replace(tmp, path)
    return v
