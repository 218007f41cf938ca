"""Soft irregular shadow mapping (Johnson, Hunt, Hux, Mark, Burns, Junkins
2009), method id ``irregular``: average visibility (equation 2) exactly at
the camera's visible points, from the triangles.

Figure 2, step by step:
  (a) receiver points: the camera G-buffer hits, moved off their surface by
      ``sampling.offset_origin`` (the self-intersection scheme the Embree
      reference uses), stored in a light-space grid (``grid``): a
      perspective grid from the light centre (one face, or cube faces when
      the receivers spread wider than 60 degrees), orthographic for a sun;
      columns x depth slices, receivers stored contiguously by counting sort.
  (b) umbra (section 2.4): each triangle's light-view projection is tested
      against the receivers of the columns it covers; the count of triangles
      between each receiver and the light centre (the "depth complexity") is
      exact at the receiver points (watertight 3D orientation tests).
  (c) penumbra quads (2.2): one per silhouette edge w.r.t. the light centre
      (adjacency from hashing vertex positions, ``mesh``), sized from the
      light radius and the largest receiver depth, sorted into bins; with
      ``bin_refine`` each bin rebuilds the quad from its own largest receiver
      depth, with ``wedge_test`` each column starts at the depth where the
      edge's penumbra wedge enters it (2.5).
  (d) for every receiver under a quad, the edge is projected from the
      receiver onto the light's plane, clipped to the light and measured by
      equation 3 (disk, ellipse, sphere, sun) or the rectangle kernel
      (square / rectangle area lights), signed by the edge equation (2.3).
  Composition: equation 5, V = 1 - clamp(umbra + penumbra - C, 0, 1), with
      the overlap C between occluders (``overlap``): "sampled" (default)
      estimates it from the depth complexity at an m x m grid of light
      samples (Laine et al. 2005's counts, the bitmask section 5.2 mentions):
      each penumbra term also adds its sign at the samples inside the region
      it measures, so umbra + counts = the occluders covering each sample and
      C = mean_j max(count_j - 1, 0); where occluders do not overlap C = 0
      and V stays the analytic one (no sampling noise), the umbra stays
      exact. "zero" is the paper's C = 0 (equation 4), bit for bit.

Per light type (DESIGN.md light domains):
  * sphere (point / spot, radius r): the disk of radius r through the centre
    facing each receiver, exactly as the reference samples it (the paper's
    "disk-projected spherical light"); frame per receiver.
  * area disk / ellipse: the light's own plane, scaled to the unit disk (an
    affine map keeps area fractions, so equation 3 stays exact).
  * area square / rectangle: ``rect_kernel`` (default) uses the exact
    rectangle kernel section 2.3 allows (Assarsson et al. 2003); off, the
    disk kernel on the ellipse of equal area and aspect (an approximation;
    its error is measured in the tests and the report).
  * sun (angle a): gnomonic projection of directions around the sun
    direction, where the cone of half-angle a/2 is the disk of radius
    tan(a/2); the kernel treats that disk as uniform (the reference is
    uniform in solid angle: relative weight cos^3 of the angle from the
    axis, 1 - 1e-4 for the real sun's 0.5 degrees).

Departures from the paper, each stated:
  * the footprint radius R = r (1/z_q - 1/z_p) of section 2.3 is evaluated at
    both endpoints of the edge (the edge is projected from the receiver onto
    the light's plane in homogeneous coordinates) rather than at the single
    point q nearest p; for an edge at constant depth this is the same, for
    others it is the exact projection;
  * occluders are counted once per layer: for closed meshes only the faces
    through which rays from the light centre enter the solid (or leave it,
    when the centre is inside), so front and back faces of one solid are not
    summed twice (section 5.2's C = 0 would otherwise double every penumbra
    of a closed object); open surfaces count every triangle;
  * the overlap C of equation 5 is estimated on light samples (above)
    rather than set to 0 (5.2), which over-darkens wherever occluders
    overlap (foliage at 256^2: RMSE 0.101 -> 0.022, in the penumbra 0.270
    -> 0.055); its error is the samples' estimate of the overlapping area
    only;
  * the remaining approximation is the paper's own: silhouettes from the
    light centre only (5.1). At a receiver turned partly away from the
    light (a curved object's terminator, a leaf at a steep angle) the
    centre's silhouettes miss part of what its own surface hides. With
    ``horizon`` (issue 17; off by default) V is at most the share of the
    light above its tangent plane (``horizon.horizon_share``), exact for a
    convex object, which lies wholly below that plane. 256 x 256 against
    1024-sample ``embree``, every pixel the light reaches (over the pixels
    that see the whole light nothing changes): torus_plane 0.0167 ->
    0.0027, grids 0.0267 -> 0.0194, foliage 0.0323 -> 0.0278, sun_pillars
    0.0078 -> 0.0051, but sphere_plane 0.0066 -> 0.0100: there the
    reference sees the whole light from terminator points whose facet
    plane hides up to half of it (share 0.24-0.45, reference 0.9-1.0):
    its rays start a few 1e-4 off the facet (``sampling.offset_origin``)
    and at grazing angles cross the facet's plane beyond its edge, where
    the tessellated sphere has fallen away.

Cost per phase: ``silhouettes`` (adjacency + records), ``grid`` (faces,
counting sort, receiver frames), ``umbra``, ``penumbra`` (quads, binning,
kernel, sample counts), ``overlap`` (C from the counts).
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from ... import raycast, views
from ..embree_ref import trace_visibility
from ...sampling import offset_points
from ..registry import register
from ..horizon import horizon_share
from .geom import (SHAPE_DISK, SHAPE_SQUARE, SILHOUETTE_CENTRE, SILHOUETTE_LIGHT, light_samples,
                   overlap_from_counts)
from .grid import (QUAD_WHOLE_FACE, BinList, Bins, FaceBounds, KernelLight, LightSamples, Occluders, Quads,
                   ReceiverGrid, Receivers, Records, assign_faces, bin_entries_from_ranges, bin_quads,
                   counting_sort_cells, edge_quads, penumbra_bins, penumbra_brute_force, rect_k, triangle_ranges,
                   umbra_bins, umbra_brute_force)
from .mesh import classify, mesh_adjacency
from ..base import AVERAGE, GBUFFER, SHADOW_TRIANGLES, Method, MethodResult, PhaseTimer

SINGLE_FACE_HALF_ANGLE = math.radians(60.0)   # as views.MAX_SINGLE_VIEW_HALF_ANGLE
MAX_GRID_SIDE = 4096


@dataclass
class IrregularParams:
    """Switches keep the paper's vocabulary (Johnson et al. 2009)."""
    silhouette_from: str = "centre" # 2.1 / 5.1: "centre" (the paper: silhouettes and layers seen from the light
                                    # centre) | "light" (edges that are silhouettes from any point of the light,
                                    # layers counted from each receiver: exact for one closed occluder)
    silhouettes: bool = True        # 2.1: penumbra from silhouette edges only (False: every edge of the counted triangles)
    adjacency: bool = True          # 2.1: mesh adjacency by hashing vertex positions (False: "all edges are silhouettes")
    bin_refine: bool = True         # 2.5, 1st overdraw reduction: quad width per bin from its max receiver depth
    wedge_test: bool = True         # 2.5, 2nd overdraw reduction: wedge / grid-column intersection
    rect_kernel: bool = True        # rectangle kernel for square / rectangle lights (False: equal-area disk kernel)
    samples_per_cell: float = 16.0  # receivers per light-view grid column on average (the paper keeps one light-view
                                    # sample per eye pixel and several per cell; 16 measured fastest on GRIDS 512^2)
    depth_slices: int = 16          # depth cells per column of the 3D perspective grid (figure 3)
    bin_size: int = 16              # grid columns per side of a bin (Larrabee sort-middle bins)
    brute_force: bool = False       # every edge against every receiver (ground truth for the quads)
    overlap: str = "sampled"        # 5.2, equation 5's overlap C between occluders: "sampled" (C from the depth
                                    # complexity at overlap_samples^2 light points, so overlapping occluders unite)
                                    # | "zero" (the paper: C = 0, overlapping occluders over-darken)
    horizon: bool = False           # issue 17: V <= the share of the light above the receiver's tangent plane
                                    # (its own surface; off by default: worse on sphere_plane, module doc)
    overlap_samples: int = 12       # light samples per side of the grid of equal cells that estimates C (memory:
                                    # one byte per sample per receiver; foliage 256^2 RMSE 0.040 / 0.022 / 0.016
                                    # at 8 / 12 / 16, penumbra time +110% / +130% / +160%)


# --------------------------------------------------------------------------
def _basis(n: np.ndarray):
    """Duff et al. orthonormal basis around unit vectors n[..., 3]."""
    nx, ny, nz = n[..., 0], n[..., 1], n[..., 2]
    s = np.where(nz >= 0.0, 1.0, -1.0)
    a = -1.0 / (s + nz)
    b = nx * ny * a
    e1 = np.stack([1.0 + s * nx * nx * a, s * b, -s * nx], -1)
    e2 = np.stack([b, s + ny * ny * a, -ny], -1)
    return e1, e2


@dataclass
class LightModel:
    """The light as the kernels see it."""
    is_sun: bool
    shape: int              # SHAPE_DISK | SHAPE_SQUARE
    centre: np.ndarray      # local: light centre; sun: unit direction towards the sun
    rL: float               # bounding radius of the light (sun: tan of the half angle)
    s1: float = 0.0         # half extents of the normalized shape (area lights)
    s2: float = 0.0
    approx: str = ""        # which approximation applies, if any

    @property
    def zero(self) -> bool:
        return not (self.rL > 0.0)


LINE_ASPECT = 1e-6


def light_model(light, rect_kernel: bool = True) -> LightModel:
    if light.kind == "sun":
        return LightModel(True, SHAPE_DISK, -light.direction, light.sun_spread,
                          approx="gnomonic disk treated as uniform")
    c = light.position
    if light.kind == "sphere":
        return LightModel(False, SHAPE_DISK, c, float(light.radius))
    hx, hy = light.half_size
    # a line light (one side 0): a rectangle / ellipse of relative width
    # LINE_ASPECT, so the kernels' divisions by the half sizes stay finite
    hx, hy = max(hx, LINE_ASPECT * hy), max(hy, LINE_ASPECT * hx)
    if light.is_round:
        return LightModel(False, SHAPE_DISK, c, max(hx, hy), hx, hy)
    if rect_kernel:
        return LightModel(False, SHAPE_SQUARE, c, math.hypot(hx, hy), hx, hy)
    k = 2.0 / math.sqrt(math.pi)      # ellipse of the rectangle's area and aspect
    return LightModel(False, SHAPE_DISK, c, max(hx, hy) * k, hx * k, hy * k,
                      approx="rectangle as equal-area ellipse")


def receiver_frames(light, lm: LightModel, Ps: np.ndarray) -> np.ndarray:
    """float64[n, 12]: e1/s1, e2/s2, n, h_p, p2x, p2y per receiver (see
    ``geom.penumbra_term``); h_p <= 0 marks receivers without penumbra."""
    n = len(Ps)
    RF = np.zeros((n, 12))
    if n == 0 or lm.zero:
        return RF
    if lm.is_sun:
        w = np.asarray(lm.centre, np.float64)
        e1, e2 = _basis(w[None])
        RF[:, 0:3] = e1[0] / lm.rL
        RF[:, 3:6] = e2[0] / lm.rL
        RF[:, 6:9] = w
        RF[:, 9] = 1.0
        return RF
    c = np.asarray(lm.centre, np.float64)
    d = Ps - c
    if light.kind == "sphere":
        h = np.linalg.norm(d, axis=1)
        nrm = d / np.where(h > 0, h, 1.0)[:, None]
        e1, e2 = _basis(nrm)
        RF[:, 0:3] = e1 / lm.rL
        RF[:, 3:6] = e2 / lm.rL
        RF[:, 6:9] = nrm
        RF[:, 9] = np.where(h > lm.rL * 1e-9, h, 0.0)
        return RF
    ax, ay, az = light.axes
    side = np.where(d @ az >= 0.0, 1.0, -1.0)
    nrm = side[:, None] * az[None]
    h = np.einsum("ij,ij->i", d, nrm)
    RF[:, 0:3] = ax / lm.s1
    RF[:, 3:6] = ay / lm.s2
    RF[:, 6:9] = nrm
    RF[:, 9] = np.where(h > 1e-12 * max(lm.rL, 1e-300), h, 0.0)
    RF[:, 10] = d @ (ax / lm.s1)
    RF[:, 11] = d @ (ay / lm.s2)
    return RF


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

    def __init__(self, light, lm: LightModel, P: np.ndarray, bounds, params: IrregularParams):
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
        # per-face constants of the quad bound (module docstring of grid)
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


def soft_irregular(P, Nrm, triangles, tri_object, light, params: IrregularParams, scale: float,
                   timer: PhaseTimer | None = None, bounds=None):
    """V (float32[n]) at points P with normals Nrm (facing the camera), plus
    the raw umbra count and penumbra sum per point and statistics."""
    timer = timer or PhaseTimer()
    n = len(P)
    P = np.ascontiguousarray(P, np.float64)
    Nrm = np.ascontiguousarray(Nrm, np.float64)
    tris = np.ascontiguousarray(triangles, np.float32).reshape(-1, 3, 3)
    lm = light_model(light, params.rect_kernel)
    stats = {"receivers": int(n), "triangles": int(len(tris)), "light": light.kind}
    if lm.approx:
        stats["approximation"] = lm.approx
    umbra = np.zeros(n, np.int64)
    pen = np.zeros(n, np.float64)
    if n == 0:
        return np.ones(0, np.float32), umbra, pen, stats
    Poff = offset_points(P, Nrm, float(scale), False)
    cx, cy, cz = (float(v) for v in lm.centre)
    with timer("silhouettes"):
        tv = tris.astype(np.float64)
        nv = np.cross(tv[:, 1] - tv[:, 0], tv[:, 2] - tv[:, 0])
        valid = (nv != 0.0).any(axis=1)
        if len(tris):
            adj = mesh_adjacency(tris, np.asarray(tri_object))
        else:
            z = np.zeros(0, np.int64)
            adj = (np.zeros((0, 3), np.int64), z, z, z, np.zeros(0, np.int8), np.zeros(0, np.int8),
                   z, np.zeros(0, np.bool_))
        if params.silhouette_from not in ("centre", "light"):
            raise ValueError(f"silhouette_from must be 'centre' or 'light', not {params.silhouette_from!r}")
        if params.overlap not in ("sampled", "zero"):
            raise ValueError(f"overlap must be 'sampled' or 'zero', not {params.overlap!r}")
        mode = SILHOUETTE_CENTRE if params.silhouette_from == "centre" else SILHOUETTE_LIGHT
        reach = lm.rL / math.sqrt(1.0 + lm.rL ** 2) if lm.is_sun else lm.rL
        counted, facing, orient, rec_t, rec_k = classify(
            tv, nv, valid, *adj, cx, cy, cz, lm.is_sun, bool(params.adjacency), bool(params.silhouettes),
            mode, float(reach))
        facing = facing.astype(np.int64)
        orient = orient.astype(np.int64)
        if lm.is_sun:
            sl = np.sign(nv @ lm.centre)
        else:
            sl = np.sign(np.einsum("ij,ij->i", tv[:, 0] - lm.centre, nv))
        side_light = sl.astype(np.int64)
        tri_ids = np.flatnonzero(counted).astype(np.int64)
        if lm.zero:
            rec_t = rec_t[:0]
            rec_k = rec_k[:0]
        stats.update(counted_triangles=int(len(tri_ids)), records=int(len(rec_t)),
                     closed_components=int(len(np.unique(adj[6][adj[7][adj[6]]]))))
    with timer("grid"):
        if bounds is None:
            bounds = (tv.reshape(-1, 3).min(0), tv.reshape(-1, 3).max(0)) if len(tv) else (P.min(0), P.max(0))
        g = Grid(light, lm, Poff, bounds, params)
        Ps = np.ascontiguousarray(Poff[g.order])
        RF = receiver_frames(light, lm, Ps)
        stats.update(grid_faces=[f.label for f in g.faces], grid_columns=g.shape,
                     depth_slices=g.gd, bins=int(g.bin_base[-1]))
    ns = len(Ps)
    cnt_s = np.zeros(ns, np.int64)
    pen_s = np.zeros(ns, np.float64)
    F = len(g.faces)
    lit = KernelLight(cx, cy, cz, lm.is_sun, lm.shape, lm.rL, lm.rL if lm.is_sun else 0.0)
    occ = Occluders(tv, nv, facing, orient, side_light)
    side = max(0, int(params.overlap_samples)) if params.overlap == "sampled" else 0
    rows, first = light_samples(lm.shape, side)
    m = int(first[-1])
    ls = LightSamples(rows, first, np.zeros((ns, m), np.int8))
    bins = Bins(g.perm, g.bin_face, g.bin_bx, g.bin_by, g.B, g.binmax)
    grid = ReceiverGrid(g.packed, g.col_base, g.gd, g.zlo, g.zhi, g.logz, g.cell_start, g.colmax)
    with timer("umbra"):
        if params.brute_force:
            umbra_brute_force(Ps, tri_ids, tv, nv, side_light, cx, cy, cz, lm.is_sun, cnt_s)
            stats["umbra_tests"] = int(ns * len(tri_ids))
        elif F and len(tri_ids):
            rng, zmin = triangle_ranges(tv, tri_ids, g.packed, g.near_u)
            bstart, bitems = bin_entries_from_ranges(rng, g.bin_base, g.nbx, g.B)
            tests = np.zeros(int(g.bin_base[-1]), np.int64)
            umbra_bins(bins, BinList(bstart, bitems), rng, zmin, tri_ids, occ, grid, Ps, lit, cnt_s, tests)
            stats["umbra_bin_entries"] = int(len(bitems))
            stats["umbra_tests"] = int(tests.sum())
    with timer("penumbra"):
        if len(rec_t) and ns:
            if params.brute_force:
                penumbra_brute_force(Receivers(Ps, g.xyz, RF), Records(rec_t, rec_k), occ, lit, mode, pen_s, ls)
                stats["penumbra_evals"] = int(ns * len(rec_t))
            elif F:
                ep, flag, rng = edge_quads(tv, rec_t, rec_k, g.packed, g.zhi, g.k, g.rho, g.near,
                                           g.rnear, lit.rL, lit.tan_a)
                bstart, bitems = bin_quads(ep, flag, rng, g.packed, g.bin_base, g.nbx, g.B, g.binmax,
                                           g.rho, g.k, g.par, lit.rL, lit.tan_a, bool(params.bin_refine))
                evals = np.zeros(int(g.bin_base[-1]), np.int64)
                penumbra_bins(bins, BinList(bstart, bitems), Quads(ep, flag, rng), grid,
                              FaceBounds(g.zhi, g.k, g.rho, g.par), Receivers(Ps, g.xyz, RF),
                              Records(rec_t, rec_k), occ, lit, mode, bool(params.bin_refine),
                              bool(params.wedge_test), pen_s, ls, evals)
                stats["quads_whole_face"] = int((flag == QUAD_WHOLE_FACE).sum())
                stats["quad_bin_entries"] = int(len(bitems))
                stats["penumbra_evals"] = int(evals.sum())
    umbra[g.order] = cnt_s
    pen[g.order] = pen_s
    if m:
        with timer("overlap"):
            over = np.zeros(n)
            over[g.order] = overlap_from_counts(cnt_s, ls.counts)
            occ = np.clip(umbra + pen - over, 0.0, 1.0)
            stats["overlap_samples"] = m
    else:
        occ = np.clip(umbra + pen, 0.0, 1.0)
    V = (1.0 - occ).astype(np.float32)
    V[g.face < 0] = 1.0
    return V, umbra, pen, stats


#: shadow rays per receiver through the alpha-matte blockers (``matte_visibility``)
MATTE_SAMPLES = 64


def matte_visibility(mattes, P, Nrm, idx, light, scale) -> np.ndarray:
    """Alpha-matte blockers (issue 18; not in the paper): the receivers'
    average transmittance through them, by the reference's shadow rays
    (``embree_ref.trace_visibility``, MATTE_SAMPLES per receiver) against a
    BVH of the matte triangles alone. The opaque triangles go through the
    algorithm as before and the two are multiplied: the paper's own
    independence of occluders (C = 0, section 5.2), here between the opaque
    and the matte layers."""
    ns = 1 if light.is_zero_size else MATTE_SAMPLES
    va, _, _ = trace_visibility(mattes, P, Nrm, idx, light, ns, 0, scale)
    return va


@register
class SoftIrregularShadowMapping(Method):
    id = "irregular"
    paper = "Johnson, Hunt, Hux, Mark, Burns, Junkins 2009"
    passes = {"irregular": AVERAGE}
    needs = frozenset({GBUFFER, SHADOW_TRIANGLES})
    packed = True                # shades each receiver of a packed G-buffer on its own
    Params = IrregularParams

    def run(self, buffers, light, params: IrregularParams) -> MethodResult:
        timer = PhaseTimer()
        g = buffers.gbuffer
        H, W = g.shape
        with timer("select"):
            idx, P, Nrm = g.hit_points()
            tris, tobj = buffers.shadow_triangles
            has, mattes = raycast.TriangleScene.matte_casters(buffers.scene)
            if has is not None:
                tris, tobj = tris[~has], tobj[~has]
        V, _, _, stats = soft_irregular(P, Nrm, tris, tobj, light, params, buffers.scale, timer,
                                        bounds=buffers.scene.bounds())
        if mattes is not None:
            with timer("mattes"):
                V = V * matte_visibility(mattes, P, Nrm, g.seed_ids(idx), light, buffers.scale)
        if params.horizon and not light.is_zero_size:
            with timer("horizon"):
                V = np.minimum(V, horizon_share(light, P, Nrm).astype(np.float32))
        out = np.ones(H * W, np.float32)
        out[idx] = V
        return MethodResult(passes={"irregular": out.reshape(H, W)}, time_s=timer.result(), stats=stats)
