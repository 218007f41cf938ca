"""Interior blockers of closed meshes: the most powerful occluders of a
smooth solid, cast first (Laine & Aila 2005, section 3.3: "it is favorable
to find large shadow regions early", and section 5: several triangles at
once).

A smooth mesh of many small triangles puts each receiver in the umbra behind
many blockers, each covering a few of its light samples, so optimization A
stops the work only after most of them. A closed surface (every edge shared
by exactly two triangles) bounds a solid; a point inside a single loop of
its slice by a plane is inside the solid, so a segment from a receiver to a
light sample outside the solid through that point is blocked by the mesh
itself. Convex polygons inside the slice therefore block only relations the
mesh blocks: cast first (the coarse sort puts them first, being the largest
blockers), they set the umbra bits of most umbra receivers at once. The
blocked relations are the same up to rays within rounding of the surface
(the polygons are shrunk by ``SHRINK`` toward their centre).

Per closed component of at least ``MIN_TRIANGLES`` triangles whose box holds
no point of the light's bounding polygon: up to ``SLICES`` slices
perpendicular to the light's direction (one per ``SLICE_TRIANGLES``); where a
slice is one loop, ``CORNERS`` points evenly along it, shrunk toward its
centre, make a strictly convex polygon no loop edge enters, cut into a fan of
``MAXB``-corner polygons. Also per component: the disk inside each slice
polygon (``hidden_behind_cores``) and the outward winding (``backface_cull``).
"""
from __future__ import annotations

from collections import namedtuple

import numpy as np

from ...jit import kernel
from .blockers import _adjacency, _unique_vertices
from .geometry import MAXB

MIN_TRIANGLES = 64
CORNERS = 128
SLICES = 16            # at most this many slices per closed solid, evenly along the light's direction
SLICE_TRIANGLES = 4096  # a slice per this many triangles of the solid (at least one, the centroid's)
MIN_TURN = 1e-6        # a slice polygon's corners turn by at least this (radians)
SHRINK = 1e-4          # relative shrink of the polygon toward the loop's centre
DISK_SHRINK = 1e-6     # relative shrink of the disk inside the polygon (``hidden_behind_cores``)


@kernel
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


@kernel
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


def _prime():
    """Call the slicing kernels once on empty input: the warm-up's tiny scene
    has no closed solid, so without this a real scene's first cast would
    compile them inside the method's time."""
    ids = np.zeros((0, 3), np.int64)
    _components(ids)
    _slice_loop(np.zeros((0, 3)), ids, ids, np.zeros(0, np.int64), 0.0, 0.0, 1.0, 0.0, np.empty((0, 3)))


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
    got = _convex_core(loop, normal)
    return None if got is None else got[:2]


def _convex_core(loop, normal, corners=CORNERS):
    """``_convex_fan``'s fan and the disk inside the fan's union (centre,
    radius: the polygon's centroid and its distance to the nearest edge,
    shrunk by ``DISK_SHRINK``), or None."""
    u = np.cross(normal, [1.0, 0.0, 0.0] if abs(normal[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(normal, u)
    c = loop.mean(0)
    x, y = (loop - c) @ u, (loop - c) @ v
    area = 0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)
    if area < 0:                                      # counter-clockwise
        loop, x, y = loop[::-1], x[::-1], y[::-1]
    k = min(int(corners), len(loop))
    # evenly along the loop's length (a slice of a UV sphere crosses its rings unevenly)
    seg = np.hypot(np.roll(x, -1) - x, np.roll(y, -1) - y)
    arc = np.concatenate([[0.0], np.cumsum(seg)[:-1]])
    sel = np.unique(np.minimum(np.searchsorted(arc, np.linspace(0.0, seg.sum(), k, endpoint=False)), len(loop) - 1))
    # corners that do not turn left (collinear ones: the slice of one flat face) dropped;
    # the polygon left must still lie inside the loop (checked below)
    for _ in range(len(sel)):
        ex, ey = np.roll(x[sel], -1) - x[sel], np.roll(y[sel], -1) - y[sel]
        turn = np.roll(ex, 1) * ey - np.roll(ey, 1) * ex          # at each corner
        # and nearly collinear ones (a turn under MIN_TURN radians): a hard volume's
        # edge plane is oriented by the next corner, which must be off the edge's line
        bad = turn <= MIN_TURN * np.hypot(np.roll(ex, 1), np.roll(ey, 1)) * np.hypot(ex, ey)
        if not bad.any() or len(sel) < 3:
            break
        sel = sel[~bad] if (~bad).sum() >= 3 else sel[:0]
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
    # the disk: distance from the polygon's centroid (inside: convex) to each edge line
    cr = qx * np.roll(qy, -1) - np.roll(qx, -1) * qy
    mx = float(np.sum((qx + np.roll(qx, -1)) * cr) / (3.0 * np.sum(cr)))
    my = float(np.sum((qy + np.roll(qy, -1)) * cr) / (3.0 * np.sum(cr)))
    el = np.hypot(ex, ey)
    dist = (ex * (my - qy) - ey * (mx - qx)) / el     # > 0 inside (counter-clockwise)
    rad = (1.0 - DISK_SHRINK) * float(dist.min())
    centre = c + mx * u + my * v
    return np.array(quads), np.array(counts, np.int64), centre, rad


def _oriented(ids, nbr):
    """Per triangle: every neighbour across an edge traverses that edge the
    other way (consistent winding)."""
    n = len(ids)
    t = np.repeat(np.arange(n), 3)
    e = np.tile(np.arange(3), n)
    o = nbr.ravel()
    has = o >= 0
    a = ids[t, e]
    b = ids[t, (e + 1) % 3]
    oo = np.where(has, o, 0)
    # in o, the corner after b must be a (o runs b -> a)
    ok = np.ones(3 * n, np.bool_)
    for j in range(3):
        at = ids[oo, j] == b
        ok &= ~has | ~at | (ids[oo, (j + 1) % 3] == a)
    return ok.reshape(n, 3).all(1)


Solids = namedtuple("Solids", "polys nverts solid_of solids disks facing mesh")
"""``closed_solids``: the interior blockers (polys float64[M, MAXB, 3],
nverts int64[M]); per triangle its solid ``solid_of`` (int64[T], -1: none)
into ``solids`` (float64[S, 10]: centroid c, unit slicing direction n, the
offset h0 of its first slice along n from c, the slice spacing dh, its first
disk in ``disks`` and its slice count); ``disks`` (float64[K, 8]: plane nx,
ny, nz, o, centre, radius^2, or radius^2 = -1 where the slice gave no
polygon); per triangle ``facing`` (int8[T]): +1 / -1 when its component is
a closed, consistently wound mesh the light is outside of, the sign that
makes (b - a) x (c - a) point out of the solid; 0 otherwise; ``mesh``: the
vertices, vertex ids, adjacency and non-manifold flag of ``tris`` (for
``blockers.sub_mesh``; None under ``MIN_TRIANGLES``)."""


def interior_blockers(tris: np.ndarray, light_point, light_dir, light_lo, light_hi):
    """Convex polygons inside the closed components of ``tris`` (float64
    [T,3,3]); returns (polys float64[M, MAXB, 3], nverts int64[M]).
    ``light_point``: the light's centre (None for the sun, whose
    ``light_dir`` is used); ``light_lo/hi``: the box of its bounding polygon
    (None: at infinity, outside every solid)."""
    got = closed_solids(tris, light_point, light_dir, light_lo, light_hi)
    return got.polys, got.nverts


def closed_solids(tris: np.ndarray, light_point, light_dir, light_lo, light_hi, slices: int = SLICES,
                  corners: int = CORNERS) -> Solids:
    """``interior_blockers`` and what the casting may drop because of them
    (``Solids``): ``SLICES`` slices of each closed component perpendicular to
    the light's direction (evenly over its extent), the disk inside each
    slice's polygon (``hidden_behind_cores``), and the outward orientation of
    each closed, consistently wound component the light is outside of
    (``backface_cull``)."""
    n = len(tris)
    none = Solids(np.zeros((0, MAXB, 3)), np.zeros(0, np.int64), np.full(n, -1, np.int64), np.zeros((1, 10)),
                  np.zeros((1, 8)), np.zeros(n, np.int8), None)
    if n < MIN_TRIANGLES:
        _prime()
        return none
    P, inv = _unique_vertices(np.ascontiguousarray(tris.reshape(-1, 3), np.float64))
    ids = np.ascontiguousarray(inv.reshape(n, 3), np.int64)
    nbr, nonmanifold = _adjacency(ids, True)
    none = none._replace(mesh=(P, ids, nbr, nonmanifold))
    label, closed = _components(nbr)
    sizes = np.bincount(label, minlength=len(closed))
    good = np.flatnonzero(closed & (sizes >= MIN_TRIANGLES))
    if not len(good):
        return none
    order = np.argsort(label, kind="stable")
    starts = np.searchsorted(label[order], np.arange(len(closed) + 1))
    wound = _oriented(ids, nbr)
    polys, nvs, disks, solids = [], [], [], []
    solid_of = np.full(n, -1, np.int64)
    facing = np.zeros(n, np.int8)
    for comp in good:                     # per closed object, not per triangle
        tl = np.ascontiguousarray(order[starts[comp]:starts[comp + 1]])
        used = np.zeros(len(P), np.bool_)
        used[ids[tl].ravel()] = True      # the component's vertices (np.unique's set, no sort)
        verts = P[used]
        lo, hi = verts.min(0), verts.max(0)
        if light_lo is not None and np.all(light_hi >= lo) and np.all(light_lo <= hi):
            continue                      # the light may be inside the solid
        centroid = verts.mean(0)
        if wound[tl].all():
            # signed volume about the centroid: > 0 when (b - a) x (c - a) points out
            t = tris[tl] - centroid
            vol = np.einsum("ij,ij->i", t[:, 0], np.cross(t[:, 1], t[:, 2])).sum()
            if vol != 0.0:
                facing[tl] = 1 if vol > 0 else -1
        d = centroid - light_point if light_point is not None else np.asarray(light_dir, float)
        ln = np.linalg.norm(d)
        if not ln > 0:
            continue
        nrm = d / ln
        hv = (verts - centroid) @ nrm
        ns = min(max(1, int(slices)), max(1, len(tl) // SLICE_TRIANGLES))
        dh = float(hv.max() - hv.min()) / ns
        if not dh > 0:
            continue
        h0 = float(hv.min()) + 0.5 * dh if ns > 1 else 0.0      # one slice: through the centroid
        out = np.empty((len(tl), 3))
        step = 1e-7 * float(np.abs(hi - lo).max())
        first = len(disks)
        for s_i in range(ns):
            off = float(nrm @ centroid) + h0 + s_i * dh
            for nudge in range(3):        # off a vertex lying exactly on the plane
                k = _slice_loop(P, ids, nbr, tl, nrm[0], nrm[1], nrm[2], off + nudge * step, out)
                if k >= 3:
                    break
            fan = _convex_core(out[:k], nrm, corners) if k >= 3 else None
            if fan is None:
                disks.append(np.r_[nrm, off, centroid, -1.0])
                continue
            polys.append(fan[0])
            nvs.append(fan[1])
            disks.append(np.r_[nrm, nrm @ fan[2], fan[2], fan[3] ** 2 if fan[3] > 0.0 else -1.0])
        if len(polys) and any(dk[7] > 0 for dk in disks[first:]):
            solid_of[tl] = len(solids)
            solids.append(np.r_[centroid, nrm, h0, dh, first, ns])
    if not polys:
        return none._replace(facing=facing)
    return Solids(np.ascontiguousarray(np.concatenate(polys)), np.concatenate(nvs), solid_of,
                  np.array(solids).reshape(-1, 10) if solids else np.zeros((1, 10)),
                  np.array(disks).reshape(-1, 8), facing, none.mesh)
