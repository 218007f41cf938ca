"""Embree ray casting (embreex): the camera G-buffer and light-view depth/ID maps.

embreex's ``run()`` is vectorized (one call per batch) and holds the GIL.
Origins, directions and distances are handed over as float32; Embree's tnear
is fixed at 0, so callers that shoot from a surface offset the origin
(``sampling.offset_origin``).
"""
from __future__ import annotations

from typing import Optional

import numpy as np

from .scene import GBuffer, LightView, Scene, ViewFace, Camera
from . import views

BATCH = 1 << 20   # rays per embreex call: bounds the float32 temporaries


class TriangleScene:
    """An Embree BVH over a subset of a Scene's triangles.

    ``tri_index`` maps Embree primIDs back to indices into ``Scene.triangles``.
    An empty subset is valid: every ray misses.
    """

    def __init__(self, triangles: np.ndarray, tri_index: Optional[np.ndarray] = None):
        triangles = np.ascontiguousarray(triangles, np.float32).reshape(-1, 3, 3)
        if tri_index is None:
            tri_index = np.arange(len(triangles), dtype=np.int32)
        self.tri_index = np.asarray(tri_index, np.int32)
        self.count = len(triangles)
        self._scene = None
        if self.count:
            from embreex import rtcore_scene as rtcs
            from embreex.mesh_construction import TriangleMesh
            self._scene = rtcs.EmbreeScene()
            self._mesh = TriangleMesh(self._scene, triangles)

    @classmethod
    def from_scene(cls, scene: Scene, mask: np.ndarray) -> "TriangleScene":
        idx = np.nonzero(mask)[0].astype(np.int32)
        return cls(scene.triangles[idx], idx)

    def occluded(self, origins, dirs, tfar) -> np.ndarray:
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
                                query="OCCLUDED")
            out[s:e] = r != -1
        return out

    def occluded_f32(self, origins, dirs, tfar) -> np.ndarray:
        """Like ``occluded`` for arrays already float32 and contiguous; returns
        embreex's raw int32 result (-1 = unblocked)."""
        if self._scene is None:
            return np.full(len(origins), -1, np.int32)
        return self._scene.run(origins, dirs, dists=tfar, query="OCCLUDED")

    def intersect(self, origins, dirs, tfar=None):
        """Closest hits: (global triangle id or -1, t, u, v) as arrays."""
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
            r = self._scene.run(np.ascontiguousarray(origins[s:e], np.float32),
                                np.ascontiguousarray(dirs[s:e], np.float32),
                                output=1, **kw)
            prim = r["primID"]
            hit = prim >= 0
            tri[s:e][hit] = self.tri_index[prim[hit]]
            t[s:e][hit] = r["tfar"][hit]
            u[s:e][hit] = r["u"][hit]
            v[s:e][hit] = r["v"][hit]
        return tri, t, u, v


def camera_gbuffer(scene: Scene, width: int, height: int,
                   tri_scene: Optional[TriangleScene] = None) -> GBuffer:
    """The camera G-buffer at pixel centres (DESIGN.md "GBuffer").

    Position comes from the hit's barycentrics on the float32 triangle (its
    error does not grow with the ray's length), the geometric normal from the
    triangle's edges, flipped to face the camera; depth is along the view axis.
    """
    cam: Camera = scene.camera
    if tri_scene is None:
        tri_scene = TriangleScene.from_scene(scene, scene.tri_visible_camera)
    org, d, tfar, axis_scale = views.camera_rays(cam, width, height)
    n = width * height
    tri, t, u, v = tri_scene.intersect(org.reshape(n, 3), d.reshape(n, 3), tfar.reshape(n))
    hit = tri >= 0
    pos = np.zeros((n, 3), np.float64)
    nrm = np.zeros((n, 3), np.float32)
    if hit.any():
        T = scene.triangles[tri[hit]].astype(np.float64)
        uu, vv = u[hit][:, None], v[hit][:, None]
        pos[hit] = (1.0 - uu - vv) * T[:, 0] + uu * T[:, 1] + vv * T[:, 2]
        ng = np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0])
        ln = np.linalg.norm(ng, axis=1, keepdims=True)
        ng = np.where(ln > 0, ng / np.where(ln > 0, ln, 1.0), 0.0)
        dh = d.reshape(n, 3)[hit]
        flip = np.einsum("ij,ij->i", ng, dh) > 0
        ng[flip] *= -1.0
        nrm[hit] = ng.astype(np.float32)
    depth = np.full(n, np.inf, np.float32)
    if hit.any():
        depth[hit] = ((pos[hit] - cam.position) @ cam.forward).astype(np.float32)
    obj = np.full(n, -1, np.int32)
    obj[hit] = scene.tri_object[tri[hit]]
    return GBuffer(position=pos.reshape(height, width, 3),
                   normal=nrm.reshape(height, width, 3),
                   depth=depth.reshape(height, width),
                   object_id=obj.reshape(height, width),
                   triangle_id=tri.reshape(height, width),
                   hit=hit.reshape(height, width))


def render_face(face: ViewFace, tri_scene: TriangleScene, tri_object: np.ndarray):
    """Depth (float32, -z in view space, +inf where empty) and object-id maps
    of one face, by rays through its pixel centres."""
    org, d, scale = views.face_rays(face)
    n = face.width * face.height
    tri, t, _, _ = tri_scene.intersect(org.reshape(n, 3), d.reshape(n, 3))
    hit = tri >= 0
    depth = np.full(n, np.inf, np.float32)
    depth[hit] = (t[hit] * scale.reshape(n)[hit]).astype(np.float32)
    ids = np.full(n, -1, np.int32)
    ids[hit] = tri_object[tri[hit]]
    return depth.reshape(face.height, face.width), ids.reshape(face.height, face.width)


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
