"""Mesh adjacency and silhouette edges for soft irregular shadow mapping
(Johnson et al. 2009, section 2.1).

Adjacency is rebuilt from the triangle soup by hashing vertex positions
(float32 bit patterns plus the object id, so touching objects are not
stitched together) and then undirected edges (pairs of vertex ids); both
hash tables are open-addressing tables in Numba, O(n).

Which triangles count as occluders ("counted"):
  equation 4 sums occluders independently (C = 0, section 5.2). A closed
  mesh seen from the light centre has two layers wherever it has one (front
  and back faces), which would double every penumbra. So for a *closed*,
  consistently wound component (every edge shared by exactly two triangles
  traversing it in opposite directions) only one layer counts: the faces
  through which rays from the light centre *enter* the solid (outward normal
  facing the centre), or, when the centre is inside the solid (generalized
  winding number), the faces through which they leave it. Open components
  (planes, non-manifold or inconsistently wound pieces) count every triangle.
  The umbra (depth complexity) and the penumbra both use counted triangles
  only, so every triangle's contribution stays exact (see ``geom``).

Records (silhouette edges):
  one record per (counted triangle, edge). A manifold edge whose two
  triangles are both counted and face the same way as seen from the light
  centre is not a silhouette: the two records cancel exactly (their
  projections lie on opposite sides of the edge) and both are dropped. All
  others are kept: silhouettes between a counted and an uncounted face,
  folds of open surfaces (kept twice: both layers end there), boundary and
  non-manifold edges. Without adjacency every edge of every triangle is a
  record ("we assume all edges are silhouettes", section 2.1).
"""
from __future__ import annotations

import math

import numpy as np

from ...jit import inner, kernel
from .geom import SILHOUETTE_CENTRE


@inner
def _mix(h, x):
    h = (h ^ np.uint64(x)) * np.uint64(1099511628211)
    return h ^ (h >> np.uint64(29))


@kernel
def vertex_ids(bits):
    """bits: uint32[M, 4] (x, y, z float32 bit patterns, object id) ->
    int64[M] ids of equal keys, number of distinct keys."""
    M = bits.shape[0]
    size = 16
    while size < 2 * M:
        size <<= 1
    mask = np.uint64(size - 1)
    table = np.full(size, -1, np.int64)
    ids = np.empty(M, np.int64)
    nv = 0
    for i in range(M):
        h = np.uint64(14695981039346656037)
        for j in range(4):
            h = _mix(h, np.uint64(bits[i, j]))
        s = h & mask
        while True:
            j = table[s]
            if j == -1:
                table[s] = i
                ids[i] = nv
                nv += 1
                break
            if (bits[j, 0] == bits[i, 0] and bits[j, 1] == bits[i, 1]
                    and bits[j, 2] == bits[i, 2] and bits[j, 3] == bits[i, 3]):
                ids[i] = ids[j]
                break
            s = (s + np.uint64(1)) & mask
    return ids, nv


@inner
def _find(parent, i):
    r = i
    while parent[r] != r:
        r = parent[r]
    while parent[i] != r:
        n = parent[i]
        parent[i] = r
        i = n
    return r


@kernel
def build_edges(vid, nv):
    """vid: int64[T, 3] vertex ids. Returns per-triangle edge ids
    tri_edge int64[T, 3] (-1 for collapsed triangles), per-edge count,
    first two (triangle, direction) uses, and the component root of every
    triangle (union-find over shared edges)."""
    T = vid.shape[0]
    size = 16
    while size < 6 * T:
        size <<= 1
    mask = np.uint64(size - 1)
    table = np.full(size, -1, np.int64)
    keys = np.empty(3 * T, np.int64)
    tri_edge = np.full((T, 3), -1, np.int64)
    count = np.zeros(3 * T, np.int64)
    t0 = np.full(3 * T, -1, np.int64)
    t1 = np.full(3 * T, -1, np.int64)
    d0 = np.zeros(3 * T, np.int8)
    d1 = np.zeros(3 * T, np.int8)
    ne = 0
    for t in range(T):
        a, b, c = vid[t, 0], vid[t, 1], vid[t, 2]
        if a == b or b == c or a == c:
            continue
        for k in range(3):
            u = vid[t, k]
            v = vid[t, (k + 1) % 3]
            lo = min(u, v)
            hi = max(u, v)
            direction = 1 if u == lo else 0
            key = lo * nv + hi
            h = _mix(np.uint64(14695981039346656037), np.uint64(key))
            s = h & mask
            while True:
                e = table[s]
                if e == -1:
                    e = ne
                    table[s] = e
                    keys[e] = key
                    ne += 1
                    break
                if keys[e] == key:
                    break
                s = (s + np.uint64(1)) & mask
            tri_edge[t, k] = e
            if count[e] == 0:
                t0[e] = t
                d0[e] = direction
            elif count[e] == 1:
                t1[e] = t
                d1[e] = direction
            count[e] += 1
    parent = np.arange(T)
    for t in range(T):
        for k in range(3):
            e = tri_edge[t, k]
            if e >= 0 and count[e] >= 2:
                ra = _find(parent, t)
                rb = _find(parent, t0[e])
                if ra != rb:
                    if ra < rb:
                        parent[rb] = ra
                    else:
                        parent[ra] = rb
    root = np.empty(T, np.int64)
    for t in range(T):
        root[t] = _find(parent, t)
    closed = np.ones(T, np.bool_)
    for t in range(T):
        for k in range(3):
            e = tri_edge[t, k]
            if e < 0 or not (count[e] == 2 and d0[e] != d1[e]):
                closed[root[t]] = False
    return tri_edge, count[:ne], t0[:ne], t1[:ne], d0[:ne], d1[:ne], root, closed


@inner
def _solid_angle(ax, ay, az, bx, by, bz, cx, cy, cz):
    """Van Oosterom & Strackee: signed solid angle of a triangle seen from 0."""
    la = math.sqrt(ax * ax + ay * ay + az * az)
    lb = math.sqrt(bx * bx + by * by + bz * bz)
    lc = math.sqrt(cx * cx + cy * cy + cz * cz)
    det = ax * (by * cz - bz * cy) - ay * (bx * cz - bz * cx) + az * (bx * cy - by * cx)
    den = (la * lb * lc + (ax * bx + ay * by + az * bz) * lc
           + (ax * cx + ay * cy + az * cz) * lb + (bx * cx + by * cy + bz * cz) * la)
    return 2.0 * math.atan2(det, den)


@kernel
def classify(tv, nv, valid, tri_edge, count, t0, t1, d0, d1, root, closed,
             cx, cy, cz, is_sun, use_adjacency, silhouettes_only, mode, reach):
    """Counted triangles and silhouette records for one light.

    tv float64[T,3,3], nv float64[T,3] (unnormalized normals), valid: nonzero
    normal. For a sun (cx, cy, cz) is the unit direction towards it.
    ``mode`` SILHOUETTE_CENTRE (the paper): counted = entries from the light
    centre for closed components (exits when the centre is inside), records
    = edges that are silhouettes from the centre. SILHOUETTE_LIGHT (receiver):
    the umbra counts the exits from the centre (= entries seen from the receiver),
    the penumbra decides per receiver (``orient``), and records are the
    edges that are silhouettes from *some* point of the light (its bounding
    ball of radius ``reach``; sun: directions within asin(reach) of it).
    Returns counted bool[T], facing int8[T], orient int8[T] (orientation of
    the closed component, 0 = open) and the records (triangle, edge)."""
    T = tv.shape[0]
    facing = np.zeros(T, np.int8)
    for t in range(T):
        if not valid[t]:
            continue
        if is_sun:
            s = nv[t, 0] * cx + nv[t, 1] * cy + nv[t, 2] * cz
        else:
            s = (nv[t, 0] * (cx - tv[t, 0, 0]) + nv[t, 1] * (cy - tv[t, 0, 1])
                 + nv[t, 2] * (cz - tv[t, 0, 2]))
        facing[t] = 1 if s > 0.0 else (-1 if s < 0.0 else 0)
    vol = np.zeros(T)
    wind = np.zeros(T)
    if use_adjacency:
        for t in range(T):
            r = root[t]
            if not closed[r]:
                continue
            ox, oy, oz = (0.0, 0.0, 0.0) if is_sun else (cx, cy, cz)
            ax, ay, az = tv[t, 0, 0] - ox, tv[t, 0, 1] - oy, tv[t, 0, 2] - oz
            bx, by, bz = tv[t, 1, 0] - ox, tv[t, 1, 1] - oy, tv[t, 1, 2] - oz
            qx, qy, qz = tv[t, 2, 0] - ox, tv[t, 2, 1] - oy, tv[t, 2, 2] - oz
            vol[r] += (ax * (by * qz - bz * qy) - ay * (bx * qz - bz * qx)
                       + az * (bx * qy - by * qx)) / 6.0
            if not is_sun and mode == SILHOUETTE_CENTRE:
                wind[r] += _solid_angle(ax, ay, az, bx, by, bz, qx, qy, qz)
    counted = np.zeros(T, np.bool_)
    orient = np.zeros(T, np.int8)
    for t in range(T):
        if not valid[t]:
            continue
        r = root[t]
        if use_adjacency and closed[r] and vol[r] != 0.0:
            o = 1 if vol[r] > 0.0 else -1
            orient[t] = o
            f = facing[t] * o
            if mode == SILHOUETTE_CENTRE:
                inside = abs(wind[r]) > 2.0 * math.pi      # winding number > 1/2
                counted[t] = (f < 0) if inside else (f > 0)
            else:
                counted[t] = f < 0
        else:
            counted[t] = True
    n = 0
    keep = np.zeros((T, 3), np.bool_)
    for t in range(T):
        if not valid[t] or (mode == SILHOUETTE_CENTRE and not counted[t]):
            continue
        for k in range(3):
            ok = True
            if use_adjacency and silhouettes_only:
                e = tri_edge[t, k]
                if e >= 0 and count[e] == 2 and d0[e] != d1[e]:
                    o = t1[e] if t0[e] == t else t0[e]
                    if mode == SILHOUETTE_CENTRE:
                        if counted[o] and facing[o] == facing[t] and facing[t] != 0:
                            ok = False
                    elif valid[o] and facing[o] == facing[t] and facing[t] != 0:
                        # silhouette from no point of the light's bounding ball?
                        far = True
                        for u in (t, o):
                            ln = math.sqrt(nv[u, 0] ** 2 + nv[u, 1] ** 2 + nv[u, 2] ** 2)
                            if is_sun:
                                dd = (nv[u, 0] * cx + nv[u, 1] * cy + nv[u, 2] * cz) / ln
                            else:
                                dd = (nv[u, 0] * (cx - tv[u, 0, 0]) + nv[u, 1] * (cy - tv[u, 0, 1])
                                      + nv[u, 2] * (cz - tv[u, 0, 2])) / ln
                            if abs(dd) <= reach * (1.0 + 1e-9):
                                far = False
                        if far:
                            ok = False
            if ok:
                keep[t, k] = True
                n += 1
    rec_t = np.empty(n, np.int64)
    rec_k = np.empty(n, np.int64)
    j = 0
    for t in range(T):
        for k in range(3):
            if keep[t, k]:
                rec_t[j] = t
                rec_k[j] = k
                j += 1
    return counted, facing, orient, rec_t, rec_k


def mesh_adjacency(triangles: np.ndarray, tri_object: np.ndarray):
    """Light-independent part: vertex ids by position hashing, edges,
    components and their closedness."""
    T = len(triangles)
    f32 = np.ascontiguousarray(triangles, np.float32).reshape(T * 3, 3) + np.float32(0.0)  # -0 -> +0
    bits = np.empty((T * 3, 4), np.uint32)
    bits[:, :3] = f32.view(np.uint32)
    bits[:, 3] = np.repeat(np.asarray(tri_object, np.int64), 3).astype(np.uint32)
    ids, nv = vertex_ids(bits)
    return build_edges(ids.reshape(T, 3), max(int(nv), 1))
