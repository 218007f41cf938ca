"""The light-space receiver grid and the binned umbra / penumbra passes of
soft irregular shadow mapping (Johnson et al. 2009, figures 2-3, section 2.5).

Grid (figure 3): receivers are projected into the light's view faces (one
perspective face, cube faces, or one orthographic face for a sun); each face
is cut into columns (``gw x gh``) and every column into ``gd`` depth slices
(log-spaced for perspective faces). Cells are numbered column-major with the
slices of a column consecutive, and receivers are stored contiguously by a
counting sort (O(n)), so the receivers of a column at or beyond a given
slice are one contiguous range.

Bins (section 2.5, Larrabee's sort-middle rasterizer): columns are grouped
into ``B x B`` bins. Triangles (umbra) and penumbra quads are sorted into the
bins they overlap (counting sort again), then bins are processed in parallel;
each bin owns its receivers, so there are no write races and the result does
not depend on the thread count.

Penumbra quad of an edge (section 2.2): light points x lie within ``r_L`` of
the centre; for a receiver p at depth z_p occluded by an edge point q at
depth z_q, in face-plane (tangent) units

    |q' - p'| <= r_L k (z_p - z_q) / (z_q (z_p - rho))

with k = sqrt(1 + |p'|^2) and rho the largest depth of a light point in the
face (k = 1, rho = 0 for an area light seen along its own axis, where this
is Parker et al.'s r (1/z_q - 1/z_p)). It grows with z_p, so with z_p <= Z
(the largest receiver depth: of the face, or of the bin when ``bin_refine``)
the quad is the convex hull of two disks around the edge's projected
endpoints (the radius is linear in 1/z, hence along the projected edge).
The wedge test (``wedge_test``) solves the same bound for the smallest depth
a receiver in a given column can have and still be reached. Sun: the
orthographic face gives |q' - p'| <= tan(a/2) (z_p - z_q).
"""
from __future__ import annotations

import math
from collections import namedtuple

import numpy as np
from numba import prange

from ...jit import HOT, inner, kernel
from ...kernels import borrowed, each_dealt_chunk, face_project, pick_face
from .geom import blocks_centre, penumbra_term

# penumbra quad of a (record, face): ``edge_quads``' flag
QUAD_NONE = 0           # no receiver of the face can be reached
QUAD_EDGE = 1           # the convex hull of the two endpoint disks
QUAD_WHOLE_FACE = 2     # unbounded (edge through the light's near ball): every column

# argument groups of the binned kernels (built by the package's ``__init__``)
Bins = namedtuple("Bins", "perm face bx by size maxz")
"""Bins in processing order ``perm``; per bin its face, column block (bx, by)
of ``size x size`` columns and its largest receiver depth (-inf: empty)."""
BinList = namedtuple("BinList", "start items")
"""What each bin holds: ``items[start[b]:start[b + 1]]``."""
ReceiverGrid = namedtuple("ReceiverGrid", "faces col_base gd zlo zhi logz cell_start colmax")
"""The light-space grid (figure 3): packed faces, first column of each face,
depth slices per column and their range, cell -> first receiver, and the
largest receiver depth of each column."""
FaceBounds = namedtuple("FaceBounds", "Z k rho par")
"""Per face: largest receiver depth, k and rho of the quad bound, and whether
the face is parallel to the light (k = 1, rho = 0)."""
Receivers = namedtuple("Receivers", "Ps XYZ RF")
"""Receivers in cell order: offset positions, light-view coordinates
(face u, v, depth) and frames (``receiver_frames``: e1, e2, n, h_p, p2)."""
Occluders = namedtuple("Occluders", "tv nv facing orient side_light")
"""Triangles (float64[T,3,3]), unnormalized normals, facing towards the light
centre, orientation of the closed component (0: open) and side of the light."""
Records = namedtuple("Records", "t k")
"""Silhouette records: edge ``k`` of triangle ``t``."""
Quads = namedtuple("Quads", "ep flag rng")
"""Per (record, face): projected endpoints, QUAD_* flag and column/row range
(``edge_quads``)."""
LightSamples = namedtuple("LightSamples", "rows first counts")
"""Equation 5's overlap C: light samples in rows (unit-shape coordinates,
``geom.light_samples``: per row y, first x, spacing; first sample index) and
every receiver's depth complexity there beyond its umbra count (int8[n, m],
cell order; no rows: the paper's C = 0)."""
KernelLight = namedtuple("KernelLight", "cx cy cz is_sun shape rL tan_a")
"""The light's centre (sun: unit direction towards it), kind, shape
(SHAPE_*), bounding radius r_L and, for the sun, tan of the half angle."""


# --------------------------------------------------------------------------
# grid construction
def assign_faces(P, faces, fu, fv, fz, threads=None):
    """Face, face-pixel coordinates and depth of every receiver (-1: none):
    ``_assign_faces`` on Numba's thread count (``kernels.each_dealt_chunk``)."""
    face = np.empty(P.shape[0], np.int64)
    each_dealt_chunk(lambda idx: _assign_faces(idx, P, faces, fu, fv, fz, face), P.shape[0], threads)
    return face


@kernel(nogil=True, error_model="numpy")
def _assign_faces(idx, P, faces, fu, fv, fz, face):
    """``assign_faces`` for receivers ``idx``: a serial ``nogil`` kernel with
    ``kernels.borrowed`` arguments (as ``_penumbra_bins``; issue 15)."""
    P, faces, fu, fv, fz, face = borrowed((P, faces, fu, fv, fz, face))
    for i in idx:
        f = pick_face(faces, P[i, 0], P[i, 1], P[i, 2])
        face[i] = f
        if f >= 0:
            u, v, z = face_project(faces[f], P[i, 0], P[i, 1], P[i, 2])
            fu[i] = u
            fv[i] = v
            fz[i] = z
        else:
            fu[i] = 0.0
            fv[i] = 0.0
            fz[i] = 0.0


@inner(forceinline=True)
def slice_of(z, zlo, zhi, gd, logz):
    if not (zhi > zlo):
        return 0
    if logz:
        if z <= zlo:
            return 0
        s = (math.log(z) - math.log(zlo)) / (math.log(zhi) - math.log(zlo))
    else:
        s = (z - zlo) / (zhi - zlo)
    k = int(math.floor(s * gd))
    if k < 0:
        return 0
    if k >= gd:
        return gd - 1
    return k


@kernel
def counting_sort_cells(face, fu, fv, fz, faces, col_base, gd, zlo, zhi, logz, ncols, bin_size,
                        bin_base, nbx):
    """Counting sort of the receivers into cells; also the largest receiver
    depth per column and per bin (measured during construction, 2.5)."""
    n = face.shape[0]
    ncells = ncols * gd
    cell = np.empty(n, np.int64)
    cnt = np.zeros(ncells + 1, np.int64)
    colmax = np.full(ncols, -np.inf)
    nbins = bin_base[-1]
    binmax = np.full(nbins, -np.inf)
    for i in range(n):
        f = face[i]
        if f < 0:
            cell[i] = -1
            continue
        gw = int(faces[f, 21])
        gh = int(faces[f, 22])
        iu = min(max(int(math.floor(fu[i])), 0), gw - 1)
        iv = min(max(int(math.floor(fv[i])), 0), gh - 1)
        col = col_base[f] + iv * gw + iu
        k = slice_of(fz[i], zlo[f], zhi[f], gd, logz[f])
        c = col * gd + k
        cell[i] = c
        cnt[c + 1] += 1
        if fz[i] > colmax[col]:
            colmax[col] = fz[i]
        b = bin_base[f] + (iv // bin_size) * nbx[f] + iu // bin_size
        if fz[i] > binmax[b]:
            binmax[b] = fz[i]
    for c in range(ncells):
        cnt[c + 1] += cnt[c]
    start = cnt.copy()
    pos = cnt[:-1].copy()
    m = start[ncells]
    order = np.empty(m, np.int64)
    for i in range(n):
        c = cell[i]
        if c >= 0:
            order[pos[c]] = i
            pos[c] += 1
    return order, start, colmax, binmax


# --------------------------------------------------------------------------
# face-plane helpers
@inner(forceinline=True)
def to_view(fp, x, y, z):
    vx = fp[0] * x + fp[1] * y + fp[2] * z + fp[3]
    vy = fp[4] * x + fp[5] * y + fp[6] * z + fp[7]
    vz = fp[8] * x + fp[9] * y + fp[10] * z + fp[11]
    return vx, vy, -vz


@inner(forceinline=True)
def _cell_span(edge0, edge1, n, lo, hi):
    """Cells 0..n-1 of an axis whose cell 0 starts at ``edge0`` and cell n
    ends at ``edge1`` that cover [lo, hi] measured from ``edge0`` (clamped;
    first > last if none)."""
    a = (lo - edge0) / (edge1 - edge0) * n - 1e-6
    b = (hi - edge0) / (edge1 - edge0) * n + 1e-6
    if b < 0.0 or a >= n or not (a <= b):
        return 1, 0
    return int(math.floor(max(a, 0.0))), int(math.floor(min(b, n - 1.0)))


@inner(forceinline=True)
def col_range(fp, xmin, xmax):
    """Columns covering face-plane x in [xmin, xmax] (clamped; c0 > c1 if none)."""
    return _cell_span(fp[17], fp[18], fp[21], xmin, xmax)


@inner(forceinline=True)
def row_range(fp, ymin, ymax):
    """Rows covering face-plane y in [ymin, ymax]; row 0 is the top (y = t)."""
    return _cell_span(fp[20], fp[19], fp[22], ymax, ymin)


@inner(forceinline=True)
def col_rect(fp, c0, c1, r0, r1):
    """Face-plane rectangle (x0, x1, y0, y1) of columns c0..c1, rows r0..r1."""
    l, r, bt, tp, gw, gh = fp[17], fp[18], fp[19], fp[20], fp[21], fp[22]
    x0 = l + c0 * (r - l) / gw
    x1 = l + (c1 + 1) * (r - l) / gw
    y1 = tp - r0 * (tp - bt) / gh
    y0 = tp - (r1 + 1) * (tp - bt) / gh
    return x0, x1, y0, y1


@kernel(forceinline=True)
def rect_k(x0, x1, y0, y1):
    """sqrt(1 + max |p'|^2) over a face-plane rectangle."""
    mx = max(abs(x0), abs(x1))
    my = max(abs(y0), abs(y1))
    return math.sqrt(1.0 + mx * mx + my * my)


@inner
def point_seg_dist2(px, py, ax, ay, bx, by):
    ex = bx - ax
    ey = by - ay
    L2 = ex * ex + ey * ey
    t = 0.0
    if L2 > 0.0:
        t = ((px - ax) * ex + (py - ay) * ey) / L2
        t = min(max(t, 0.0), 1.0)
    dx = ax + t * ex - px
    dy = ay + t * ey - py
    return dx * dx + dy * dy


@inner
def seg_rect_dist(ax, ay, bx, by, x0, x1, y0, y1):
    """Distance between segment AB and the rectangle [x0,x1] x [y0,y1]."""
    # segment meets the rectangle? (Liang-Barsky)
    t0, t1 = 0.0, 1.0
    dx = bx - ax
    dy = by - ay
    ok = True
    for (p, q) in ((-dx, ax - x0), (dx, x1 - ax), (-dy, ay - y0), (dy, y1 - ay)):
        if p == 0.0:
            if q < 0.0:
                ok = False
        else:
            r = q / p
            if p < 0.0:
                t0 = max(t0, r)
            else:
                t1 = min(t1, r)
    if ok and t0 <= t1:
        return 0.0
    best = np.inf
    for (px, py) in ((ax, ay), (bx, by)):
        cx = min(max(px, x0), x1)
        cy = min(max(py, y0), y1)
        d = (px - cx) ** 2 + (py - cy) ** 2
        if d < best:
            best = d
    for (px, py) in ((x0, y0), (x1, y0), (x0, y1), (x1, y1)):
        d = point_seg_dist2(px, py, ax, ay, bx, by)
        if d < best:
            best = d
    return math.sqrt(best)


@inner(forceinline=True)
def seg_x_in_band(ax, ay, bx, by, y0, y1):
    """x-extent of the part of segment AB with y in [y0, y1] (xa > xb: none)."""
    t0, t1 = 0.0, 1.0
    dy = by - ay
    if dy == 0.0:
        if ay < y0 or ay > y1:
            return 1.0, 0.0
    else:
        ta = (y0 - ay) / dy
        tb = (y1 - ay) / dy
        if ta > tb:
            ta, tb = tb, ta
        t0 = max(t0, ta)
        t1 = min(t1, tb)
        if t0 > t1:
            return 1.0, 0.0
    xa = ax + t0 * (bx - ax)
    xb = ax + t1 * (bx - ax)
    return min(xa, xb), max(xa, xb)


# --------------------------------------------------------------------------
# umbra: triangles -> face columns
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
    ``nogil`` kernel with ``kernels.borrowed`` arguments (issue 15)."""
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
    ``_penumbra_bins``)."""
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


# --------------------------------------------------------------------------
# penumbra: records (silhouette edges) -> quads -> bins
@inner
def _quad_width(persp, rL, k, rho, tan_a, Z, z):
    """Half width of the penumbra quad at an edge endpoint of depth z for
    receivers no deeper than Z (face-plane units); -1 = unbounded."""
    if z >= Z:
        return 0.0
    if not persp:
        return tan_a * (Z - z)
    if not (Z > rho) or not (z > rho):
        return -1.0
    return rL * k * (Z - z) / (z * (Z - rho)) * (1.0 + 1e-9)


def edge_quads(tv, rec_t, rec_k, faces, face_Z, face_k, face_rho, face_near, face_rnear,
               rL, tan_a, threads=None):
    """Per (record, face): projected endpoints of the edge (clipped to depth
    >= near for perspective faces), whole-face flag, and the global quad's
    column/row range (quad width from the face's largest receiver depth):
    ``_edge_quads`` on Numba's thread count (``kernels.each_dealt_chunk``)."""
    R, F = rec_t.shape[0], faces.shape[0]
    ep = np.zeros((R, F, 6))
    flag = np.zeros((R, F), np.int8)      # QUAD_*
    rng = np.empty((R, F, 4), np.int64)
    each_dealt_chunk(lambda rs: _edge_quads(rs, tv, rec_t, rec_k, faces, face_Z, face_k, face_rho, face_near,
                                            face_rnear, rL, tan_a, ep, flag, rng), R, threads)
    return ep, flag, rng


@kernel(nogil=True, error_model="numpy")
def _edge_quads(rs, tv, rec_t, rec_k, faces, face_Z, face_k, face_rho, face_near, face_rnear, rL, tan_a,
                ep, flag, rng):
    """``edge_quads`` for records ``rs``: a serial ``nogil`` kernel with
    ``kernels.borrowed`` arguments (issue 15)."""
    tv, rec_t, rec_k, faces, face_Z, face_k, face_rho, face_near, face_rnear, ep, flag, rng = borrowed(
        (tv, rec_t, rec_k, faces, face_Z, face_k, face_rho, face_near, face_rnear, ep, flag, rng))
    F = faces.shape[0]
    for r in rs:
        t = rec_t[r]
        k = rec_k[r]
        k1 = (k + 1) % 3
        for f in range(F):
            fp = faces[f]
            rng[r, f, 0] = 1
            rng[r, f, 1] = 0
            rng[r, f, 2] = 1
            rng[r, f, 3] = 0
            ax, ay, az = to_view(fp, tv[t, k, 0], tv[t, k, 1], tv[t, k, 2])
            bx, by, bz = to_view(fp, tv[t, k1, 0], tv[t, k1, 1], tv[t, k1, 2])
            persp = fp[16] == 0.0
            whole = False
            if persp:
                zn = face_near[f]
                if az < zn or bz < zn:
                    # distance from the light centre to the edge (view space)
                    ex, ey, ez = bx - ax, by - ay, bz - az
                    L2 = ex * ex + ey * ey + ez * ez
                    s = 0.0
                    if L2 > 0.0:
                        s = -(ax * ex + ay * ey + az * ez) / L2
                        s = min(max(s, 0.0), 1.0)
                    qx, qy, qz = ax + s * ex, ay + s * ey, az + s * ez
                    if math.sqrt(qx * qx + qy * qy + qz * qz) <= face_rnear[f]:
                        whole = True
                    elif az < zn and bz < zn:
                        continue
                    else:
                        s = (zn - az) / (bz - az)
                        mx, my = ax + s * (bx - ax), ay + s * (by - ay)
                        if az < zn:
                            ax, ay, az = mx, my, zn
                        else:
                            bx, by, bz = mx, my, zn
                if not whole:
                    ax, ay = ax / az, ay / az
                    bx, by = bx / bz, by / bz
            if whole:
                flag[r, f] = QUAD_WHOLE_FACE
                rng[r, f, 0] = 0
                rng[r, f, 1] = int(fp[21]) - 1
                rng[r, f, 2] = 0
                rng[r, f, 3] = int(fp[22]) - 1
                continue
            ep[r, f, 0] = ax
            ep[r, f, 1] = ay
            ep[r, f, 2] = az
            ep[r, f, 3] = bx
            ep[r, f, 4] = by
            ep[r, f, 5] = bz
            Z = face_Z[f]
            wa = _quad_width(persp, rL, face_k[f], face_rho[f], tan_a, Z, az)
            wb = _quad_width(persp, rL, face_k[f], face_rho[f], tan_a, Z, bz)
            if wa < 0.0 or wb < 0.0:
                flag[r, f] = QUAD_WHOLE_FACE
                rng[r, f, 0] = 0
                rng[r, f, 1] = int(fp[21]) - 1
                rng[r, f, 2] = 0
                rng[r, f, 3] = int(fp[22]) - 1
                continue
            if wa <= 0.0 and wb <= 0.0:
                continue
            c0, c1 = col_range(fp, min(ax - wa, bx - wb), max(ax + wa, bx + wb))
            r0, r1 = row_range(fp, min(ay - wa, by - wb), max(ay + wa, by + wb))
            if c0 > c1 or r0 > r1:
                continue
            flag[r, f] = QUAD_EDGE
            rng[r, f, 0] = c0
            rng[r, f, 1] = c1
            rng[r, f, 2] = r0
            rng[r, f, 3] = r1


@inner(forceinline=True)
def _bin_quad(ep, r, f, fp, persp, rL, rho, tan_a, Zb, kb):
    za = ep[r, f, 2]
    zb = ep[r, f, 5]
    wa = _quad_width(persp, rL, kb, rho, tan_a, Zb, za)
    wb = _quad_width(persp, rL, kb, rho, tan_a, Zb, zb)
    return wa, wb


@kernel
def bin_quads(ep, flag, rng, faces, bin_base, nbx, bin_size, binmax, face_rho, face_k, face_par,
              rL, tan_a, refine):
    """Sort penumbra quads into bins. With ``refine`` (section 2.5, first
    optimization) the quad is rebuilt per bin from the bin's largest receiver
    depth and dropped from bins it no longer overlaps."""
    R = ep.shape[0]
    F = ep.shape[1]
    nbins = bin_base[-1]
    cnt = np.zeros(nbins + 1, np.int64)
    for phase in range(2):
        if phase == 1:
            for b in range(nbins):
                cnt[b + 1] += cnt[b]
            pos = cnt[:-1].copy()
            items = np.empty(cnt[nbins], np.int64)
        for r in range(R):
            for f in range(F):
                if flag[r, f] == QUAD_NONE:
                    continue
                fp = faces[f]
                persp = fp[16] == 0.0
                gw = int(fp[21])
                gh = int(fp[22])
                for by in range(rng[r, f, 2] // bin_size, rng[r, f, 3] // bin_size + 1):
                    for bx in range(rng[r, f, 0] // bin_size, rng[r, f, 1] // bin_size + 1):
                        b = bin_base[f] + by * nbx[f] + bx
                        Zb = binmax[b]
                        if not (Zb > -np.inf):
                            continue           # empty bin
                        if refine and flag[r, f] == QUAD_EDGE:
                            c0 = bx * bin_size
                            c1 = min(c0 + bin_size, gw) - 1
                            r0 = by * bin_size
                            r1 = min(r0 + bin_size, gh) - 1
                            x0, x1, y0, y1 = col_rect(fp, c0, c1, r0, r1)
                            kb = 1.0 if face_par[f] else rect_k(x0, x1, y0, y1)
                            wa, wb = _bin_quad(ep, r, f, fp, persp, rL, face_rho[f], tan_a, Zb, kb)
                            if wa >= 0.0 and wb >= 0.0:
                                w = max(wa, wb)
                                if w <= 0.0:
                                    continue
                                d = seg_rect_dist(ep[r, f, 0], ep[r, f, 1], ep[r, f, 3], ep[r, f, 4],
                                                  x0, x1, y0, y1)
                                if d > w:
                                    continue
                        if phase == 0:
                            cnt[b + 1] += 1
                        else:
                            items[pos[b]] = r
                            pos[b] += 1
    return cnt, items


def penumbra_bins(bins, blist, quads, grid, fb, rec, records, occ, lit, mode, refine, wedge, pen, ls, evals,
                  threads=None):
    """Soft shadow kernel (sections 2.3, 2.5): ``_penumbra_bins`` over every
    bin of ``bins.perm`` on Numba's thread count (bins dealt into chunks:
    ``kernels.each_dealt_chunk``). A bin
    writes only its own receivers, so the result does not depend on the
    thread count."""
    each_dealt_chunk(lambda jbs: _penumbra_bins(jbs, bins, blist, quads, grid, fb, rec, records, occ, lit, mode,
                                                refine, wedge, pen, ls, evals), bins.perm.shape[0], threads)


@kernel(opt=HOT, nogil=True, error_model="numpy")
def _penumbra_bins(jbs, bins, blist, quads, grid, fb, rec, records, occ, lit, mode, refine, wedge, pen, ls, evals):
    """Per bin ``bins.perm[jb]``, jb in ``jbs`` (in turn): every quad listed
    in it is rasterized over the bin's columns; the wedge test (second
    optimization) or the quad test selects the receivers, and each gets the
    signed analytic term of the edge.

    bins: Bins; blist: BinList of records; quads: Quads; grid: ReceiverGrid;
    fb: FaceBounds; rec: Receivers; records: Records; occ: Occluders; lit:
    KernelLight; mode: geom.SILHOUETTE_*; refine / wedge: the two overdraw
    reductions; ``pen`` per receiver, ls: LightSamples (updated), ``evals``
    per bin. A serial ``nogil`` kernel (issue 15: a prange one's parfor
    lowering was most of its compile time), its arguments
    ``kernels.borrowed`` and ``error_model="numpy"`` as a prange body's."""
    bins, blist, quads, grid, fb, rec, records, occ, lit, pen, ls, evals = borrowed(
        (bins, blist, quads, grid, fb, rec, records, occ, lit, pen, ls, evals))
    perm, bin_face, bin_bx, bin_by, bin_size = bins.perm, bins.face, bins.bx, bins.by, bins.size
    binmax = bins.maxz
    bin_start, bin_items = blist.start, blist.items
    ep, flag = quads.ep, quads.flag
    faces, col_base, gd, zlo, zhi = grid.faces, grid.col_base, grid.gd, grid.zlo, grid.zhi
    logz, cell_start, colmax = grid.logz, grid.cell_start, grid.colmax
    face_Z, face_k, face_rho, face_par = fb.Z, fb.k, fb.rho, fb.par
    Ps, XYZ, RF = rec.Ps, rec.XYZ, rec.RF
    rec_t, rec_k = records.t, records.k
    tv, nv, facing, orient = occ.tv, occ.nv, occ.facing, occ.orient
    cx, cy, cz, is_sun, rL, tan_a = lit.cx, lit.cy, lit.cz, lit.is_sun, lit.rL, lit.tan_a
    for jb in jbs:
        b = perm[jb]
        f = bin_face[b]
        fp = faces[f]
        persp = fp[16] == 0.0
        gw = int(fp[21])
        gh = int(fp[22])
        bc0 = bin_bx[b] * bin_size
        bc1 = min(bc0 + bin_size, gw) - 1
        br0 = bin_by[b] * bin_size
        br1 = min(br0 + bin_size, gh) - 1
        bx0, bx1, by0, by1 = col_rect(fp, bc0, bc1, br0, br1)
        kbin = 1.0 if face_par[f] else rect_k(bx0, bx1, by0, by1)
        Zuse = binmax[b] if refine else face_Z[f]
        kuse = kbin if refine else face_k[f]
        nev = 0
        for e in range(bin_start[b], bin_start[b + 1]):
            r = bin_items[e]
            t = rec_t[r]
            k = rec_k[r]
            whole = flag[r, f] == QUAD_WHOLE_FACE
            ax, ay, az = ep[r, f, 0], ep[r, f, 1], ep[r, f, 2]
            qx, qy, qz = ep[r, f, 3], ep[r, f, 4], ep[r, f, 5]
            zq = min(az, qz)
            c0, c1, r0, r1 = bc0, bc1, br0, br1
            wmax = 0.0
            if not whole:
                wa, wb = _bin_quad(ep, r, f, fp, persp, rL, face_rho[f], tan_a, Zuse, kuse)
                if wa < 0.0 or wb < 0.0:
                    whole = True
                else:
                    wmax = max(wa, wb)
                    q0, q1 = col_range(fp, min(ax - wa, qx - wb), max(ax + wa, qx + wb))
                    s0_, s1_ = row_range(fp, min(ay - wa, qy - wb), max(ay + wa, qy + wb))
                    c0 = max(c0, q0)
                    c1 = min(c1, q1)
                    r0 = max(r0, s0_)
                    r1 = min(r1, s1_)
            for row in range(r0, r1 + 1):
                rc0, rc1 = c0, c1
                if not whole:
                    # rasterize the quad, not its box: columns within wmax of
                    # the part of the edge inside this row's band
                    _, _, y0r, y1r = col_rect(fp, c0, c0, row, row)
                    xa, xb = seg_x_in_band(ax, ay, qx, qy, y0r - wmax, y1r + wmax)
                    if xa > xb:
                        continue
                    q0, q1 = col_range(fp, xa - wmax, xb + wmax)
                    rc0 = max(rc0, q0)
                    rc1 = min(rc1, q1)
                for col in range(rc0, rc1 + 1):
                    column = col_base[f] + row * gw + col
                    cm = colmax[column]
                    if not (cm > -np.inf):
                        continue
                    k0 = 0
                    kc = 1.0
                    if not whole:
                        x0, x1, y0, y1 = col_rect(fp, col, col, row, row)
                        D = seg_rect_dist(ax, ay, qx, qy, x0, x1, y0, y1)
                        if wedge:
                            if persp:
                                kc = 1.0 if face_par[f] else rect_k(x0, x1, y0, y1)
                                a = D * zq / (rL * kc)
                                if a >= 1.0:
                                    continue
                                zs = (zq - a * face_rho[f]) / (1.0 - a)
                            else:
                                zs = zq + D / tan_a
                            zs *= 1.0 - 1e-9
                            if zs > cm:
                                continue
                            k0 = slice_of(zs, zlo[f], zhi[f], gd, logz[f])
                        elif D > wmax:
                            continue
                    s0 = cell_start[column * gd + k0]
                    s1 = cell_start[column * gd + gd]
                    for s in range(s0, s1):
                        if RF[s, 9] <= 0.0:
                            continue
                        if wedge and not whole:
                            # the wedge bound at the receiver's own image point and depth
                            zp = XYZ[s, 2]
                            if not (zp > zq):
                                continue
                            if persp:
                                wz = rL * kc * (zp - zq) / (zq * (zp - face_rho[f]))
                            else:
                                wz = tan_a * (zp - zq)
                            wz *= 1.0 + 1e-9
                            if point_seg_dist2(XYZ[s, 0], XYZ[s, 1], ax, ay, qx, qy) > wz * wz:
                                continue
                        px, py, pz = Ps[s, 0], Ps[s, 1], Ps[s, 2]
                        if is_sun:
                            dx, dy, dz = cx, cy, cz
                        else:
                            dx, dy, dz = cx - px, cy - py, cz - pz
                        nev += 1
                        pen[s] += penumbra_term(px, py, pz, dx, dy, dz, tv, nv, facing[t], orient[t], mode, t, k,
                                                lit, RF, s, ls)
        evals[b] = nev


@kernel(parallel=True)
def penumbra_brute_force(rec, records, occ, lit, mode, pen, ls):
    """Every record against every receiver (no quads): the ground truth the
    quads and both overdraw reductions must reproduce (tests, ablation).
    rec: Receivers; records: Records; occ: Occluders; lit: KernelLight;
    ls: LightSamples."""
    Ps, RF = rec.Ps, rec.RF
    rec_t, rec_k = records.t, records.k
    tv, nv, facing, orient = occ.tv, occ.nv, occ.facing, occ.orient
    cx, cy, cz, is_sun = lit.cx, lit.cy, lit.cz, lit.is_sun
    for s in prange(Ps.shape[0]):
        px, py, pz = Ps[s, 0], Ps[s, 1], Ps[s, 2]
        if RF[s, 9] <= 0.0:
            continue
        if is_sun:
            dx, dy, dz = cx, cy, cz
        else:
            dx, dy, dz = cx - px, cy - py, cz - pz
        acc = 0.0
        for r in range(rec_t.shape[0]):
            acc += penumbra_term(px, py, pz, dx, dy, dz, tv, nv, facing[rec_t[r]], orient[rec_t[r]], mode,
                                 rec_t[r], rec_k[r], lit, RF, s, ls)
        pen[s] = acc


@kernel(parallel=True)
def umbra_brute_force(Ps, tri_ids, tv, nv, side_light, cx, cy, cz, is_sun, count):
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
