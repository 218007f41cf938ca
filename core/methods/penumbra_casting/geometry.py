"""Plane geometry of hierarchical penumbra casting (Laine & Aila 2005, section 3.2).

Points of a light's bounding polygon / volume are homogeneous ``(x, y, z, w)``:
``w = 1`` for a point, ``w = 0`` for a direction (a point at infinity, the sun).
A plane is ``(nx, ny, nz, o)`` with value ``n . x - o w``; every volume here is
oriented so that its inside (where shadow can be) is value >= 0. A blocker T
is a triangle or a convex planar polygon of up to ``MAXB`` corners
(``blockers``), given as ``poly[MAXB, 3]`` and its corner count ``nb``.

* ``penumbra_volume``: the separating planes between a convex light polygon
  (or polytope, section 3.4 "Volumetric light sources") and T, from every
  vertex-edge pair of the two, plus T's plane as a cap when it does not cut
  the light.
* ``hard_volume`` / ``in_hard_volume``: the hard shadow volume V_l of one
  sample, ``nb`` planes through the sample and T's edges and T's plane. A
  receiver r is inside iff the segment from r to the sample (or the ray from
  r along a sun direction) meets T: edges inclusive, T's plane strict, as
  Embree's watertight test treats a ray through a shared edge or ending on T.
* ``receiver_edge_functions`` / ``blocked_by_edges``: the same test with
  sample and receiver exchanged: per receiver, ``nb`` edge forms linear in
  the sample's homogeneous coordinates.

Culling tests (``box_vs_volume``, ``point_in_volume``) take a slack ``tol``
(scene units): they may only ever keep too much, never drop a blocked
relation, so the exact per-sample test alone decides the output.
"""
from __future__ import annotations

import math

import numpy as np

from ...jit import inner

MAXP = 31          # planes kept per penumbra volume (cap first); bit masks fit int64
MAXB = 6           # corners of a blocker polygon (a leaf's hexagon)
ALL = np.int64(-1)  # active plane set token "ALL" (every bit set)


@inner(forceinline=True)
def _cross(ax, ay, az, bx, by, bz):
    return ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx


@inner
def _separating(tri, nb, DV, nv, eps, nx, ny, nz, sx, sy, sz, out, k):
    """Candidate plane with normal n through point s: append it to ``out``
    at column k, oriented with T's side >= 0, when it separates T and the
    light (all of T on one side, all light vertices on the other, not both
    in the plane); returns the new plane count."""
    ln = math.sqrt(nx * nx + ny * ny + nz * nz)
    if not (ln > 1e-300):
        return k
    nx /= ln
    ny /= ln
    nz /= ln
    o = nx * sx + ny * sy + nz * sz
    tmin = 1e300
    tmax = -1e300
    for t in range(nb):
        h = nx * tri[t, 0] + ny * tri[t, 1] + nz * tri[t, 2] - o
        tmin = min(tmin, h)
        tmax = max(tmax, h)
    dmin = 1e300
    dmax = -1e300
    for v in range(nv):
        h = nx * DV[v, 0] + ny * DV[v, 1] + nz * DV[v, 2] - o * DV[v, 3]
        dmin = min(dmin, h)
        dmax = max(dmax, h)
    if tmin >= -eps and dmax <= eps and (tmax > eps or dmin < -eps):
        s = 1.0
    elif tmax <= eps and dmin >= -eps and (tmin < -eps or dmax > eps):
        s = -1.0
    else:
        return k
    out[0, k] = s * nx
    out[1, k] = s * ny
    out[2, k] = s * nz
    out[3, k] = s * o
    return k + 1


@inner
def penumbra_volume(tri, nb, DV, nv, DE, ne, eps, out):
    """Separating planes between light polygon/polytope ``DV[:nv]`` (homogeneous
    vertices, edges ``DE[:ne]`` as vertex index pairs) and blocker ``tri``
    (float64[>=nb, 3], ``nb`` corners); unit normals, T's side >= 0. Writes ``out[:, :k]`` (rows
    nx, ny, nz, o: structure of arrays, so the tests below vectorize over the
    planes) and returns
    k (0 = no plane: the whole space), or -1 for a degenerate triangle (it
    blocks nothing)."""
    ax, ay, az = tri[0, 0], tri[0, 1], tri[0, 2]
    bx, by, bz = tri[1, 0], tri[1, 1], tri[1, 2]
    cx, cy, cz = tri[2, 0], tri[2, 1], tri[2, 2]
    tnx, tny, tnz = _cross(bx - ax, by - ay, bz - az, cx - ax, cy - ay, cz - az)
    tl = math.sqrt(tnx * tnx + tny * tny + tnz * tnz)
    e1 = math.sqrt((bx - ax) ** 2 + (by - ay) ** 2 + (bz - az) ** 2)
    e2 = math.sqrt((cx - ax) ** 2 + (cy - ay) ** 2 + (cz - az) ** 2)
    if not (tl > 1e-14 * e1 * e2) or not (tl > 0.0):
        return -1
    if nb > 3:
        tnx, tny, tnz = _newell(tri, nb)
        tl = math.sqrt(tnx * tnx + tny * tny + tnz * tnz)
    k = 0
    # cap: T's plane, when every light vertex lies strictly on one side
    tnx /= tl
    tny /= tl
    tnz /= tl
    to = tnx * ax + tny * ay + tnz * az
    if nv > 0:
        pos = True
        neg = True
        for v in range(nv):
            h = tnx * DV[v, 0] + tny * DV[v, 1] + tnz * DV[v, 2] - to * DV[v, 3]
            if not (h > eps):
                pos = False
            if not (h < -eps):
                neg = False
        if pos or neg:
            s = -1.0 if pos else 1.0
            out[0, k] = s * tnx
            out[1, k] = s * tny
            out[2, k] = s * tnz
            out[3, k] = s * to
            k += 1
    # candidate planes: (edge of T, vertex of light) and (vertex of T, edge of
    # light), in that order (nested loops: no integer division per candidate)
    for e in range(nb):
        i0 = e
        i1 = e + 1 if e + 1 < nb else 0            # no integer division
        sx, sy, sz = tri[i0, 0], tri[i0, 1], tri[i0, 2]
        for v in range(nv):
            if k >= MAXP:
                return k
            px, py, pz, pw = DV[v, 0], DV[v, 1], DV[v, 2], DV[v, 3]
            nx, ny, nz = _cross(tri[i1, 0] - sx, tri[i1, 1] - sy, tri[i1, 2] - sz,
                                px - pw * sx, py - pw * sy, pz - pw * sz)
            k = _separating(tri, nb, DV, nv, eps, nx, ny, nz, sx, sy, sz, out, k)
    for t in range(nb):
        sx, sy, sz = tri[t, 0], tri[t, 1], tri[t, 2]
        for e in range(ne):
            if k >= MAXP:
                return k
            v0 = DE[e, 0]
            v1 = DE[e, 1]
            nx, ny, nz = _cross(DV[v0, 0] - DV[v0, 3] * sx, DV[v0, 1] - DV[v0, 3] * sy,
                                DV[v0, 2] - DV[v0, 3] * sz,
                                DV[v1, 0] - DV[v1, 3] * sx, DV[v1, 1] - DV[v1, 3] * sy,
                                DV[v1, 2] - DV[v1, 3] * sz)
            k = _separating(tri, nb, DV, nv, eps, nx, ny, nz, sx, sy, sz, out, k)
    return k


@inner
def hard_volume(tri, nb, px, py, pz, pw, hv):
    """Hard shadow volume V_l of sample ``(p, w)`` and T into ``hv[MAXB + 1, 4]``:
    row 0 T's plane (inside strictly > 0), rows 1..nb the edge planes through
    the sample (inside >= 0). Returns False when the sample lies on T's plane
    or T is degenerate (T blocks nothing from it)."""
    ax, ay, az = tri[0, 0], tri[0, 1], tri[0, 2]
    if nb == 3:
        tnx, tny, tnz = _cross(tri[1, 0] - ax, tri[1, 1] - ay, tri[1, 2] - az,
                               tri[2, 0] - ax, tri[2, 1] - ay, tri[2, 2] - az)
    else:
        tnx, tny, tnz = _newell(tri, nb)
    to = tnx * ax + tny * ay + tnz * az
    s = tnx * px + tny * py + tnz * pz - to * pw
    if s == 0.0 or not (s == s):
        return False
    if s > 0.0:
        tnx, tny, tnz, to = -tnx, -tny, -tnz, -to
    hv[0, 0] = tnx
    hv[0, 1] = tny
    hv[0, 2] = tnz
    hv[0, 3] = to
    for e in range(nb):
        i0 = e
        i1 = e + 1 if e + 1 < nb else 0            # no integer division
        i2 = i1 + 1 if i1 + 1 < nb else 0
        sx, sy, sz = tri[i0, 0], tri[i0, 1], tri[i0, 2]
        nx, ny, nz = _cross(tri[i1, 0] - sx, tri[i1, 1] - sy, tri[i1, 2] - sz,
                            px - pw * sx, py - pw * sy, pz - pw * sz)
        o = nx * sx + ny * sy + nz * sz
        if nx * tri[i2, 0] + ny * tri[i2, 1] + nz * tri[i2, 2] - o < 0.0:
            nx, ny, nz, o = -nx, -ny, -nz, -o
        hv[e + 1, 0] = nx
        hv[e + 1, 1] = ny
        hv[e + 1, 2] = nz
        hv[e + 1, 3] = o
    return True


@inner(forceinline=True)
def in_hard_volume(hv, nb, x, y, z):
    """POINT-IN-VOLUME(r, V_l): nb + 1 dot products."""
    if hv[0, 0] * x + hv[0, 1] * y + hv[0, 2] * z - hv[0, 3] <= 0.0:
        return False
    for e in range(1, nb + 1):
        if hv[e, 0] * x + hv[e, 1] * y + hv[e, 2] * z - hv[e, 3] < 0.0:
            return False
    return True


@inner(forceinline=True)
def box_vs_volume(bb, i, planes, p, n, active, use_b, tol):
    """INTERSECTS(B_N, V, P, P'): box ``bb[i]`` (lo, hi) against volume
    ``planes[p]``; False if the box lies outside one active plane; otherwise
    the new active set P' (optimization B drops the planes the box lies
    entirely inside of). Centre / half-extent form; every plane is evaluated
    (no early exit, unsigned indices) so the loop vectorizes. Arrays and
    indices rather than row views: a view in a Numba loop costs two atomic
    reference count updates."""
    if active == 0:
        return True, active          # B: inside every plane already
    cx = 0.5 * (bb[i, 0] + bb[i, 3])
    cy = 0.5 * (bb[i, 1] + bb[i, 4])
    cz = 0.5 * (bb[i, 2] + bb[i, 5])
    hx = 0.5 * (bb[i, 3] - bb[i, 0])
    hy = 0.5 * (bb[i, 4] - bb[i, 1])
    hz = 0.5 * (bb[i, 5] - bb[i, 2])
    outside = np.uint64(0)
    inside = np.uint64(0)
    for j in range(np.uint64(n)):
        nx, ny, nz = planes[p, 0, j], planes[p, 1, j], planes[p, 2, j]
        d = nx * cx + ny * cy + nz * cz - planes[p, 3, j]
        rr = abs(nx) * hx + abs(ny) * hy + abs(nz) * hz
        outside |= np.uint64(d + rr < -tol) << j
        inside |= np.uint64(d - rr >= -tol) << j
    act = np.uint64(active)
    if outside & act:
        return False, active
    if use_b:
        return True, np.int64(act & ~inside)
    return True, active


@inner(forceinline=True)
def point_in_volume(planes, p, n, active, x, y, z, tol):
    """POINT-IN-VOLUME(r, V, P) over the active planes of ``planes[p]``, with
    slack ``tol``."""
    if active == 0:
        return True
    outside = np.uint64(0)
    for j in range(np.uint64(n)):
        v = planes[p, 0, j] * x + planes[p, 1, j] * y + planes[p, 2, j] * z - planes[p, 3, j]
        outside |= np.uint64(v < -tol) << j
    return (outside & np.uint64(active)) == 0


@inner(forceinline=True)
def receiver_edge_functions(tri, nb, tn, x, y, z, ef):
    """The hard shadow volume test of section 3.2 with the roles of sample
    and receiver exchanged. Edge plane e of V_l through sample (p, w) and edge
    (a, b) evaluated at r is [(b - a) x (p - w a)] . (r - a) = p . U_e - w (a . U_e)
    with U_e = (r - a) x (b - a): linear in the sample. ``ef[e] = (U_e, a . U_e)``
    for r, so each sample costs nb + 1 dot products and no volume is built.
    Rows nb..MAXB-1 are zero (a test every sample passes). ``tn``: T's plane
    (``triangle_plane``). Returns T's plane value at r (its sign: r's side of T)."""
    for e in range(ef.shape[0]):
        if e >= nb:
            ef[e, 0] = 0.0
            ef[e, 1] = 0.0
            ef[e, 2] = 0.0
            ef[e, 3] = 0.0
            continue
        i0 = e
        i1 = e + 1 if e + 1 < nb else 0            # no integer division
        ax, ay, az = tri[i0, 0], tri[i0, 1], tri[i0, 2]
        ux, uy, uz = _cross(x - ax, y - ay, z - az, tri[i1, 0] - ax, tri[i1, 1] - ay, tri[i1, 2] - az)
        ef[e, 0] = ux
        ef[e, 1] = uy
        ef[e, 2] = uz
        ef[e, 3] = ux * ax + uy * ay + uz * az
    return tn[0] * x + tn[1] * y + tn[2] * z - tn[3]


@inner(forceinline=True)
def blocked_by_edges(ef, rho, tn, px, py, pz, pw):
    """POINT-IN-VOLUME(r, V_l) from ``receiver_edge_functions``: the sample
    strictly on the other side of T's plane from r, and r inside every edge
    plane (inclusive), oriented by the sample's side as in ``hard_volume``."""
    s = tn[0] * px + tn[1] * py + tn[2] * pz - tn[3] * pw
    if s > 0.0:
        if not (rho < 0.0):
            return False
        for e in range(ef.shape[0]):
            if ef[e, 0] * px + ef[e, 1] * py + ef[e, 2] * pz - ef[e, 3] * pw > 0.0:
                return False
        return True
    if s < 0.0:
        if not (rho > 0.0):
            return False
        for e in range(ef.shape[0]):
            if ef[e, 0] * px + ef[e, 1] * py + ef[e, 2] * pz - ef[e, 3] * pw < 0.0:
                return False
        return True
    return False


@inner
def _newell(tri, nb):
    """Newell's normal of polygon ``tri[:nb]`` (twice its area, oriented by its winding)."""
    nx = ny = nz = 0.0
    for j in range(nb):
        q = j + 1 if j + 1 < nb else 0
        nx += (tri[j, 1] - tri[q, 1]) * (tri[j, 2] + tri[q, 2])
        ny += (tri[j, 2] - tri[q, 2]) * (tri[j, 0] + tri[q, 0])
        nz += (tri[j, 0] - tri[q, 0]) * (tri[j, 1] + tri[q, 1])
    return nx, ny, nz


@inner
def triangle_plane(tri, nb, tn):
    """T's (unnormalized) plane into tn[4]: n_T = (b - a) x (c - a) for a
    triangle, Newell's normal for a polygon; o_T = n_T . a."""
    ax, ay, az = tri[0, 0], tri[0, 1], tri[0, 2]
    if nb == 3:
        tnx, tny, tnz = _cross(tri[1, 0] - ax, tri[1, 1] - ay, tri[1, 2] - az,
                               tri[2, 0] - ax, tri[2, 1] - ay, tri[2, 2] - az)
    else:
        tnx, tny, tnz = _newell(tri, nb)
    tn[0] = tnx
    tn[1] = tny
    tn[2] = tnz
    tn[3] = tnx * ax + tny * ay + tnz * az
