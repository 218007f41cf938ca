"""Helpers shared by the tests that need no bpy: the brute-force reference
on a frame's buffers, error measures, and the invariants every pass keeps."""
from __future__ import annotations

from typing import Optional

import numpy as np

from penumbra.core.buffers import FrameBuffers
from penumbra.core.methods import producer_of
from penumbra.core.metrics import errors


def buffers_of(scene, map_size: Optional[int] = None) -> FrameBuffers:
    """The frame's buffers at the scene's own resolution."""
    return FrameBuffers(scene, *scene.resolution, map_size)


def run_method(method_id: str, fb: FrameBuffers, light, **params):
    """``method_id``'s MethodResult on buffers ``fb`` for ``light``, its
    Params taken from ``params`` (unknown names ignored, as the CLI does)."""
    m = producer_of(method_id)
    return m.run(fb, light, m.make_params(params))


def embree_pass(fb: FrameBuffers, light, samples: int = 256, seed: int = 0, pass_id: str = "embree") -> np.ndarray:
    """The brute-force reference pass (``embree``: average visibility;
    ``embree_irr``: the irradiance ratio) on buffers ``fb``."""
    return run_method("embree", fb, light, samples=samples, seed=seed).passes[pass_id]


def rmse(a, b, mask=None) -> float:
    """Root-mean-square difference over ``mask`` (all pixels by default), as
    the JSON's ``error.rmse``."""
    return errors(a, b, mask)["rmse"]


def in_range(v) -> bool:
    """A pass as every method must write it: float32, finite, in [0, 1]."""
    v = np.asarray(v)
    return v.dtype == np.float32 and bool(np.isfinite(v).all()) and float(v.min()) >= 0.0 and float(v.max()) <= 1.0
