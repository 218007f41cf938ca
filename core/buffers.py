"""The buffers of one frame, each built once on first request and shared by
every method (DESIGN.md: "the planner ... builds only those buffers, once").

``needs`` is a contract (Falcor's ``reflect()`` / ``execute()``): a method
declares the buffers it reads (``Method.needs``), ``NEED_BUILDERS`` names the
FrameBuffers members that build each, and ``FrameBuffers.view(needs)`` is all
a method's ``run()`` gets: those members and the frame's inputs
(``FRAME_INPUTS``); anything else raises ``UndeclaredBufferError``.

Each build is timed in the frame's ``BuildLedger`` (``core/ledger.py``): a
method is billed the builds it used and what they were built from
(``BufferView.phase_times``), whoever built them.
"""
from __future__ import annotations

import dataclasses
from typing import Callable, Dict, FrozenSet, Iterable, Optional, Set, Tuple

import numpy as np

from . import embree4, raycast, views
from .kernels import hit_box
from .ledger import BuildLedger, _closure
from .methods.base import (GBUFFER, LIGHT_SAMPLE_VIEWS, LIGHT_VIEW, MESH_PIECES, PRECOMPUTE, SHADOW_GEOMETRY,
                           SHADOW_TRIANGLES, params_dict)
from .methods.surfaces import mesh_pieces
from .motion import move_triangles
from .scene import (ExpandedInstances, GBuffer, Light, LightView, Scene, expand_instances, expandable,
                    expansion_counts)
from .sampling import scene_scale

# at most this many receiver points are used to fit light frusta
_FIT_POINTS = 1 << 16
# a per-light culled BVH is built only when culling drops this share of casters
CULL_MIN_FRACTION = 0.1

#: need -> the FrameBuffers members a method that declares it may use
NEED_BUILDERS: Dict[str, Tuple[str, ...]] = {
    GBUFFER: ("gbuffer", "receivers", "light_extent", "camera"),
    SHADOW_GEOMETRY: ("shadow_scene", "shadow_scene_for"),
    SHADOW_TRIANGLES: ("shadow_triangles", "matte_casters"),
    LIGHT_VIEW: ("light_view", "object_casts_shadow"),
    LIGHT_SAMPLE_VIEWS: ("sample_view",),
    MESH_PIECES: ("mesh_pieces", "piece_casts_shadow", "triangle_pieces"),
    PRECOMPUTE: ("precomputed",),
}
#: need -> the needs its buffers are built from (a light view is rendered on a
#: shadow BVH and fitted to the G-buffer's receivers)
NEED_BUILT_FROM: Dict[str, Tuple[str, ...]] = {
    LIGHT_VIEW: (GBUFFER, SHADOW_GEOMETRY),
    LIGHT_SAMPLE_VIEWS: (SHADOW_GEOMETRY,),
}
#: need -> the phase of a method's cost its build time is billed as (in this
#: order); a need without one (a method's own precompute) is billed in the
#: method's own phases
NEED_PHASE: Dict[str, str] = {
    GBUFFER: "gbuffer",
    SHADOW_GEOMETRY: "bvh",
    LIGHT_VIEW: "light_view",
    SHADOW_TRIANGLES: "shadow_triangles",
    LIGHT_SAMPLE_VIEWS: "bvh",      # sample views are the method's own work, on the shared BVH
    MESH_PIECES: "mesh_pieces",
}
#: the phase a scene kept as instances is billed for expanding the instances
#: the world-space triangle buffers are made of (``FrameBuffers.expansion``)
EXPAND_PHASE = "expand_instances"
#: the frame's inputs (not buffers): every method sees them
FRAME_INPUTS = ("width", "height", "map_size_for", "scale", "bounds")


class UndeclaredBufferError(RuntimeError):
    """A method's ``run()`` used a buffer its ``needs`` do not declare."""


class FrameBuffers:
    """The frame's shared buffers, each built on first use (see the module
    docstring); ``view(needs)`` is what a method's ``run()`` gets."""

    def __init__(self, scene: Scene, width: int, height: int, map_size: Optional[int] = None):
        self.scene = scene
        self.width = int(width)
        self.height = int(height)
        self.map_size_given = int(map_size) if map_size else None
        self._map_base = (self.width, self.height)     # the view the default map sizes follow
        self.ledger = BuildLedger(dict.fromkeys([*NEED_PHASE.values(), EXPAND_PHASE]))
        self._gbuffer: Optional[GBuffer] = None
        self._receivers: Optional[Tuple[np.ndarray, np.ndarray, np.ndarray]] = None
        self._reach: Dict[str, np.ndarray] = {}   # light -> metrics.reach_mask on the G-buffer
        self._shadow: Optional[raycast.TriangleScene] = None
        self._camera_scene: Optional[raycast.TriangleScene] = None
        self._shadow_triangles: Optional[Tuple[np.ndarray, np.ndarray]] = None
        self._matte_casters: Optional[tuple] = None
        self._pieces: Optional[Tuple[np.ndarray, np.ndarray]] = None
        self._views: Dict[Tuple[str, int, str], LightView] = {}   # (light, map size, key)
        self._labelled: Set[Tuple[str, int, str]] = set()          # views labelled per triangle
        self._expansion: Optional[ExpandedInstances] = None
        self._culled: Dict[str, raycast.TriangleScene] = {}
        self._bvh_key: Dict[str, str] = {}        # light -> key of the BVH its shadow rays use
        self.culling: Dict[str, Dict[str, int]] = {}
        self._precomputed: Optional[Dict[tuple, object]] = None   # ``share_precomputed``
        self._bounds = scene.bounds()
        self.scale = scene_scale(*self._bounds)
        #: rays go through the instances (``raycast.InstanceScene``) when the
        #: scene was captured as instances and is not flattened
        self.instanced = not scene.is_flattened
        self._mesh_bvhs = None
        #: a filtered frame's sub-pixel stage (``supersampled``), not the frame's own view
        self.subpixel = False
        #: the shutter time the occluders are taken at (``supersampled``'s
        #: ``at_time``); None: the frame's
        self.shutter_slice: Optional[float] = None
        self._at_slice: Dict[int, object] = {}    # id of a BVH -> it at ``shutter_slice``
        #: shutter time -> what every sub-pixel stage at that time shares: its light
        #: views ("views", "labelled") and moved shadow triangles ("moved": id of
        #: the triangles moved -> (them, the moved ones))
        self._slice_state: Dict[float, dict] = {}
        self._moved: Dict[int, tuple] = {}

    @property
    def build_times(self) -> Dict[str, float]:
        """Seconds per buffer built in this frame (the JSON's ``buffers_time_s``)."""
        return self.ledger.build_times

    def bounds(self) -> Tuple[np.ndarray, np.ndarray]:
        """The scene's axis-aligned bounds (``Scene.bounds``)."""
        return self._bounds

    @property
    def camera(self):
        """The camera the G-buffer is rendered from."""
        return self.scene.camera

    def map_size_for(self, light: Light) -> int:
        """The larger side of ``light``'s maps: the one given, else
        ``views.default_map_size`` of the frame's view (a sun's: its larger
        side; a sub-pixel stage's: the pixel-centre view's)."""
        return self.map_size_given or views.default_map_size(*self._map_base, light.kind)

    def supersampled(self, scene: Scene, width: int, height: int, gbuffer: GBuffer,
                     seconds: float, at_time: Optional[float] = None,
                     bounds: Optional[Tuple[np.ndarray, np.ndarray]] = None) -> "FrameBuffers":
        """Buffers for ``pixel_filter``'s sub-pixel stage: ``scene`` at the
        supersampled ``width`` x ``height`` with its camera G-buffer given
        (built in ``seconds``; a packed one: the passes are packed too,
        ``shape``), sharing this frame's BVHs, shadow triangles, mesh pieces,
        light views (fitted to the pixel-centre receivers; their build time is
        billed to the pixel-centre stage), method precomputes, its map size and
        its receivers: what is fitted to them (views, depth tolerances:
        ``light_extent``) is the pixel-centre stage's, so a sub-pixel receiver
        is shaded as a pixel centre there would be; their box grows to hold the
        sub-pixel receivers (occluder culling keeps what can shadow them; the
        culled BVHs are shared when it did not grow).

        ``at_time`` (a shutter time in [0, 1], ``filtered_frame``'s time
        slices): the occluders where they are then. The BVHs are traced at
        that time (``TriangleScene.at_time``), the shadow triangles are moved
        (``motion.move_triangles``), the light views and method precomputes
        are built for that time, fitted to ``bounds`` (the frame's and what
        moves over the shutter), once for every stage at that time (billed
        to the one that built them)."""
        sub = FrameBuffers(scene, width, height, self.map_size_given)
        sub.subpixel = True
        sub._map_base = self._map_base
        sub._gbuffer = gbuffer
        sub.ledger.record("gbuffer", NEED_PHASE[GBUFFER], seconds)
        sub._shadow, sub._camera_scene = self._shadow, self._camera_scene
        sub.instanced, sub._mesh_bvhs = self.instanced, self._mesh_bvhs
        sub._shadow_triangles, sub._matte_casters = self._shadow_triangles, self._matte_casters
        sub._pieces, sub._expansion = self._pieces, self._expansion
        sub._views, sub._labelled = dict(self._views), set(self._labelled)
        sub._precomputed = self._precomputed
        pts, lo, hi = self._receiver_points()
        P = gbuffer.position[gbuffer.hit]
        if lo is not None and len(P):
            slo, shi = np.minimum(lo, P.min(0)), np.maximum(hi, P.max(0))
            sub._receivers = (pts, slo, shi)
            if np.array_equal(slo, lo) and np.array_equal(shi, hi):
                sub._culled, sub._bvh_key = dict(self._culled), dict(self._bvh_key)
                sub.culling = dict(self.culling)
            elif self.instanced:          # more instances can shadow the grown box: expanded anew
                sub._drop_expansion()
        if at_time is not None:
            sub.shutter_slice = float(at_time)
            sub._slice_state = self._slice_state
            state = self._slice_state.setdefault(sub.shutter_slice, {"views": {}, "labelled": set(), "moved": {}})
            sub._views, sub._labelled, sub._moved = state["views"], state["labelled"], state["moved"]
            if bounds is not None:
                sub._bounds = (np.asarray(bounds[0], np.float64), np.asarray(bounds[1], np.float64))
        return sub

    def stand_for_shutter(self) -> None:
        """From now on the pixel-centre G-buffer's receivers stand for the
        whole shutter (``GBuffer.over_shutter``: a filtered frame of moving
        objects seen by a still camera, away from their images)."""
        g = self.gbuffer
        self._gbuffer = dataclasses.replace(g, over_shutter=np.ones(g.shape, bool))

    def _sliced(self, bvh):
        """``bvh`` traced at ``shutter_slice`` (itself without one)."""
        if self.shutter_slice is None or bvh is None:
            return bvh
        if id(bvh) not in self._at_slice:
            self._at_slice[id(bvh)] = (bvh, bvh.at_time(self.shutter_slice))
        return self._at_slice[id(bvh)][1]

    def _drop_expansion(self) -> None:
        """Forget the expanded instances and what was made of them (the
        world-space triangle buffers, the views labelled per triangle)."""
        self._expansion = self._shadow = self._shadow_triangles = self._pieces = None
        self._views = {k: v for k, v in self._views.items() if k not in self._labelled}
        self._labelled = set()

    def share_precomputed(self) -> None:
        """From now on ``precomputed`` keeps what it builds, for this frame's
        sub-pixel stage (``filtered_frame``; ``supersampled`` hands it on).
        Off by default: buffers that time several runs of a method (the
        study, the benchmark) rebuild its precompute every run."""
        if self._precomputed is None:
            self._precomputed = {}

    def precomputed(self, tag: str, light: Light, params, build: Callable[[], object]):
        """A method's own light-space precompute (layered's LDI,
        depth_raytrace's reference maps) for ``light`` and ``params``
        (PRECOMPUTE): with ``share_precomputed``, built once per frame, from
        the pixel-centre stage's receivers, and shared with its sub-pixel
        stage (``supersampled``), which shades other receivers with the same
        maps: billed where it was built; else ``build()`` every call."""
        if self._precomputed is None:
            return build()
        key = (tag, light.name, light_key(light), params_key(params_dict(params)), self.map_size_for(light),
               self.shutter_slice)
        if key not in self._precomputed:
            self._precomputed[key] = build()
        return self._precomputed[key]

    def adopt(self, prev: "FrameBuffers") -> None:
        """Take over what ``prev`` built for the same camera and geometry:
        the BVHs, the camera G-buffer and its receivers, the mesh pieces, and
        each light's views and culled BVH while that light is unchanged
        (``light_key``; a moved light gets new ones). The caller vouches that
        the geometry (triangles, their flags and mattes) did not change since
        ``prev`` was built (the add-on's Preview knows it from the depsgraph,
        ``bridge/buffer_cache.py``); the resolution, the camera and the
        triangle count are checked here (ValueError). Adopted buffers are
        billed 0 s: nothing was built for them in this frame."""
        if (prev.width, prev.height) != (self.width, self.height):
            raise ValueError("buffers of another resolution cannot be reused")
        if prev.scene.geometry_counts() != self.scene.geometry_counts() or not np.array_equal(
                raycast.camera_params(prev.scene.camera, self.width, self.height),
                raycast.camera_params(self.scene.camera, self.width, self.height)):
            raise ValueError("buffers of another camera or geometry cannot be reused")
        same = unchanged_lights(prev.scene, self.scene)
        self._gbuffer, self._receivers = prev._gbuffer, prev._receivers
        self._shadow, self._camera_scene = prev._shadow, prev._camera_scene
        self.instanced, self._mesh_bvhs = prev.instanced, prev._mesh_bvhs
        self._shadow_triangles, self._matte_casters = prev._shadow_triangles, prev._matte_casters
        self._pieces, self._expansion = prev._pieces, prev._expansion
        self._views = {k: v for k, v in prev._views.items() if k[0] in same}
        self._labelled = {k for k in prev._labelled if k in self._views}
        self._culled = {n: b for n, b in prev._culled.items() if n in same}
        self._bvh_key = {n: k for n, k in prev._bvh_key.items() if n in same}
        self.culling = {n: c for n, c in prev.culling.items() if n in same}
        self._reach = {n: m for n, m in prev._reach.items() if n in same}
        if self.instanced and len(same) < len(self.scene.lights):   # the expansion covers every light
            self._drop_expansion()
        kept = {"bvh_shadow", "bvh_camera", "gbuffer", "shadow_triangles", "matte_casters", "mesh_pieces",
                "expand_instances"}
        kept |= {f"bvh_culled:{n}" for n in same} | {f"light_view:{n}:{ms}:{k}" for n, ms, k in self._views}
        self.ledger.carry(prev.ledger, kept)

    def _timed(self, key: str, phase: str, fn, built_from: Iterable[str] = (), total: Optional[str] = None):
        return self.ledger.timed(key, phase, fn, built_from, total)

    def _use(self, key: str) -> None:
        self.ledger.use(key)

    @property
    def shape(self) -> Tuple[int, int]:
        """(rows, cols) of every pass of this frame: (height, width), or
        (1, N) when the G-buffer given is a packed one (``supersampled``)."""
        g = self._gbuffer
        return g.shape if g is not None and g.pixel is not None else (self.height, self.width)

    def view(self, needs: Iterable[str], owner: str = "method") -> "BufferView":
        """What ``owner``'s ``run()`` may see: the builders of ``needs``."""
        return BufferView(self, needs, owner)

    def billed(self, used: Iterable[str], needs: Iterable[str]) -> Dict[str, float]:
        """Build times of the buffers ``used`` and of what they were built
        from, summed per phase; every phase ``needs`` call for is present."""
        return self.ledger.billed(used, (NEED_PHASE[n] for n in _with_sources(needs) if n in NEED_PHASE))

    # -- geometry ---------------------------------------------------------
    def _expand_mask(self) -> np.ndarray:
        """bool per instance: those that can shadow a visible receiver of
        some light of the scene (one that casts shadows, has energy and
        reaches a visible receiver): the box of the instance meets the box
        every such shadow ray stays in (``_inside_occluder_box``). The
        instances holding the visible receivers are among them."""
        boxes = self.scene.instances.instance_boxes()
        keep = np.zeros(len(boxes), bool)
        for light in self.scene.lights:
            if light.casts_shadow and light.energy > 0 and self.reach(light).any():
                keep |= self._inside_occluder_box(light, boxes)
        return keep

    @property
    def expansion(self) -> Optional[ExpandedInstances]:
        """On a scene kept as instances: the instances that can shadow a
        visible receiver (``_expand_mask``), flattened once per frame; None
        on a flattened scene (nothing is expanded)."""
        if not self.instanced:
            return None
        if self._expansion is None:
            self.receivers()              # build the G-buffer outside this phase's timer
            self._expansion = self._timed(
                "expand_instances", EXPAND_PHASE,
                lambda: expand_instances(self.scene, self._expand_mask()), built_from=("gbuffer",))
        self._use("expand_instances")
        return self._expansion

    def expansion_counts(self) -> Optional[dict]:
        """``ExpandedInstances.counts`` of the frame's expansion, found from
        the instances' boxes without expanding them (the plan's words);
        None on a flattened scene."""
        if not self.instanced:
            return None
        if self._expansion is not None:
            return self._expansion.counts()
        return expansion_counts(self.scene, expandable(self.scene.instances, self._expand_mask()))

    def _soup(self) -> Tuple[Scene, Tuple[str, ...]]:
        """(the scene whose world-space triangles the triangle buffers are
        made of, the builds it comes from): the scene itself, or on a scene
        kept as instances the flattened ``expansion``."""
        if not self.instanced:
            return self.scene, ()
        return self.expansion.scene, ("expand_instances",)

    def _bvh(self, key, phase, mask, other, other_key, other_mask) -> raycast.TriangleScene:
        """The Embree BVH of the triangles ``mask`` selects, timed as ``key``:
        the other BVH (``other``, built as ``other_key`` from ``other_mask``)
        when it holds the same triangles (one build per frame)."""
        if other is not None and np.array_equal(mask, other_mask):
            return self._timed(key, phase, lambda: other, built_from=(other_key,))
        return self._timed(key, phase, lambda: raycast.TriangleScene.from_scene(self.scene, mask))

    @property
    def shadow_scene(self) -> raycast.TriangleScene:
        """Embree BVH of the triangles that cast shadows (SHADOW_GEOMETRY);
        on a scene kept as instances, of the ``expansion``'s."""
        if self._shadow is None and self.instanced:
            soup, source = self._soup()
            self._shadow = self._timed("bvh_shadow", "bvh", lambda: raycast.TriangleScene.from_scene(
                soup, soup.tri_casts_shadow), built_from=source)
        if self._shadow is None:
            self._shadow = self._bvh("bvh_shadow", "bvh", self.scene.tri_casts_shadow,
                                     self._camera_scene, "bvh_camera", self.scene.tri_visible_camera)
        self._use("bvh_shadow")
        return self._sliced(self._shadow)

    @property
    def shadow_triangles(self) -> Tuple[np.ndarray, np.ndarray]:
        """(float32[T,3,3], int32[T]): the shadow-casting triangles and their
        object ids, as captured (SHADOW_TRIANGLES: no BVH is built); on a
        scene kept as instances, the ``expansion``'s: every triangle that can
        shadow a visible receiver."""
        if self._shadow_triangles is None:
            soup, source = self._soup()

            def select():
                mask = soup.tri_casts_shadow
                return soup.triangles[mask], soup.tri_object[mask]
            self._shadow_triangles = self._timed("shadow_triangles", "shadow_triangles", select, built_from=source)
        self._use("shadow_triangles")
        if self.shutter_slice is not None and self.scene.motion is not None:
            tris, ids = self._shadow_triangles
            if id(tris) not in self._moved:
                self._moved[id(tris)] = (tris, self._timed(
                    "shadow_triangles_moved", "shadow_triangles",
                    lambda: (move_triangles(self.scene.motion, tris, ids, self.shutter_slice), ids),
                    built_from=("shadow_triangles",)))
            self._use("shadow_triangles_moved")
            return self._moved[id(tris)][1]
        return self._shadow_triangles

    @property
    def matte_casters(self):
        """(bool over the shadow-casting triangles: has an alpha matte, an
        Embree BVH of those), or (None, None) when none has one
        (``TriangleScene.matte_casters``; SHADOW_TRIANGLES)."""
        if self._matte_casters is None:
            self._matte_casters = self._timed("matte_casters", "shadow_triangles",
                                              lambda: raycast.TriangleScene.matte_casters(self.scene))
        self._use("matte_casters")
        return self._matte_casters

    def _mesh_pieces(self) -> Tuple[np.ndarray, np.ndarray]:
        if self._pieces is None:
            soup, source = self._soup()

            def build():
                labels = mesh_pieces(soup)
                casts = np.zeros(len(labels), bool)
                casts[labels] = soup.tri_casts_shadow
                return labels, casts
            self._pieces = self._timed("mesh_pieces", "mesh_pieces", build, built_from=source)
        self._use("mesh_pieces")
        return self._pieces

    @property
    def mesh_pieces(self) -> np.ndarray:
        """int32 per triangle: its connected mesh piece, a surface label finer
        than the object id (``methods.surfaces.mesh_pieces``; MESH_PIECES).
        On a scene kept as instances, per triangle of the ``expansion``: a
        G-buffer's triangle ids go through ``triangle_pieces``."""
        return self._mesh_pieces()[0]

    def triangle_pieces(self, tri: np.ndarray) -> np.ndarray:
        """int32 like ``tri`` (triangle ids of the G-buffer, -1: none): the
        mesh piece of each (``mesh_pieces``), -1 for none (or for a triangle
        of an instance not expanded)."""
        labels = self._mesh_pieces()[0]
        if self.instanced:
            tri = self.expansion.local_ids(tri)
        return np.ascontiguousarray(np.where(tri >= 0, labels[np.maximum(tri, 0)], -1), np.int32)

    @property
    def piece_casts_shadow(self) -> np.ndarray:
        """bool per mesh-piece label: whether the piece casts shadows (its
        object does)."""
        return self._mesh_pieces()[1]

    @property
    def object_casts_shadow(self) -> np.ndarray:
        """bool per object id: whether the object casts shadows (a light
        view's id map holds object ids)."""
        return np.array([o.casts_shadow for o in self.scene.objects], bool)

    def _instance_scene(self, mask: np.ndarray) -> raycast.InstanceScene:
        """The two-level BVH of the instances ``mask`` selects (the meshes'
        BVHs built once per frame)."""
        ins = self.scene.instances
        if self._mesh_bvhs is None:
            self._mesh_bvhs = ([embree4.Mesh(v, f) for v, f in zip(ins.vertices, ins.faces)], ins.packed())
        meshes, geometry = self._mesh_bvhs
        return raycast.InstanceScene(ins, meshes, np.nonzero(mask)[0], geometry, self.scene.motion)

    @property
    def camera_scene(self) -> raycast.TriangleScene:
        """Embree BVH of the triangles the camera sees (the G-buffer's)."""
        if self._camera_scene is None and self.instanced:
            self._camera_scene = self._timed("bvh_camera", "gbuffer", lambda: self._instance_scene(
                self.scene.instance_flag("visible_camera")))
        if self._camera_scene is None:
            self._camera_scene = self._bvh("bvh_camera", "gbuffer", self.scene.tri_visible_camera,
                                           self._shadow, "bvh_shadow", self.scene.tri_casts_shadow)
        self._use("bvh_camera")
        return self._camera_scene

    @property
    def gbuffer(self) -> GBuffer:
        """The camera G-buffer at pixel centres (GBUFFER)."""
        if self._gbuffer is None:
            cs = self.camera_scene
            self._gbuffer = self._timed(
                "gbuffer", "gbuffer", lambda: raycast.camera_gbuffer(self.scene, self.width, self.height, cs),
                built_from=("bvh_camera",))
        self._use("gbuffer")
        return self._gbuffer

    def light_extent(self, light: Light) -> float:
        """Largest side of the box around the visible receivers and the
        light (a sun: the receivers only), at most the scene's
        largest side: the box every shadow ray of a visible receiver stays in.
        Depth tolerances scaled by it (``pcf``'s bias, ``layered``'s epsilon)
        do not grow with far geometry the light's view never holds (a 1e3
        ground under a 0.5-unit gap: near/far 1e6)."""
        e = self.scene.extent()
        pts = self.receivers()
        if len(pts):
            if light.kind != "sun":
                pts = np.vstack([pts, *(b[None] for b in light.box())])
            local = float(np.max(pts.max(0) - pts.min(0)))
            if 0 < local < e:
                e = local
        return e

    def _receiver_points(self) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(subsampled hit positions, their box's lo, hi), gathered once per
        frame from the G-buffer."""
        if self._receivers is None:
            g = self.gbuffer
            # the box in one pass over the G-buffer (``kernels.hit_box``) and only the
            # subsample gathered, not every hit
            idx = np.flatnonzero(g.hit)
            flat = np.ascontiguousarray(g.position.reshape(-1, 3), np.float64)
            lo, hi = None, None
            if len(idx):
                box = np.array(hit_box(flat, np.ascontiguousarray(g.hit.reshape(-1))))
                lo, hi = box[:3], box[3:]
            if len(idx) > _FIT_POINTS:
                step = int(np.ceil(len(idx) / _FIT_POINTS))
                idx = np.concatenate([idx[::step], idx[[0, -1]]])
            pts = flat.take(idx, axis=0)
            pts.setflags(write=False)    # shared by every caller
            self._receivers = (pts, lo, hi)
        self._use("gbuffer")
        return self._receivers

    def reach(self, light: Light) -> np.ndarray:
        """bool[H,W]: the visible pixels ``light`` can illuminate, ignoring
        occlusion (``metrics.reach_mask`` on the G-buffer), once per light."""
        if light.name not in self._reach:
            from .metrics import reach_mask
            m = reach_mask(self.gbuffer, light)
            m.setflags(write=False)       # shared by the plan and every method's pass
            self._reach[light.name] = m
        return self._reach[light.name]

    def receivers(self) -> np.ndarray:
        """World positions of the visible receivers (subsampled for fitting)."""
        return self._receiver_points()[0]

    def occluder_mask(self, light: Light) -> np.ndarray:
        """bool[T]: shadow-casting triangles that can lie between ``light`` and
        a visible receiver. A shadow ray runs from a receiver (inside the
        receivers' box) to a point of the light (inside the light's box), so
        it stays inside the box around both; a triangle whose box misses that
        box can shadow nothing the camera sees. For a sun the receivers' box
        is swept towards the sun across the scene, widened by the cone."""
        tris = self.scene.triangles
        casts = self.scene.tri_casts_shadow
        if len(tris) == 0:
            return np.zeros(0, bool)
        boxes = np.stack([tris.min(axis=1), tris.max(axis=1)], axis=1)
        return (self._inside_occluder_box(light, boxes) | self._moving(self.scene.tri_object)) & casts

    def _moving(self, object_id: np.ndarray) -> np.ndarray:
        """bool per entry of ``object_id``: its object moves over the shutter
        (box culling, which sees the frame's placement, keeps it)."""
        motion = self.scene.motion
        if motion is None or not len(motion.objects):
            return np.zeros(len(object_id), bool)
        return motion.slot_of(object_id) >= 0

    def _inside_occluder_box(self, light: Light, boxes: np.ndarray) -> np.ndarray:
        """bool per box (lo, hi rows of ``boxes``): it meets the box every
        shadow ray of a visible receiver stays in (``occluder_mask``)."""
        _, lo, hi = self._receiver_points()
        if lo is None:
            return np.zeros(len(boxes), bool)
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
        return np.all((boxes[:, 1] >= lo) & (boxes[:, 0] <= hi), axis=1)

    def shadow_scene_for(self, light: Light) -> raycast.TriangleScene:
        """The shadow BVH for ``light``: only ``occluder_mask``'s triangles when
        that drops at least CULL_MIN_FRACTION of the casters, else the shared one.
        Either gives the same answer for every shadow ray of a visible receiver."""
        if light.name not in self._culled and self.instanced:
            casts = self.scene.instance_flag("casts_shadow")
            mask = casts & (self._inside_occluder_box(light, self.scene.instances.instance_boxes())
                            | self._moving(self.scene.instances.object_id))
            per = self.scene.instances.instance_triangles()
            self.culling[light.name] = {"casters": int(per[casts].sum()), "kept": int(per[mask].sum())}
            key = f"bvh_culled:{light.name}"
            self._culled[light.name] = self._timed(key, "bvh", lambda: self._instance_scene(mask),
                                                   built_from=("gbuffer",))
            self._bvh_key[light.name] = key
        if light.name not in self._culled:
            mask = self.occluder_mask(light)
            casts = int(self.scene.tri_casts_shadow.sum())
            kept = int(mask.sum())
            self.culling[light.name] = {"casters": casts, "kept": kept}
            if casts and kept <= (1.0 - CULL_MIN_FRACTION) * casts:
                key = f"bvh_culled:{light.name}"
                self._culled[light.name] = self._timed(
                    key, "bvh", lambda: raycast.TriangleScene.from_scene(self.scene, mask), built_from=("gbuffer",))
            else:
                key = "bvh_shadow"
                self.shadow_scene
                self._culled[light.name] = self._shadow
            self._bvh_key[light.name] = key
        self._use(self._bvh_key[light.name])
        return self._sliced(self._culled[light.name])

    # -- light views -------------------------------------------------------
    def light_view(self, light: Light, map_size: Optional[int] = None,
                   eye: Optional[np.ndarray] = None, key: str = "centre",
                   tri_label: Optional[np.ndarray] = None) -> LightView:
        """Depth + object-id maps of ``light`` from ``eye`` (default its centre),
        fitted to the visible receivers (LIGHT_VIEW), one per (map size, key).
        ``tri_label`` (int32 per triangle) replaces the object ids in the id
        map; give such a view its own ``key``."""
        ms = int(map_size or self.map_size_for(light))
        k = (light.name, ms, key)
        name = f"light_view:{light.name}:{ms}:{key}"
        if k not in self._views:
            def build():
                faces = views.light_view_faces(light, self.receivers(), self._bounds, ms, eye)
                e = light.position if eye is None else eye
                labels = tri_label
                if labels is None and not isinstance(occ, raycast.InstanceScene):
                    labels = self.scene.tri_object
                return raycast.render_light_view(faces, occ, labels, e)
            self.receivers()              # build the G-buffer outside this phase's timer
            occ = self.shadow_scene_for(light)
            bvh = self._bvh_key[light.name]
            if tri_label is not None and isinstance(occ, raycast.InstanceScene):
                occ, bvh = self.shadow_scene, "bvh_shadow"   # labels per triangle: the expanded casters
            if tri_label is not None:
                self._labelled.add(k)
            self._views[k] = self._timed(name, "light_view", build, total=f"light_view:{light.name}",
                                         built_from=("gbuffer", bvh))
        self._use(name)
        return self._views[k]

    def sample_view(self, faces, eye: np.ndarray, tri_label: Optional[np.ndarray] = None) -> LightView:
        """Depth + object-id maps through ``faces`` from ``eye``, a point on
        the light (LIGHT_SAMPLE_VIEWS), rendered on the shared shadow BVH.
        ``tri_label`` (int32 per triangle) replaces the object ids in the id
        map (e.g. mesh components; on a scene kept as instances, per
        triangle of the ``expansion``). Not kept: each method picks its own
        samples and faces, and times the rendering as its own phase. Build
        ``shadow_scene`` first when calling this from several threads."""
        labels = self._soup()[0].tri_object if tri_label is None else tri_label
        return raycast.render_light_view(faces, self.shadow_scene, labels, eye)


def light_key(light: Light) -> tuple:
    """What a light's views and culled BVH are built from: its kind, shape,
    sizes, cones and placement (not its colour or energy)."""
    return (light.kind, light.blender_type, light.shape, float(light.size), float(light.size_y),
            float(light.radius), float(light.spot_size), float(light.angle), bool(light.casts_shadow),
            np.asarray(light.world_from_light, np.float64).tobytes())


def unchanged_lights(prev: Scene, scene: Scene) -> Set[str]:
    """Names of ``scene``'s lights that ``prev`` has with the same
    ``light_key`` (their views and results still hold)."""
    return {lt.name for lt in scene.lights
            if any(p.name == lt.name and light_key(p) == light_key(lt) for p in prev.lights)}


def params_key(params: dict) -> str:
    """A method's parameters as a key (``params_dict`` values, sorted)."""
    import json
    return json.dumps(params, sort_keys=True, default=str)


def _with_sources(needs: Iterable[str]) -> FrozenSet[str]:
    """``needs`` and the needs their buffers are built from (NEED_BUILT_FROM)."""
    return _closure(needs, lambda n: NEED_BUILT_FROM.get(n, ()))


_NEED_OF_MEMBER = {m: n for n, members in NEED_BUILDERS.items() for m in members}


class BufferView:
    """What one method's ``run()`` sees of the frame's buffers: the members
    NEED_BUILDERS lists for its ``needs`` and the FRAME_INPUTS; any other
    buffer raises UndeclaredBufferError. Used as a context manager it records
    which buffers the method used (``used``), whoever built them, so
    ``phase_times`` bills it their build times."""

    def __init__(self, buffers: FrameBuffers, needs: Iterable[str], owner: str = "method"):
        needs = frozenset(needs)
        unknown = sorted(needs - set(NEED_BUILDERS))
        if unknown:
            raise ValueError(f"{owner}: no buffer builds the need(s) {', '.join(unknown)}")
        self._buffers = buffers
        self._owner = owner
        self.needs = needs
        self._members = {m for n in needs for m in NEED_BUILDERS[n]}
        self.used: Set[str] = set()

    def __getattr__(self, name):
        if name in FRAME_INPUTS or name in self._members:
            return getattr(self._buffers, name)
        need = _NEED_OF_MEMBER.get(name)
        if need is not None:
            raise UndeclaredBufferError(
                f"{self._owner} uses FrameBuffers.{name} without declaring {need!r} in its needs")
        raise UndeclaredBufferError(f"{self._owner} uses FrameBuffers.{name}, which no need exposes "
                                    f"(needs: {', '.join(sorted(NEED_BUILDERS))}; "
                                    f"inputs: {', '.join(FRAME_INPUTS)})")

    def __enter__(self):
        self._recording = self._buffers.ledger.recording(self.used)
        self._recording.__enter__()
        return self

    def __exit__(self, *exc):
        return self._recording.__exit__(*exc)

    def phase_times(self) -> Dict[str, float]:
        """Seconds per buffer phase billed to this method (FrameBuffers.billed)."""
        return self._buffers.billed(self.used, self.needs)
