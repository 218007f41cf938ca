"""Interior blockers of closed meshes: the most powerful occluders of a
smooth solid, cast first (issue 17; Laine & Aila 2005, section 3.3: "it is
favorable to find large shadow regions early in the process", and section 5:
processing several triangles at once).

A smooth mesh of a million small triangles puts each receiver in the umbra
behind thousands of blockers, each covering a few of its light samples, so
optimization A (umbra bits) only stops the work after most of them. A closed
surface (every edge shared by exactly two of its triangles) bounds a solid;
its slice by a plane is a set of loops, and a point inside a single slice
loop is inside the solid (a ray in the plane from it crosses the surface an
odd number of times). A segment from a receiver to a light sample *outside*
the solid that passes through such a point crosses the surface, so it is
blocked by one of the mesh's own triangles. Convex polygons inside the slice
therefore block only relations the mesh blocks anyway: cast first (coarse
sorting puts them first: they are the largest blockers), they set the umbra
bits of most umbra receivers at once, and every later triangle skips them.
The output is the same set of blocked relations, up to rays within rounding
of the surface (the polygons are shrunk by ``SHRINK`` toward their centre).

Per closed component of at least ``MIN_TRIANGLES`` triangles whose box does
not contain any point of the light's bounding polygon: the slice through its
vertex centroid perpendicular to the light's direction; used when it is one
loop: ``CORNERS`` of its points evenly along it, shrunk toward its centre,
used when they form a strictly convex polygon that no edge of the loop enters
(so it lies inside the slice), cut into a fan of polygons of ``MAXB`` corners.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from .blockers import _adjacency, _unique_vertices
from .geometry import MAXB

MIN_TRIANGLES = 64
CORNERS = 16
SHRINK = 1e-4          # relative shrink of the polygon toward the loop's centre


@njit(cache=True)
def _components(nbr):
    """Connected components over shared edges: (label[T], closed[C]) where
    closed = every edge of the component is shared by exactly two triangles."""
    n = nbr.shape[0]
    label = np.full(n, -1, np.int64)
    closed = np.ones(n, np.bool_)
    stack = np.empty(n, np.int64)
    c = 0
    for s in range(n):
        if label[s] >= 0:
            continue
        label[s] = c
        stack[0] = s
        sp = 1
        while sp > 0:
            sp -= 1
            t = stack[sp]
            for e in range(3):
                o = nbr[t, e]
                if o < 0:
                    closed[c] = False
                    continue
                if label[o] < 0:
                    label[o] = c
                    stack[sp] = o
                    sp += 1
        c += 1
    return label, closed[:c].copy()


@njit(cache=True)
def _slice_loop(P, ids, nbr, tri_list, nx, ny, nz, off, out):
    """Walk the slice of closed component ``tri_list`` by plane n . x = off;
    writes the crossing points in loop order to ``out`` and returns their
    count, or -1 unless the slice is exactly one loop (no vertex on the plane)."""
    m = tri_list.shape[0]
    crossing = 0
    first = -1
    for q in range(m):
        t = tri_list[q]
        pos = 0
        for j in range(3):
            v = ids[t, j]
            h = nx * P[v, 0] + ny * P[v, 1] + nz * P[v, 2] - off
            if h == 0.0:
                return -1
            if h > 0.0:
                pos += 1
        if 0 < pos < 3:
            crossing += 1
            if first < 0:
                first = t
    if crossing < 3 or crossing > out.shape[0]:
        return -1
    t = first
    prev = -1
    k = 0
    while True:
        # the crossing edge of t not shared with prev
        nxt = -1
        for e in range(3):
            a = ids[t, e]
            b = ids[t, (e + 1) % 3]
            ha = nx * P[a, 0] + ny * P[a, 1] + nz * P[a, 2] - off
            hb = nx * P[b, 0] + ny * P[b, 1] + nz * P[b, 2] - off
            if (ha > 0.0) == (hb > 0.0):
                continue
            o = nbr[t, e]
            if o == prev and prev >= 0:
                continue
            s = ha / (ha - hb)
            out[k, 0] = P[a, 0] + s * (P[b, 0] - P[a, 0])
            out[k, 1] = P[a, 1] + s * (P[b, 1] - P[a, 1])
            out[k, 2] = P[a, 2] + s * (P[b, 2] - P[a, 2])
            nxt = o
            break
        if nxt < 0:
            return -1
        k += 1
        prev = t
        t = nxt
        if t == first:
            break
        if k >= crossing:
            return -1
    if k != crossing:
        return -1            # more than one loop
    return k


def _inside_loop(x, y, qx, qy):
    """Convex polygon (qx, qy) (counter-clockwise) inside the simple loop
    (x, y) that holds its corners: no edge of the loop enters its interior
    (each loop edge clipped by the polygon's half-planes leaves nothing)."""
    ex, ey = np.roll(qx, -1) - qx, np.roll(qy, -1) - qy
    # inward normal (-ey, ex) of each polygon edge; f_i(p) > 0 inside
    fa = -ey[None, :] * (x[:, None] - qx[None, :]) + ex[None, :] * (y[:, None] - qy[None, :])
    bx, by = np.roll(x, -1), np.roll(y, -1)
    fb = -ey[None, :] * (bx[:, None] - qx[None, :]) + ex[None, :] * (by[:, None] - qy[None, :])
    df = fb - fa
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -fa / df                                  # where f_i crosses 0 along the edge
    lo = np.where(df > 0, t, -np.inf).max(1)          # f_i > 0 for t > lo
    hi = np.where(df < 0, t, np.inf).min(1)           # f_i > 0 for t < hi
    never = ((df == 0) & (fa <= 0)).any(1)            # parallel and outside
    return not np.any(~never & (np.maximum(lo, 0.0) < np.minimum(hi, 1.0)))


def _convex_fan(loop, normal):
    """``CORNERS`` points evenly along the slice ``loop``, shrunk toward its
    centre, as a fan of polygons [Q, MAXB, 3], when they form a convex
    polygon inside the loop (else None)."""
    u = np.cross(normal, [1.0, 0.0, 0.0] if abs(normal[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(normal, u)
    c = loop.mean(0)
    x, y = (loop - c) @ u, (loop - c) @ v
    area = 0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)
    if area < 0:                                      # counter-clockwise
        loop, x, y = loop[::-1], x[::-1], y[::-1]
    k = min(CORNERS, len(loop))
    sel = np.unique(np.linspace(0, len(loop), k, endpoint=False).astype(np.int64))
    pick = c + (1.0 - SHRINK) * (loop[sel] - c)
    qx, qy = (1.0 - SHRINK) * x[sel], (1.0 - SHRINK) * y[sel]
    ex, ey = np.roll(qx, -1) - qx, np.roll(qy, -1) - qy
    if len(sel) < 3 or np.any(ex * np.roll(ey, -1) - ey * np.roll(ex, -1) <= 0.0):
        return None                                   # the picked corners are not strictly convex
    if not _inside_loop(x, y, qx, qy):
        return None
    quads, counts = [], []
    for a in range(1, len(pick) - 1, MAXB - 2):
        q = pick[[0] + list(range(a, min(a + MAXB - 1, len(pick))))]
        counts.append(len(q))
        quads.append(np.concatenate([q, np.repeat(q[-1:], MAXB - len(q), 0)]))
    return np.array(quads), np.array(counts, np.int64)


def interior_blockers(tris: np.ndarray, light_point, light_dir, light_lo, light_hi):
    """Convex polygons inside the closed components of ``tris`` (float64
    [T,3,3]); returns (polys float64[M, MAXB, 3], nverts int64[M]).
    ``light_point``: the light's centre (None for the sun, whose
    ``light_dir`` is used); ``light_lo/hi``: the box of its bounding polygon
    (None: at infinity, outside every solid)."""
    empty = (np.zeros((0, MAXB, 3)), np.zeros(0, np.int64))
    n = len(tris)
    if n < MIN_TRIANGLES:
        return empty
    P, inv = _unique_vertices(np.ascontiguousarray(tris.reshape(-1, 3), np.float64))
    ids = np.ascontiguousarray(inv.reshape(n, 3), np.int64)
    nbr = _adjacency(ids)
    label, closed = _components(nbr)
    sizes = np.bincount(label, minlength=len(closed))
    good = np.flatnonzero(closed & (sizes >= MIN_TRIANGLES))
    if not len(good):
        return empty
    order = np.argsort(label, kind="stable")
    starts = np.searchsorted(label[order], np.arange(len(closed) + 1))
    polys, nvs = [], []
    for comp in good:                     # per closed object, not per triangle
        tl = np.ascontiguousarray(order[starts[comp]:starts[comp + 1]])
        verts = P[np.unique(ids[tl])]
        lo, hi = verts.min(0), verts.max(0)
        if light_lo is not None and np.all(light_hi >= lo) and np.all(light_lo <= hi):
            continue                      # the light may be inside the solid
        centroid = verts.mean(0)
        d = centroid - light_point if light_point is not None else np.asarray(light_dir, float)
        ln = np.linalg.norm(d)
        if not ln > 0:
            continue
        nrm = d / ln
        out = np.empty((len(tl), 3))
        step = 1e-7 * float(np.abs(hi - lo).max())
        for nudge in range(3):            # off a vertex lying exactly on the plane
            k = _slice_loop(P, ids, nbr, tl, nrm[0], nrm[1], nrm[2], float(nrm @ centroid) + nudge * step, out)
            if k >= 3:
                break
        if k < 3:
            continue
        fan = _convex_fan(out[:k], nrm)
        if fan is None:
            continue
        polys.append(fan[0])
        nvs.append(fan[1])
    if not polys:
        return empty
    return np.ascontiguousarray(np.concatenate(polys)), np.concatenate(nvs)
