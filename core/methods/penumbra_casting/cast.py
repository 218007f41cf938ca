"""The per-blocker traversal of hierarchical penumbra casting (Laine & Aila
2005, figures 2 and 3) as one Numba kernel with an explicit stack.

``cast_chunk`` casts blockers ``tri_sel[t0:]`` against one chunk's receiver
hierarchy and returns where it stopped: at the end, or where optimization A
asks for a rebuild (line 29), which the caller makes before calling again.
Every switch only prunes work (conservatively) or changes what is stored; a
relation ``l_i -> r_j`` is marked blocked by one exact test, so the output
does not depend on the switches. There is one kernel per way of testing
line 70 (``cast_chunk_for``: sample words, the paper's V_li planes, the
reference's own samples): Numba prunes the other variants' branches before
typing, so a cold start compiles only the helpers its light needs.

Arguments travel in named groups (the namedtuples below); the per-chunk
counters ``st`` (int64[N_ST]) have the slots ``ST_*``.

Speed: line 70 runs 64 samples of a mask word at a time with unsigned
indices and shifts, which LLVM vectorizes (signed indices keep Numba's
negative-index wraparound in the loop and block it); the plane tests read
structure-of-arrays planes and evaluate every plane without early exit, for
the same reason; no loop creates an array view or reassigns an array (each
costs atomic reference counting). The helpers are inlined by LLVM
(``forceinline``), not by Numba's IR inliner (``inline="always"``, which
re-types a body at every call site), so each is typed and cached once.

Mask memory (D): ``pool`` has a row for every receiver of the chunk,
allocated zeroed (the operating system commits a page on first touch); rows
are handed out in order, released rows first, so the memory in use follows
the peak of live masks.
"""
from __future__ import annotations

from collections import namedtuple

import numpy as np

from ...jit import HOT, inner, kernel
from .geometry import MAXB, MAXP, blocked_by_edges, box_vs_volume, hard_volume, in_hard_volume, \
    penumbra_volume, point_in_volume, receiver_edge_functions, triangle_plane
from .hierarchy import leaf_umbra_bits
from .light import MODE_FIXED, MODE_SHARED, MODE_SPHERE, sample_point

ALLP = np.int64(-1)

# counter slots of ``st``
ST_FREE = 0             # released mask slots (on the free stack)
ST_LIVE = 1             # live masks
ST_PEAK = 2             # peak live masks
ST_UMBRA = 3            # points of the current hierarchy in full umbra
ST_POINTS = 4           # points in the current hierarchy
ST_STAMP = 5            # triangle stamp
ST_NODES = 6            # nodes visited
ST_POINT_TESTS = 7      # point-vs-V_L tests
ST_HARD_TESTS = 8       # hard shadow volume tests
ST_GROUP_VOLUMES = 9    # triangles whose group volumes were built
ST_HARD_BUILT = 10      # hard volumes built
ST_SLOTS = 11           # mask slots handed out (pool rows ever touched)
ST_ROOT_CULLED = 12     # triangles culled at the root
ST_LEAF_VISITS = 13     # (blocker, leaf node) pairs reaching a leaf's points
ST_PAIRS = 14           # (blocker, receiver) pairs inside V_L (the receiver's blocker count)
ST_GROUP_TESTS = 15     # point-vs-V_Gk penumbra volume tests
ST_HIDDEN = 16          # (blocker, receiver) pairs in V_L skipped: hidden behind its solid's core
ST_HIDDEN_NODES = 17    # (blocker, node) pairs skipped: the whole box hidden behind its solid's core
N_ST = 18

# argument groups of ``cast_chunk``
Blockers = namedtuple("Blockers", "tri_sel tris nverts VL nVL solid solids disks gface")
"""Blocker polygons (float64[T, MAXB, 3], corners ``nverts``), their light
volumes V_L (planes ``VL[t, :, :nVL[t]]``), the cast order ``tri_sel``, and
per blocker its closed solid ``solid[t]`` (-1: none) with the solid's slices
and their disks (``cores.Solids``), and ``gface[t, k]`` = 0 where every
sample of G_k sees the back of a solid's blocker (it blocks nothing from
them that the solid's other triangles do not: G_k never active for it)."""
LightGroups = namedtuple("LightGroups", "DVg nvg DEg neg g_start")
"""Bounding polygons Delta_Gk (vertices DVg/nvg, edges DEg/neg) and the bit
range ``g_start[k]:g_start[k + 1]`` of each group G_k."""
Receivers = namedtuple("Receivers", "pts set_id pix Pg M N", defaults=(np.zeros((0, 3)),))
"""Receiver points r_j, their sample set, pixel id, G-buffer position,
(sphere) rotation rows M and normals N for the irradiance weights (zero
rows, the default: none, V is the average; ``visibility``)."""
Hierarchy = namedtuple("Hierarchy", "perm bb left right start count depth")
"""The receiver hierarchy (``hierarchy.build_hierarchy``)."""
UmbraBits = namedtuple("UmbraBits", "fu gu node_gu node_fu")
"""Optimization A: full / group umbra bits of receivers and of nodes."""
Masks = namedtuple("Masks", "slot pool free")
"""Optimization D: the mask row of each receiver (-1: none), the mask pool
and the stack of released rows."""
CastSwitches = namedtuple("CastSwitches", "optA optB optC optD rebuild_frac leaf_size tol eps materialize hidden")
"""Optimizations A-D, ``RebuildFraction``, ``LeafSize``, tolerances,
``materialize_hard_volumes`` and ``hidden_behind_cores``."""


@inner(forceinline=True)
def _bits_full(pool, sl, a, b):
    """Every bit in [a, b) of mask ``pool[sl]`` set."""
    i = a
    while i < b:
        w = i >> 6
        o = i & 63
        n = min(b - i, 64 - o)
        if n == 64:
            want = np.uint64(0xFFFFFFFFFFFFFFFF)
        else:
            want = ((np.uint64(1) << np.uint64(n)) - np.uint64(1)) << np.uint64(o)
        if (pool[sl, w] & want) != want:
            return False
        i += n
    return True


@inner(forceinline=True)
def _coefficients(ef, tn, rho, mode, r, M, centre, co):
    """Per receiver: the MAXB edge functions (rows of edges T lacks are zero)
    and T's plane (last) as linear forms in the sample, signed so that
    "blocked" reads v_e >= 0 for every e and s > 0 (the sample strictly on the
    other side of T from r); negation is exact, so this decides exactly as
    ``blocked_by_edges``. For the sphere the receiver's rotation is folded in:
    p = c + M q gives a . p - k w = (M^T a) . q - (k - a . c)."""
    sr = 1.0 if rho > 0.0 else -1.0
    for e in range(MAXB + 1):
        if e < MAXB:
            ax, ay, az, k = sr * ef[e, 0], sr * ef[e, 1], sr * ef[e, 2], sr * ef[e, 3]
        else:
            ax, ay, az, k = -sr * tn[0], -sr * tn[1], -sr * tn[2], -sr * tn[3]
        if mode == MODE_SPHERE:
            bx = M[r, 0] * ax + M[r, 3] * ay + M[r, 6] * az
            by = M[r, 1] * ax + M[r, 4] * ay + M[r, 7] * az
            bz = M[r, 2] * ax + M[r, 5] * ay + M[r, 8] * az
            k = k - (ax * centre[0] + ay * centre[1] + az * centre[2])
            ax, ay, az = bx, by, bz
        co[4 * e] = ax
        co[4 * e + 1] = ay
        co[4 * e + 2] = az
        co[4 * e + 3] = k


@inner(forceinline=True)
def _word_tests(T4, j, a, e, base, co, nb):
    """Bits [a, e) of one 64-bit mask word: sample i blocked by T (the edge
    forms and the plane: three edges for a triangle, four for a quad, MAXB
    for a larger polygon, whose missing edges are zero rows that pass)."""
    u0x, u0y, u0z, c0 = co[0], co[1], co[2], co[3]
    u1x, u1y, u1z, c1 = co[4], co[5], co[6], co[7]
    u2x, u2y, u2z, c2 = co[8], co[9], co[10], co[11]
    u3x, u3y, u3z, c3 = co[12], co[13], co[14], co[15]
    u4x, u4y, u4z, c4 = co[16], co[17], co[18], co[19]
    u5x, u5y, u5z, c5 = co[20], co[21], co[22], co[23]
    P0 = 4 * MAXB
    tx, ty, tz, tc = co[P0], co[P0 + 1], co[P0 + 2], co[P0 + 3]
    # unsigned indices and shifts: no negative-index wraparound or
    # out-of-range-shift selects in the loop body, so LLVM vectorizes it
    ua = np.uint64(a)
    sh = np.uint64(a - base)
    acc = np.uint64(0)
    if nb > 4:
        for k in range(np.uint64(e - a)):
            i = ua + k
            px, py, pz, pw = T4[j, 0, i], T4[j, 1, i], T4[j, 2, i], T4[j, 3, i]
            v0 = u0x * px + u0y * py + u0z * pz - c0 * pw
            v1 = u1x * px + u1y * py + u1z * pz - c1 * pw
            v2 = u2x * px + u2y * py + u2z * pz - c2 * pw
            v3 = u3x * px + u3y * py + u3z * pz - c3 * pw
            v4 = u4x * px + u4y * py + u4z * pz - c4 * pw
            v5 = u5x * px + u5y * py + u5z * pz - c5 * pw
            sp = tx * px + ty * py + tz * pz - tc * pw
            blk = (v0 >= 0.0) & (v1 >= 0.0) & (v2 >= 0.0) & (v3 >= 0.0) & (v4 >= 0.0) & (v5 >= 0.0) & (sp > 0.0)
            acc |= np.uint64(blk) << (k + sh)
    elif nb == 4:
        for k in range(np.uint64(e - a)):
            i = ua + k
            px, py, pz, pw = T4[j, 0, i], T4[j, 1, i], T4[j, 2, i], T4[j, 3, i]
            v0 = u0x * px + u0y * py + u0z * pz - c0 * pw
            v1 = u1x * px + u1y * py + u1z * pz - c1 * pw
            v2 = u2x * px + u2y * py + u2z * pz - c2 * pw
            v3 = u3x * px + u3y * py + u3z * pz - c3 * pw
            sp = tx * px + ty * py + tz * pz - tc * pw
            blk = (v0 >= 0.0) & (v1 >= 0.0) & (v2 >= 0.0) & (v3 >= 0.0) & (sp > 0.0)
            acc |= np.uint64(blk) << (k + sh)
    else:
        for k in range(np.uint64(e - a)):
            i = ua + k
            px, py, pz, pw = T4[j, 0, i], T4[j, 1, i], T4[j, 2, i], T4[j, 3, i]
            v0 = u0x * px + u0y * py + u0z * pz - c0 * pw
            v1 = u1x * px + u1y * py + u1z * pz - c1 * pw
            v2 = u2x * px + u2y * py + u2z * pz - c2 * pw
            sp = tx * px + ty * py + tz * pz - tc * pw
            blk = (v0 >= 0.0) & (v1 >= 0.0) & (v2 >= 0.0) & (sp > 0.0)
            acc |= np.uint64(blk) << (k + sh)
    return acc


@inner(forceinline=True)
def _slice_of(solids, sid, x, y, z, ax, ay, az):
    """The disk of solid ``sid`` for the ray from (x, y, z) along (ax, ay,
    az): the slice nearest the ray's closest approach to the centroid (-1:
    that slice has no disk)."""
    aa = ax * ax + ay * ay + az * az
    if not (aa > 0.0):
        return np.int64(-1)
    sm = ((solids[sid, 0] - x) * ax + (solids[sid, 1] - y) * ay + (solids[sid, 2] - z) * az) / aa
    hm = (solids[sid, 3] * (x + sm * ax - solids[sid, 0]) + solids[sid, 4] * (y + sm * ay - solids[sid, 1])
          + solids[sid, 5] * (z + sm * az - solids[sid, 2]))
    fi = (hm - solids[sid, 6]) / solids[sid, 7] + 0.5
    fi = min(max(fi, 0.0), solids[sid, 9] - 1.0)
    return np.int64(solids[sid, 8]) + np.int64(fi)


@inner(forceinline=True)
def _through_disk(disks, c, x, y, z, vx, vy, vz):
    """The ray from (x, y, z) through (vx, vy, vz) meets disk ``c`` at a
    positive distance: 1 before the point, 2 beyond it, 0 not."""
    nx, ny, nz, o = disks[c, 0], disks[c, 1], disks[c, 2], disks[c, 3]
    hr = nx * x + ny * y + nz * z - o
    dx = vx - x
    dy = vy - y
    dz = vz - z
    den = nx * dx + ny * dy + nz * dz
    if not (den * hr < 0.0):             # the disk's plane behind r along this ray, or parallel
        return 0
    t = -hr / den
    qx = x + t * dx - disks[c, 4]
    qy = y + t * dy - disks[c, 5]
    qz = z + t * dz - disks[c, 6]
    if not (qx * qx + qy * qy + qz * qz < disks[c, 7]):
        return 0
    return 1 if t < 1.0 else 2


@inner
def _box_hidden(bb, node, tris, k, nb, solids, disks, sid):
    """``_hidden_behind`` for every point of box ``bb[node]``: for each corner
    v of T, the 8 box corners all see the same disk through v, and all
    before v or all beyond it (each of those two sets of points is convex:
    the disk's shadow frustum from v, and the cone from v away from it)."""
    c = _slice_of(solids, sid, 0.5 * (bb[node, 0] + bb[node, 3]), 0.5 * (bb[node, 1] + bb[node, 4]),
                  0.5 * (bb[node, 2] + bb[node, 5]),
                  tris[k, 0, 0] - 0.5 * (bb[node, 0] + bb[node, 3]), tris[k, 0, 1] - 0.5 * (bb[node, 1] + bb[node, 4]),
                  tris[k, 0, 2] - 0.5 * (bb[node, 2] + bb[node, 5]))
    if c < 0 or not (disks[c, 7] > 0.0):
        return False
    for j in range(nb):
        vx, vy, vz = tris[k, j, 0], tris[k, j, 1], tris[k, j, 2]
        side = -1
        for q in range(8):
            x = bb[node, 3] if q & 1 else bb[node, 0]
            y = bb[node, 4] if q & 2 else bb[node, 1]
            z = bb[node, 5] if q & 4 else bb[node, 2]
            h = _through_disk(disks, c, x, y, z, vx, vy, vz)
            if h == 0 or (side >= 0 and h != side):
                return False
            side = h
    return True


@inner(forceinline=True)
def _hidden_behind(tris, k, nb, solids, disks, sid, x, y, z):
    """Every ray from r = (x, y, z) through a corner of blocker ``k`` (so
    through all of it: convex) passes, at a positive distance, through one
    disk inside an interior blocker of its solid ``sid`` (the slice nearest
    the closest approach of the ray through the first corner to the solid's
    centroid): any segment from r to a light sample that T blocks is blocked
    by that polygon (``hidden_behind_cores``)."""
    c = _slice_of(solids, sid, x, y, z, tris[k, 0, 0] - x, tris[k, 0, 1] - y, tris[k, 0, 2] - z)
    if c < 0 or not (disks[c, 7] > 0.0):
        return False
    for j in range(nb):
        if _through_disk(disks, c, x, y, z, tris[k, j, 0], tris[k, j, 1], tris[k, j, 2]) == 0:
            return False
    return True


def _make_cast_chunk(variant: str):
    """``cast_chunk`` for one way of testing line 70 (``variant``): "words"
    (the sample table a word at a time: fixed and sphere samples), "planes"
    (``materialize_hard_volumes``: the paper's V_li planes) or "shared" (the
    reference's own per-pixel samples). Each is its own kernel: Numba prunes
    the other variants' branches before typing, so a cold start compiles only
    the helpers its light needs."""
    PLANES = variant == "planes"
    SHARED = variant == "shared"

    def cast_chunk(t0, blk, grp, smp, rec, hier, umb, masks, st, opt):
        """Cast ``blk.tri_sel[t0:]`` against one chunk; returns where it stopped.

        blk: Blockers; grp: LightGroups; smp: light.LightSamples; rec: Receivers
        (the chunk's, in leaf order); hier: Hierarchy; umb: UmbraBits (A);
        masks: Masks (D); st: counters (``ST_*``); opt: CastSwitches."""
        tri_sel, tris, nverts, VL, nVL = blk.tri_sel, blk.tris, blk.nverts, blk.VL, blk.nVL
        bsolid, solids, disks, gface = blk.solid, blk.solids, blk.disks, blk.gface
        DVg, nvg, DEg, neg, g_start = grp.DVg, grp.nvg, grp.DEg, grp.neg, grp.g_start
        mode, SP, Q, centre, bit2s = smp.mode, smp.SP, smp.Q, smp.centre, smp.bit2s
        pts, set_id, M = rec.pts, rec.set_id, rec.M
        perm, bb, left, right = hier.perm, hier.bb, hier.left, hier.right
        start, count, depth = hier.start, hier.count, hier.depth
        fu, gu, node_gu, node_fu = umb.fu, umb.gu, umb.node_gu, umb.node_fu
        slot, pool, free = masks.slot, masks.pool, masks.free
        optA, optB, optC, optD = opt.optA, opt.optB, opt.optC, opt.optD
        rebuild_frac, leaf_size, tol, eps = opt.rebuild_frac, opt.leaf_size, opt.tol, opt.eps
        hidden = opt.hidden
        G = g_start.shape[0] - 1
        planes = PLANES                                     # the paper's V_li planes per (set, sample)
        S = bit2s.shape[0]
        nsets = SP.shape[0]
        nwords = pool.shape[1]
        L = depth + 3
        PLv = np.empty(L, np.int64)
        act = np.empty((L, G), np.int64)
        act_on = np.zeros((L, G), np.uint8)
        st_node = np.empty(2 * L + 4, np.int64)
        st_lev = np.empty(2 * L + 4, np.int64)
        st_state = np.empty(2 * L + 4, np.int64)
        VG = np.zeros((G, 4, MAXP))
        nVG = np.zeros(G, np.int64)
        hsets = nsets if planes else 1
        HV = np.zeros((hsets, S if planes else 1, MAXB + 1, 4))
        hv_ok = np.zeros((hsets, S if planes else 1), np.bool_)
        tn = np.zeros(4)
        ef = np.zeros((MAXB, 4))
        co = np.zeros(4 * MAXB + 4)
        # samples as structure of arrays (x, y, z, w rows): fixed points, or the
        # sphere's disk offsets with w = 1 (the per-receiver rotation goes into
        # the coefficients)
        if mode == MODE_SPHERE:
            T4 = np.ones((Q.shape[0], 4, S))
            for jj in range(Q.shape[0]):
                for ii in range(S):
                    for aa in range(3):
                        T4[jj, aa, ii] = Q[jj, ii, aa]
        else:
            T4 = np.zeros((SP.shape[0], 4, SP.shape[1]))
            for jj in range(SP.shape[0]):
                for ii in range(SP.shape[1]):
                    for aa in range(4):
                        T4[jj, aa, ii] = SP[jj, ii, aa]
        hv_stamp = np.full((hsets, G), -1, np.int64)
        for ti in range(t0, tri_sel.shape[0]):
            # line 29 (A): rebuild when enough points of the hierarchy are in umbra
            if optA and st[ST_POINTS] > 2 * leaf_size and st[ST_UMBRA] > rebuild_frac * st[ST_POINTS]:
                return ti
            if st[ST_POINTS] == 0:
                return tri_sel.shape[0]
            k = tri_sel[ti]
            nL = nVL[k]
            tri = tris[k]
            nb = nverts[k]
            kc = bsolid[k] if hidden else np.int64(-1)
            triangle_plane(tri, nb, tn)
            st[ST_STAMP] += 1
            stamp = st[ST_STAMP]
            vol_built = False
            if not optC:
                # basic algorithm, lines 2-3: every V_Gk and V_li up front
                for g in range(G):
                    nVG[g] = max(0, penumbra_volume(tri, nb, DVg[g], nvg[g], DEg[g], neg[g], eps, VG[g]))
                if PLANES:
                    for j in range(nsets):
                        for i in range(S):
                            hv_ok[j, i] = hard_volume(tri, nb, SP[j, i, 0], SP[j, i, 1], SP[j, i, 2],
                                                      SP[j, i, 3], HV[j, i])
                        for g in range(G):
                            hv_stamp[j, g] = stamp
                    st[ST_HARD_BUILT] += nsets * S
                vol_built = True
                st[ST_GROUP_VOLUMES] += 1
            # lines 32-34
            PLv[0] = ALLP
            anyface = False
            for g in range(G):
                act[0, g] = ALLP
                act_on[0, g] = gface[k, g]
                if gface[k, g]:
                    anyface = True
            if not anyface:
                continue
            sp = 1
            st_node[0] = 0
            st_lev[0] = 0
            st_state[0] = 0
            first = True
            while sp > 0:
                sp -= 1
                node = st_node[sp]
                lev = st_lev[sp]
                if st_state[sp] == 1:
                    # lines 50-54 (A): AND of the children's umbra bits
                    ca = left[node]
                    cb = right[node]
                    for g in range(G):
                        node_gu[node, g] = node_gu[ca, g] & node_gu[cb, g]
                    node_fu[node] = node_fu[ca] & node_fu[cb]
                    continue
                st[ST_NODES] += 1
                if optA and node_fu[node]:                                   # line 35
                    continue
                ok, pl = box_vs_volume(bb, node, VL, k, nL, PLv[lev], optB, tol)  # line 36
                if first:
                    first = False
                    if not ok:
                        st[ST_ROOT_CULLED] += 1
                if not ok:
                    continue
                if kc >= 0 and count[node] <= 4 * leaf_size and _box_hidden(bb, node, tris, k, nb, solids, disks, kc):
                    st[ST_HIDDEN_NODES] += 1
                    continue
                nl = lev + 1
                anyg = False
                for g in range(G):                                           # lines 37-45
                    act_on[nl, g] = 0
                    if act_on[lev, g] == 0:
                        continue
                    if optA and node_gu[node, g]:                            # line 39
                        continue
                    if vol_built:                                            # lines 40-43
                        ok2, a2 = box_vs_volume(bb, node, VG, g, nVG[g], act[lev, g], optB, tol)
                        if not ok2:
                            continue
                        act[nl, g] = a2
                    else:                                                    # line 44
                        act[nl, g] = ALLP
                    act_on[nl, g] = 1
                    anyg = True
                if not anyg:                                                 # line 46
                    continue
                PLv[nl] = pl
                if left[node] >= 0:                                          # lines 47-49
                    if optA:
                        st_node[sp] = node
                        st_lev[sp] = lev
                        st_state[sp] = 1
                        sp += 1
                    st_node[sp] = right[node]
                    st_lev[sp] = nl
                    st_state[sp] = 0
                    st_node[sp + 1] = left[node]
                    st_lev[sp + 1] = nl
                    st_state[sp + 1] = 0
                    sp += 2
                    continue
                # leaf: lines 56-80
                st[ST_LEAF_VISITS] += 1
                for q in range(start[node], start[node] + count[node]):
                    r = perm[q]
                    if (optA or optD) and fu[r]:                             # line 57
                        continue
                    x, y, z = pts[r, 0], pts[r, 1], pts[r, 2]
                    st[ST_POINT_TESTS] += 1
                    if not point_in_volume(VL, k, nL, PLv[nl], x, y, z, tol):  # line 58
                        continue
                    st[ST_PAIRS] += 1
                    if kc >= 0 and _hidden_behind(tris, k, nb, solids, disks, kc, x, y, z):
                        st[ST_HIDDEN] += 1
                        continue
                    if slot[r] < 0:                                          # line 59 (D)
                        if st[ST_FREE] > 0:
                            st[ST_FREE] -= 1
                            sl = free[st[ST_FREE]]
                        else:
                            sl = st[ST_SLOTS]
                            st[ST_SLOTS] += 1
                        for w in range(nwords):
                            pool[sl, w] = np.uint64(0)
                        slot[r] = sl
                        st[ST_LIVE] += 1
                        if st[ST_LIVE] > st[ST_PEAK]:
                            st[ST_PEAK] = st[ST_LIVE]
                    if not vol_built:                                        # lines 60-64 (C)
                        for g in range(G):
                            nVG[g] = max(0, penumbra_volume(tri, nb, DVg[g], nvg[g], DEg[g], neg[g],
                                                            eps, VG[g]))
                        vol_built = True
                        st[ST_GROUP_VOLUMES] += 1
                    sl = slot[r]
                    j = set_id[r] if mode != MODE_SHARED else 0
                    rho = 0.0
                    have_ef = False
                    for g in range(G):                                       # line 65
                        if act_on[nl, g] == 0:
                            continue
                        if optA and gu[r, g]:                                # line 66
                            continue
                        st[ST_GROUP_TESTS] += 1
                        if not point_in_volume(VG, g, nVG[g], act[nl, g], x, y, z, tol):  # line 67
                            continue
                        i0 = g_start[g]
                        i1 = g_start[g + 1]
                        if PLANES:                                           # lines 68-71
                            if hv_stamp[j, g] != stamp:
                                # C: the hard volumes of this group of this set, on first need
                                for i in range(i0, i1):
                                    hv_ok[j, i] = hard_volume(tri, nb, SP[j, i, 0], SP[j, i, 1], SP[j, i, 2],
                                                              SP[j, i, 3], HV[j, i])
                                hv_stamp[j, g] = stamp
                                st[ST_HARD_BUILT] += i1 - i0
                            for i in range(i0, i1):
                                w = i >> 6
                                b = np.uint64(1) << np.uint64(i & 63)
                                if pool[sl, w] & b:
                                    continue
                                st[ST_HARD_TESTS] += 1
                                if hv_ok[j, i] and in_hard_volume(HV[j, i], nb, x, y, z):
                                    pool[sl, w] |= b
                        elif SHARED:
                            if not have_ef:
                                rho = receiver_edge_functions(tri, nb, tn, x, y, z, ef)
                                have_ef = True
                            for i in range(i0, i1):
                                w = i >> 6
                                b = np.uint64(1) << np.uint64(i & 63)
                                if pool[sl, w] & b:
                                    continue
                                st[ST_HARD_TESTS] += 1
                                px, py, pz, pw = sample_point(smp, i, r, rec)
                                if blocked_by_edges(ef, rho, tn, px, py, pz, pw):
                                    pool[sl, w] |= b
                        else:
                            if not have_ef:
                                # per receiver and triangle, on the first group that needs it
                                rho = receiver_edge_functions(tri, nb, tn, x, y, z, ef)
                                if rho != 0.0:
                                    _coefficients(ef, tn, rho, mode, r, M, centre, co)
                                have_ef = True
                            if rho != 0.0:
                                # the same four plane tests, a word of samples at a time
                                for w in range(i0 >> 6, ((i1 - 1) >> 6) + 1):
                                    a = max(i0, w << 6)
                                    e = min(i1, (w + 1) << 6)
                                    pool[sl, w] |= _word_tests(T4, j, a, e, w << 6, co, nb)
                                    st[ST_HARD_TESTS] += e - a
                        if optA:                                             # line 72
                            if _bits_full(pool, sl, g_start[g], g_start[g + 1]):
                                gu[r, g] = 1
                    if optA:                                                 # line 74
                        allg = True
                        for g in range(G):
                            if gu[r, g] == 0:
                                allg = False
                                break
                        if allg:
                            fu[r] = 1
                            st[ST_UMBRA] += 1
                    if optD:                                                 # line 75
                        full = fu[r] == 1 if optA else _bits_full(pool, sl, np.int64(0), S)
                        if full:
                            fu[r] = 1
                            free[st[ST_FREE]] = sl
                            st[ST_FREE] += 1
                            slot[r] = -1
                            st[ST_LIVE] -= 1
                if optA:                                                     # lines 77-80
                    leaf_umbra_bits(node, start, count, perm, gu, fu, node_gu, node_fu)
        return tri_sel.shape[0]

    cast_chunk.__name__ = cast_chunk.__qualname__ = f"cast_chunk_{variant}"
    return kernel(opt=HOT, nogil=True)(cast_chunk)


cast_chunk_words = _make_cast_chunk("words")
cast_chunk_planes = _make_cast_chunk("planes")
cast_chunk_shared = _make_cast_chunk("shared")


def cast_chunk_for(mode: int, materialize: bool):
    """The ``cast_chunk`` kernel of a light setup's sample ``mode`` and
    ``materialize_hard_volumes``."""
    if mode == MODE_SHARED:
        return cast_chunk_shared
    if materialize and mode == MODE_FIXED:
        return cast_chunk_planes
    return cast_chunk_words
