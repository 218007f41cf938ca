"""Embree ray casting: the camera G-buffer and light-view depth/ID maps.

A ``TriangleScene`` traces a batch of rays in one call that releases the GIL
(``embree4.MeshRays.run``), so the primary rays of a view are traced in
bands on several threads (``trace_pixels``).
Origins, directions and distances are handed over as float32; Embree's tnear
is fixed at 0, so callers that shoot from a surface offset the origin
(``sampling.offset_origin``).
"""
from __future__ import annotations

import copy
import threading
from typing import Optional

import numba
import numpy as np

from .scene import Camera, GBuffer, InstanceGeometry, LightView, MeshInstances, Scene, ViewFace
from . import alpha_rays, embree4, pixel_rays, views
from .motion import blend, move_points
from .sampling import scene_scale
from .kernels import each_in_threads

BATCH = 1 << 20   # rays per BVH call: bounds the float32 temporaries
BAND_RAYS = 1 << 18   # primary rays per band of rows (``trace_pixels``): at most
BANDS_PER_THREAD = 4  # and at least this many bands per thread
_SPLIT_LOCK = threading.Lock()   # ``TriangleScene.transmittance`` splits its BVH once


class TriangleScene:
    """An Embree BVH over a subset of a Scene's triangles.

    ``tri_index`` maps Embree primIDs back to indices into ``Scene.triangles``.
    An empty subset is valid: every ray misses. ``alpha``
    (``alpha_rays.AlphaGeometry``) is set only when one of the triangles has
    an alpha matte: shadow rays then carry a transmittance
    (``transmittance``) and primary rays pass through clear texels
    (``alpha_rays.pass_through``); otherwise nothing changes.

    ``moving`` (``embree4.MeshRays``' groups): triangles that move over the
    shutter; every query then takes each ray's time (``time``, float32 in
    [0, 1]; None: the frame's, ``frame_time``). The matte triangles' own BVH
    (``transmittance``) stands still at the frame.
    """

    def __init__(self, triangles: np.ndarray, tri_index: Optional[np.ndarray] = None,
                 alpha: Optional[alpha_rays.AlphaGeometry] = None, moving=None, frame_time: float = 0.0):
        triangles = np.ascontiguousarray(triangles, np.float32).reshape(-1, 3, 3)
        if tri_index is None:
            tri_index = np.arange(len(triangles), dtype=np.int32)
        self.tri_index = np.asarray(tri_index, np.int32)
        self.count = len(triangles)
        self.alpha = alpha
        self._parts = None
        self._scene = None
        if self.count:
            self._scene = embree4.MeshRays(triangles, moving, frame_time)

    @classmethod
    def from_scene(cls, scene: Scene, mask: np.ndarray) -> "TriangleScene":
        """The triangles ``mask`` selects; those of objects that move over
        the shutter (``Scene.motion``) move with them."""
        idx = np.nonzero(mask)[0].astype(np.int32)
        alpha = None
        if scene.alpha is not None and scene.alpha.any_matte(mask):
            alpha = alpha_rays.AlphaGeometry(scene.alpha.packed(), scene.triangles, scene_scale(*scene.bounds()))
        moving = None
        motion = scene.motion
        if motion is not None and len(motion.objects) and len(idx):
            slot = motion.slot_of(scene.tri_object[idx])
            order = np.argsort(slot, kind="stable")         # the still ones (-1) first, then by object
            idx, slot = idx[order], slot[order]
            ends = np.searchsorted(slot, np.arange(len(motion.objects) + 1) - 0.5)   # the still ones', object j's
            moving = [(int(a), int(b), motion.delta[:, j]) for j, (a, b) in enumerate(zip(ends[:-1], ends[1:]))
                      if b > a] or None
        return cls(scene.triangles[idx], idx, alpha, moving, motion.frame_time if moving else 0.0)

    @staticmethod
    def matte_casters(scene: Scene):
        """(bool over the shadow-casting triangles, in ``Scene.triangles``
        order: has an alpha matte; a TriangleScene of those), or (None, None)
        when none has one: the split of methods that cast opaque triangles
        themselves and leave the matte ones to ``transmittance``."""
        if scene.alpha is None:
            return None, None
        casts = scene.tri_casts_shadow
        has = scene.alpha.tri_matte[casts] >= 0
        if not has.any():
            return None, None
        mask = casts.copy()
        mask[casts] = has
        return has, TriangleScene.from_scene(scene, mask)

    @property
    def empty(self) -> bool:
        """Every ray misses."""
        return self._scene is None

    def at_time(self, t: float) -> "TriangleScene":
        """This BVH with a ray without a time taken at shutter time ``t``
        (the moving triangles where they are then; shares the BVH; itself
        when nothing moves)."""
        if self._scene is None:
            return self
        moved = self._scene.at_time(t)
        if moved is self._scene:
            return self
        other = copy.copy(self)
        other._scene = moved
        return other

    def closest(self, org, dirs, tfar=None, time=None) -> dict:
        """Closest hits of a band of float32 rays in this thread
        (``MeshRays.run``'s dict; ``tfar`` None: unbounded)."""
        kw = {"dists": tfar} if tfar is not None else {}
        return self._scene.run(org, dirs, output=1, time=time, **kw)

    def local_ids(self, tri: np.ndarray) -> np.ndarray:
        """Embree primIDs of the global triangle ids ``tri`` (-1 for -1)."""
        local = np.full(len(self.alpha.triangles) + 1, -1, np.int32)
        local[self.tri_index] = np.arange(self.count, dtype=np.int32)
        return local[tri]

    def transmittance(self, origins, dirs, tfar, time=None) -> np.ndarray:
        """float32[N]: the share of each ray (float32, contiguous) that gets
        through within (0, tfar): 0 or 1 past opaque triangles, the product
        of (1 - alpha) past mattes (``alpha_rays.transmittance``; the opaque
        and the matte triangles get a BVH each, built on first use)."""
        if self.alpha is None:
            return np.where(self.occluded_f32(origins, dirs, np.array(tfar, np.float32), time) == -1,
                            np.float32(1), np.float32(0))
        with _SPLIT_LOCK:
            if self._parts is None:
                self._parts = self._split()
        return alpha_rays.transmittance(self._parts[0], self._parts[1], origins, dirs, tfar)

    def _split(self):
        """(opaque triangles, matte triangles), each a TriangleScene."""
        has = self.alpha.mattes.tri_matte[self.tri_index] >= 0
        tris = self.alpha.triangles[self.tri_index]
        return (TriangleScene(tris[~has], self.tri_index[~has]),
                TriangleScene(tris[has], self.tri_index[has], self.alpha))

    def occluded(self, origins, dirs, tfar, time=None) -> np.ndarray:
        """bool[N]: True where something lies on the ray within (0, tfar)."""
        n = len(origins)
        if self._scene is None or n == 0:
            return np.zeros(n, bool)
        out = np.empty(n, bool)
        for s in range(0, n, BATCH):
            e = min(n, s + BATCH)
            r = self._scene.run(np.ascontiguousarray(origins[s:e], np.float32),
                                np.ascontiguousarray(dirs[s:e], np.float32),
                                dists=np.ascontiguousarray(tfar[s:e], np.float32),
                                query="OCCLUDED", time=None if time is None else time[s:e])
            out[s:e] = r != -1
        return out

    def occluded_f32(self, origins, dirs, tfar, time=None) -> np.ndarray:
        """Like ``occluded`` for arrays already float32 and contiguous; returns
        the BVH's raw int32 result (-1 = unblocked)."""
        if self._scene is None:
            return np.full(len(origins), -1, np.int32)
        return self._scene.run(origins, dirs, dists=tfar, query="OCCLUDED", time=time)

    def intersect(self, origins, dirs, tfar=None, time=None):
        """Closest hits: (global triangle id or -1, t, u, v) as arrays;
        with ``alpha``, the first surface not clear there
        (``alpha_rays.pass_through``)."""
        n = len(origins)
        tri = np.full(n, -1, np.int32)
        t = np.full(n, np.inf, np.float64)
        u = np.zeros(n, np.float64)
        v = np.zeros(n, np.float64)
        if self._scene is None or n == 0:
            return tri, t, u, v
        for s in range(0, n, BATCH):
            e = min(n, s + BATCH)
            kw = {}
            if tfar is not None:
                kw["dists"] = np.array(tfar[s:e], np.float32, copy=True)  # Embree writes hits into it
            o = np.ascontiguousarray(origins[s:e], np.float32)
            d = np.ascontiguousarray(dirs[s:e], np.float32)
            r = self._scene.run(o, d, output=1, time=None if time is None else time[s:e], **kw)
            if self.alpha is not None:     # alpha-tested like the light maps
                tf = (np.array(tfar[s:e], np.float32) if tfar is not None
                      else np.full(e - s, np.inf, np.float32))
                alpha_rays.pass_through(self, lambda: (o, d, tf), r["primID"], r["u"], r["v"], r["tfar"])
            prim = r["primID"]
            hit = prim >= 0
            tri[s:e][hit] = self.tri_index[prim[hit]]
            t[s:e][hit] = r["tfar"][hit]
            u[s:e][hit] = r["u"][hit]
            v[s:e][hit] = r["v"][hit]
        return tri, t, u, v


class InstanceScene:
    """Embree's two-level BVH over some of a Scene's instances
    (``MeshInstances``): the meshes' BVHs (``embree4.Mesh``, shared) under a
    top level over ``selected`` (instance indices). Rays find the instance
    and the triangle of its mesh; ``geometry`` (``InstanceGeometry``) turns
    those into G-buffer entries (``pixel_rays.gbuffer_instances``) and
    object ids, without the flattened soup. No alpha mattes (``alpha``
    None): a scene with mattes is flattened at capture."""

    alpha = None

    def __init__(self, instances: MeshInstances, meshes, selected: np.ndarray,
                 geometry: Optional[InstanceGeometry] = None, motion=None):
        selected = np.asarray(selected, np.int64)
        self.selected = selected
        self.geometry = geometry if geometry is not None else instances.packed()
        self.count = int(instances.instance_triangles()[selected].sum())
        xf = instances.world_from_mesh[selected]
        moving = None
        self.frame_time = None             # a ray without a time: the still scene's (or the frame's)
        if motion is not None and len(motion.objects):
            self.frame_time = motion.frame_time
            slot = motion.slot_of(instances.object_id[selected])
            ids = np.flatnonzero(slot >= 0)
            if len(ids):     # each step's placement: the object's step delta after the frame's
                moving = (ids, np.einsum("kmij,mjl->kmil", motion.delta[:, slot[ids]], xf[ids]))
        self._top = embree4.InstancedScene(meshes, instances.mesh[selected], xf, moving)

    @property
    def empty(self) -> bool:
        return not self._top.handle

    def at_time(self, t: float) -> "InstanceScene":
        """This BVH with a ray without a time taken at shutter time ``t``
        (shares the BVH; itself when nothing moves)."""
        if self.frame_time is None:
            return self
        other = copy.copy(self)
        other.frame_time = float(t)
        return other

    def closest(self, org, dirs, tfar=None, time=None) -> dict:
        """Closest hits of float32 rays in this thread (at their ``time``):
        primID (the triangle in its mesh, -1: none), instance (index in the
        scene's instances), u, v, tfar (a miss keeps its tfar)."""
        time = self.frame_time if time is None else time
        t, inst, prim, u, v, _ = embree4.intersect(self._top, org, dirs, tfar=tfar, threads=1, time=time)
        hit = prim >= 0
        inst[hit] = self.selected[inst[hit]]
        tf = np.full(len(org), 1e37, np.float32) if tfar is None else np.array(tfar, np.float32)
        tf[hit] = t[hit]
        return {"primID": prim.astype(np.int32), "instance": inst, "u": u, "v": v, "tfar": tf}

    def occluded(self, origins, dirs, tfar, time=None) -> np.ndarray:
        """bool[N]: True where something lies on the ray within (0, tfar)."""
        time = self.frame_time if time is None else time
        return embree4.occluded(self._top, origins, dirs, tfar=tfar, threads=1, time=time)

    def transmittance(self, origins, dirs, tfar, time=None) -> np.ndarray:
        """float32[N]: 1 where the ray gets through within (0, tfar), else 0."""
        return np.where(self.occluded(origins, dirs, tfar, time), np.float32(0), np.float32(1))

    def object_ids(self, r: dict) -> np.ndarray:
        """int32 object id of each hit of ``closest``'s result (-1: none)."""
        ids = np.full(len(r["primID"]), -1, np.int32)
        hit = r["primID"] >= 0
        ids[hit] = self.geometry.object_id[r["instance"][hit]]
        return ids


def trace_pixels(tri_scene: TriangleScene, params: np.ndarray, width: int, height: int,
                 bounded: bool, finish, threads: Optional[int] = None) -> None:
    """Trace the rays through every pixel centre of the view ``params``
    (``pixel_rays.pack_rays``) in bands of rows, ``threads`` bands at a time
    (default: Numba's thread count): each band's rays are generated straight
    into float32, traced (``bounded``: they stop at the far plane) and handed
    to ``finish(hits, row0, row1, dirs)`` (hits: ``MeshRays.run``'s dict of
    primID, u, v, tfar, ...; None when the BVH is empty: every ray misses;
    dirs: the band's float32 ray directions).
    Bands hold at most BAND_RAYS rays, and there are at least
    BANDS_PER_THREAD per thread (with as few bands as threads, one slow
    band leaves the other threads idle until it ends).
    The bands write disjoint rows, so the result does not depend on
    ``threads``."""
    workers = max(1, int(threads or numba.get_num_threads()))
    rows = max(1, min(BAND_RAYS // max(1, width), -(-height // (BANDS_PER_THREAD * workers))))
    bands = [(r, min(height, r + rows)) for r in range(0, height, rows)]

    def band(rng):
        row0, row1 = rng
        m = (row1 - row0) * width
        org = np.empty((m, 3), np.float32)
        dirs = np.empty((m, 3), np.float32)
        tfar = np.empty(m, np.float32)
        pixel_rays.make_rays(params, width, height, row0, row1, org, dirs, tfar)
        if tri_scene.empty:
            finish(None, row0, row1, dirs)
            return
        finish(tri_scene.closest(org, dirs, tfar if bounded else None), row0, row1, dirs)

    each_in_threads(band, bands, workers)


def camera_params(cam: Camera, width: int, height: int) -> np.ndarray:
    """The camera's primary rays as ``pixel_rays.pack_rays`` packs them:
    ``views.camera_rays`` (from the near to the far clip plane)."""
    m = np.asarray(cam.world_from_camera, np.float64)
    rot = m[:3, :3] / np.linalg.norm(m[:3, :3], axis=0)
    return pixel_rays.pack_rays(rot, m[:3, 3], views.camera_viewplane(cam, width, height),
                                cam.kind == "ORTHO", cam.clip_start, cam.clip_end)


def face_params(face: ViewFace) -> np.ndarray:
    """A light-view face's rays as ``pixel_rays.pack_rays`` packs them
    (``views.face_rays``: from the eye, unbounded)."""
    inv = np.linalg.inv(np.asarray(face.view_from_world, np.float64))
    return pixel_rays.pack_rays(inv[:3, :3], inv[:3, 3], face.bounds, face.ortho)


def camera_gbuffer(scene: Scene, width: int, height: int,
                   tri_scene: Optional[TriangleScene] = None, threads: Optional[int] = None) -> GBuffer:
    """The camera G-buffer at pixel centres (DESIGN.md "GBuffer").

    Position comes from the hit's barycentrics on the float32 triangle (its
    error does not grow with the ray's length), the geometric normal from the
    triangle's edges, flipped to face the camera; depth is along the view axis
    (``pixel_rays.gbuffer_list``).
    """
    cam: Camera = scene.camera
    if tri_scene is None:
        tri_scene = TriangleScene.from_scene(scene, scene.tri_visible_camera)
    n = width * height
    params = camera_params(cam, width, height)
    pos = np.empty((n, 3), np.float64)
    nrm = np.empty((n, 3), np.float32)
    depth = np.empty(n, np.float32)
    obj = np.empty(n, np.int32)
    tri = np.empty(n, np.int32)
    shade = _hit_shader(scene, tri_scene, params, cam.forward)

    def finish(r, row0, row1, dirs):
        a, b = row0 * width, row1 * width
        if r is None:
            r = {"primID": np.full(b - a, -1, np.int32), "u": np.zeros(b - a, np.float32),
                 "v": np.zeros(b - a, np.float32), "instance": np.full(b - a, -1, np.int64)}
        shade(r, dirs, pos[a:b], nrm[a:b], depth[a:b], obj[a:b], tri[a:b])

    trace_pixels(tri_scene, params, width, height, True, finish, threads)
    if tri_scene.alpha is not None:
        _see_through_mattes(tri_scene, cam, scene.tri_object, pos, nrm, depth, obj, tri)
    return GBuffer(position=pos.reshape(height, width, 3),
                   normal=nrm.reshape(height, width, 3),
                   depth=depth.reshape(height, width),
                   object_id=obj.reshape(height, width),
                   triangle_id=tri.reshape(height, width),
                   hit=(tri >= 0).reshape(height, width))


def camera_gbuffer_at(scene: Scene, width: int, height: int, cols: np.ndarray, rows: np.ndarray,
                      tri_scene: Optional[TriangleScene] = None, threads: Optional[int] = None,
                      packed: bool = False, lens: Optional[np.ndarray] = None,
                      time: Optional[np.ndarray] = None) -> GBuffer:
    """The camera G-buffer of a ``width`` x ``height`` view at the listed
    pixels (cols[i], rows[i]) only (``pixel_filter``'s sub-pixel samples are
    the pixel centres of a supersampled view); every other pixel is empty
    (hit False). Each listed pixel gets the same bits ``camera_gbuffer``
    gives it (``pixel_rays.gbuffer_list``). ``packed``: only the listed
    pixels, as a packed G-buffer (shape (1, N), ``GBuffer.pixel``; dense:
    ``unpack_gbuffer``). ``lens`` (float64[N, 2], ``camera_samples.lens_points``):
    pixel i's ray starts at that camera-local lens point and passes through
    the plane in focus (``pixel_rays.lens_ray_batch``). ``time`` (float32[N]
    in [0, 1], ``camera_samples.shutter_times``): pixel i is seen at that
    shutter time (``Scene.motion``): the camera's ray and the geometry where
    they are then, the entry moved with its object (``motion.move_points``),
    and ``GBuffer.time`` holds it."""
    cam: Camera = scene.camera
    motion = scene.motion if time is not None and scene.motion is not None and scene.motion.moves else None
    if tri_scene is None:
        tri_scene = TriangleScene.from_scene(scene, scene.tri_visible_camera)
    cols = np.ascontiguousarray(cols, np.int64)
    rows = np.ascontiguousarray(rows, np.int64)
    m = len(cols)
    params = camera_params(cam, width, height)
    pos = np.zeros((m, 3), np.float64)
    nrm = np.zeros((m, 3), np.float32)
    depth = np.full(m, np.inf, np.float32)
    obj = np.full(m, -1, np.int32)
    tri = np.full(m, -1, np.int32)
    shade = _hit_shader(scene, tri_scene, params, cam.forward)
    moving_eye = lens is not None or (motion is not None and motion.camera is not None)
    origins = np.zeros((m, 3), np.float64) if moving_eye and tri_scene.alpha is not None else None

    def chunk(rng):
        a, b = rng
        if tri_scene.empty:
            return
        org = np.empty((b - a, 3), np.float32)
        dirs = np.empty((b - a, 3), np.float32)
        tfar = np.empty(b - a, np.float32)
        if lens is None:
            pixel_rays.make_rays_list(params, width, height, cols[a:b], rows[a:b], org, dirs, tfar)
        else:
            pixel_rays.lens_ray_batch(params, width, height, cols[a:b], rows[a:b], lens[a:b],
                                      float(cam.focus_distance), org, dirs, tfar)
        if motion is not None and motion.camera is not None:
            _camera_at(motion, time[a:b], org, dirs)
        if origins is not None:
            origins[a:b] = org
        if motion is None:
            shade(tri_scene.closest(org, dirs, tfar), dirs, pos[a:b], nrm[a:b], depth[a:b], obj[a:b], tri[a:b])
            return
        shade(tri_scene.closest(org, dirs, tfar, time[a:b]), dirs, pos[a:b], nrm[a:b], depth[a:b], obj[a:b],
              tri[a:b])
        moved = move_points(motion, pos[a:b], nrm[a:b], obj[a:b], time[a:b])
        if len(moved):                    # facing the ray again; depth along the frame's view axis
            n, p = nrm[a:b], pos[a:b]
            back = (n[moved] * dirs[moved]).sum(1) > 0
            n[moved[back]] *= -1
            depth[a:b][moved] = (p[moved] - cam.position) @ cam.forward

    each_in_threads(chunk, [(a, min(m, a + BAND_RAYS)) for a in range(0, m, BAND_RAYS)],
                    max(1, int(threads or numba.get_num_threads())))
    if tri_scene.alpha is not None:          # the camera sees through clear texels
        _see_through_mattes(tri_scene, cam, scene.tri_object, pos, nrm, depth, obj, tri, origins)
    g = GBuffer(position=pos.reshape(1, m, 3), normal=nrm.reshape(1, m, 3), depth=depth.reshape(1, m),
                object_id=obj.reshape(1, m), triangle_id=tri.reshape(1, m), hit=(tri >= 0).reshape(1, m),
                pixel=rows * width + cols,
                time=None if time is None else np.asarray(time, np.float32).reshape(1, m))
    return g if packed else unpack_gbuffer(g, width, height)


def _camera_at(motion, time: np.ndarray, org: np.ndarray, dirs: np.ndarray) -> None:
    """Camera rays of the frame (float32, in place) as the camera that moves
    over the shutter casts them at ``time``: each moved by the camera's
    blended delta (``motion.blend``)."""
    D = blend(motion.camera, time)
    o = np.einsum("nij,nj->ni", D[:, :3, :3], org.astype(np.float64)) + D[:, :3, 3]
    d = np.einsum("nij,nj->ni", D[:, :3, :3], dirs.astype(np.float64))
    org[:] = o
    dirs[:] = d / np.linalg.norm(d, axis=1)[:, None]


def _hit_shader(scene: Scene, tri_scene, params, fwd):
    """``shade(hits, dirs, pos, nrm, depth, obj, tri)``: a band's closest
    hits as G-buffer entries, on the flattened triangles
    (``pixel_rays.gbuffer_list``) or on the instances
    (``pixel_rays.gbuffer_instances``)."""
    if isinstance(tri_scene, InstanceScene):
        geo = tri_scene.geometry

        def shade(r, dirs, pos, nrm, depth, obj, tri):
            pixel_rays.gbuffer_instances(params, r["instance"], r["primID"], r["u"], r["v"], geo, fwd, dirs,
                                         pos, nrm, depth, obj, tri)
        return shade
    triangles = np.ascontiguousarray(scene.triangles, np.float32)
    tri_object = np.ascontiguousarray(scene.tri_object, np.int32)

    def shade(r, dirs, pos, nrm, depth, obj, tri):
        pixel_rays.gbuffer_list(params, r["primID"], r["u"], r["v"], tri_scene.tri_index, triangles,
                                tri_object, fwd, dirs, pos, nrm, depth, obj, tri)
    return shade


def unpack_gbuffer(g: GBuffer, width: int, height: int) -> GBuffer:
    """The dense ``width`` x ``height`` G-buffer of packed ``g``: its pixels
    where ``g.pixel`` puts them, every other pixel empty (hit False)."""
    flat = g.pixel
    g_pos = np.zeros((height * width, 3), np.float64)
    g_nrm = np.zeros((height * width, 3), np.float32)
    g_depth = np.full(height * width, np.inf, np.float32)
    g_obj = np.full(height * width, -1, np.int32)
    g_tri = np.full(height * width, -1, np.int32)
    g_pos[flat], g_nrm[flat] = g.position.reshape(-1, 3), g.normal.reshape(-1, 3)
    g_depth[flat], g_obj[flat], g_tri[flat] = g.depth.reshape(-1), g.object_id.reshape(-1), g.triangle_id.reshape(-1)
    g_time = None
    if g.time is not None:
        g_time = np.zeros(height * width, np.float32)
        g_time[flat] = g.time.reshape(-1)
        g_time = g_time.reshape(height, width)
    spread = None
    if g.over_shutter is not None:
        spread = np.zeros(height * width, bool)
        spread[flat] = g.over_shutter.reshape(-1)
        spread = spread.reshape(height, width)
    return GBuffer(position=g_pos.reshape(height, width, 3), normal=g_nrm.reshape(height, width, 3),
                   depth=g_depth.reshape(height, width), object_id=g_obj.reshape(height, width),
                   triangle_id=g_tri.reshape(height, width), hit=(g_tri >= 0).reshape(height, width),
                   time=g_time, over_shutter=spread)


def _see_through_mattes(tri_scene: TriangleScene, cam: Camera, tri_object, pos, nrm, depth, obj, tri,
                        origins: Optional[np.ndarray] = None) -> None:
    """Post-step of ``camera_gbuffer``: pixels whose surface is a
    matte clear there (alpha below ``alpha_rays.ALPHA_CUTOFF``) are re-traced
    from just past it along the same ray (from the eye through the point;
    orthographic: along the view axis; ``origins[i]``, the ray's start, when
    given: through a lens) to the far clip plane, and get the surface they
    stop at (``alpha_rays.pass_through``)."""
    geo = tri_scene.alpha
    pix = np.flatnonzero(tri >= 0)
    pix = pix[geo.mattes.tri_matte[tri[pix]] >= 0]
    if not len(pix):
        return
    P = pos[pix]
    u = np.empty(len(pix), np.float64)
    v = np.empty(len(pix), np.float64)
    alpha_rays.barycentrics(geo.triangles, tri[pix], P, u, v)
    prim = tri_scene.local_ids(tri[pix])
    eye, fwd = cam.position, cam.forward

    def rays():
        if origins is not None:
            d = P - origins[pix]
            d = d / np.linalg.norm(d, axis=1)[:, None]
            tfar = (cam.clip_end - depth[pix].astype(np.float64)) / np.maximum(d @ fwd, 1e-12)
        elif cam.kind == "ORTHO":
            d = np.broadcast_to(fwd, P.shape)
            tfar = cam.clip_end - depth[pix].astype(np.float64)
        else:
            d = P - eye
            dist = np.linalg.norm(d, axis=1)
            d = d / dist[:, None]
            tfar = cam.clip_end / np.maximum(d @ fwd, 1e-12) - dist
        return (P.astype(np.float32), np.ascontiguousarray(d, np.float32),
                np.maximum(tfar, 0.0).astype(np.float32))

    t = np.zeros(len(pix), np.float32)
    seen = alpha_rays.pass_through(tri_scene, rays, prim, u, v, t)
    if len(seen):
        _, d, _ = rays()
        alpha_rays.gbuffer_hits(prim[seen], u[seen], v[seen], d[seen], tri_scene.tri_index, geo.triangles,
                                tri_object, eye, fwd, pix[seen], pos, nrm, depth, obj, tri)


def _band_rays(params, width, height, row0, row1):
    """The rays of rows [row0, row1) of a view (``pixel_rays.make_rays``)."""
    m = (row1 - row0) * width
    org = np.empty((m, 3), np.float32)
    dirs = np.empty((m, 3), np.float32)
    tfar = np.empty(m, np.float32)
    pixel_rays.make_rays(params, width, height, row0, row1, org, dirs, tfar)
    return org, dirs, tfar


def render_face(face: ViewFace, tri_scene: TriangleScene, tri_object: np.ndarray,
                threads: Optional[int] = None):
    """Depth (float32, -z in view space, +inf where empty) and object-id maps
    of one face, by rays through its pixel centres (``pixel_rays.depth_pixels``).
    Alpha mattes are tested: a ray passes through texels with
    alpha below an ordered-dither cutoff (``alpha_rays.DITHER``), so maps
    hold leaf shapes, not cards, and a surface of alpha a in a share a of
    the pixels. ``tri_object``: the id of each triangle; None on an
    ``InstanceScene``, whose ids are its instances' objects."""
    w, h = face.width, face.height
    depth = np.full(h * w, np.inf, np.float32)
    ids = np.full(h * w, -1, np.int32)
    params = face_params(face)
    if tri_object is not None:
        tri_object = np.ascontiguousarray(tri_object, np.int32)

    def finish(r, row0, row1, dirs):
        if r is not None and isinstance(tri_scene, InstanceScene):
            a, b = row0 * w, row1 * w
            ids_of_hits = tri_scene.object_ids(r)
            each = np.arange(b - a, dtype=np.int32)
            pixel_rays.depth_pixels(params, w, h, row0, row1, np.where(ids_of_hits >= 0, each, -1), r["tfar"],
                                    each, ids_of_hits, depth[a:b], ids[a:b])
        elif r is not None:
            a, b = row0 * w, row1 * w
            if tri_scene.alpha is not None:
                alpha_rays.pass_through(tri_scene, lambda: _band_rays(params, w, h, row0, row1),
                                        r["primID"], r["u"], r["v"], r["tfar"],
                                        alpha_rays.dither_band(row0, row1, w), dither=True)
            pixel_rays.depth_pixels(params, w, h, row0, row1, r["primID"], r["tfar"], tri_scene.tri_index,
                                    tri_object, depth[a:b], ids[a:b])

    trace_pixels(tri_scene, params, w, h, False, finish, threads)
    return depth.reshape(h, w), ids.reshape(h, w)


def render_light_view(faces, tri_scene: TriangleScene, tri_object: np.ndarray,
                      eye) -> LightView:
    """A LightView: each face rendered with Embree from the same eye point."""
    if not faces:
        return LightView([], np.zeros((0, 1, 1), np.float32), np.zeros((0, 1, 1), np.int32),
                         np.asarray(eye, np.float64))
    h, w = faces[0].height, faces[0].width
    depth = np.full((len(faces), h, w), np.inf, np.float32)
    ids = np.full((len(faces), h, w), -1, np.int32)
    for k, f in enumerate(faces):
        if (f.height, f.width) != (h, w):
            raise ValueError("faces of one light view must share a resolution")
        depth[k], ids[k] = render_face(f, tri_scene, tri_object)
    return LightView(list(faces), depth, ids, np.asarray(eye, np.float64))
