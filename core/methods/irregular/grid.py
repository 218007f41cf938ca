"""The light-space receiver grid of soft irregular shadow mapping (Johnson
et al. 2009, figure 3) and the face-plane helpers of its binned passes.

Grid (figure 3): receivers are projected into the light's view faces (one
perspective face when they lie within ``SINGLE_FACE_HALF_ANGLE`` of the
light's axis, else cube faces; one orthographic face for a sun); each face
is cut into columns (``gw x gh``, about ``samples_per_cell`` receivers per
column) and every column into ``gd`` depth slices (log-spaced for
perspective faces). Cells are numbered column-major with the slices of a
column consecutive, and receivers are stored contiguously by a counting sort
(O(n)), so the receivers of a column at or beyond a given slice are one
contiguous range.

Bins (section 2.5, Larrabee's sort-middle rasterizer): columns are grouped
into ``B x B`` bins. Triangles (``umbra``) and penumbra quads (``penumbra``)
are sorted into the bins they overlap (counting sort again), then bins are
processed in parallel; each bin owns its receivers, so there are no write
races and the result does not depend on the thread count.
"""
from __future__ import annotations

import dataclasses
import math
from collections import namedtuple

import numpy as np

from ... import views
from ...jit import inner, kernel
from ...kernels import borrowed, each_dealt_chunk, face_project, pick_face
from .light import LightModel

SINGLE_FACE_HALF_ANGLE = math.radians(60.0)   # as views.MAX_SINGLE_VIEW_HALF_ANGLE
MAX_GRID_SIDE = 4096

# argument groups of the binned kernels (``umbra``, ``penumbra``)
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
LightSamples = namedtuple("LightSamples", "rows first counts")
"""Equation 5's overlap C: light samples in rows (unit-shape coordinates,
``geom.light_samples``: per row y, first x, spacing; first sample index) and
every receiver's depth complexity there beyond its umbra count (int8[n, m],
cell order; no rows: the paper's C = 0)."""


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
    ``kernels.borrowed`` arguments (as ``penumbra._penumbra_bins``)."""
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
# the grid of one light
def grid_faces(light, pts: np.ndarray, bounds):
    """The light-view faces of the receiver grid (views.py's projections)."""
    if light.kind == "sun":
        return views.light_view_faces(light, pts, bounds, 64)
    eye = light.position
    fwd = light.direction
    d = pts - eye
    dist = np.linalg.norm(d, axis=1)
    if (dist > 0).all():
        cosang = (d @ fwd) / dist
        if cosang.min() >= math.cos(SINGLE_FACE_HALF_ANGLE):
            f = views.fit_perspective_face(eye, fwd, pts, 64)
            if f is not None:
                return [f]
    return views.cube_faces(eye, pts, 64)


def _sized(face, n: int, spc: float):
    cols = max(1.0, n / max(spc, 1e-3))
    l, r, b, t = face.bounds
    aspect = (r - l) / (t - b)
    gw = int(min(MAX_GRID_SIDE, max(1, round(math.sqrt(cols * aspect)))))
    gh = int(min(MAX_GRID_SIDE, max(1, round(cols / gw))))
    return dataclasses.replace(face, width=gw, height=gh)


class Grid:
    """The receiver grid of one light (figure 3) and its per-face data."""

    def __init__(self, light, lm: LightModel, P: np.ndarray, bounds, params):
        """Receivers ``P`` (offset, float64[n,3]) of ``light`` (``lm`` its
        ``light_model``); ``params``: the method's IrregularParams
        (``samples_per_cell``, ``depth_slices``, ``bin_size``)."""
        self.n = len(P)
        faces = grid_faces(light, P, bounds)
        packed = np.stack([f.packed() for f in faces]) if faces else np.zeros((0, 24))
        fu, fv, fz = (np.empty(self.n) for _ in range(3))
        face = assign_faces(P, packed, fu, fv, fz) if len(faces) else np.full(self.n, -1, np.int64)
        keep = [f for f in range(len(faces)) if (face == f).any()]
        counts = [int((face == f).sum()) for f in keep]
        faces = [_sized(faces[f], c, params.samples_per_cell) for f, c in zip(keep, counts)]
        self.faces = faces
        F = len(faces)
        self.packed = np.stack([f.packed() for f in faces]) if F else np.zeros((0, 24))
        if F:
            face = assign_faces(P, self.packed, fu, fv, fz)
        else:
            face = np.full(self.n, -1, np.int64)
        self.face = face
        gw = np.array([f.width for f in faces], np.int64)
        gh = np.array([f.height for f in faces], np.int64)
        B = max(1, int(params.bin_size))
        self.B = B
        self.col_base = np.concatenate([[0], np.cumsum(gw * gh)]).astype(np.int64)
        self.nbx = ((gw + B - 1) // B).astype(np.int64)
        nby = ((gh + B - 1) // B).astype(np.int64)
        self.bin_base = np.concatenate([[0], np.cumsum(self.nbx * nby)]).astype(np.int64)
        self.logz = np.array([not f.ortho for f in faces], np.bool_)
        zlo = np.zeros(F)
        zhi = np.zeros(F)
        for f in range(F):
            z = fz[face == f]
            zlo[f], zhi[f] = float(z.min()), float(z.max())
        self.zlo, self.zhi = zlo, zhi
        self.gd = max(1, int(params.depth_slices))
        self.order, self.cell_start, self.colmax, self.binmax = counting_sort_cells(
            face, fu, fv, fz, self.packed, self.col_base, self.gd, zlo, zhi, self.logz,
            int(self.col_base[-1]), B, self.bin_base, self.nbx)
        # face-plane coordinates and depth of the sorted receivers (wedge test)
        o = self.order
        self.xyz = np.empty((len(o), 3))
        if len(o):
            fo = face[o]
            fpk = self.packed[fo]
            self.xyz[:, 0] = fpk[:, 17] + fu[o] / fpk[:, 21] * (fpk[:, 18] - fpk[:, 17])
            self.xyz[:, 1] = fpk[:, 20] - fv[o] / fpk[:, 22] * (fpk[:, 20] - fpk[:, 19])
            self.xyz[:, 2] = fz[o]
        nb = int(self.bin_base[-1])
        self.bin_face = np.zeros(nb, np.int64)
        self.bin_bx = np.zeros(nb, np.int64)
        self.bin_by = np.zeros(nb, np.int64)
        for f in range(F):
            ids = np.arange(self.bin_base[f], self.bin_base[f + 1])
            loc = ids - self.bin_base[f]
            self.bin_face[ids] = f
            self.bin_bx[ids] = loc % self.nbx[f]
            self.bin_by[ids] = loc // self.nbx[f]
        self.perm = np.random.default_rng(0x15A).permutation(nb).astype(np.int64)
        # per-face constants of the quad bound (module docstring of ``penumbra``)
        self.par = np.zeros(F, np.bool_)
        self.k = np.ones(F)
        self.rho = np.zeros(F)
        self.near = np.zeros(F)          # penumbra: edges clipped to depth >= near
        self.rnear = np.zeros(F)         # ... unless closer than this to the light centre
        self.near_u = np.zeros(F)        # umbra: triangles clipped to depth >= near_u
        axis = None
        if light.kind == "area":
            axis = light.axes[2]
        for f, fc in enumerate(faces):
            if fc.ortho:
                continue
            vz = np.asarray(fc.view_from_world)[2, :3]
            self.par[f] = axis is not None and abs(float(vz @ axis)) > 1.0 - 1e-12
            l, r, b, t = fc.bounds
            self.k[f] = 1.0 if self.par[f] else float(rect_k(l, r, b, t))
            self.rho[f] = 0.0 if self.par[f] else lm.rL
            tiny = 1e-7 * zlo[f]
            self.near[f] = max(2.0 * self.rho[f], tiny)
            self.rnear[f] = lm.rL + self.k[f] * (self.near[f] + lm.rL)
            self.near_u[f] = tiny

    @property
    def shape(self):
        return [(f.width, f.height) for f in self.faces]
