"""The umbra of soft irregular shadow mapping (Johnson et al. 2009, section
2.4, figure 2b): hard irregular shadow mapping modified to count the depth
complexity between each receiver and the light centre. Each counted
triangle's light-view image (``triangle_ranges``) is sorted into the grid's
bins (``bin_entries_from_ranges``); per bin, the triangle is tested against
the receivers of the columns it covers at or beyond its nearest depth, with
the watertight orientation test ``geom.blocks_centre`` (exact at the
receiver points).
"""
from __future__ import annotations

import numpy as np
from numba import prange

from ...jit import HOT, kernel
from ...kernels import borrowed, each_dealt_chunk
from .geom import blocks_centre
from .grid import col_range, row_range, slice_of, to_view


def triangle_ranges(tv, tri_ids, faces, near, threads=None):
    """Column/row ranges and nearest depth of each triangle's light-view
    image per face (perspective faces: the triangle clipped to depth >= near[f]):
    ``_triangle_ranges`` on Numba's thread count (``kernels.each_dealt_chunk``)."""
    nt, F = tri_ids.shape[0], faces.shape[0]
    rng = np.empty((nt, F, 4), np.int64)
    zmin = np.empty((nt, F))
    each_dealt_chunk(lambda js: _triangle_ranges(js, tv, tri_ids, faces, near, rng, zmin), nt, threads)
    return rng, zmin


@kernel(nogil=True, error_model="numpy")
def _triangle_ranges(js, tv, tri_ids, faces, near, rng, zmin):
    """``triangle_ranges`` for entries ``js`` of ``tri_ids``: a serial
    ``nogil`` kernel with ``kernels.borrowed`` arguments."""
    tv, tri_ids, faces, near, rng, zmin = borrowed((tv, tri_ids, faces, near, rng, zmin))
    F = faces.shape[0]
    for j in js:
        t = tri_ids[j]
        for f in range(F):
            fp = faces[f]
            rng[j, f, 0] = 1
            rng[j, f, 1] = 0
            rng[j, f, 2] = 1
            rng[j, f, 3] = 0
            zmin[j, f] = np.inf
            vx = np.empty(3)
            vy = np.empty(3)
            vz = np.empty(3)
            for k in range(3):
                vx[k], vy[k], vz[k] = to_view(fp, tv[t, k, 0], tv[t, k, 1], tv[t, k, 2])
            xmin, xmax, ymin, ymax = np.inf, -np.inf, np.inf, -np.inf
            zm = np.inf
            if fp[16] == 1.0:
                for k in range(3):
                    xmin = min(xmin, vx[k])
                    xmax = max(xmax, vx[k])
                    ymin = min(ymin, vy[k])
                    ymax = max(ymax, vy[k])
                    zm = min(zm, vz[k])
            else:
                zn = near[f]
                # Sutherland-Hodgman against depth >= zn, projecting as we go
                for k in range(3):
                    k1 = (k + 1) % 3
                    ina = vz[k] >= zn
                    inb = vz[k1] >= zn
                    if ina:
                        xmin = min(xmin, vx[k] / vz[k])
                        xmax = max(xmax, vx[k] / vz[k])
                        ymin = min(ymin, vy[k] / vz[k])
                        ymax = max(ymax, vy[k] / vz[k])
                        zm = min(zm, vz[k])
                    if ina != inb:
                        s = (zn - vz[k]) / (vz[k1] - vz[k])
                        x = vx[k] + s * (vx[k1] - vx[k])
                        y = vy[k] + s * (vy[k1] - vy[k])
                        xmin = min(xmin, x / zn)
                        xmax = max(xmax, x / zn)
                        ymin = min(ymin, y / zn)
                        ymax = max(ymax, y / zn)
                        zm = min(zm, zn)
            if not (xmax >= xmin):
                continue
            c0, c1 = col_range(fp, xmin, xmax)
            r0, r1 = row_range(fp, ymin, ymax)
            if c0 > c1 or r0 > r1:
                continue
            rng[j, f, 0] = c0
            rng[j, f, 1] = c1
            rng[j, f, 2] = r0
            rng[j, f, 3] = r1
            zmin[j, f] = zm


@kernel
def bin_entries_from_ranges(rng, bin_base, nbx, bin_size):
    """Counting sort of (item, face) ranges into bins: bin_start, items."""
    ni = rng.shape[0]
    F = rng.shape[1]
    nbins = bin_base[-1]
    cnt = np.zeros(nbins + 1, np.int64)
    for j in range(ni):
        for f in range(F):
            if rng[j, f, 0] > rng[j, f, 1]:
                continue
            for by in range(rng[j, f, 2] // bin_size, rng[j, f, 3] // bin_size + 1):
                for bx in range(rng[j, f, 0] // bin_size, rng[j, f, 1] // bin_size + 1):
                    cnt[bin_base[f] + by * nbx[f] + bx + 1] += 1
    for b in range(nbins):
        cnt[b + 1] += cnt[b]
    pos = cnt[:-1].copy()
    items = np.empty(cnt[nbins], np.int64)
    for j in range(ni):
        for f in range(F):
            if rng[j, f, 0] > rng[j, f, 1]:
                continue
            for by in range(rng[j, f, 2] // bin_size, rng[j, f, 3] // bin_size + 1):
                for bx in range(rng[j, f, 0] // bin_size, rng[j, f, 1] // bin_size + 1):
                    b = bin_base[f] + by * nbx[f] + bx
                    items[pos[b]] = j
                    pos[b] += 1
    return cnt, items


def umbra_bins(bins, blist, rng, zmin, tri_ids, occ, grid, Ps, lit, count, tests, threads=None):
    """Hard irregular shadow mapping (section 2.4, figure 2b):
    ``_umbra_bins`` over every bin of ``bins.perm`` on Numba's thread count
    (``kernels.each_dealt_chunk``); a bin counts only its own receivers."""
    each_dealt_chunk(lambda jbs: _umbra_bins(jbs, bins, blist, rng, zmin, tri_ids, occ, grid, Ps, lit, count,
                                             tests), bins.perm.shape[0], threads)


@kernel(opt=HOT, nogil=True, error_model="numpy")
def _umbra_bins(jbs, bins, blist, rng, zmin, tri_ids, occ, grid, Ps, lit, count, tests):
    """Per bin ``bins.perm[jb]``, jb in ``jbs`` (in turn): every triangle
    listed in it is tested against the receivers of the columns it covers at
    or beyond its nearest depth; ``count`` = depth complexity between each
    receiver and the light centre (counted triangles).

    bins: Bins; blist: BinList of entries j of ``tri_ids`` (ranges ``rng``,
    nearest depths ``zmin`` from ``triangle_ranges``); occ: Occluders; grid:
    ReceiverGrid; Ps: receiver positions; lit: KernelLight; ``tests`` per bin.
    Serial and ``nogil``, arguments ``kernels.borrowed`` (as
    ``penumbra._penumbra_bins``)."""
    bins, blist, rng, zmin, tri_ids, occ, grid, Ps, lit, count, tests = borrowed(
        (bins, blist, rng, zmin, tri_ids, occ, grid, Ps, lit, count, tests))
    perm, bin_face, bin_bx, bin_by, bin_size = bins.perm, bins.face, bins.bx, bins.by, bins.size
    bin_start, bin_items = blist.start, blist.items
    tv, nv, side_light = occ.tv, occ.nv, occ.side_light
    faces, col_base, gd, zlo, zhi = grid.faces, grid.col_base, grid.gd, grid.zlo, grid.zhi
    logz, cell_start, colmax = grid.logz, grid.cell_start, grid.colmax
    cx, cy, cz, is_sun = lit.cx, lit.cy, lit.cz, lit.is_sun
    for jb in jbs:
        b = perm[jb]
        f = bin_face[b]
        fp = faces[f]
        gw = int(fp[21])
        gh = int(fp[22])
        bc0 = bin_bx[b] * bin_size
        bc1 = min(bc0 + bin_size, gw) - 1
        br0 = bin_by[b] * bin_size
        br1 = min(br0 + bin_size, gh) - 1
        ntest = 0
        for e in range(bin_start[b], bin_start[b + 1]):
            j = bin_items[e]
            t = tri_ids[j]
            c0 = max(rng[j, f, 0], bc0)
            c1 = min(rng[j, f, 1], bc1)
            r0 = max(rng[j, f, 2], br0)
            r1 = min(rng[j, f, 3], br1)
            zt = zmin[j, f]
            k0 = slice_of(zt, zlo[f], zhi[f], gd, logz[f])
            sl = side_light[t]
            for row in range(r0, r1 + 1):
                for col in range(c0, c1 + 1):
                    column = col_base[f] + row * gw + col
                    if not (colmax[column] > zt):
                        continue
                    s0 = cell_start[column * gd + k0]
                    s1 = cell_start[column * gd + gd]
                    for s in range(s0, s1):
                        px, py, pz = Ps[s, 0], Ps[s, 1], Ps[s, 2]
                        if is_sun:
                            dx, dy, dz = cx, cy, cz
                        else:
                            dx, dy, dz = cx - px, cy - py, cz - pz
                        ntest += 1
                        if blocks_centre(px, py, pz, dx, dy, dz, tv, nv, sl, t, is_sun):
                            count[s] += 1
        tests[b] = ntest


@kernel(parallel=True)
def umbra_brute_force(Ps, tri_ids, tv, nv, side_light, cx, cy, cz, is_sun, count):
    """Every counted triangle ``tri_ids`` against every receiver (no grid):
    the ground truth of the binned umbra (``brute_force``)."""
    for s in prange(Ps.shape[0]):
        px, py, pz = Ps[s, 0], Ps[s, 1], Ps[s, 2]
        if is_sun:
            dx, dy, dz = cx, cy, cz
        else:
            dx, dy, dz = cx - px, cy - py, cz - pz
        c = 0
        for j in range(tri_ids.shape[0]):
            t = tri_ids[j]
            if blocks_centre(px, py, pz, dx, dy, dz, tv, nv, side_light[t], t, is_sun):
                c += 1
        count[s] = c
