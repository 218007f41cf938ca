"""Alpha-matte blockers of penumbra casting (Laine & Aila 2005, section 3.4,
"Alpha matte textures"): processed after all opaque blockers, each relation
l_i -> r_j left open gets its transmittance through the matte blockers, the
product of (1 - alpha) of the texture at each crossing (as Cycles and
``embree`` compute it, ``alpha_rays.transmittance``): V_j = (1 / S) sum of
the open relations' transmittances, or their irradiance-weighted sum over
the sum of every relation's weight (``visibility``). The umbra shortcuts
of optimization A do not hold for a partly clear blocker, so each relation a
matte blocker may take is tested once, after the opaque cast; relations in
an opaque umbra never are.

Two ways to find the crossings (``alpha_fetch``):

* the paper's texture fetch (default, ``fetch_visibility``): the matte
  blockers' V_L find, through the receiver hierarchy (``matte_candidates``),
  the receivers each may shadow; every open relation of such a receiver is
  intersected with those blockers only, by the edge functions of
  ``geometry.receiver_edge_functions`` (linear in the sample, they give the
  barycentrics too), and the alpha fetched there. Shared edges are
  watertight: an edge function is exactly antisymmetric in its edge, and a
  ray exactly on an edge belongs to one side by a fixed vertex order. Ours:
  the fetch runs per receiver after the traversal, not inside it. Embree's
  rays start again just past each crossing; the segment here does not, so a
  second crossing within that offset can count here and not there.
* Embree rays (``transmitted_visibility``): every open relation is traced
  through a BVH of the matte blockers, as the reference traces its rays.
"""
from __future__ import annotations

import math
from collections import namedtuple
from typing import Optional, Tuple

import numpy as np

from ... import alpha_rays, raycast
from ...alpha import alpha_at
from ...jit import kernel
from .blockers import pad_triangles
from .culling import light_volumes
from .geometry import MAXP, box_vs_volume, point_in_volume
from .light import receiver_samples
from .visibility import sample_weights

#: relations traced per Embree batch
RELATIONS_PER_BATCH = 1 << 18
SUN_TFAR = np.float32(1e30)


def split_blockers(matte_casters, casting: np.ndarray) -> Tuple[np.ndarray, Optional[raycast.TriangleScene]]:
    """(the shadow-casting triangles ``casting`` without a matte, a BVH of
    those with one, or None when there are none: then ``casting`` itself);
    ``matte_casters``: ``FrameBuffers.matte_casters`` of the frame."""
    has, mattes = matte_casters
    return (casting, None) if has is None else (casting[~has], mattes)


@kernel(nogil=True, inline="always")
def _open_count(pool, sl, S):
    """How many of the S relations of the receiver with mask row ``sl``
    (-1: none) no opaque blocker took."""
    if sl < 0:
        return S
    c = 0
    for i in range(S):
        if not (pool[sl, i >> 6] >> np.uint64(i & 63)) & np.uint64(1):
            c += 1
    return c


@kernel(nogil=True)
def _open_relations(fu, slot, pool, S, count):
    """Per receiver: how many of its S relations no opaque blocker took
    (full umbra: none; no mask: all)."""
    for r in range(fu.shape[0]):
        count[r] = 0 if fu[r] else _open_count(pool, slot[r], S)


@kernel(nogil=True)
def _relation_rays(smp, rec, r0, r1, fu, slot, pool, S, org, dirs, tfar, owner, wray, wsum):
    """The rays r_j -> l_i of the open relations of receivers [r0, r1), as
    the reference casts them (from the receiver point, float32, to the light
    sample; a sun's samples are directions); ``owner``: each ray's receiver.
    With normals ``rec.N``: each ray's irradiance weight ``wray`` and each
    receiver's sum of the weights of all its relations ``wsum[r - r0]``."""
    weighted = rec.N.shape[0] > 0
    P = np.empty((4, S))
    wts = np.empty(S if weighted else 0)
    k = 0
    for r in range(r0, r1):
        if fu[r]:
            continue
        px, py, pz = rec.pts[r, 0], rec.pts[r, 1], rec.pts[r, 2]
        receiver_samples(smp, rec, r, P)
        if weighted:
            sample_weights(smp.lp, P, px, py, pz, rec.N[r, 0], rec.N[r, 1], rec.N[r, 2], wts)
            for i in range(S):
                wsum[r - r0] += wts[i]
        for i in range(S):
            if slot[r] >= 0 and (pool[slot[r], i >> 6] >> np.uint64(i & 63)) & np.uint64(1):
                continue
            x, y, z, w = P[0, i], P[1, i], P[2, i], P[3, i]
            if weighted:
                wray[k] = wts[i]
            if w != 0.0:
                dx, dy, dz = x / w - px, y / w - py, z / w - pz
            else:
                dx, dy, dz = x, y, z
            ln = np.sqrt(dx * dx + dy * dy + dz * dz)
            if ln > 0:
                dx, dy, dz = dx / ln, dy / ln, dz / ln
            org[k, 0], org[k, 1], org[k, 2] = px, py, pz
            dirs[k, 0], dirs[k, 1], dirs[k, 2] = dx, dy, dz
            tfar[k] = ln * (1.0 - 1e-6) if w != 0.0 else SUN_TFAR
            owner[k] = r
            k += 1


def transmitted_visibility(bvh: raycast.TriangleScene, smp, rec, fu, slot, pool, S: int) -> np.ndarray:
    """V per receiver of one chunk (float64): its open relations'
    transmittance through the matte blockers ``bvh``, summed, over S; with
    normals ``rec.N`` weighted, over the sum of all its relations' weights
    (where that is 0: the average, as ``visibility.chunk_visibility``)."""
    m = len(fu)
    weighted = len(rec.N) > 0
    count = np.empty(m, np.int64)
    _open_relations(fu, slot, pool, S, count)
    none = raycast.TriangleScene(np.zeros((0, 3, 3), np.float32))
    total = np.zeros(m, np.float64)
    lit = np.zeros(m if weighted else 0, np.float64)
    wsum = np.zeros(m, np.float64)
    ends = np.cumsum(count)
    r0 = 0
    while r0 < m:
        base = ends[r0 - 1] if r0 else 0
        r1 = int(np.searchsorted(ends, base + RELATIONS_PER_BATCH, side="right"))
        r1 = max(r1, r0 + 1)
        n = int(ends[r1 - 1] - base)
        if n:
            org = np.empty((n, 3), np.float32)
            dirs = np.empty((n, 3), np.float32)
            tfar = np.empty(n, np.float32)
            owner = np.empty(n, np.int64)
            wray = np.empty(n if weighted else 0, np.float64)
            _relation_rays(smp, rec, r0, r1, fu, slot, pool, S, org, dirs, tfar, owner, wray, wsum[r0:r1])
            trans = alpha_rays.transmittance(none, bvh, org, dirs, tfar)
            total += np.bincount(owner, weights=trans, minlength=m)
            if weighted:
                lit += np.bincount(owner, weights=wray * trans, minlength=m)
        r0 = r1
    V = total / S
    if weighted:
        np.divide(lit, wsum, out=V, where=wsum > 0.0)
    return V


# -- the paper's texture fetch (section 4) -----------------------------------
MatteBlockers = namedtuple("MatteBlockers", "tris tri lex VL nVL")
"""Matte blocker triangles as Embree holds them (float64[K,3,3] of the
float32 corners), their ids in ``Scene.triangles`` (``alpha_at``),
``lex[k, e]``: corner e+1 before corner e+2 in lexicographic order (the
tie rule of an edge function that is exactly 0), and their penumbra volumes
V_L (planes ``VL[k, :, :nVL[k]]``)."""

ALL_PLANES = np.int64(-1)


def matte_triangles(mattes: raycast.TriangleScene):
    """(float64[K,3,3] finite matte triangles, their global ids)."""
    tris = np.asarray(mattes.alpha.triangles[mattes.tri_index], np.float64).reshape(-1, 3, 3)
    ok = np.isfinite(tris.reshape(len(tris), 9)).all(axis=1)
    return np.ascontiguousarray(tris[ok]), np.ascontiguousarray(mattes.tri_index[ok], np.int64)


def corner_order(tris: np.ndarray) -> np.ndarray:
    """uint8[K,3]: ``MatteBlockers.lex``."""
    lex = np.zeros((len(tris), 3), np.uint8)
    for e in range(3):
        p, q = tris[:, (e + 1) % 3], tris[:, (e + 2) % 3]
        before = (p[:, 0] < q[:, 0]) | ((p[:, 0] == q[:, 0]) & ((p[:, 1] < q[:, 1])
                                                                 | ((p[:, 1] == q[:, 1]) & (p[:, 2] < q[:, 2]))))
        lex[:, e] = before
    return lex


def matte_blockers(mattes: raycast.TriangleScene, L, eps: float, root_bb: np.ndarray, tol: float) -> MatteBlockers:
    """The matte blockers with their V_L for light setup ``L``
    (``light.LightSetup``), those that cannot shadow the receivers' box
    ``root_bb`` dropped."""
    tris, tri = matte_triangles(mattes)
    polys, nv = pad_triangles(tris)
    VL = np.zeros((len(tris), 4, MAXP))
    nVL = np.zeros(len(tris), np.int64)
    keep = np.zeros(len(tris), np.bool_)
    light_volumes(polys, nv, L.DVL, L.nvl, L.DEL, L.nel, eps, root_bb, tol, VL, nVL, keep)
    tris = np.ascontiguousarray(tris[keep])
    return MatteBlockers(tris, np.ascontiguousarray(tri[keep]), corner_order(tris),
                         np.ascontiguousarray(VL[keep]), np.ascontiguousarray(nVL[keep]))


@kernel(nogil=True)
def matte_candidates(mb, hier, pts, fu, tol, ptr, lists):
    """Per receiver the matte blockers whose V_L holds it (figure 2's box and
    point tests, B's active planes; receivers in full umbra skipped): with
    ``lists`` empty, their count into ``ptr[r + 1]``; else the blockers,
    ascending, into ``lists[ptr[r]:ptr[r + 1]]``."""
    fill = len(lists) > 0
    at = np.zeros(pts.shape[0], np.int64)
    stack = np.empty(2 * hier.depth + 8, np.int64)
    act_stack = np.empty(2 * hier.depth + 8, np.int64)
    for k in range(mb.nVL.shape[0]):
        n = mb.nVL[k]
        if n < 0:
            continue
        stack[0] = 0
        act_stack[0] = ALL_PLANES
        sp = 1
        while sp > 0:
            sp -= 1
            node = stack[sp]
            ok, act = box_vs_volume(hier.bb, node, mb.VL, k, n, act_stack[sp], True, tol)
            if not ok:
                continue
            if hier.left[node] < 0:
                for q in range(hier.start[node], hier.start[node] + hier.count[node]):
                    r = hier.perm[q]
                    if fu[r] or not point_in_volume(mb.VL, k, n, act, pts[r, 0], pts[r, 1], pts[r, 2], tol):
                        continue
                    if fill:
                        lists[ptr[r] + at[r]] = k
                        at[r] += 1
                    else:
                        ptr[r + 1] += 1
            else:
                stack[sp] = hier.left[node]
                act_stack[sp] = act
                stack[sp + 1] = hier.right[node]
                act_stack[sp + 1] = act
                sp += 2


@kernel(nogil=True, inline="always")
def _edge_ok(e, lex, k, j, front):
    """An edge function exactly 0 (the segment through edge j's line):
    the hit counts for one of the two triangles sharing the edge only."""
    return e != 0.0 or (lex[k, j] != 0) == front


@kernel(nogil=True)
def fetch_visibility(smp, rec, fu, slot, pool, S, ptr, lists, mb, mattes, V):
    """V per receiver: (1 / S) sum over its open relations of the product of
    (1 - alpha) at every matte blocker of ``lists[ptr[r]:ptr[r + 1]]`` the
    segment r_j -> l_i crosses (Laine & Aila section 4: the texture fetch at
    the ray-blocker intersection); more than ``alpha_rays.MAX_CROSSINGS``
    crossings block it (as ``alpha_rays.transmittance``). With normals
    ``rec.N`` the sum is weighted and over the sum of all S weights (where
    that is 0: the average); a receiver in no matte blocker's V_L keeps
    ``visibility.chunk_visibility``'s V from ``V`` on entry. Per receiver and
    blocker: the edge functions U_e = (b - r) x (c - r) (linear forms in the
    direction d = l_i - r: U_e . d) and T's plane; per relation three dot
    products per blocker give the test, the barycentrics and t. The test
    runs over all S samples of a receiver without branches (it vectorizes),
    the fetch only where it hit."""
    cap = alpha_rays.MAX_CROSSINGS
    dx = np.empty(S)
    dy = np.empty(S)
    dz = np.empty(S)
    tmax = np.empty(S)
    tr = np.empty(S, np.float32)
    hits = np.empty(S, np.int64)
    hit = np.empty(S, np.uint8)
    weighted = rec.N.shape[0] > 0
    P = np.empty((4, S))
    wts = np.empty(S if weighted else 0)
    pts = rec.pts
    tris = mb.tris
    for r in range(fu.shape[0]):
        if fu[r]:
            V[r] = 0.0
            continue
        sl = slot[r]
        a, b = ptr[r], ptr[r + 1]
        if a == b:                       # in no matte blocker's V_L: the opaque V
            if not weighted:
                V[r] = _open_count(pool, sl, S) / S
            continue
        px, py, pz = pts[r, 0], pts[r, 1], pts[r, 2]
        receiver_samples(smp, rec, r, P)
        if weighted:
            sample_weights(smp.lp, P, px, py, pz, rec.N[r, 0], rec.N[r, 1], rec.N[r, 2], wts)
        for i in range(S):
            hits[i] = 0
            if sl >= 0 and (pool[sl, i >> 6] >> np.uint64(i & 63)) & np.uint64(1):
                tr[i] = 0.0              # taken by an opaque blocker
                dx[i] = dy[i] = dz[i] = tmax[i] = 0.0
                continue
            tr[i] = 1.0
            x, y, z, w = P[0, i], P[1, i], P[2, i], P[3, i]
            if w != 0.0:
                dx[i], dy[i], dz[i] = x / w - px, y / w - py, z / w - pz
                tmax[i] = 1.0 - 1e-6     # the reference's ray length, in units of |d|
            else:
                dx[i], dy[i], dz[i] = x, y, z
                tmax[i] = math.inf
        for j in range(b - a):
            k = lists[a + j]
            ax, ay, az = tris[k, 0, 0] - px, tris[k, 0, 1] - py, tris[k, 0, 2] - pz
            bx, by, bz = tris[k, 1, 0] - px, tris[k, 1, 1] - py, tris[k, 1, 2] - pz
            cx, cy, cz = tris[k, 2, 0] - px, tris[k, 2, 1] - py, tris[k, 2, 2] - pz
            x0, x1, x2 = by * cz - bz * cy, bz * cx - bx * cz, bx * cy - by * cx
            y0, y1, y2 = cy * az - cz * ay, cz * ax - cx * az, cx * ay - cy * ax
            z0, z1, z2 = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
            ex, ey, ez = bx - ax, by - ay, bz - az
            fx, fy, fz = cx - ax, cy - ay, cz - az
            nx, ny, nz = ey * fz - ez * fy, ez * fx - ex * fz, ex * fy - ey * fx
            no = nx * ax + ny * ay + nz * az
            any_hit = np.uint8(0)
            for i in range(S):
                u0 = dx[i] * x0 + dy[i] * x1 + dz[i] * x2
                u1 = dx[i] * y0 + dy[i] * y1 + dz[i] * y2
                u2 = dx[i] * z0 + dy[i] * z1 + dz[i] * z2
                s = u0 + u1 + u2
                den = dx[i] * nx + dy[i] * ny + dz[i] * nz
                inside = (((s > 0.0) & (u0 >= 0.0) & (u1 >= 0.0) & (u2 >= 0.0))
                          | ((s < 0.0) & (u0 <= 0.0) & (u1 <= 0.0) & (u2 <= 0.0)))
                # 0 < t = no / den < tmax, without the division
                ahead = (((den > 0.0) & (no > 0.0) & (no < tmax[i] * den))
                         | ((den < 0.0) & (no < 0.0) & (no > tmax[i] * den)))
                h = np.uint8(inside & ahead)
                hit[i] = h
                any_hit |= h
            if not any_hit:
                continue
            for i in range(S):
                if not hit[i] or tr[i] == 0.0:
                    continue
                u0 = dx[i] * x0 + dy[i] * x1 + dz[i] * x2
                u1 = dx[i] * y0 + dy[i] * y1 + dz[i] * y2
                u2 = dx[i] * z0 + dy[i] * z1 + dz[i] * z2
                s = u0 + u1 + u2
                front = s > 0.0
                if not (_edge_ok(u0, mb.lex, k, 0, front) and _edge_ok(u1, mb.lex, k, 1, front)
                        and _edge_ok(u2, mb.lex, k, 2, front)):
                    continue
                hits[i] += 1
                if hits[i] > cap:
                    tr[i] = 0.0
                else:
                    tr[i] *= np.float32(1.0 - alpha_at(mattes, mb.tri[k], u1 / s, u2 / s))
        total = 0.0
        for i in range(S):
            total += tr[i]
        V[r] = total / S
        if weighted:
            lit = 0.0
            tot = 0.0
            for i in range(S):
                tot += wts[i]
                lit += wts[i] * tr[i]
            if tot > 0.0:
                V[r] = lit / tot


def matte_pairs(mb: MatteBlockers, hier, pts, fu, tol):
    """(ptr, lists): ``matte_candidates`` as CSR arrays."""
    m = len(pts)
    ptr = np.zeros(m + 1, np.int64)
    matte_candidates(mb, hier, pts, fu, tol, ptr, np.zeros(0, np.int64))
    np.cumsum(ptr, out=ptr)
    lists = np.empty(max(1, int(ptr[-1])), np.int64)
    if ptr[-1]:
        matte_candidates(mb, hier, pts, fu, tol, ptr, lists)
    return ptr, lists
