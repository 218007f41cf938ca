"""What a frame keeps for the next one on the same camera and geometry (the
add-on's Preview): its buffers and each method's result.

A frame that starts from a ``FrameCache`` (``following``) takes over the
cached buffers (``FrameBuffers.adopt``: the G-buffer, the BVHs, the views of
unchanged lights) and the results of every light, method and parameter set
that did not change (``key``): those are billed 0 s and marked ``reused``.
The caller vouches that the geometry did not change (the add-on knows it
from the depsgraph, ``bridge/buffer_cache.py``).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Dict, Optional

import numba

from .buffers import FrameBuffers, light_key, params_key, unchanged_lights
from .methods.base import MethodResult
from .scene import Light


@dataclass
class FrameCache:
    buffers: FrameBuffers
    results: Dict[tuple, MethodResult] = field(default_factory=dict)

    @classmethod
    def following(cls, prev: Optional["FrameCache"], buffers: FrameBuffers) -> "FrameCache":
        """The cache of a frame built on ``buffers``: ``prev``'s buffers
        adopted and its results of unchanged lights kept (None: empty)."""
        cache = cls(buffers)
        if prev is not None:
            buffers.adopt(prev.buffers)
            same = unchanged_lights(prev.buffers.scene, buffers.scene)
            cache.results = {k: r for k, r in prev.results.items() if k[0] in same}
        return cache

    def key(self, light: Light, method_id: str, params: dict) -> tuple:
        """What a method's result on these buffers is a function of: the
        light (``light_key``), the method, its parameters, the frame's map
        size and Numba's thread count (the same inputs, seed and thread
        count give the same bits); the camera and geometry are the buffers'."""
        return (light.name, light_key(light), method_id, params_key(params),
                self.buffers.map_size_for(light), numba.get_num_threads())

    def get(self, key: tuple) -> Optional[MethodResult]:
        return self.results.get(key)

    def put(self, key: tuple, result: MethodResult) -> None:
        self.results[key] = result
