"""The receiver point hierarchy of hierarchical penumbra casting (Laine & Aila
2005, section 3.2): a bounding volume hierarchy of axis-aligned boxes built
by recursively dividing the points in two. Above ``midpoint_limit`` points a
node's box is split in two equal halves (longest axis); below it, the split
minimizing the surface area heuristic n_L A_L + n_R A_R over all three axes
(the paper: "the split position that minimizes the total surface area of the
resulting child nodes"; weighting by counts is the usual SAH and avoids
peeling single points off flat point sets, where the plain area sum ties).
Leaves hold at most ``leaf_size`` points. The umbra bits of nodes
(optimization A) are the AND of their points' or children's.

Nodes are numbered in creation (pre-)order, so a child always has a larger
index than its parent: a reverse sweep combines children before parents.
"""
from __future__ import annotations

import numpy as np

from ...jit import inner, kernel


@inner
def _area(x0, y0, z0, x1, y1, z1):
    dx, dy, dz = x1 - x0, y1 - y0, z1 - z0
    return dx * dy + dy * dz + dz * dx


@inner
def _grow(a, cap):
    """``a`` (1-D) in a new array of length ``cap``. Element by element: a
    slice assignment compiles Numba's shape-mismatch error message (string
    formatting), a large part of a cold start's compile."""
    b = np.empty(cap, a.dtype)
    for i in range(a.shape[0]):
        b[i] = a[i]
    return b


@inner
def _grow_boxes(a, cap):
    """``_grow`` for the (m, 6) node boxes."""
    b = np.empty((cap, 6), a.dtype)
    for i in range(a.shape[0]):
        for j in range(6):
            b[i, j] = a[i, j]
    return b


_RUN = 16          # ``_stable_order``: runs insertion-sorted before the merges


@inner
def _stable_order(keys, c, order, tmp, kb, kt):
    """``order[:c]`` = the stable ascending order of ``keys[:c]`` (what
    ``np.argsort(keys[:c], kind="mergesort")`` gives: ties keep their index
    order): insertion-sorted runs of ``_RUN``, then bottom-up merges, the
    keys carried along in ``kb`` / ``kt`` (buffers of at least ``c``). Its own
    few lines compile in a fraction of the time of Numba's argsort."""
    for k in range(c):
        order[k] = k
        kb[k] = keys[k]
    for lo in range(0, c, _RUN):
        hi = min(lo + _RUN, c)
        for i in range(lo + 1, hi):
            kv = kb[i]
            ov = order[i]
            j = i - 1
            while j >= lo and kb[j] > kv:           # strictly greater: ties stay in order
                kb[j + 1] = kb[j]
                order[j + 1] = order[j]
                j -= 1
            kb[j + 1] = kv
            order[j + 1] = ov
    width = _RUN
    src, dst, ks, kd = order, tmp, kb, kt
    in_tmp = False
    while width < c:
        lo = 0
        while lo < c:
            mid = min(lo + width, c)
            hi = min(lo + 2 * width, c)
            i, j, o = lo, mid, lo
            while i < mid and j < hi:
                if ks[j] < ks[i]:                  # strictly less: the left run wins ties
                    dst[o] = src[j]
                    kd[o] = ks[j]
                    j += 1
                else:
                    dst[o] = src[i]
                    kd[o] = ks[i]
                    i += 1
                o += 1
            while i < mid:
                dst[o] = src[i]
                kd[o] = ks[i]
                i += 1
                o += 1
            while j < hi:
                dst[o] = src[j]
                kd[o] = ks[j]
                j += 1
                o += 1
            lo = hi
        src, dst = dst, src
        ks, kd = kd, ks
        in_tmp = not in_tmp
        width *= 2
    if in_tmp:
        for k in range(c):
            order[k] = tmp[k]


def build_hierarchy(pts, idx, leaf_size, midpoint_limit):
    """BVH over receivers ``idx`` (indices into ``pts``). Returns perm (the
    receivers in leaf order), node boxes (m, 6: lo, hi), left, right (-1 for
    a leaf), start, count (into perm), and the maximum depth."""
    perm, bb, left, right, start, count, m, depth = _build_nodes(pts, idx, leaf_size, midpoint_limit)
    return perm, bb[:m], left[:m], right[:m], start[:m], count[:m], depth


@kernel(nogil=True)
def _build_nodes(pts, idx, leaf_size, midpoint_limit):
    """``build_hierarchy``'s kernel: its node arrays at their allocated length
    and the node count m, trimmed by the caller (slicing and copying here
    would add to its compile time)."""
    n = idx.shape[0]
    perm = idx.copy()
    cap = max(16, 4 * (n // max(1, leaf_size)) + 16)
    bb = np.empty((cap, 6))
    left = np.full(cap, -1, np.int64)
    right = np.full(cap, -1, np.int64)
    start = np.zeros(cap, np.int64)
    count = np.zeros(cap, np.int64)
    m = 1
    start[0] = 0
    count[0] = n
    st_node = np.empty(64, np.int64)
    st_depth = np.empty(64, np.int64)
    sp = 0
    st_node[0] = 0
    st_depth[0] = 0
    sp = 1
    max_depth = 0
    keys = np.empty(max(1, min(n, midpoint_limit)))
    order = np.empty(keys.shape[0], np.int64)
    otmp = np.empty(keys.shape[0], np.int64)
    kb = np.empty(keys.shape[0])
    kt = np.empty(keys.shape[0])
    best_order = np.empty(keys.shape[0], np.int64)
    suf = np.empty(keys.shape[0] + 1)
    while sp > 0:
        sp -= 1
        node = st_node[sp]
        depth = st_depth[sp]
        if depth > max_depth:
            max_depth = depth
        s = start[node]
        c = count[node]
        x0 = y0 = z0 = np.inf
        x1 = y1 = z1 = -np.inf
        for k in range(s, s + c):
            p = perm[k]
            x, y, z = pts[p, 0], pts[p, 1], pts[p, 2]
            x0 = min(x0, x)
            y0 = min(y0, y)
            z0 = min(z0, z)
            x1 = max(x1, x)
            y1 = max(y1, y)
            z1 = max(z1, z)
        if c == 0:
            x0 = y0 = z0 = x1 = y1 = z1 = 0.0
        bb[node, 0], bb[node, 1], bb[node, 2] = x0, y0, z0
        bb[node, 3], bb[node, 4], bb[node, 5] = x1, y1, z1
        if c <= leaf_size:
            continue
        split = -1
        if c > midpoint_limit:
            ext0, ext1, ext2 = x1 - x0, y1 - y0, z1 - z0
            # axes by decreasing extent
            a0 = 0
            if ext1 > ext0 and ext1 >= ext2:
                a0 = 1
            elif ext2 > ext0 and ext2 > ext1:
                a0 = 2
            for t in range(3):
                ax = (a0 + t) % 3
                lo = bb[node, ax]
                hi = bb[node, 3 + ax]
                if not (hi > lo):
                    continue
                mid = 0.5 * (lo + hi)
                i = s
                j = s + c - 1
                while i <= j:
                    if pts[perm[i], ax] < mid:
                        i += 1
                    else:
                        tmp = perm[i]
                        perm[i] = perm[j]
                        perm[j] = tmp
                        j -= 1
                if i > s and i < s + c:
                    split = i
                    break
            if split < 0:
                split = s + c // 2      # every point equal: any split
        else:
            best = np.inf
            best_ax = -1
            best_k = -1
            for ax in range(3):
                for k in range(c):
                    keys[k] = pts[perm[s + k], ax]
                _stable_order(keys, c, order, otmp, kb, kt)
                # suffix areas
                sx0 = sy0 = sz0 = np.inf
                sx1 = sy1 = sz1 = -np.inf
                suf[c] = 0.0
                for k in range(c - 1, -1, -1):
                    p = perm[s + order[k]]
                    sx0 = min(sx0, pts[p, 0])
                    sy0 = min(sy0, pts[p, 1])
                    sz0 = min(sz0, pts[p, 2])
                    sx1 = max(sx1, pts[p, 0])
                    sy1 = max(sy1, pts[p, 1])
                    sz1 = max(sz1, pts[p, 2])
                    suf[k] = _area(sx0, sy0, sz0, sx1, sy1, sz1)
                px0 = py0 = pz0 = np.inf
                px1 = py1 = pz1 = -np.inf
                for k in range(c - 1):
                    p = perm[s + order[k]]
                    px0 = min(px0, pts[p, 0])
                    py0 = min(py0, pts[p, 1])
                    pz0 = min(pz0, pts[p, 2])
                    px1 = max(px1, pts[p, 0])
                    py1 = max(py1, pts[p, 1])
                    pz1 = max(pz1, pts[p, 2])
                    cost = (k + 1) * _area(px0, py0, pz0, px1, py1, pz1) + (c - k - 1) * suf[k + 1]
                    # ties (flat or repeated points) go to the most balanced split
                    if cost < best or (cost == best and abs(2 * (k + 1) - c) < abs(2 * best_k - c)):
                        best = cost
                        best_ax = ax
                        best_k = k + 1
                if best_ax == ax:                   # this axis's order is the split's (no fourth sort)
                    for k in range(c):
                        best_order[k] = order[k]
            for k in range(c):
                otmp[k] = perm[s + best_order[k]]
            for k in range(c):
                perm[s + k] = otmp[k]
            split = s + best_k
        if m + 2 > bb.shape[0]:
            nc = 2 * bb.shape[0]
            bb = _grow_boxes(bb, nc)
            left = _grow(left, nc)
            right = _grow(right, nc)
            start = _grow(start, nc)
            count = _grow(count, nc)
            for q in range(m, nc):
                left[q] = -1
                right[q] = -1
        l = m
        r = m + 1
        m += 2
        left[node] = l
        right[node] = r
        left[l] = right[l] = left[r] = right[r] = -1
        start[l] = s
        count[l] = split - s
        start[r] = split
        count[r] = s + c - split
        if sp + 2 > st_node.shape[0]:
            st_node = _grow(st_node, 2 * st_node.shape[0])
            st_depth = _grow(st_depth, 2 * st_depth.shape[0])
        st_node[sp] = r
        st_depth[sp] = depth + 1
        st_node[sp + 1] = l
        st_depth[sp + 1] = depth + 1
        sp += 2
    return perm, bb, left, right, start, count, m, max_depth


@inner(forceinline=True)
def leaf_umbra_bits(node, start, count, perm, gu, fu, node_gu, node_fu):
    """A leaf's umbra bits (optimization A, lines 77-80): the AND of its
    receivers' per-group bits ``gu`` and whole-light bits ``fu``."""
    G = gu.shape[1]
    f = np.uint8(1)
    for k in range(G):
        node_gu[node, k] = 1
    for q in range(start[node], start[node] + count[node]):
        r = perm[q]
        f &= fu[r]
        for k in range(G):
            node_gu[node, k] &= gu[r, k]
    node_fu[node] = f


@kernel(nogil=True)
def node_umbra_bits(left, right, start, count, perm, gu, fu, node_gu, node_fu):
    """Umbra bits of every node from its receivers' (optimization A, lines
    50-54 and 77-80): the AND over the leaf's points, then over children."""
    m = left.shape[0]
    G = gu.shape[1]
    for node in range(m - 1, -1, -1):
        if left[node] < 0:
            leaf_umbra_bits(node, start, count, perm, gu, fu, node_gu, node_fu)
        else:
            a = left[node]
            b = right[node]
            for k in range(G):
                node_gu[node, k] = node_gu[a, k] & node_gu[b, k]
            node_fu[node] = node_fu[a] & node_fu[b]
