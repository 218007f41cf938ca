"""Embree 4 called directly: two-level (instanced) scenes and ray queries from
Numba kernels.

embreex wraps a flat triangle scene only; the Embree 4 library it ships
(``embreex.libs`` / ``embreex/.dylibs``) has the rest of Embree's C API.
This module loads that library with ctypes for building scenes (one BVH per
unique mesh, a top level over the instances) and calls ``rtcIntersect1`` /
``rtcOccluded1`` from ``nogil`` Numba kernels through the functions'
addresses (``call3``), so a kernel traces one ray at a time on every thread
without the GIL and without a Python call per ray; the kernels stay in
Numba's on-disk cache because the addresses are arguments, not constants.

Data handed to Embree
---------------------
* a mesh: float32 vertices [V,3] and uint32 triangles [T,3] in the mesh's own
  space (``Mesh``); one BVH each, shared by every instance of it;
* instances: per instance a mesh index and a 4x4 world-from-mesh matrix
  (``InstancedScene``): one Embree instance-array geometry per mesh, holding
  all of that mesh's instances; a hit's ``instPrimID`` and geometry id give
  the instance back (``InstancedScene.instance_of``);
* moving instances: K 4x4 matrices each, evenly over the shutter (t in
  [0, 1]); each is an instance geometry of its own with K time steps, which
  Embree blends linearly at a ray's time (``motion``; rays carry a time).

Every ray cast in Penumbra goes through here: ``MeshRays`` is one world-space
mesh traced in the calling thread behind the batch interface ``raycast``'s
``TriangleScene`` and ``alpha_rays`` use; ``InstancedScene`` with
``intersect`` / ``occluded`` is the two-level form, chunked over threads.

Ray layout (``RTCRayHit``, 16-byte aligned): org xyz, tnear, dir xyz, time,
tfar, mask, id, flags, then the hit: Ng xyz, u, v, primID, geomID,
instID[1], instPrimID[1]. Hits report Ng in the mesh's space; callers turn
it into world space with the instance's normal matrix.
"""
from __future__ import annotations

import copy
import ctypes
import glob
import os
import threading
from typing import List, Optional, Sequence

import numba
import numpy as np
from llvmlite import ir
from numba import types
from numba.extending import intrinsic

from .jit import HOT, inner, kernel
from .kernels import each_in_threads

INVALID_ID = 0xFFFFFFFF
GEOMETRY_TRIANGLE = 0
GEOMETRY_INSTANCE = 121
GEOMETRY_INSTANCE_ARRAY = 122
BUFFER_INDEX, BUFFER_VERTEX, BUFFER_TRANSFORM = 0, 1, 23
FORMAT_UINT3 = 0x5003
FORMAT_FLOAT3 = 0x9003
FORMAT_FLOAT3X4_COLUMN_MAJOR = 0x9234
BUILD_QUALITY_HIGH = 2
SCENE_FLAG_ROBUST = 1 << 2

# float32 slots of an RTCRayHit
RAY_ORG, RAY_TNEAR, RAY_DIR, RAY_TIME, RAY_TFAR = 0, 3, 4, 7, 8
RAY_MASK, RAY_ID, RAY_FLAGS = 9, 10, 11
HIT_NG, HIT_U, HIT_V, HIT_PRIM, HIT_GEOM, HIT_INST, HIT_INST_PRIM = 12, 15, 16, 17, 18, 19, 20
RAYHIT_FLOATS = 24   # 96 bytes: RTCRay (48) + RTCHit (36, padded to 48)

_lock = threading.Lock()
_api = None


class EmbreeLibraryError(RuntimeError):
    """The Embree library embreex ships could not be found or used."""


def _library_path() -> str:
    import embreex.rtcore_scene  # noqa: F401  (loads the library and its TBB)
    root = os.path.dirname(os.path.dirname(os.path.abspath(embreex.rtcore_scene.__file__)))
    pkg = os.path.join(root, "embreex")
    for pattern in ("embreex.libs/*embree4*", "embreex/.dylibs/*embree4*", "embreex/*embree4*"):
        found = sorted(glob.glob(os.path.join(root, pattern)))
        if found:
            return found[0]
    raise EmbreeLibraryError(f"no Embree 4 library beside embreex in {pkg}")


class _Api:
    """The Embree C functions Penumbra uses, with their ctypes signatures."""

    def __init__(self, path: str):
        lib = ctypes.CDLL(path)
        vp, u32, sz = ctypes.c_void_p, ctypes.c_uint32, ctypes.c_size_t
        sigs = {
            "rtcNewDevice": (vp, [ctypes.c_char_p]),
            "rtcGetDeviceError": (ctypes.c_int, [vp]),
            "rtcNewScene": (vp, [vp]),
            "rtcSetSceneBuildQuality": (None, [vp, ctypes.c_int]),
            "rtcSetSceneFlags": (None, [vp, ctypes.c_int]),
            "rtcCommitScene": (None, [vp]),
            "rtcReleaseScene": (None, [vp]),
            "rtcNewGeometry": (vp, [vp, ctypes.c_int]),
            "rtcSetNewGeometryBuffer": (vp, [vp, ctypes.c_int, u32, ctypes.c_int, sz, sz]),
            "rtcSetGeometryInstancedScene": (None, [vp, vp]),
            "rtcSetGeometryTimeStepCount": (None, [vp, u32]),
            "rtcSetGeometryTransform": (None, [vp, u32, ctypes.c_int, vp]),
            "rtcCommitGeometry": (None, [vp]),
            "rtcAttachGeometry": (u32, [vp, vp]),
            "rtcReleaseGeometry": (None, [vp]),
        }
        for name, (res, args) in sigs.items():
            fn = getattr(lib, name)
            fn.restype, fn.argtypes = res, args
            setattr(self, name[3:], fn)
        self.lib = lib
        self.intersect1 = ctypes.cast(lib.rtcIntersect1, vp).value
        self.occluded1 = ctypes.cast(lib.rtcOccluded1, vp).value
        self.device = self.NewDevice(b"threads=0")
        if not self.device:
            raise EmbreeLibraryError("rtcNewDevice failed")

    def check(self, what: str):
        err = self.GetDeviceError(self.device)
        if err:
            raise EmbreeLibraryError(f"Embree error {err} in {what}")


def api() -> _Api:
    """The loaded library and Penumbra's device (made once per process)."""
    global _api
    with _lock:
        if _api is None:
            _api = _Api(_library_path())
        return _api


def _new_scene(a: _Api) -> int:
    """An empty scene: a high-quality BVH, watertight (robust) triangle
    tests as embreex's scenes have, so rays through a shared edge hit."""
    scene = a.NewScene(a.device)
    a.SetSceneFlags(scene, SCENE_FLAG_ROBUST)
    a.SetSceneBuildQuality(scene, BUILD_QUALITY_HIGH)
    return scene


def _copy_into(ptr: int, array: np.ndarray) -> None:
    ctypes.memmove(ptr, np.ascontiguousarray(array).ctypes.data, array.nbytes)


def _add_triangles(a: _Api, scene: int, vertices: np.ndarray, triangles: np.ndarray,
                   steps: Optional[np.ndarray] = None) -> None:
    """Attach a triangle geometry to ``scene``: float32 ``vertices`` [V, 3],
    uint32 ``triangles`` [T, 3]; with ``steps`` (float64[K, 4, 4]) K time
    steps, the vertices placed by each step's matrix."""
    geom = a.NewGeometry(a.device, GEOMETRY_TRIANGLE)
    if steps is None:
        _copy_into(a.SetNewGeometryBuffer(geom, BUFFER_VERTEX, 0, FORMAT_FLOAT3, 12, len(vertices)), vertices)
    else:
        a.SetGeometryTimeStepCount(geom, len(steps))
        v64 = vertices.astype(np.float64)
        for k, m in enumerate(steps):
            vk = (v64 @ m[:3, :3].T + m[:3, 3]).astype(np.float32)
            _copy_into(a.SetNewGeometryBuffer(geom, BUFFER_VERTEX, k, FORMAT_FLOAT3, 12, len(vertices)), vk)
    _copy_into(a.SetNewGeometryBuffer(geom, BUFFER_INDEX, 0, FORMAT_UINT3, 12, len(triangles)), triangles)
    a.CommitGeometry(geom)
    a.AttachGeometry(scene, geom)
    a.ReleaseGeometry(geom)


class Mesh:
    """One BVH over a triangle mesh in its own space (float32 vertices [V,3],
    triangles [T,3] of vertex indices; or triangles float32[T,3,3] with
    ``vertices=None``). An empty mesh has no BVH (``handle`` 0)."""

    def __init__(self, vertices: Optional[np.ndarray], triangles: np.ndarray):
        if vertices is None:
            tris = np.asarray(triangles, np.float32).reshape(-1, 3, 3)
            vertices = tris.reshape(-1, 3)
            triangles = np.arange(len(vertices), dtype=np.uint32).reshape(-1, 3)
        vertices = np.ascontiguousarray(vertices, np.float32).reshape(-1, 3)
        triangles = np.ascontiguousarray(triangles, np.uint32).reshape(-1, 3)
        self.count = len(triangles)
        self.handle = 0
        if not self.count:
            return
        a = api()
        scene = _new_scene(a)
        _add_triangles(a, scene, vertices, triangles)
        a.CommitScene(scene)
        a.check("building a mesh BVH")
        self.handle = scene

    def __del__(self):
        if self.handle and _api is not None:
            _api.ReleaseScene(self.handle)
            self.handle = 0


class InstancedScene:
    """A top level over instances of ``meshes`` (``Mesh`` list): instance i
    is ``meshes[mesh_of[i]]`` placed by ``world_from_mesh[i]`` (4x4). Empty
    meshes, meshes without instances and instances whose matrix is singular
    or not finite (they cover no area) are left out; with nothing left every
    ray misses. A hit's instance is ``order[first[geomID] + instPrimID]``.

    ``motion`` (moving instance ids int[m], their matrices float64[K, m, 4, 4]
    at K >= 2 times evenly over the shutter; ``world_from_mesh`` still gives
    their normal matrix): those instances move, each an instance geometry
    with K time steps; rays then carry a time in [0, 1].

    ``intersect`` and ``occluded`` trace float32 rays in chunks on Numba's
    thread count (the kernels release the GIL)."""

    def __init__(self, meshes: Sequence[Mesh], mesh_of: np.ndarray, world_from_mesh: np.ndarray,
                 motion: Optional[tuple] = None):
        mesh_of = np.asarray(mesh_of, np.int64)
        xf = np.asarray(world_from_mesh, np.float64).reshape(-1, 4, 4)
        self.meshes = list(meshes)       # the top level instances their BVHs
        self.handle = 0
        det = np.linalg.det(xf[:, :3, :3]) if len(xf) else np.zeros(0)
        placed = np.isfinite(xf).all(axis=(1, 2)) & (np.abs(det) > 0)
        moving = np.zeros(len(xf), bool)
        if motion is not None:
            moving[np.asarray(motion[0], np.int64)] = True
        order = np.nonzero(placed & ~moving)[0]
        order = order[np.argsort(mesh_of[order], kind="stable")]
        firsts: List[int] = []
        a = api()
        scene = _new_scene(a)
        start = 0
        attached = 0
        bounds = np.searchsorted(mesh_of[order], np.arange(len(self.meshes) + 1))
        keep = []
        for m, mesh in enumerate(self.meshes):
            lo, hi = bounds[m], bounds[m + 1]
            if hi == lo or not mesh.handle:
                continue
            ids = order[lo:hi]
            geom = a.NewGeometry(a.device, GEOMETRY_INSTANCE_ARRAY)
            a.SetGeometryInstancedScene(geom, mesh.handle)
            cols = np.ascontiguousarray(np.transpose(xf[ids, :3, :4], (0, 2, 1)), np.float32)
            _copy_into(a.SetNewGeometryBuffer(geom, BUFFER_TRANSFORM, 0, FORMAT_FLOAT3X4_COLUMN_MAJOR,
                                              48, len(ids)), cols)
            _attach(a, scene, geom, attached)
            firsts.append(start)
            keep.append(ids)
            start += len(ids)
            attached += 1
        if motion is not None:
            for j, i in enumerate(np.asarray(motion[0], np.int64)):
                steps = np.asarray(motion[1], np.float64)[:, j]
                if not np.isfinite(steps).all() or not self.meshes[mesh_of[i]].handle:
                    continue
                geom = a.NewGeometry(a.device, GEOMETRY_INSTANCE)
                a.SetGeometryInstancedScene(geom, self.meshes[mesh_of[i]].handle)
                a.SetGeometryTimeStepCount(geom, len(steps))
                for k, m in enumerate(steps):
                    cols = np.ascontiguousarray(m[:3, :4].T, np.float32)
                    a.SetGeometryTransform(geom, k, FORMAT_FLOAT3X4_COLUMN_MAJOR, cols.ctypes.data)
                _attach(a, scene, geom, attached)
                firsts.append(start)
                keep.append(np.array([i], np.int64))
                start += 1
                attached += 1
        if not attached:
            a.ReleaseScene(scene)
            scene = 0
        else:
            a.CommitScene(scene)
            a.check("building the instance top level")
        self.handle = scene
        self.first = np.asarray(firsts + [start], np.int64)
        self.order = np.concatenate(keep).astype(np.int64) if keep else np.zeros(0, np.int64)
        self.normal_matrix = np.zeros((len(xf), 3, 3), np.float64)
        if placed.any():
            self.normal_matrix[placed] = np.transpose(np.linalg.inv(xf[placed, :3, :3]), (0, 2, 1))

    def __del__(self):
        if self.handle and _api is not None:
            _api.ReleaseScene(self.handle)
            self.handle = 0


def _attach(a: _Api, scene: int, geom: int, expect: int) -> None:
    """Commit ``geom`` and attach it to ``scene`` as geometry id ``expect``
    (the scene keeps it; the caller's reference is released)."""
    a.CommitGeometry(geom)
    gid = a.AttachGeometry(scene, geom)
    a.ReleaseGeometry(geom)
    if gid != expect:
        raise EmbreeLibraryError("unexpected geometry id")


@intrinsic
def call3(typingctx, fn, a, b, c):
    """Call the C function ``void fn(void*, void*, void*)`` at address ``fn``
    with three addresses (integers)."""
    if not all(isinstance(t, types.Integer) for t in (fn, a, b, c)):
        return None
    sig = types.void(fn, a, b, c)

    def codegen(context, builder, signature, args):
        i8p = ir.IntType(8).as_pointer()
        fnty = ir.FunctionType(ir.VoidType(), [i8p, i8p, i8p])
        vals = [context.cast(builder, v, t, types.uintp) for v, t in zip(args, signature.args)]
        ptr = builder.inttoptr(vals[0], fnty.as_pointer())
        builder.call(ptr, [builder.inttoptr(v, i8p) for v in vals[1:]])
        return context.get_dummy_value()
    return sig, codegen



@inner(inline="always")
def _rayhit_buffer():
    """A zeroed float32 RTCRayHit on 16 bytes (and its uint32 view, address)."""
    buf = np.zeros(RAYHIT_FLOATS + 4, np.float32)
    base = buf.ctypes.data
    off = (((base + 15) & ~np.uintp(15)) - base) // 4
    f = buf[off:off + RAYHIT_FLOATS]
    return f, f.view(np.uint32), base + off * 4


@inner(inline="always")
def _load_ray(f, w, org, dirs, tnear, tfar, time, i):
    """Ray i into the RTCRay at the start of ``f`` (float32) / ``w`` (uint32);
    its time ``time[i]`` (``time`` empty: 0, a still scene's)."""
    for k in range(3):
        f[RAY_ORG + k] = org[i, k]
        f[RAY_DIR + k] = dirs[i, k]
    f[RAY_TNEAR] = tnear[i]
    f[RAY_TIME] = time[i] if time.shape[0] else 0.0
    f[RAY_TFAR] = tfar[i]
    w[RAY_MASK] = INVALID_ID
    w[RAY_ID] = 0
    w[RAY_FLAGS] = 0


@kernel(nogil=True, opt=HOT)
def intersect_range(fn, scene, org, dirs, tnear, tfar, time, first, order, normal_matrix,
                    t_out, inst_out, prim_out, u_out, v_out, ng_out, i0, i1):
    """Closest hits of rays i0..i1: t (inf: none), instance (-1), primID,
    u, v and the world-space geometric normal (unit, not flipped). A
    ``scene`` that is one mesh's BVH, with no top level, reports instance 0
    (``first`` = [0, 1], ``order`` = [0], ``normal_matrix`` the identity).
    ``time``: each ray's time (empty: 0)."""
    f, w, addr = _rayhit_buffer()
    for i in range(i0, i1):
        _load_ray(f, w, org, dirs, tnear, tfar, time, i)
        w[HIT_GEOM] = INVALID_ID
        w[HIT_INST] = INVALID_ID
        w[HIT_INST_PRIM] = INVALID_ID
        call3(fn, scene, addr, 0)
        g = w[HIT_GEOM]
        if g == INVALID_ID:
            t_out[i] = np.inf
            inst_out[i] = -1
            prim_out[i] = -1
            continue
        gi = w[HIT_INST]
        ip = w[HIT_INST_PRIM]
        inst = 0 if gi == INVALID_ID else order[first[gi] + (0 if ip == INVALID_ID else ip)]
        t_out[i] = f[RAY_TFAR]
        inst_out[i] = inst
        prim_out[i] = w[HIT_PRIM]
        u_out[i] = f[HIT_U]
        v_out[i] = f[HIT_V]
        nx = f[HIT_NG]
        ny = f[HIT_NG + 1]
        nz = f[HIT_NG + 2]
        m = normal_matrix[inst]
        wx = m[0, 0] * nx + m[0, 1] * ny + m[0, 2] * nz
        wy = m[1, 0] * nx + m[1, 1] * ny + m[1, 2] * nz
        wz = m[2, 0] * nx + m[2, 1] * ny + m[2, 2] * nz
        ln = np.sqrt(wx * wx + wy * wy + wz * wz)
        if ln > 0:
            wx /= ln
            wy /= ln
            wz /= ln
        ng_out[i, 0] = wx
        ng_out[i, 1] = wy
        ng_out[i, 2] = wz


@kernel(nogil=True, opt=HOT)
def occluded_range(fn, scene, org, dirs, tnear, tfar, time, out, i0, i1):
    """out[i] = True where something lies on ray i within (tnear, tfar) at
    its time ``time[i]`` (empty: 0)."""
    f, w, addr = _rayhit_buffer()
    for i in range(i0, i1):
        _load_ray(f, w, org, dirs, tnear, tfar, time, i)
        call3(fn, scene, addr, 0)
        out[i] = f[RAY_TFAR] < 0.0


CHUNK = 1 << 14   # rays per kernel call: the unit of work a thread takes


def _chunks(n: int):
    return [(s, min(n, s + CHUNK)) for s in range(0, n, CHUNK)]


def _as_rays(org, dirs, tnear, tfar):
    n = len(org)
    org = np.ascontiguousarray(org, np.float32).reshape(n, 3)
    dirs = np.ascontiguousarray(dirs, np.float32).reshape(n, 3)
    tnear = np.broadcast_to(np.asarray(0.0 if tnear is None else tnear, np.float32), (n,))
    tfar = np.broadcast_to(np.asarray(np.inf if tfar is None else tfar, np.float32), (n,))
    return n, org, dirs, np.ascontiguousarray(tnear), np.ascontiguousarray(tfar)


_STILL = np.zeros(0, np.float32)     # rays without a time (a still scene's: 0)


def _times(time, n: int) -> np.ndarray:
    """float32[n] ray times in [0, 1] (``_STILL`` for None)."""
    return _STILL if time is None else np.ascontiguousarray(np.broadcast_to(np.asarray(time, np.float32), (n,)))


def _no_hits(n: int):
    """``intersect``'s arrays for n rays, every one a miss."""
    return (np.full(n, np.inf, np.float32), np.full(n, -1, np.int64), np.full(n, -1, np.int64),
            np.zeros(n, np.float32), np.zeros(n, np.float32), np.zeros((n, 3), np.float32))


def intersect(scene: InstancedScene, org, dirs, tnear=None, tfar=None, threads=None, time=None):
    """Closest hits of the rays (at their ``time``, None: 0): (t float32
    (inf: none), instance int64 (-1), prim int64 (-1), u, v float32, world
    geometric normal float32[N,3])."""
    n, org, dirs, tnear, tfar = _as_rays(org, dirs, tnear, tfar)
    time = _times(time, n)
    t, inst, prim, u, v, ng = _no_hits(n)
    if scene.handle and n:
        fn = api().intersect1

        def one(rng):
            intersect_range(fn, scene.handle, org, dirs, tnear, tfar, time, scene.first, scene.order,
                            scene.normal_matrix, t, inst, prim, u, v, ng, rng[0], rng[1])
        each_in_threads(one, _chunks(n), _workers(threads))
    return t, inst, prim, u, v, ng


def occluded(scene: InstancedScene, org, dirs, tnear=None, tfar=None, threads=None, time=None) -> np.ndarray:
    """bool[N]: True where something lies on the ray within (tnear, tfar)
    at its ``time`` (None: 0)."""
    n, org, dirs, tnear, tfar = _as_rays(org, dirs, tnear, tfar)
    time = _times(time, n)
    out = np.zeros(n, bool)
    if scene.handle and n:
        fn = api().occluded1

        def one(rng):
            occluded_range(fn, scene.handle, org, dirs, tnear, tfar, time, out, rng[0], rng[1])
        each_in_threads(one, _chunks(n), _workers(threads))
    return out


def _workers(threads) -> int:
    return max(1, int(threads or numba.get_num_threads()))


class MotionTriangles:
    """One BVH over triangles float32[T, 3, 3] of which the groups
    ``moving`` (a list of (start, stop, float64[K, 4, 4])) move: a triangle
    geometry of the still ones and one per group with K time steps, its
    vertices placed by each step's matrix (Embree blends vertices linearly
    between steps). Rays carry a time; hits report no triangle (for
    occlusion queries)."""

    def __init__(self, triangles: np.ndarray, moving: Sequence[tuple]):
        tris = np.asarray(triangles, np.float32).reshape(-1, 3, 3)
        still = np.ones(len(tris), bool)
        for a_, b_, _ in moving:
            still[a_:b_] = False
        a = api()
        scene = _new_scene(a)
        parts = [(tris[still], None)] + [(tris[a_:b_], np.asarray(steps, np.float64)) for a_, b_, steps in moving]
        for part, steps in parts:
            if len(part):
                v = np.ascontiguousarray(part.reshape(-1, 3))
                _add_triangles(a, scene, v, np.arange(len(v), dtype=np.uint32).reshape(-1, 3), steps)
        a.CommitScene(scene)
        a.check("building a moving triangles' BVH")
        self.handle = scene

    def __del__(self):
        if self.handle and _api is not None:
            _api.ReleaseScene(self.handle)
            self.handle = 0


class MeshRays:
    """One triangle mesh (float32[T,3,3], world space) traced in the calling
    thread with embreex's ``EmbreeScene.run`` contract, which the ray casting
    in ``raycast`` and ``alpha_rays`` is written against: rays start at
    t = 0 and end at ``dists`` (default 1e37); ``query="OCCLUDED"`` returns
    int32 0 (blocked) / -1 (free); ``output=1`` a dict of primID (int32, -1
    for a miss), u, v, tfar (the hit's t; a miss keeps its tfar; a ``dists``
    array given is overwritten with these) and geomID. The mesh is one
    BVH (``Mesh``), traced without a top level.

    ``moving`` (a list of (start, stop, float64[K, 4, 4])): triangles
    [start, stop) move rigidly over the shutter by those K matrices (taking
    them from where ``triangles`` has them, evenly over t in [0, 1]); each
    such group, and the still rest, gets a BVH of its own under a top level
    whose moving instances Embree blends at a ray's time (``run``'s
    ``time``, float32 per ray in [0, 1]; None: ``frame_time``, where
    ``triangles`` has them); primIDs stay indices into ``triangles``.
    Occlusion queries go to a second BVH, built on the first of them
    (``MotionTriangles``): the still triangles and each moving group's
    vertices at its K steps, which Embree blends linearly as the matrices
    are (the same places at every time), without a top level to cross."""

    def __init__(self, triangles: np.ndarray, moving: Optional[Sequence[tuple]] = None, frame_time: float = 0.0):
        self.frame_time = float(frame_time)
        self.first = np.array([0, 1], np.int64)
        self.order = np.zeros(1, np.int64)
        self.normal_matrix = np.eye(3)[None]
        self.start = np.zeros(1, np.int64)      # per instance of the top level: its first triangle
        if not moving:
            self.mesh = Mesh(None, triangles)
            self.handle = self.mesh.handle
            return
        tris = np.asarray(triangles, np.float32).reshape(-1, 3, 3)
        still = np.ones(len(tris), bool)
        groups = []
        for a, b, steps in moving:
            still[a:b] = False
            groups.append((np.arange(a, b), np.asarray(steps, np.float64)))
        groups.insert(0, (np.flatnonzero(still), None))
        self.index = np.concatenate([g[0] for g in groups]).astype(np.int64)   # top-level order -> triangle
        self.start = np.cumsum([0] + [len(g[0]) for g in groups])[:-1].astype(np.int64)
        meshes = [Mesh(None, tris[g[0]]) for g in groups]
        eye = np.broadcast_to(np.eye(4), (len(groups), 4, 4))
        self.top = InstancedScene(meshes, np.arange(len(groups)), eye,
                                  motion=(np.arange(1, len(groups)), np.stack([g[1] for g in groups[1:]], 1)))
        self.mesh = None
        self.handle = self.top.handle
        self.first, self.order, self.normal_matrix = self.top.first, self.top.order, self.top.normal_matrix
        self._occluder = {"bvh": None, "lock": threading.Lock(), "from": (tris, moving)}   # shared by ``at_time``

    def _occlusion_bvh(self) -> "MotionTriangles":
        """The occlusion queries' BVH (built on first use)."""
        occ = self._occluder
        with occ["lock"]:
            if occ["bvh"] is None:
                occ["bvh"] = MotionTriangles(*occ.pop("from"))
        return occ["bvh"]

    def at_time(self, t: float) -> "MeshRays":
        """These rays' BVH with a ray without a time taken at shutter time
        ``t`` instead of ``frame_time`` (shares the BVH; itself when nothing
        moves)."""
        if self.mesh is not None:
            return self
        other = copy.copy(self)
        other.frame_time = float(t)
        return other

    def run(self, origins, dirs, dists=None, query="INTERSECT", output=None, time=None):
        n = len(origins)
        if dists is None or np.isscalar(dists):
            tfar = np.full(n, 1e37 if dists is None else dists, np.float32)
        else:
            tfar = dists
        org = np.ascontiguousarray(origins, np.float32)
        d = np.ascontiguousarray(dirs, np.float32)
        tnear = np.zeros(n, np.float32)
        time = _times(self.frame_time if time is None and self.mesh is None else time, n)
        a = api()
        if query == "OCCLUDED":
            hit = np.zeros(n, bool)
            handle = self.handle if self.mesh is not None else self._occlusion_bvh().handle
            if handle:
                occluded_range(a.occluded1, handle, org, d, tnear, tfar, time, hit, 0, n)
            return np.where(hit, np.int32(0), np.int32(-1))
        if query != "INTERSECT":
            raise ValueError(f"unknown ray query {query!r}")
        t, inst, prim, u, v, ng = _no_hits(n)
        if self.handle:
            intersect_range(a.intersect1, self.handle, org, d, tnear, np.ascontiguousarray(tfar, np.float32), time,
                            self.first, self.order, self.normal_matrix, t, inst, prim, u, v, ng, 0, n)
            if self.mesh is None:                 # moving groups: back to indices into the triangles
                ok = prim >= 0
                prim[ok] = self.index[self.start[inst[ok]] + prim[ok]]
        primID = prim.astype(np.int32)
        if not output:
            return primID
        hit = primID >= 0
        tfar[hit] = t[hit]
        return {"primID": primID, "geomID": np.where(hit, np.int32(0), np.int32(-1)),
                "u": u, "v": v, "tfar": tfar, "Ng": ng}
