"""Primary rays through pixel centres, fused: ray generation straight into
the ray caster's float32 arrays, and the hits turned into G-buffer / depth-map
pixels in one pass (no float64 temporaries, no boolean gathers). Each kernel
works on a band of rows ``[row0, row1)`` (its arrays hold that band only) and
releases the GIL, so ``raycast`` runs bands on several threads, each one
generating, tracing (the ray caster releases the GIL too) and finishing its own.

The formulas are ``views.camera_rays`` / ``views.face_rays`` and the
G-buffer's hit post-processing written in NumPy, operation for operation, so
the buffers are bit-identical to those (NumPy's 3x3 products go through
BLAS, which may fuse multiply-adds: those agree with these to the float64
ulp, and the float32 ray each feeds Embree is the same).

A view is packed as float64[RAY_PARAMS] (``pack_rays``): world-from-view
rotation (row-major), eye, view-plane window (xmin, xmax, ymin, ymax: at
unit distance for perspective, scene units for orthographic), ortho flag,
near (rays start there along the view axis), far (view-axis depth where rays
stop; inf: unbounded).
"""
from __future__ import annotations

import math

import numpy as np

from .jit import inner, kernel

ROT, EYE, WINDOW, ORTHO, NEAR, FAR = 0, 9, 12, 16, 17, 18
RAY_PARAMS = 19


def pack_rays(rotation, eye, window, ortho: bool, near: float = 0.0, far: float = math.inf) -> np.ndarray:
    """float64[RAY_PARAMS] for the kernels below (see the module docstring)."""
    p = np.zeros(RAY_PARAMS, np.float64)
    p[ROT:ROT + 9] = np.asarray(rotation, np.float64).reshape(9)
    p[EYE:EYE + 3] = eye
    p[WINDOW:WINDOW + 4] = window
    p[ORTHO] = 1.0 if ortho else 0.0
    p[NEAR] = near
    p[FAR] = far
    return p


@kernel(inline="always")
def _local_xy(p, col, row, width, height):
    """View-plane point of the pixel centre (col + 0.5, row + 0.5)."""
    x = p[WINDOW] + (col + 0.5) / width * (p[WINDOW + 1] - p[WINDOW])
    y = p[WINDOW + 3] - (row + 0.5) / height * (p[WINDOW + 3] - p[WINDOW + 2])
    return x, y


@kernel(inline="always")
def _ray(p, col, row, width, height):
    """(origin, unit direction, view-axis depth per unit of ray length) of one
    pixel's ray, float64, as ``views.camera_rays`` computes them."""
    x, y = _local_xy(p, col, row, width, height)
    if p[ORTHO] == 1.0:
        z = -p[NEAR]
        ox = x * p[0] + y * p[1] + z * p[2] + p[EYE]
        oy = x * p[3] + y * p[4] + z * p[5] + p[EYE + 1]
        oz = x * p[6] + y * p[7] + z * p[8] + p[EYE + 2]
        return ox, oy, oz, -p[2], -p[5], -p[8], 1.0
    n = math.sqrt(x * x + y * y + 1.0)
    lx, ly, lz = x / n, y / n, -1.0 / n
    dx = lx * p[0] + ly * p[1] + lz * p[2]
    dy = lx * p[3] + ly * p[4] + lz * p[5]
    dz = lx * p[6] + ly * p[7] + lz * p[8]
    axis = 1.0 / n
    s = p[NEAR] / axis
    return p[EYE] + dx * s, p[EYE + 1] + dy * s, p[EYE + 2] + dz * s, dx, dy, dz, axis


@kernel(inline="always")
def _put_ray(p, col, row, width, height, i, org, dirs, tfar):
    """Ray i of a batch: pixel (col, row)'s, as float32."""
    ox, oy, oz, dx, dy, dz, axis = _ray(p, col, row, width, height)
    org[i, 0], org[i, 1], org[i, 2] = ox, oy, oz
    dirs[i, 0], dirs[i, 1], dirs[i, 2] = dx, dy, dz
    tfar[i] = (p[FAR] - p[NEAR]) / axis


_NO_PIXELS = np.empty(0, np.int64)


def make_rays(p, width, height, row0, row1, org, dirs, tfar):
    """float32 origins [N,3], unit directions [N,3] and ray lengths [N] (to
    the far plane) through the pixel centres of rows [row0, row1), row-major."""
    pixel_ray_batch(p, width, height, row0, row1, _NO_PIXELS, _NO_PIXELS, org, dirs, tfar)


def make_rays_list(p, width, height, cols, rows, org, dirs, tfar):
    """``make_rays`` for the listed pixels (cols[i], rows[i]) only: a sparse
    set of sub-pixel samples is the pixel centres of a supersampled view."""
    pixel_ray_batch(p, width, height, 0, 0, cols, rows, org, dirs, tfar)


@kernel(nogil=True)
def pixel_ray_batch(p, width, height, row0, row1, cols, rows, org, dirs, tfar):
    """``make_rays`` (``cols`` empty) or ``make_rays_list``: one kernel for
    both (two kernels would each compile the inlined ``_put_ray``)."""
    if cols.shape[0] == 0:
        for row in range(row0, row1):
            for col in range(width):
                _put_ray(p, col, row, width, height, (row - row0) * width + col, org, dirs, tfar)
    else:
        for i in range(cols.shape[0]):
            _put_ray(p, cols[i], rows[i], width, height, i, org, dirs, tfar)


@kernel(nogil=True)
def lens_ray_batch(p, width, height, cols, rows, lens, focus, org, dirs, tfar):
    """``make_rays_list`` through a thin lens (``camera_samples``): ray i
    starts at camera-local lens point (lens[i, 0], lens[i, 1], 0) and passes
    through the point where pixel (cols[i], rows[i])'s pinhole ray meets the
    plane ``focus`` along the view axis, as Cycles' camera does; it starts
    where Cycles clips it (the pinhole ray's near-plane scale along it) and
    ends at the far plane's."""
    for i in range(cols.shape[0]):
        x, y = _local_xy(p, cols[i], rows[i], width, height)
        lx, ly = lens[i, 0], lens[i, 1]
        if p[ORTHO] == 1.0:
            ax, ay, az = -lx, -ly, -focus           # towards the in-focus point of the pinhole ray
            n = math.sqrt(ax * ax + ay * ay + az * az)
            ax, ay, az = ax / n, ay / n, az / n
            s0 = p[NEAR] / -az
            length = p[FAR] - p[NEAR]
            ox, oy, oz = x + lx + ax * s0, y + ly + ay * s0, az * s0
        else:
            ax, ay, az = x * focus - lx, y * focus - ly, -focus
            n = math.sqrt(ax * ax + ay * ay + az * az)
            ax, ay, az = ax / n, ay / n, az / n
            scale = math.sqrt(x * x + y * y + 1.0)  # Cycles: near and far along the pinhole ray
            s0 = p[NEAR] * scale
            length = (p[FAR] - p[NEAR]) * scale
            ox, oy, oz = lx + ax * s0, ly + ay * s0, az * s0
        org[i, 0] = ox * p[0] + oy * p[1] + oz * p[2] + p[EYE]
        org[i, 1] = ox * p[3] + oy * p[4] + oz * p[5] + p[EYE + 1]
        org[i, 2] = ox * p[6] + oy * p[7] + oz * p[8] + p[EYE + 2]
        dirs[i, 0] = ax * p[0] + ay * p[1] + az * p[2]
        dirs[i, 1] = ax * p[3] + ay * p[4] + az * p[5]
        dirs[i, 2] = ax * p[6] + ay * p[7] + az * p[8]
        tfar[i] = length


@kernel(inline="always")
def _gbuffer_miss(i, position, normal, depth, object_id, triangle_id):
    """An empty G-buffer entry i (nothing hit)."""
    position[i, 0], position[i, 1], position[i, 2] = 0.0, 0.0, 0.0
    normal[i, 0], normal[i, 1], normal[i, 2] = 0.0, 0.0, 0.0
    depth[i] = np.inf
    object_id[i] = -1
    triangle_id[i] = -1


@inner
def _gbuffer_hit(p, i, prim, u, v, tri_index, triangles, tri_object, fwd, dirs,
                 position, normal, depth, object_id, triangle_id):
    """``gbuffer_list``' body for hit i, traced along ``dirs[i]``."""
    t = tri_index[prim[i]]
    triangle_id[i] = t
    object_id[i] = tri_object[t]
    corner = np.empty((3, 3), np.float64)
    for c in range(3):
        for r in range(3):
            corner[c, r] = np.float64(triangles[t, c, r])
    _shade_hit(p, i, corner, np.float64(u[i]), np.float64(v[i]), fwd, dirs, position, normal, depth)


@inner
def _shade_hit(p, i, corner, uu, vv, fwd, dirs, position, normal, depth):
    """G-buffer entry i of a hit at barycentrics (uu, vv) on the triangle
    ``corner`` (float64[3,3]): position, normal facing the ray, depth."""
    a0, a1, a2 = corner[0, 0], corner[0, 1], corner[0, 2]
    b0, b1, b2 = corner[1, 0], corner[1, 1], corner[1, 2]
    c0, c1, c2 = corner[2, 0], corner[2, 1], corner[2, 2]
    w = 1.0 - uu - vv
    px = w * a0 + uu * b0 + vv * c0
    py = w * a1 + uu * b1 + vv * c1
    pz = w * a2 + uu * b2 + vv * c2
    position[i, 0], position[i, 1], position[i, 2] = px, py, pz
    e0, e1, e2 = b0 - a0, b1 - a1, b2 - a2
    f0, f1, f2 = c0 - a0, c1 - a1, c2 - a2
    n0 = e1 * f2 - e2 * f1
    n1 = e2 * f0 - e0 * f2
    n2 = e0 * f1 - e1 * f0
    ln = math.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
    if ln > 0:
        n0, n1, n2 = n0 / ln, n1 / ln, n2 / ln
    else:
        n0, n1, n2 = 0.0, 0.0, 0.0
    dx, dy, dz = dirs[i, 0], dirs[i, 1], dirs[i, 2]     # the float32 ray Embree traced
    if n0 * dx + n1 * dy + n2 * dz > 0:
        n0, n1, n2 = -n0, -n1, -n2
    normal[i, 0], normal[i, 1], normal[i, 2] = n0, n1, n2
    depth[i] = (px - p[EYE]) * fwd[0] + (py - p[EYE + 1]) * fwd[1] + (pz - p[EYE + 2]) * fwd[2]


@kernel(nogil=True)
def gbuffer_list(p, prim, u, v, tri_index, triangles, tri_object, fwd, dirs,
                 position, normal, depth, object_id, triangle_id):
    """Embree's closest hits (local primID, u, v) of rays ``dirs`` (a band
    of pixel rows, ``make_rays``, or a pixel list, ``make_rays_list``: entry
    i is ray i) -> G-buffer entries: position from the barycentrics on the
    float32 triangle, in float64; the geometric normal, unit, flipped to
    face the ray; depth along the view axis ``fwd`` from the eye; object and
    global triangle ids (-1, +inf, 0 where empty)."""
    for i in range(prim.shape[0]):
        if prim[i] < 0:
            _gbuffer_miss(i, position, normal, depth, object_id, triangle_id)
        else:
            _gbuffer_hit(p, i, prim, u, v, tri_index, triangles, tri_object, fwd, dirs,
                         position, normal, depth, object_id, triangle_id)


@kernel(nogil=True)
def depth_pixels(p, width, height, row0, row1, prim, t, tri_index, tri_object, depth, object_id):
    """Embree's closest hits -> a light view's pixels: depth along the view
    axis (ray length times its cosine to the axis; +inf where empty) and
    object id (-1 where empty)."""
    for row in range(row0, row1):
        for col in range(width):
            i = (row - row0) * width + col
            if prim[i] < 0:
                depth[i] = np.inf
                object_id[i] = -1
                continue
            if p[ORTHO] == 1.0:
                axis = 1.0
            else:
                x, y = _local_xy(p, col, row, width, height)
                axis = 1.0 / math.sqrt(x * x + y * y + 1.0)
            depth[i] = np.float64(t[i]) * axis
            object_id[i] = tri_object[tri_index[prim[i]]]


@kernel(nogil=True)
def gbuffer_instances(p, inst, prim, u, v, geo, fwd, dirs, position, normal, depth, object_id, triangle_id):
    """``gbuffer_list`` for hits on instances (instance ``inst[i]``, triangle
    ``prim[i]`` of its mesh): the triangle is placed in float64 by the
    instance's matrix and rounded to float32, as ``MeshInstances.flatten``
    places it, then shaded as ``gbuffer_list`` does; its triangle id is its
    index in the flattened soup. ``geo``: ``InstanceGeometry``."""
    for i in range(prim.shape[0]):
        if prim[i] < 0:
            _gbuffer_miss(i, position, normal, depth, object_id, triangle_id)
            continue
        k = inst[i]
        m = geo.mesh[k]
        f = geo.face_start[m] + prim[i]
        corner = np.empty((3, 3), np.float64)
        for c in range(3):
            vtx = geo.vertex_start[m] + geo.faces[f, c]
            x, y, z = geo.vertices[vtx, 0], geo.vertices[vtx, 1], geo.vertices[vtx, 2]
            for r in range(3):
                w = geo.world_from_mesh[k, r, 0] * x + geo.world_from_mesh[k, r, 1] * y \
                    + geo.world_from_mesh[k, r, 2] * z + geo.world_from_mesh[k, r, 3]
                corner[c, r] = np.float64(np.float32(w))
        triangle_id[i] = geo.triangle_offset[k] + prim[i]
        object_id[i] = geo.object_id[k]
        _shade_hit(p, i, corner, np.float64(u[i]), np.float64(v[i]), fwd, dirs, position, normal, depth)
