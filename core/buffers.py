"""The buffers of one frame, each built once on first request and shared by
every method (DESIGN.md: "the planner ... builds only those buffers, once").

Build times are recorded per buffer so the JSON can report them as phases.
"""
from __future__ import annotations

import time
from typing import Dict, Optional, Tuple

import numpy as np

from . import raycast, views
from .scene import GBuffer, Light, LightView, Scene
from .sampling import scene_scale

# at most this many receiver points are used to fit light frusta
_FIT_POINTS = 1 << 16


class FrameBuffers:
    def __init__(self, scene: Scene, width: int, height: int, map_size: Optional[int] = None):
        self.scene = scene
        self.width = int(width)
        self.height = int(height)
        self.map_size = int(map_size or max(width, height))
        self.build_times: Dict[str, float] = {}
        self._gbuffer: Optional[GBuffer] = None
        self._shadow: Optional[raycast.TriangleScene] = None
        self._camera_scene: Optional[raycast.TriangleScene] = None
        self._views: Dict[Tuple[str, int], LightView] = {}
        lo, hi = scene.bounds()
        self.scale = scene_scale(lo, hi)

    def _timed(self, key, fn):
        t = time.perf_counter()
        out = fn()
        self.build_times[key] = self.build_times.get(key, 0.0) + time.perf_counter() - t
        return out

    # -- geometry ---------------------------------------------------------
    @property
    def shadow_scene(self) -> raycast.TriangleScene:
        """Embree BVH of the triangles that cast shadows."""
        if self._shadow is None:
            self._shadow = self._timed(
                "bvh_shadow", lambda: raycast.TriangleScene.from_scene(self.scene, self.scene.tri_casts_shadow))
        return self._shadow

    @property
    def camera_scene(self) -> raycast.TriangleScene:
        if self._camera_scene is None:
            mask = self.scene.tri_visible_camera
            if mask.all() and self._shadow is not None and self.scene.tri_casts_shadow.all():
                self._camera_scene = self._shadow
            else:
                self._camera_scene = self._timed(
                    "bvh_camera", lambda: raycast.TriangleScene.from_scene(self.scene, mask))
        return self._camera_scene

    @property
    def gbuffer(self) -> GBuffer:
        if self._gbuffer is None:
            cs = self.camera_scene
            self._gbuffer = self._timed(
                "gbuffer", lambda: raycast.camera_gbuffer(self.scene, self.width, self.height, cs))
        return self._gbuffer

    def receivers(self) -> np.ndarray:
        """World positions of the visible receivers (subsampled for fitting)."""
        g = self.gbuffer
        pts = g.position[g.hit]
        if len(pts) > _FIT_POINTS:
            step = int(np.ceil(len(pts) / _FIT_POINTS))
            pts = np.concatenate([pts[::step], pts[[0, -1]]])
        return pts

    # -- light views -------------------------------------------------------
    def light_view(self, light: Light, map_size: Optional[int] = None,
                   eye: Optional[np.ndarray] = None, key: str = "centre") -> LightView:
        """Depth + object-id maps of ``light`` from ``eye`` (default its centre),
        fitted to the visible receivers."""
        ms = int(map_size or self.map_size)
        k = (light.name, ms, key)
        if k not in self._views:
            def build():
                faces = views.light_view_faces(light, self.receivers(), self.scene.bounds(), ms, eye)
                e = light.position if eye is None else eye
                return raycast.render_light_view(faces, self.shadow_scene, self.scene.tri_object, e)
            rec = self.receivers()  # build the G-buffer outside this phase's timer
            del rec
            sc = self.shadow_scene
            del sc
            self._views[k] = self._timed(f"light_view:{light.name}", build)
        return self._views[k]
