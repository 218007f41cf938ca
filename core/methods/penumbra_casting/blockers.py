"""Blocker polygons of hierarchical penumbra casting: coplanar triangles
merged into convex polygons (Laine & Aila 2005, section 5: "process multiple
blocker triangles simultaneously"), and the coarse sort by area (section 3.3).

Edge-adjacent triangles that lie in one plane and together form a convex
polygon of at most ``MAXB`` corners are cast as that polygon: a Blender quad
becomes one blocker, and so does a subdivided flat face. The union of the
triangles is the polygon, so the blocked relations are the same except for
rays within rounding of the removed inner edges.

Representation: ``polys`` float64[M, MAXB, 3] with ``nverts`` int64[M]; a
triangle is stored with its last corner repeated (its box is unchanged and
no code reads past ``nverts``). Corners follow the first triangle's winding,
so the polygon's plane (Newell's normal) is oriented like it.

Greedy region growing: each unassigned triangle seeds a polygon; a neighbour
sharing a whole polygon edge is added when every corner of the grown polygon
lies within ``PLANE_ULPS`` float32 ULPs (of the largest coordinate involved)
of its plane (the receivers sit 32 ULPs off their surface, so a merged plane
cannot swing past one), the polygon stays strictly convex, and, corners that
became collinear dropped, it has at most MAXB corners. Vertices are
identified by bit-equal coordinates; an edge joins two triangles only when
exactly two share it.
"""
from __future__ import annotations

import numpy as np

from ...jit import inner, kernel
from .geometry import MAXB     # corners per blocker polygon (one more plane test per sample and corner)

PLANE_ULPS = 4.0    # coplanarity / collinearity tolerance in float32 ULPs
_ULP32 = 2.0 ** -23


def pad_triangles(tris: np.ndarray):
    """Triangles float[T,3,3] as blocker polygons (no merging)."""
    n = len(tris)
    polys = np.empty((n, MAXB, 3), np.float64)
    polys[:, :3] = tris
    polys[:, 3:] = tris[:, 2:3]
    return polys, np.full(n, 3, np.int64)


def _adjacency(ids: np.ndarray, nonmanifold: bool = False):
    """nbr[t, e]: the triangle sharing edge e = (ids[t, e], ids[t, e+1]) with t
    when exactly two triangles share it, else -1 (vectorized edge sort);
    ``nonmanifold``: also whether some edge is shared by three or more."""
    n = len(ids)
    a = ids[:, [0, 1, 2]].ravel()
    b = ids[:, [1, 2, 0]].ravel()
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    order = np.lexsort((hi, lo))
    lo_s, hi_s = lo[order], hi[order]
    same = (lo_s[1:] == lo_s[:-1]) & (hi_s[1:] == hi_s[:-1])
    # runs of exactly two: the pair (k, k+1) equal, and neither (k-1, k) nor (k+1, k+2)
    prev_same = np.concatenate([[False], same[:-1]])
    next_same = np.concatenate([same[1:], [False]])
    pair = same & ~prev_same & ~next_same
    k = np.flatnonzero(pair)
    nbr = np.full(3 * n, -1, np.int64)
    e0, e1 = order[k], order[k + 1]
    t0, t1 = e0 // 3, e1 // 3
    ok = t0 != t1
    nbr[e0[ok]] = t1[ok]
    nbr[e1[ok]] = t0[ok]
    if nonmanifold:
        return nbr.reshape(n, 3), bool(np.any(same & prev_same))
    return nbr.reshape(n, 3)


@inner
def _turn(P, u, v, p, q, r):
    """2D cross product (q - p) x (r - q) in the plane basis (u, v), and the
    length of r - p (the collinearity yardstick)."""
    px = P[p, 0] * u[0] + P[p, 1] * u[1] + P[p, 2] * u[2]
    py = P[p, 0] * v[0] + P[p, 1] * v[1] + P[p, 2] * v[2]
    qx = P[q, 0] * u[0] + P[q, 1] * u[1] + P[q, 2] * u[2]
    qy = P[q, 0] * v[0] + P[q, 1] * v[1] + P[q, 2] * v[2]
    rx = P[r, 0] * u[0] + P[r, 1] * u[1] + P[r, 2] * u[2]
    ry = P[r, 0] * v[0] + P[r, 1] * v[1] + P[r, 2] * v[2]
    cr = (qx - px) * (ry - qy) - (qy - py) * (rx - qx)
    dot = (qx - px) * (rx - qx) + (qy - py) * (ry - qy)
    ln = np.sqrt((rx - px) ** 2 + (ry - py) ** 2)
    return cr, dot, ln


@inner
def _planar(P, c, k, tol):
    """Corners ``P[c[:k]]`` within ``tol`` of their best plane (Newell's
    normal through their centroid)."""
    nx = ny = nz = 0.0
    mx = my = mz = 0.0
    for j in range(k):
        p = c[j]
        q = c[(j + 1) % k]
        nx += (P[p, 1] - P[q, 1]) * (P[p, 2] + P[q, 2])
        ny += (P[p, 2] - P[q, 2]) * (P[p, 0] + P[q, 0])
        nz += (P[p, 0] - P[q, 0]) * (P[p, 1] + P[q, 1])
        mx += P[p, 0]
        my += P[p, 1]
        mz += P[p, 2]
    nl = np.sqrt(nx * nx + ny * ny + nz * nz)
    if not (nl > 0.0):
        return False
    nx, ny, nz = nx / nl, ny / nl, nz / nl
    off = (nx * mx + ny * my + nz * mz) / k
    for j in range(k):
        p = c[j]
        if abs(nx * P[p, 0] + ny * P[p, 1] + nz * P[p, 2] - off) > tol:
            return False
    return True


@kernel
def _grow(P, ids, nbr, maxb, ulps):
    """Greedy coplanar convex merging; returns polygon vertex ids [M, maxb],
    corner counts [M] and the polygon of every triangle [T]."""
    n = ids.shape[0]
    poly_of = np.full(n, -1, np.int64)
    out = np.empty((n, maxb), np.int64)
    nout = np.empty(n, np.int64)
    tried = np.full(n, -1, np.int64)
    stack = np.empty(3 * n + 3, np.int64)
    cur = np.empty(maxb + 1, np.int64)
    nxt = np.empty(maxb + 2, np.int64)
    u = np.empty(3)
    v = np.empty(3)
    m = 0
    for seed in range(n):
        if poly_of[seed] >= 0:
            continue
        a, b, c = ids[seed, 0], ids[seed, 1], ids[seed, 2]
        poly_of[seed] = m
        for j in range(3):
            cur[j] = ids[seed, j]
        k = 3
        ex, ey, ez = P[b, 0] - P[a, 0], P[b, 1] - P[a, 1], P[b, 2] - P[a, 2]
        fx, fy, fz = P[c, 0] - P[a, 0], P[c, 1] - P[a, 1], P[c, 2] - P[a, 2]
        nx, ny, nz = ey * fz - ez * fy, ez * fx - ex * fz, ex * fy - ey * fx
        nl = np.sqrt(nx * nx + ny * ny + nz * nz)
        el = np.sqrt(ex * ex + ey * ey + ez * ez)
        mag = 0.0
        for j in range(3):
            for d in range(3):
                mag = max(mag, abs(P[ids[seed, j], d]))
        if not (nl > 1e-12 * el * el) or a == b or b == c or a == c:
            for j in range(maxb):
                out[m, j] = cur[min(j, 2)]
            nout[m] = 3
            m += 1
            continue                      # degenerate: a triangle of its own
        nx, ny, nz = nx / nl, ny / nl, nz / nl
        # plane basis: u along the first edge, v = n x u (winding positive)
        u[0], u[1], u[2] = ex / el, ey / el, ez / el
        v[0], v[1], v[2] = ny * u[2] - nz * u[1], nz * u[0] - nx * u[2], nx * u[1] - ny * u[0]
        sp = 0
        for e in range(3):
            if nbr[seed, e] >= 0:
                stack[sp] = nbr[seed, e]
                sp += 1
        while sp > 0:
            sp -= 1
            t = stack[sp]
            if poly_of[t] >= 0 or tried[t] == m:
                continue
            tried[t] = m
            # the edge t shares with the polygon's triangles
            ins = -1
            w = -1
            for e in range(3):
                o = nbr[t, e]
                if o < 0 or poly_of[o] != m:
                    continue
                p0, p1, p2 = ids[t, e], ids[t, (e + 1) % 3], ids[t, (e + 2) % 3]
                for j in range(k):
                    q0, q1 = cur[j], cur[(j + 1) % k]
                    if (q0 == p0 and q1 == p1) or (q0 == p1 and q1 == p0):
                        ins = j
                        w = p2
                        break
                if ins >= 0:
                    break
            if ins < 0:
                continue
            dup = False
            for j in range(k):
                if cur[j] == w:
                    dup = True
            if dup:
                continue
            mg = mag
            for d in range(3):
                mg = max(mg, abs(P[w, d]))
            tol = ulps * _ULP32 * mg
            # insert w after position ins
            kk = np.int64(0)              # not a literal: _planar compiles once
            for j in range(k):
                nxt[kk] = cur[j]
                kk += 1
                if j == ins:
                    nxt[kk] = w
                    kk += 1
            # every corner within tol of the grown polygon's own plane (Newell's
            # normal: a small seed triangle's plane, extrapolated along a long
            # face, would drift by more than the rounding of its vertices)
            if not _planar(P, nxt, kk, tol):
                continue
            # drop corners that became collinear
            changed = True
            while changed and kk > 3:
                changed = False
                for j in range(kk):
                    cr, dot, ln = _turn(P, u, v, nxt[(j - 1) % kk], nxt[j], nxt[(j + 1) % kk])
                    if abs(cr) <= tol * ln and dot > 0.0:
                        for jj in range(j, kk - 1):
                            nxt[jj] = nxt[jj + 1]
                        kk -= 1
                        changed = True
                        break
            if kk > maxb:
                continue
            convex = True
            for j in range(kk):
                cr, dot, ln = _turn(P, u, v, nxt[(j - 1) % kk], nxt[j], nxt[(j + 1) % kk])
                if not (cr > tol * ln):
                    convex = False
                    break
            if not convex:
                continue
            for j in range(kk):
                cur[j] = nxt[j]
            k = kk
            mag = mg
            poly_of[t] = m
            for e in range(3):
                o = nbr[t, e]
                if o >= 0 and poly_of[o] < 0:
                    stack[sp] = o
                    sp += 1
        for j in range(maxb):
            out[m, j] = cur[min(j, k - 1)]     # the last corner repeated
        nout[m] = k
        m += 1
    return out[:m], nout[:m], poly_of


def _unique_vertices(V: np.ndarray):
    """Vertex identity: equal coordinates (a mesh's triangles share them).
    ``np.unique(V, axis=0, return_inverse=True)`` (the same lexicographic
    order and ids) by one lexsort of the three columns, not the slow
    structured-array sort ``np.unique`` makes."""
    order = np.lexsort((V[:, 2], V[:, 1], V[:, 0]))
    s = V[order]
    first = np.empty(len(V), np.bool_)
    first[:1] = True
    first[1:] = np.any(s[1:] != s[:-1], axis=1)
    inv = np.empty(len(V), np.int64)
    inv[order] = np.cumsum(first) - 1
    return np.ascontiguousarray(s[first]), inv


def sub_mesh(mesh, sel: np.ndarray):
    """``mesh`` = (P, ids, nbr, nonmanifold) of some triangles restricted to
    triangles ``sel`` (indices): the same as building it from them, unless
    an edge of the whole is shared by three or more (None then)."""
    P, ids, nbr, nonmanifold = mesh
    if nonmanifold:
        return None
    remap = np.full(len(ids) + 1, -1, np.int64)
    remap[sel] = np.arange(len(sel))
    sub = nbr[sel]
    return P, np.ascontiguousarray(ids[sel]), np.ascontiguousarray(remap[sub]), False


def coplanar_blockers(tris: np.ndarray, max_corners: int = MAXB, mesh=None):
    """Merge edge-adjacent coplanar triangles float64[T,3,3] into convex
    polygons of at most ``max_corners`` (3..MAXB) corners; returns (polys
    float64[M, MAXB, 3], nverts int64[M], poly_of int64[T]: the polygon
    holding each triangle). ``mesh``: their vertices, vertex ids and
    adjacency already built (``sub_mesh``)."""
    max_corners = min(MAXB, max(3, int(max_corners)))
    tris = np.ascontiguousarray(tris, np.float64)
    n = len(tris)
    if n == 0:
        return np.zeros((0, MAXB, 3)), np.zeros(0, np.int64), np.zeros(0, np.int64)
    if mesh is not None:
        P, ids, nbr = mesh[0], mesh[1], mesh[2]
    else:
        P, inv = _unique_vertices(tris.reshape(-1, 3))
        ids = np.ascontiguousarray(inv.reshape(n, 3), np.int64)
        nbr = _adjacency(ids)
    vid, nv, poly_of = _grow(P, ids, nbr, max_corners, PLANE_ULPS)
    if max_corners < MAXB:                           # the last corner repeated
        vid = np.concatenate([vid, np.repeat(vid[:, -1:], MAXB - max_corners, 1)], 1)
    polys = P[vid]                                   # [M, MAXB, 3]
    return np.ascontiguousarray(polys), nv, poly_of


def bucket_sort_by_area(tris, nverts, nb):
    """Coarse blocker sorting (section 3.3): bucket by area on a log scale
    into ``nb`` buckets, largest first; linear time (histogram + counting
    sort: a stable sort of small integers), stable. A polygon's area is half
    its Newell normal (``geometry._newell``) over its ``nverts`` corners.
    NumPy, not a kernel: nothing to compile on a cold start."""
    n = tris.shape[0]
    out = np.arange(n, dtype=np.int64)
    if n == 0:
        return out
    t = tris.transpose(1, 2, 0)                          # [corner, axis, blocker]
    u, v = t[1] - t[0], t[2] - t[0]
    c = np.stack([u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]])
    poly = np.flatnonzero(nverts > 3)
    if len(poly):
        p = tris[poly]
        nv = nverts[poly][:, None]
        j = np.arange(p.shape[1])
        used = j < nv                                    # corners past nverts add no term
        q = np.take_along_axis(p, np.where(j + 1 < nv, j + 1, 0)[..., None], 1)   # the next corner
        c[:, poly] = np.stack([((p[..., 1] - q[..., 1]) * (p[..., 2] + q[..., 2]) * used).sum(1),
                               ((p[..., 2] - q[..., 2]) * (p[..., 0] + q[..., 0]) * used).sum(1),
                               ((p[..., 0] - q[..., 0]) * (p[..., 1] + q[..., 1]) * used).sum(1)])
    area = 0.5 * np.sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2])
    pos = area > 0.0
    if not pos.any():
        return out
    la = np.log(area[pos])
    lo, hi = la.min(), la.max()
    if not (hi > lo):
        return out
    bucket = np.full(n, nb - 1, np.int64)
    bucket[pos] = np.clip(((hi - la) / (hi - lo) * nb).astype(np.int64), 0, nb - 1)
    if nb <= 1 << 15:
        bucket = bucket.astype(np.int16)                 # NumPy's stable sort of 16-bit keys: a radix sort
    return np.argsort(bucket, kind="stable").astype(np.int64, copy=False)
