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
# a per-light culled BVH is built only when culling drops this share of casters
CULL_MIN_FRACTION = 0.1


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
        self._culled: Dict[str, raycast.TriangleScene] = {}
        self.culling: Dict[str, Dict[str, int]] = {}
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

    def light_extent(self, light: Light) -> float:
        """Largest side of the box around the visible receivers and the
        light (a sun: the receivers only), at most the scene's
        largest side: the box every shadow ray of a visible receiver stays in.
        Depth tolerances scaled by it (``pcf``'s bias, ``layered``'s epsilon)
        do not grow with far geometry the light's view never holds (a 1e3
        ground under a 0.5-unit gap: near/far 1e6)."""
        lo, hi = self.scene.bounds()
        e = float(np.max(hi - lo))
        e = e if e > 0 and np.isfinite(e) else 1.0
        pts = self.receivers()
        if len(pts):
            if light.kind != "sun":
                pts = np.vstack([pts, *(b[None] for b in light.box())])
            local = float(np.max(pts.max(0) - pts.min(0)))
            if 0 < local < e:
                e = local
        return e

    def receivers(self) -> np.ndarray:
        """World positions of the visible receivers (subsampled for fitting)."""
        g = self.gbuffer
        pts = g.position[g.hit]
        if len(pts) > _FIT_POINTS:
            step = int(np.ceil(len(pts) / _FIT_POINTS))
            pts = np.concatenate([pts[::step], pts[[0, -1]]])
        return pts

    def occluder_mask(self, light: Light) -> np.ndarray:
        """bool[T]: shadow-casting triangles that can lie between ``light`` and
        a visible receiver. A shadow ray runs from a receiver (inside the
        receivers' box) to a point of the light (inside the light's box), so
        it stays inside the box around both; a triangle whose box misses that
        box can shadow nothing the camera sees. For a sun the receivers' box
        is swept towards the sun across the scene, widened by the cone."""
        tris = self.scene.triangles
        casts = self.scene.tri_casts_shadow
        g = self.gbuffer
        if len(tris) == 0 or not g.hit.any():
            return np.zeros(len(tris), bool)
        pts = g.position[g.hit]
        lo, hi = pts.min(0), pts.max(0)
        pad = 1e-4 * self.scale
        if light.kind == "sun":
            to_sun = -light.direction
            reach = 2.0 * self.scale
            spread = light.sun_spread * reach
            far_lo, far_hi = lo + to_sun * reach - spread, hi + to_sun * reach + spread
            lo, hi = np.minimum(lo, far_lo), np.maximum(hi, far_hi)
        else:
            blo, bhi = light.box()
            lo, hi = np.minimum(lo, blo), np.maximum(hi, bhi)
        lo, hi = lo - pad, hi + pad
        tlo = tris.min(axis=1)
        thi = tris.max(axis=1)
        inside = np.all((thi >= lo) & (tlo <= hi), axis=1)
        return inside & casts

    def shadow_scene_for(self, light: Light) -> raycast.TriangleScene:
        """The shadow BVH for ``light``: only ``occluder_mask``'s triangles when
        that drops at least CULL_MIN_FRACTION of the casters, else the shared one.
        Either gives the same answer for every shadow ray of a visible receiver."""
        if light.name not in self._culled:
            mask = self.occluder_mask(light)
            casts = int(self.scene.tri_casts_shadow.sum())
            kept = int(mask.sum())
            self.culling[light.name] = {"casters": casts, "kept": kept}
            if casts and kept <= (1.0 - CULL_MIN_FRACTION) * casts:
                self._culled[light.name] = self._timed(
                    f"bvh_culled:{light.name}", lambda: raycast.TriangleScene.from_scene(self.scene, mask))
            else:
                self._culled[light.name] = self.shadow_scene
        return self._culled[light.name]

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
                return raycast.render_light_view(faces, occ, self.scene.tri_object, e)
            self.receivers()              # build the G-buffer outside this phase's timer
            occ = self.shadow_scene_for(light)
            self._views[k] = self._timed(f"light_view:{light.name}", build)
        return self._views[k]
