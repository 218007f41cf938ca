"""Hierarchical penumbra casting (Laine & Aila 2005), method id ``penumbra_casting``.

The transpose of ray tracing: instead of finding, per receiver and light
sample, the triangle that blocks the ray, every blocker triangle T finds all
``l_i -> r_j`` relations it blocks by traversing two hierarchies at once.

* Receiver points r_j: the camera G-buffer hits in world space (section 3.2),
  moved off their surface exactly like the reference's ray origins
  (``sampling.offset_origin``, then rounded to float32 as Embree receives
  them), in a bounding volume hierarchy (``hierarchy``: midpoint splits
  above ``MidpointLimit`` points, SAH below, ``LeafSize`` points per leaf),
  each with a bit mask of blocked light samples.
* Light samples l_i: a jittered grid of ``samples`` strata, in groups G_k of
  about ``GroupSize`` strata with convex bounding polygons Delta_Gk, under the
  bounding polygon Delta_L (``light``), in ``SampleSets`` distinct sets,
  one set per receiver chosen by a hash of its pixel (section 3.4).
* Per triangle (``cast``): the penumbra volume V_L of the whole light
  (separating planes between Delta_L and T, capped by T's plane), the
  penumbra volumes V_Gk, the hard shadow volumes V_li (4 planes), and the
  recursive traversal of figure 2 with the optimizations of figure 3, each
  behind a switch: A ``umbra_bits`` (group/full umbra bits on points and nodes,
  AND propagation, rebuild of the hierarchy when ``RebuildFraction`` of its
  points are in full umbra), B ``active_plane_sets``, C ``lazy_volumes``, D
  ``masks_on_demand`` (allocated on first need, released in full umbra); and
  ``coarse_sort``: blockers bucketed by area (``SortBuckets`` log-spaced
  buckets, linear time), largest first.
* POINT-IN-VOLUME(r_j, V_li) (line 70): by default the four plane tests of
  V_li are evaluated with the roles of sample and receiver exchanged
  (``geometry.receiver_edge_functions``): per receiver and triangle three
  cross products, then per sample four dot products against the sample's
  coordinates, a 64-bit mask word at a time, and no V_li is ever built.
  ``materialize_hard_volumes=True`` builds the paper's per-sample planes
  instead (per triangle, per set and group on first need under C); the two
  agree exactly except for rays within rounding of an edge.
* Blockers (``blockers``, ``coplanar_blockers``): edge-adjacent
  triangles in one plane that form a convex polygon of up to ``MaxCorners``
  (6: a leaf's hexagon; 4: the earlier quads) corners are
  cast as that polygon, the simplest case of the paper's section 5 suggestion
  to process several blocker triangles at once: one traversal and one
  penumbra volume instead of one per triangle, and no false penumbra along
  the inner edges. The union is the polygon, so the blocked relations are
  the same up to rays within rounding of a removed inner edge (tested).
  A polygon costs one linear form per corner per sample test. Off: the paper's
  per-triangle algorithm.
* Interior blockers (``interior_blockers``, module ``cores``): convex
  polygons inside slices of every closed mesh (up to ``CoreSlices``, one
  per 4096 triangles, perpendicular to the light's direction, of
  ``CoreCorners`` corners), cast first; they block only relations the mesh
  blocks, and put most umbra receivers in full umbra before the mesh's small
  triangles are cast (issue 17: 1M-triangle smooth solids).
* ``hidden_behind_cores`` (ours, issue 17): a (triangle, receiver) pair is
  skipped when every ray from the receiver through the triangle's corners
  passes through a disk inside one slice polygon of the triangle's solid
  (the slice nearest the ray's closest approach to the solid's centroid):
  the light is outside the solid's box, so the slice is crossed before the
  light sample and blocks every relation the triangle would; near the leaves
  (boxes of up to 4 ``LeafSize`` points) the test is made for the whole box
  (per triangle corner, the box's 8 corners all before, or all beyond it:
  two convex sets). Penumbra receivers of a smooth solid then test only the
  triangles whose rays graze its silhouette.
* ``backface_cull`` (issue 17; ``group_backface_cull`` the same per group
  G_k: a blocker never activates the groups whose bounding polygon is
  entirely behind it): triangles of a closed, consistently wound
  solid the light is outside of, facing away from every vertex of the
  light's bounding polygon / volume, are dropped: a segment from a light
  sample outside the solid that meets it enters it first (going from the
  sample) through a triangle facing that sample. Condition: the solid's
  winding number is never negative (no inside-out part: true without
  self-intersections), not checked.
* Alpha-matte blockers (issue 18, section 4 "Alpha matte textures",
  ``alpha_blockers``): processed after all opaque ones; ``alpha_fetch``
  (default) finds the receivers in each matte blocker's V_L through the
  hierarchy and, per relation left open, intersects the blocker, fetches
  the alpha there and multiplies (1 - alpha) in; off: Embree rays through
  the matte blockers for every open relation.
* Triangles that cannot shadow a visible receiver never enter the
  traversal: a bounding-box test against the hull of the light and the
  receivers, then V_L against the receivers' bounding box.

V = 1 - (blocked samples) / samples, average visibility (Agrawala et al.
equation 2), the same quantity as the ``embree`` pass.

Light types (see ``light``): area lights use their rectangle / disk /
ellipse with the reference's own maps; the sun works with directions
(points at infinity, homogeneous w = 0: hard volumes are prisms, penumbra
volumes are separating planes between a cone of directions and T); sphere
lights (disk facing each point) use a fixed disk sample set rotated per
receiver and convex bounding *volumes* (boxes) for L and G_k (section 3.4,
"Volumetric light sources").

``shared_samples_with_reference``: every receiver uses the reference's own
per-pixel jittered samples (same seed, same strata, same maps) instead of the
8 sets, so the pass equals ``embree``'s up to rays that graze an edge.
``prepare`` exposes the receivers and every light sample position so a test
can cast the same rays itself.

Parallelism (ours, not the paper's): the receivers are split into
``chunks`` spatial chunks (median splits), each with its own hierarchy and
masks, processed on worker threads (Numba's thread count; the kernels release
the GIL); a relation's status is a geometric fact, so any chunking gives the
same bits.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Dict, List, Optional

import numba
import numpy as np

from ... import sampling
from ...jit import kernel
from ...kernels import borrowed, each_dealt_chunk, each_in_threads
from ..registry import register
from .alpha_blockers import (MatteBlockers, corner_order, fetch_visibility, matte_pairs, matte_triangles,
                             split_blockers, transmitted_visibility)
from .blockers import MAXB, coplanar_blockers, pad_triangles, sub_mesh
from .cores import closed_solids
from .cast import (N_ST, ST_GROUP_TESTS, ST_HARD_BUILT, ST_HARD_TESTS, ST_GROUP_VOLUMES, ST_HIDDEN, ST_HIDDEN_NODES,
                   ST_LEAF_VISITS,
                   ST_LIVE,
                   ST_NODES, ST_PEAK, ST_PAIRS, ST_POINT_TESTS, ST_POINTS, ST_ROOT_CULLED, ST_SLOTS, ST_UMBRA, Blockers,
                   CastSwitches, Hierarchy, LightGroups, Masks, Receivers, UmbraBits, cast_chunk_for,
                   chunk_visibility)
from .geometry import MAXP, box_vs_volume, penumbra_volume
from .hierarchy import build_hierarchy, node_umbra_bits
from .light import (MAXE, MAXV, MODE_FIXED, MODE_SHARED, MODE_SPHERE, SET_KEY, LightSamples, all_sample_points,
                        assign_sets, block_polygon_2d, box_to_homog, disk_polygon, fixed_sample_table,
                        group_layout, min_rotations, polygon_to_homog, sphere_disk_table)
from ..base import AVERAGE, GBUFFER, SHADOW_TRIANGLES, Method, MethodResult, PhaseTimer


@dataclass
class PenumbraCastingParams:
    samples: int = 256                # light samples per receiver (paper's benchmark: 256)
    GroupSize: int = 32               # light samples per group G_k (paper: 32)
    LeafSize: int = 16                # receiver points per leaf (paper: 16)
    MidpointLimit: int = 1024         # midpoint splits above, SAH below (paper: 1K)
    SampleSets: int = 8               # distinct light sample sets (paper: 8, section 3.4)
    umbra_bits: bool = True           # optimization A
    active_plane_sets: bool = True    # optimization B
    lazy_volumes: bool = True         # optimization C
    masks_on_demand: bool = True      # optimization D
    coarse_sort: bool = True          # coarse blocker sorting by area, largest first
    coplanar_blockers: bool = True    # cast coplanar convex triangle groups as one polygon (section 5)
    MaxCorners: int = 6               # corners of a merged blocker (<= MAXB; 4: quads, the earlier merge)
    interior_blockers: bool = True    # convex slices inside closed meshes, cast first (``cores``)
    backface_cull: bool = True        # closed meshes: drop triangles facing away from the whole light
    hidden_behind_cores: bool = True  # skip (blocker, receiver) pairs whose rays all pass an interior blocker
    group_backface_cull: bool = True  # closed meshes: a blocker skips the groups G_k it faces away from
    CoreSlices: int = 16              # at most this many interior slices per closed solid (``cores``)
    CoreCorners: int = 128            # corners of each slice's convex polygon
    SortBuckets: int = 32             # area buckets (paper: a histogram; count not given)
    RebuildFraction: float = 0.25     # A, line 29: the paper's "large enough fraction" (not given)
    shared_samples_with_reference: bool = False   # the embree reference's own per-pixel samples
    materialize_hard_volumes: bool = False  # True: build the 4 planes of every V_li per triangle
    alpha_fetch: bool = True          # section 4: alpha fetched at the relation-blocker intersection
                                      # (False: Embree rays through the matte blockers, ``alpha_blockers``)
    chunks: int = 0                   # receiver chunks processed in parallel; 0 = automatic
    seed: int = 0


_VL_BATCH = 1 << 16

# --------------------------------------------------------------------------
# small kernels
def _light_volumes(tris, nverts, DV, nv, DE, ne, eps, root_bb, tol, VL, nVL, keep, threads=None):
    """V_L of every candidate blocker and the test against the receivers'
    bounding box: ``keep`` = T may shadow some receiver. ``_light_volumes_of``
    on Numba's thread count (``kernels.each_dealt_chunk``)."""
    each_dealt_chunk(lambda ts: _light_volumes_of(ts, tris, nverts, DV, nv, DE, ne, eps, root_bb, tol, VL, nVL,
                                                  keep), tris.shape[0], threads)


@kernel(nogil=True, error_model="numpy")
def _light_volumes_of(ts, tris, nverts, DV, nv, DE, ne, eps, root_bb, tol, VL, nVL, keep):
    """``_light_volumes`` for blockers ``ts``: a serial ``nogil`` kernel with
    ``kernels.borrowed`` arguments (issue 15: a prange one's parfor lowering
    was most of its compile time)."""
    tris, nverts, DV, nv, DE, ne, root_bb, VL, nVL, keep = borrowed(
        (tris, nverts, DV, nv, DE, ne, root_bb, VL, nVL, keep))
    for t in ts:
        k = penumbra_volume(tris[t], nverts[t], DV, nv, DE, ne, eps, VL[t])
        nVL[t] = k
        if k < 0:
            keep[t] = False
            continue
        ok, _ = box_vs_volume(root_bb, np.int64(0), VL, t, k, np.int64(-1), np.bool_(False), tol)
        keep[t] = ok


def _bucket_sort_by_area(tris, nverts, nb):
    """Coarse blocker sorting (section 3.3): bucket by area on a log scale
    into ``nb`` buckets, largest first; linear time (histogram + counting
    sort: a stable sort of small integers), stable. A polygon's area is half
    its Newell normal (``geometry._newell``) over its ``nverts`` corners.
    NumPy, not a kernel: nothing to compile (the kernel was about 1 s of a
    cold start's compile, issue 15); a million blockers take 0.09-0.15 s
    against the kernel's 0.02 s."""
    n = tris.shape[0]
    out = np.arange(n, dtype=np.int64)
    if n == 0:
        return out
    t = tris.transpose(1, 2, 0)                          # [corner, axis, blocker]
    u, v = t[1] - t[0], t[2] - t[0]
    c = np.stack([u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]])
    poly = np.flatnonzero(nverts > 3)
    if len(poly):
        p = tris[poly]
        nv = nverts[poly][:, None]
        j = np.arange(p.shape[1])
        used = j < nv                                    # corners past nverts add no term
        q = np.take_along_axis(p, np.where(j + 1 < nv, j + 1, 0)[..., None], 1)   # the next corner
        c[:, poly] = np.stack([((p[..., 1] - q[..., 1]) * (p[..., 2] + q[..., 2]) * used).sum(1),
                               ((p[..., 2] - q[..., 2]) * (p[..., 0] + q[..., 0]) * used).sum(1),
                               ((p[..., 0] - q[..., 0]) * (p[..., 1] + q[..., 1]) * used).sum(1)])
    area = 0.5 * np.sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2])
    pos = area > 0.0
    if not pos.any():
        return out
    la = np.log(area[pos])
    lo, hi = la.min(), la.max()
    if not (hi > lo):
        return out
    bucket = np.full(n, nb - 1, np.int64)
    bucket[pos] = np.clip(((hi - la) / (hi - lo) * nb).astype(np.int64), 0, nb - 1)
    if nb <= 1 << 15:
        bucket = bucket.astype(np.int16)                 # NumPy's stable sort of 16-bit keys: a radix sort
    return np.argsort(bucket, kind="stable").astype(np.int64, copy=False)


# --------------------------------------------------------------------------
# light setup
@dataclass
class LightSetup:
    mode: int
    S: int
    nx: int
    ny: int
    G: int
    nsets: int
    bit2s: np.ndarray
    g_start: np.ndarray
    DVL: np.ndarray
    nvl: int
    DEL: np.ndarray
    nel: int
    DVg: np.ndarray
    nvg: np.ndarray
    DEg: np.ndarray
    neg: np.ndarray
    SP: np.ndarray
    Q: np.ndarray
    centre: np.ndarray
    lp: np.ndarray
    theta: float = 0.0
    w0: Optional[np.ndarray] = None


def _light_setup(light, params: PenumbraCastingParams, Pg: np.ndarray, tol: float) -> LightSetup:
    S = 1 if light.is_zero_size else max(1, int(params.samples))
    nx, ny, G, bit2s, g_start, blocks = group_layout(S, max(1, int(params.GroupSize)))
    shared = bool(params.shared_samples_with_reference)
    nsets = 1 if (light.is_zero_size or shared) else max(1, int(params.SampleSets))
    lp = sampling.pack_light(light)
    seed = int(params.seed)
    centre = light.position.astype(np.float64)
    ax, ay, az = light.axes
    DVg = np.zeros((G, MAXV, 4))
    DEg = np.zeros((G, MAXE, 2), np.int64)
    nvg = np.zeros(G, np.int64)
    neg = np.zeros(G, np.int64)
    SP = np.zeros((1, 1, 4))
    Q = np.zeros((1, 1, 3))
    theta = 0.0
    w0 = None
    if light.kind == "area":
        mode = MODE_SHARED if shared else MODE_FIXED
        disk = light.is_round
        hx, hy = light.half_size
        ex, ey = ax * hx, ay * hy
        full = disk_polygon(1.0) if disk else block_polygon_2d(0, 1, 0, 1, False)
        DVL, nvl, DEL, nel = polygon_to_homog(full, centre, ex, ey, 1.0, tol)
        for g in range(G):
            poly = block_polygon_2d(*blocks[g], disk)
            DVg[g], nvg[g], DEg[g], neg[g] = polygon_to_homog(poly, centre, ex, ey, 1.0, tol)
    elif light.kind == "sun":
        mode = MODE_SHARED if shared else MODE_FIXED
        cosmax = lp[sampling.L_COSMAX]
        if cosmax < 0.05:
            # a cone this wide has no tangent-plane polygon: no culling volumes
            DVL, nvl, DEL, nel = np.zeros((MAXV, 4)), 0, np.zeros((MAXE, 2), np.int64), 0
        else:
            def radial(rho):
                c = 1.0 - rho * rho * (1.0 - cosmax)
                return math.sqrt(max(0.0, 1.0 - c * c)) / c
            full = disk_polygon(radial(1.0))
            DVL, nvl, DEL, nel = polygon_to_homog(full, az, ax, ay, 0.0, 1e-15)
            for g in range(G):
                poly = block_polygon_2d(*blocks[g], True, radial)
                DVg[g], nvg[g], DEg[g], neg[g] = polygon_to_homog(poly, az, ax, ay, 0.0, 1e-15)
    else:  # sphere
        r = float(light.radius)
        if shared:
            mode = MODE_SHARED
            DVL, nvl, DEL, nel = box_to_homog([-r] * 3, [r] * 3, centre, np.eye(3), tol)
            for g in range(G):
                DVg[g], nvg[g], DEg[g], neg[g] = DVL, nvl, DEL, nel
        else:
            mode = MODE_SPHERE
            d = centre[None, :] - Pg
            dn = np.linalg.norm(d, axis=1)
            ok = dn > 0
            mean = (d[ok] / dn[ok, None]).sum(0) if ok.any() else np.zeros(3)
            if np.linalg.norm(mean) > 1e-9 * max(1, ok.sum()):
                w0 = mean / np.linalg.norm(mean)
            else:
                w0 = az.copy()
            e1, e2 = sampling.orthonormal_basis(*w0)
            e1, e2 = np.array(e1), np.array(e2)
            frame = np.stack([e1, e2, w0])
            _, ang = min_rotations(np.ascontiguousarray(Pg), centre, w0)
            theta = float(ang.max()) if len(ang) else 0.0
            dlt = 2.0 * r * math.sin(0.5 * min(theta, math.pi))
            dz = r * (math.sin(theta) if theta < 0.5 * math.pi else 1.0)
            DVL, nvl, DEL, nel = box_to_homog([-r, -r, -dz], [r, r, dz], centre, frame, tol)
            for g in range(G):
                poly = block_polygon_2d(*blocks[g], True) * r
                lo = np.maximum(poly.min(0) - dlt, -r)
                hi = np.minimum(poly.max(0) + dlt, r)
                DVg[g], nvg[g], DEg[g], neg[g] = box_to_homog([lo[0], lo[1], -dz], [hi[0], hi[1], dz],
                                                              centre, frame, tol)
            Q = sphere_disk_table(nsets, nx, ny, bit2s, seed, SET_KEY, r, e1, e2)
    if mode == MODE_FIXED:
        SP = fixed_sample_table(lp, nsets, nx, ny, bit2s, seed, SET_KEY)
    return LightSetup(mode, S, nx, ny, G, nsets, bit2s, g_start, DVL, int(nvl), DEL, int(nel),
                      DVg, nvg, DEg, neg, SP, Q, centre, lp, theta, w0)


# --------------------------------------------------------------------------
@dataclass
class Setup:
    """Everything the casting needs, before any triangle: receivers, light
    samples, groups, polygons. ``sample_points(rows)`` gives the exact light
    sample positions (homogeneous, bit order) the casting tests for those
    receivers, so a test can cast the same rays with Embree."""

    idx: np.ndarray          # pixel ids of the receivers
    Pg: np.ndarray           # G-buffer positions
    pts: np.ndarray          # receiver points r_j (the reference's ray origins)
    set_id: np.ndarray
    M: np.ndarray
    light: LightSetup
    seed: int
    tol: float
    eps: float

    def light_samples(self) -> LightSamples:
        L = self.light
        return LightSamples(L.mode, L.SP, L.Q, L.centre, L.lp, self.seed, L.bit2s, L.nx, L.ny)

    def sample_points(self, rows) -> np.ndarray:
        rows = np.ascontiguousarray(rows, np.int64)
        return all_sample_points(self.light_samples(), rows, self.light.S,
                                 Receivers(self.pts, self.set_id, self.idx, self.Pg, self.M))


def prepare(buffers, light, params: PenumbraCastingParams) -> Setup:
    g = buffers.gbuffer
    idx, Pg, Nrm = g.hit_points()
    pts = sampling.offset_points(Pg, Nrm, float(buffers.scale), True) if len(idx) else np.empty_like(Pg)
    mag = float(np.abs(pts).max()) if len(pts) else 1.0
    mag = max(mag, float(np.abs(light.position).max()), float(buffers.scale), 1e-30)
    tol = 1e-9 * mag
    eps = 1e-12 * mag
    L = _light_setup(light, params, Pg, tol)
    seed = int(params.seed)
    if L.mode == MODE_SPHERE:
        M, _ = min_rotations(Pg, L.centre, L.w0)
    else:
        M = np.zeros((1, 9))
    set_id = assign_sets(g.seed_ids(idx), L.nsets, seed) if L.nsets > 1 else np.zeros(len(idx), np.int64)
    return Setup(idx, Pg, pts, set_id, M, L, seed, tol, eps)


def _chunk_receivers(pts, n_chunks):
    """Median splits along the longest axis into about ``n_chunks`` pieces."""
    parts = [np.arange(len(pts))]
    coords = np.ascontiguousarray(pts.T)     # rows x, y, z: NumPy reduces (N, 3) columns slowly
    while len(parts) < n_chunks:
        parts.sort(key=len)
        big = parts.pop()
        if len(big) < 2:
            parts.append(big)
            break
        p = np.take(coords, big, axis=1)         # C order (coords[:, big] is not)
        ax = int(np.argmax(p.max(1) - p.min(1)))
        h = len(big) // 2
        low = np.zeros(len(big), np.bool_)
        low[np.argpartition(p[ax], h)[:h]] = True
        parts += [big[low], big[~low]]          # rows stay in increasing order
    return [c for c in parts if len(c)]


@dataclass
class _Chunk:
    rows: np.ndarray
    pts: np.ndarray
    set_id: np.ndarray
    pix: np.ndarray
    Pg: np.ndarray
    M: np.ndarray
    hier: Hierarchy = None
    fu: np.ndarray = None
    gu: np.ndarray = None
    slot: np.ndarray = None
    pool: np.ndarray = None
    free: np.ndarray = None
    st: np.ndarray = None
    build_s: float = 0.0
    rebuild_s: float = 0.0
    cast_s: float = 0.0
    rebuilds: int = 0
    hier_nodes_peak: int = 0
    leaves: int = 0
    V: np.ndarray = None
    matte_pairs: int = 0


def _matte_blockers(mattes, L: LightSetup, eps: float, root_bb: np.ndarray, tol: float) -> MatteBlockers:
    """The matte blockers (``alpha_blockers``) with their V_L, those that
    cannot shadow the receivers' box dropped."""
    tris, tri = matte_triangles(mattes)
    polys, nv = pad_triangles(tris)
    VL = np.zeros((len(tris), 4, MAXP))
    nVL = np.zeros(len(tris), np.int64)
    keep = np.zeros(len(tris), np.bool_)
    _light_volumes(polys, nv, L.DVL, L.nvl, L.DEL, L.nel, eps, root_bb, tol, VL, nVL, keep)
    tris = np.ascontiguousarray(tris[keep])
    return MatteBlockers(tris, np.ascontiguousarray(tri[keep]), corner_order(tris),
                         np.ascontiguousarray(VL[keep]), np.ascontiguousarray(nVL[keep]))


def _backfacing(tris, facing, verts, tol: float, nverts=None) -> np.ndarray:
    """Triangles (polygons with ``nverts`` corners) of a closed solid
    (``facing`` != 0: the sign that orients (b - a) x (c - a), or Newell's
    normal, outward) whose plane has every homogeneous vertex ``verts`` (of
    the light's bounding polygon / volume, or of a group's) strictly behind
    it. A segment from a light sample outside the solid to any receiver that
    meets the solid enters it first (going from the sample) through a
    triangle facing the sample, so such triangles block nothing from those
    samples the rest of the solid does not (issue 17; the solid's winding
    number is never negative: no inside-out parts)."""
    a = tris[:, 0]
    n = np.cross(tris[:, 1] - a, tris[:, 2] - a)
    if nverts is not None and (nverts > 3).any():
        big = np.flatnonzero(nverts > 3)
        q = tris[big]
        nn = np.zeros((len(big), 3))
        for j in range(q.shape[1]):                  # Newell's normal (the kernel's triangle_plane)
            k = np.where(j + 1 < nverts[big], j + 1, 0)
            r = q[np.arange(len(big)), k]
            on = j < nverts[big]
            p = q[:, j]
            nn[:, 0] += on * (p[:, 1] - r[:, 1]) * (p[:, 2] + r[:, 2])
            nn[:, 1] += on * (p[:, 2] - r[:, 2]) * (p[:, 0] + r[:, 0])
            nn[:, 2] += on * (p[:, 0] - r[:, 0]) * (p[:, 1] + r[:, 1])
        n[big] = nn
    n = n * facing[:, None]
    if not len(verts):
        return np.zeros(len(tris), np.bool_)
    h = n @ verts[:, :3].T - np.einsum("ij,ij->i", n, a)[:, None] * verts[None, :, 3]
    margin = np.linalg.norm(n, axis=1) * tol
    return (facing != 0) & np.all(h < -margin[:, None], axis=1)


def _light_box(L: LightSetup):
    """``cores.interior_blockers``' view of the light: (centre, direction,
    box lo, box hi); the sun's samples are at infinity (no box)."""
    verts = L.DVL[:L.nvl]
    if L.lp[0] == sampling.KIND_SUN and L.mode != MODE_SPHERE:
        d = verts[:, :3].mean(0) if L.nvl else np.zeros(3)
        return None, d, None, None
    fin = verts[verts[:, 3] != 0.0, :3]
    pts = np.vstack([fin, L.centre[None, :]])
    return L.centre, None, pts.min(0), pts.max(0)


def cast(setup: Setup, tris: np.ndarray, params: PenumbraCastingParams, timer: PhaseTimer,
         threads: Optional[int] = None, mattes=None):
    """Run the casting for ``tris`` (float64[T,3,3], the shadow-casting
    triangles); returns V per receiver (float64) and stats. ``mattes``: a
    BVH of the alpha-matte blockers, processed after ``tris``
    (``alpha_blockers``)."""
    L = setup.light
    n = len(setup.idx)
    stats: Dict[str, object] = {"receivers": int(n), "samples": int(L.S), "groups": int(L.G),
                                "sample_sets": int(L.nsets), "triangles_in": int(len(tris))}
    V = np.ones(n)
    if n == 0:
        return V, stats
    optA = bool(params.umbra_bits)
    optB = bool(params.active_plane_sets)
    optC = bool(params.lazy_volumes)
    optD = bool(params.masks_on_demand)
    leaf = max(1, int(params.LeafSize))
    midl = max(leaf, int(params.MidpointLimit))
    nwords = (L.S + 63) // 64
    # -- cull: triangles that cannot shadow any receiver -------------------
    with timer("cull"):
        lo = setup.pts.min(0)
        hi = setup.pts.max(0)
        root_bb = np.concatenate([lo, hi])[None, :]
        blo, bhi = lo.copy(), hi.copy()
        verts = L.DVL[:L.nvl]
        fin = verts[verts[:, 3] != 0.0, :3]
        if len(fin):
            blo = np.minimum(blo, fin.min(0))
            bhi = np.maximum(bhi, fin.max(0))
        dirs = verts[verts[:, 3] == 0.0, :3]
        if L.nvl == 0 and L.mode != MODE_SPHERE and L.lp[0] == sampling.KIND_SUN:
            blo[:] = -np.inf
            bhi[:] = np.inf
        if len(dirs):
            blo[(dirs < 0).any(0)] = -np.inf
            bhi[(dirs > 0).any(0)] = np.inf
        tmin = tris.min(1)
        tmax = tris.max(1)
        inbox = np.all((tmax >= blo - setup.tol) & (tmin <= bhi + setup.tol), axis=1)
        cand_tris = tris[inbox]
    n_cores = 0
    n_back = 0
    solids = None
    mesh = None
    if (params.interior_blockers or params.backface_cull) and len(cand_tris):
        with timer("cores"):             # every triangle: the box cull may open a closed mesh
            solids = closed_solids(tris, *_light_box(L), params.CoreSlices, params.CoreCorners)
            sel = np.flatnonzero(inbox)
            facing = solids.facing[sel]
            core_of = solids.solid_of[sel] if (params.interior_blockers and params.hidden_behind_cores) \
                else np.full(len(cand_tris), -1, np.int64)
            if params.backface_cull and facing.any():
                back = _backfacing(cand_tris, facing, L.DVL[:L.nvl], setup.tol)
                n_back = int(back.sum())
                cand_tris, core_of, sel, facing = cand_tris[~back], core_of[~back], sel[~back], facing[~back]
            if solids.mesh is not None:
                mesh = sub_mesh(solids.mesh, sel)   # the merge reuses the vertex ids and adjacency
    with timer("merge"):
        if params.coplanar_blockers:
            cand, cand_nv, poly_of = coplanar_blockers(cand_tris, params.MaxCorners, mesh)
        else:
            cand, cand_nv = pad_triangles(cand_tris)
            poly_of = np.arange(len(cand_tris))
        cand_core = np.full(len(cand), -1, np.int64)
        cand_facing = np.zeros(len(cand), np.int8)
        if solids is not None:
            cand_core[poly_of] = core_of     # a polygon's triangles are edge-adjacent: one solid
            if params.backface_cull:
                cand_facing[poly_of] = facing
    if params.interior_blockers and solids is not None:
        n_cores = len(solids.polys)
        if n_cores:
            cand = np.concatenate([solids.polys, cand])
            cand_nv = np.concatenate([solids.nverts, cand_nv])
            cand_core = np.concatenate([np.full(n_cores, -1, np.int64), cand_core])
            cand_facing = np.concatenate([np.zeros(n_cores, np.int8), cand_facing])
    with timer("cull"):
        # V_L of every candidate, in batches (bounds the MAXP-wide temporary);
        # survivors keep only as many plane slots as they use
        parts, nparts, widest = [], [], 1
        blocker_parts, nv_parts, core_parts, facing_parts = [], [], [], []
        for a in range(0, len(cand), _VL_BATCH):
            cb = np.ascontiguousarray(cand[a:a + _VL_BATCH])
            cnv = np.ascontiguousarray(cand_nv[a:a + _VL_BATCH])
            VLb = np.zeros((len(cb), 4, MAXP))
            nVLb = np.zeros(len(cb), np.int64)
            keep = np.zeros(len(cb), np.bool_)
            _light_volumes(cb, cnv, L.DVL, L.nvl, L.DEL, L.nel, setup.eps, root_bb, setup.tol, VLb, nVLb,
                           keep)
            w = int(nVLb[keep].max()) if keep.any() else 0
            widest = max(widest, w)
            parts.append(VLb[keep, :, :max(w, 1)])
            nparts.append(nVLb[keep])
            blocker_parts.append(cb[keep])
            nv_parts.append(cnv[keep])
            core_parts.append(cand_core[a:a + _VL_BATCH][keep])
            facing_parts.append(cand_facing[a:a + _VL_BATCH][keep])
        VL = np.zeros((sum(len(q) for q in parts), 4, widest))
        o = 0
        for q in parts:
            VL[o:o + len(q), :, :q.shape[2]] = q
            o += len(q)
        nVL = np.concatenate(nparts) if nparts else np.zeros(0, np.int64)
        blockers = np.ascontiguousarray(np.concatenate(blocker_parts)) if blocker_parts \
            else np.zeros((0, MAXB, 3))
        blocker_nv = np.ascontiguousarray(np.concatenate(nv_parts)) if nv_parts else np.zeros(0, np.int64)
        blocker_core = np.ascontiguousarray(np.concatenate(core_parts)) if core_parts else np.zeros(0, np.int64)
        blocker_facing = np.concatenate(facing_parts) if facing_parts else np.zeros(0, np.int8)
        # per blocker of a solid: the groups G_k it may face (the others' samples all see its back)
        gface = np.ones((len(blockers), L.G), np.uint8)
        solid_b = np.flatnonzero(blocker_facing != 0)
        for g in range(L.G if len(solid_b) and params.group_backface_cull else 0):
            gface[solid_b, g] = ~_backfacing(blockers[solid_b], blocker_facing[solid_b], L.DVg[g, :L.nvg[g]],
                                             setup.tol, blocker_nv[solid_b])
    stats["interior_blockers"] = int(n_cores)
    stats["triangles_backface_culled"] = int(n_back)
    stats["group_backface_culled"] = int((gface == 0).sum())      # (blocker, G_k) pairs
    stats["triangles_box_culled"] = int(len(tris) - int(inbox.sum()))
    stats["blocker_polygons"] = int(len(cand))
    stats["triangles_volume_culled"] = int(len(cand) - len(blockers))   # blockers (polygons)
    stats["blockers"] = int(len(blockers))
    # -- coarse sort ---------------------------------------------------------
    with timer("sort"):
        if params.coarse_sort and len(blockers):
            order = _bucket_sort_by_area(blockers, blocker_nv, max(1, int(params.SortBuckets)))
        else:
            order = np.arange(len(blockers), dtype=np.int64)
    # -- chunks --------------------------------------------------------------
    workers = max(1, int(threads or numba.get_num_threads()))
    n_ch = int(params.chunks) if params.chunks else min(4 * workers, max(1, n // 4096))
    n_ch = max(1, n_ch)
    chunks: List[_Chunk] = []
    with timer("build"):                 # the chunks are the hierarchy's top median splits
        for rows in _chunk_receivers(setup.pts, n_ch):
            chunks.append(_Chunk(rows, np.ascontiguousarray(setup.pts[rows]), setup.set_id[rows].copy(),
                                 setup.idx[rows].copy(), np.ascontiguousarray(setup.Pg[rows]),
                                 np.ascontiguousarray(setup.M[rows]) if L.mode == MODE_SPHERE else setup.M))
    stats["chunks"] = len(chunks)
    mb = None
    if mattes is not None and params.alpha_fetch:
        with timer("cull"):
            mb = _matte_blockers(mattes, L, setup.eps, root_bb, setup.tol)
        stats["matte_blockers"] = int(len(mb.tri))
    sol = solids if solids is not None else closed_solids(np.zeros((0, 3, 3)), None, None, None, None)
    blk = Blockers(order, blockers, blocker_nv, VL, nVL, blocker_core, sol.solids, sol.disks, gface)
    grp = LightGroups(L.DVg, L.nvg, L.DEg, L.neg, L.g_start)
    smp = setup.light_samples()
    switches = CastSwitches(optA, optB, optC, optD, float(params.RebuildFraction), leaf, setup.tol, setup.eps,
                            bool(params.materialize_hard_volumes), bool(blocker_core.size and blocker_core.max() >= 0))

    cast_chunk = cast_chunk_for(L.mode, switches.materialize)

    def run_pool(fn):
        each_in_threads(fn, chunks, workers)

    def build(c: _Chunk):
        t = time.perf_counter()
        m = len(c.rows)
        c.hier = Hierarchy(*build_hierarchy(c.pts, np.arange(m, dtype=np.int64), leaf, midl))
        # receivers stored in leaf order: a leaf's points are contiguous in memory
        perm = c.hier.perm
        c.rows, c.pts, c.set_id, c.pix, c.Pg = (c.rows[perm], np.ascontiguousarray(c.pts[perm]), c.set_id[perm],
                                                c.pix[perm], np.ascontiguousarray(c.Pg[perm]))
        if L.mode == MODE_SPHERE:
            c.M = np.ascontiguousarray(c.M[perm])
        c.hier = c.hier._replace(perm=np.arange(m, dtype=np.int64))
        nn = len(c.hier.left)
        c.hier_nodes_peak = nn
        c.leaves = int((c.hier.left < 0).sum())
        c.fu = np.zeros(m, np.uint8)
        c.gu = np.zeros((m, L.G), np.uint8)
        c.node_gu = np.zeros((nn, L.G), np.uint8)
        c.node_fu = np.zeros(nn, np.uint8)
        c.st = np.zeros(N_ST, np.int64)
        # zeroed on allocation: pages are committed on first touch (see cast)
        c.pool = np.zeros((m, nwords), np.uint64)
        if optD:
            c.free = np.empty(m, np.int64)
            c.slot = np.full(m, -1, np.int64)
        else:
            c.free = np.zeros(1, np.int64)
            c.slot = np.arange(m, dtype=np.int64)
            c.st[ST_LIVE] = c.st[ST_PEAK] = c.st[ST_SLOTS] = m
        c.st[ST_POINTS] = m
        c.build_s = time.perf_counter() - t

    def run(c: _Chunk):
        t_start = time.perf_counter()
        t0 = 0
        rec = Receivers(c.pts, c.set_id, c.pix, c.Pg, c.M)
        masks = Masks(c.slot, c.pool, c.free)
        while True:
            t0 = cast_chunk(t0, blk, grp, smp, rec, c.hier, UmbraBits(c.fu, c.gu, c.node_gu, c.node_fu),
                            masks, c.st, switches)
            if t0 >= len(order):
                break
            # line 29 (A): rebuild the hierarchy over the points not in full umbra
            tr = time.perf_counter()
            live = np.flatnonzero(c.fu == 0).astype(np.int64)
            c.hier = Hierarchy(*build_hierarchy(c.pts, live, leaf, midl))
            nn = len(c.hier.left)
            c.node_gu = np.zeros((nn, L.G), np.uint8)
            c.node_fu = np.zeros(nn, np.uint8)
            if len(live):
                node_umbra_bits(c.hier.left, c.hier.right, c.hier.start, c.hier.count, c.hier.perm, c.gu, c.fu,
                                c.node_gu, c.node_fu)
            c.st[ST_UMBRA] = 0
            c.st[ST_POINTS] = len(live)
            c.rebuilds += 1
            c.rebuild_s += time.perf_counter() - tr
        c.V = np.empty(len(c.rows))
        chunk_visibility(c.fu, c.slot, c.pool, L.S, c.V)
        if mb is not None:
            ptr, lists = matte_pairs(mb, c.hier, c.pts, c.fu, setup.tol)
            c.matte_pairs = int(ptr[-1])
            fetch_visibility(smp, rec, c.fu, c.slot, c.pool, L.S, ptr, lists, mb, mattes.alpha.mattes, c.V)
        elif mattes is not None:
            c.V = transmitted_visibility(mattes, smp, rec, c.fu, c.slot, c.pool, L.S)
        c.cast_s = time.perf_counter() - t_start - c.rebuild_s

    with timer("build"):
        run_pool(build)
    with timer("cast"):
        run_pool(run)
    for c in chunks:
        V[c.rows] = c.V
    st = np.sum([c.st for c in chunks], axis=0)
    if mb is not None:
        stats["matte_pairs"] = int(sum(c.matte_pairs for c in chunks))   # (receiver, matte blocker) in V_L
    bytes_per_mask = nwords * 8
    stats.update({
        "rebuilds": int(sum(c.rebuilds for c in chunks)),
        "rebuild_thread_s": float(sum(c.rebuild_s for c in chunks)),
        "cast_thread_s": float(sum(c.cast_s for c in chunks)),
        "build_thread_s": float(sum(c.build_s for c in chunks)),
        "peak_masks": int(st[ST_PEAK]),
        "peak_mask_bytes": int(st[ST_PEAK] * bytes_per_mask),
        "mask_pool_bytes": int(st[ST_SLOTS] * bytes_per_mask),
        "hierarchy_bytes": int(sum(c.hier_nodes_peak * (6 * 8 + 4 * 8 + L.G + 1) + 8 * len(c.rows)
                                   for c in chunks)),
        "receiver_bytes": int(n * (3 * 8 + 8 + 1 + L.G)),
        "nodes_visited": int(st[ST_NODES]),
        "point_tests": int(st[ST_POINT_TESTS]),
        "hard_volume_tests": int(st[ST_HARD_TESTS]),
        "triangles_with_group_volumes": int(st[ST_GROUP_VOLUMES]),
        "hard_volumes_built": int(st[ST_HARD_BUILT]),
        "triangles_root_culled": int(st[ST_ROOT_CULLED]),
        # where the cast time goes (issue 17): blockers per receiver leaf and per
        # receiver, penumbra volume (V_Gk) tests and per-sample tests
        "leaf_visits": int(st[ST_LEAF_VISITS]),
        "receiver_blocker_pairs": int(st[ST_PAIRS]),
        "group_volume_tests": int(st[ST_GROUP_TESTS]),
        "hidden_pairs": int(st[ST_HIDDEN]),
        "hidden_nodes": int(st[ST_HIDDEN_NODES]),
        "blockers_per_leaf": float(st[ST_LEAF_VISITS] / max(1, sum(c.leaves for c in chunks))),
        "blockers_per_receiver": float(st[ST_PAIRS] / max(1, n)),
        "sample_tests_per_relation": float(st[ST_HARD_TESTS] / max(1, n * L.S)),
    })
    return V, stats


def scene_blockers(scene) -> np.ndarray:
    """Shadow-casting, finite triangles as float64[T,3,3]."""
    return finite_blockers(scene.triangles[scene.tri_casts_shadow])


def finite_blockers(tris) -> np.ndarray:
    """The finite ones of shadow-casting triangles ``tris``, as float64[T,3,3]."""
    ok = np.isfinite(tris.reshape(len(tris), 9)).all(axis=1)
    return np.ascontiguousarray(tris[ok], np.float64)


@register
class PenumbraCasting(Method):
    id = "penumbra_casting"
    paper = "Laine, Aila 2005: Hierarchical Penumbra Casting"
    passes = {"penumbra_casting": AVERAGE}
    needs = frozenset({GBUFFER, SHADOW_TRIANGLES})   # it casts the triangles themselves: no BVH
    packed = True                # shades each receiver of a packed G-buffer on its own
    Params = PenumbraCastingParams
    physical = True

    def run(self, buffers, light, params: PenumbraCastingParams) -> MethodResult:
        timer = PhaseTimer()
        g = buffers.gbuffer
        H, W = g.shape
        with timer("setup"):
            setup = prepare(buffers, light, params)
            tris, mattes = split_blockers(buffers.scene, buffers.shadow_triangles[0])
            tris = finite_blockers(tris)
        V, stats = cast(setup, tris, params, timer, mattes=mattes)
        out = np.ones(H * W, np.float32)
        out[setup.idx] = np.clip(V, 0.0, 1.0).astype(np.float32)
        return MethodResult(passes={"penumbra_casting": out.reshape(H, W)}, time_s=timer.result(),
                            stats=stats)
