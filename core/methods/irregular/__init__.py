"""Soft irregular shadow mapping (Johnson, Hunt, Hux, Mark, Burns, Junkins
2009), method id ``irregular``: visibility exactly at the camera's visible
points, from the shadow-casting triangles.

Parameters (``IrregularParams``):
  silhouette_from   "centre"    silhouettes and layers from the light's centre (5.1) | "light"
  silhouettes       True        penumbra from silhouette edges only (2.1)
  adjacency         True        hashed vertex positions (2.1); False: "all edges are silhouettes"
  bin_refine, wedge_test  True  2.5's two overdraw reductions (quad width per bin; wedge test)
  rect_kernel       True        rectangle kernel for square / rectangle lights
  overlap, overlap_samples  "sampled", 12  equation 5's C ("zero"), light samples per side
  horizon           False       V <= the light above the tangent plane
  samples_per_cell, depth_slices, bin_size  16.0, 16, 16  the light-view grid (figure 3)
  brute_force       False       every edge at every receiver (ground truth)
  visibility        "irradiance"  the irradiance ratio | "average" (equation 2)

Algorithm (figure 2): (a) the receivers, the G-buffer hits moved off their
surface by ``sampling.offset_origin`` (as the reference), are counting-sorted
into a light-space grid (``grid``); (b) umbra (2.4, ``umbra``): the count of
triangles between each receiver and the light's centre, exact at the
receiver (watertight orientation tests); (c) one penumbra quad per
silhouette record (2.2, ``mesh``, ``penumbra``), sized from the light radius
and the largest receiver depth, sorted into bins; (d) every receiver under
a quad gets the edge projected from it onto the light (``light``), clipped
and measured by equation 3 or the rectangle kernel, signed by the edge
equation (2.3, ``geom``). V = 1 - clamp(umbra + penumbra - C, 0, 1) (eq. 5).

Departures from the paper:
  * the footprint radius R = r (1/z_q - 1/z_p) (2.3) is taken at both edge
    endpoints (the edge projected from the receiver in homogeneous
    coordinates), not at the one point q nearest p: the exact projection;
  * occluders count once per layer: of a closed mesh only the faces through
    which rays from the light's centre enter it (leave it, when the centre
    is inside); C = 0 would otherwise double every penumbra of a solid;
  * C from the depth complexity at an m x m grid of light samples (Laine et
    al. 2005's counts; m = ``overlap_samples``): each penumbra term adds its
    sign at the samples inside its region, C = mean_j max(count_j - 1, 0).
    The paper's: ``overlap="zero"`` (overlapping occluders over-darken);
  * square / rectangle lights: the exact rectangle kernel (2.3 allows
    Assarsson et al.'s kernels); the paper's disk kernel, on the ellipse of
    equal area and aspect: ``rect_kernel=False``;
  * ``silhouette_from="light"``: edges that are silhouettes from any point of
    the light, layers counted from each receiver, exact for one closed
    occluder where the paper's single point of projection (5.1) misses what
    a receiver's own surface hides. The paper's version: "centre";
  * ``horizon`` (off: the paper's) bounds V by ``horizon.horizon_share``,
    exact for a convex object (average only);
  * visibility="irradiance": each term of equations 4 and 5 weighs the
    light's emission towards the receiver (cos_l / d^2), taken as linear
    over the light: exact at the term's region's centroid, so the terms
    still add up (``geom.region_centroid``, ``light.emission_gradient``; C
    from weighted samples). The light below the receiver's tangent plane
    weighs nothing (cos_r = 0) and equation 5 counts the receiver's own
    surface over it: V / h (h = ``horizon.horizon_share``), at most 1. cos_r
    is left out otherwise: its clamp there is not linear over the light. The
    paper's: visibility="average";
  * alpha-matte casters (not in the paper) are traced apart by the
    reference's rays (``matte_visibility``) and multiplied into V.

Phases timed: ``silhouettes``, ``grid``, ``umbra``, ``penumbra``,
``overlap``, ``mattes``, ``horizon``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ...sampling import offset_points
from ..base import IRRADIANCE, GBUFFER, SHADOW_TRIANGLES, Method, MethodResult, PhaseTimer
from ..embree_ref import trace_visibility
from ..horizon import horizon_share
from ..registry import register
from .geom import SILHOUETTE_CENTRE, SILHOUETTE_LIGHT, light_samples, overlap_from_counts
from .grid import BinList, Bins, FaceBounds, Grid, LightSamples, Occluders, ReceiverGrid, Receivers, Records
from .light import KernelLight, light_model, receiver_frames
from .mesh import classify, mesh_adjacency
from .penumbra import QUAD_WHOLE_FACE, Quads, bin_quads, edge_quads, penumbra_bins, penumbra_brute_force
from .umbra import bin_entries_from_ranges, triangle_ranges, umbra_bins, umbra_brute_force


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
                                    # sample per eye pixel and several per cell)
    depth_slices: int = 16          # depth cells per column of the 3D perspective grid (figure 3)
    bin_size: int = 16              # grid columns per side of a bin (Larrabee sort-middle bins)
    brute_force: bool = False       # every edge against every receiver (ground truth for the quads)
    overlap: str = "sampled"        # 5.2, equation 5's overlap C between occluders: "sampled" (C from the depth
                                    # complexity at overlap_samples^2 light points, so overlapping occluders unite)
                                    # | "zero" (the paper: C = 0, overlapping occluders over-darken)
    horizon: bool = False           # V <= the share of the light above the receiver's tangent plane (its own
                                    # surface hides the rest; off: the paper's silhouettes alone)
    overlap_samples: int = 12       # light samples per side of the grid of equal cells that estimates C (memory:
                                    # one byte per sample per receiver; more: a finer estimate of the overlap)

    visibility: str = "irradiance"   # the pass: "irradiance" (the ratio that composites, eq. 1) | "average" (eq. 2)

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
        RF = receiver_frames(light, lm, Ps, params.visibility == IRRADIANCE)
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
            if params.visibility == IRRADIANCE and RF[:, 12:14].any():
                over[g.order] = overlap_from_counts(cnt_s, ls.counts, rows=ls.rows, first=ls.first, RF=RF)
            else:
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


def matte_visibility(mattes, P, Nrm, idx, light, scale, irradiance=False) -> np.ndarray:
    """Alpha-matte blockers (not in the paper): the receivers' average
    transmittance through them (``irradiance``: its irradiance ratio), by
    the reference's shadow rays (``embree_ref.trace_visibility``,
    MATTE_SAMPLES per receiver) against a BVH of the matte triangles alone.
    The opaque triangles go through the algorithm and the two are
    multiplied: the paper's own independence of occluders (C = 0, section
    5.2), here between the opaque and the matte layers."""
    ns = 1 if light.is_zero_size else MATTE_SAMPLES
    va, vi, _ = trace_visibility(mattes, P, Nrm, idx, light, ns, 0, scale)
    return vi if irradiance else va


def above_horizon(V, h):
    """visibility="irradiance": eq. 5's V at receivers whose light is the
    share ``h`` above their tangent plane (``horizon.horizon_share``) over
    that share, at most 1 (module doc); V where h is 0."""
    hv = np.asarray(h, np.float64)
    out = np.minimum(V.astype(np.float64) / np.where(hv > 0.0, hv, 1.0), 1.0)
    return np.where(hv > 0.0, out, V).astype(np.float32)


@register
class SoftIrregularShadowMapping(Method):
    id = "irregular"
    paper = "Johnson, Hunt, Hux, Mark, Burns, Junkins 2009"
    passes = {"irregular": IRRADIANCE}
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
            has, mattes = buffers.matte_casters
            if has is not None:
                tris, tobj = tris[~has], tobj[~has]
        V, _, _, stats = soft_irregular(P, Nrm, tris, tobj, light, params, buffers.scale, timer,
                                        bounds=buffers.bounds())
        irradiance = params.visibility == IRRADIANCE
        if irradiance and not light.is_zero_size:
            with timer("horizon"):
                V = above_horizon(V, horizon_share(light, P, Nrm))
        if mattes is not None:
            with timer("mattes"):
                V = V * matte_visibility(mattes, P, Nrm, g.seed_ids(idx), light, buffers.scale, irradiance)
        if params.horizon and not light.is_zero_size and not irradiance:
            with timer("horizon"):
                V = np.minimum(V, horizon_share(light, P, Nrm).astype(np.float32))
        out = np.ones(H * W, np.float32)
        out[idx] = V
        return MethodResult(passes={"irregular": out.reshape(H, W)}, time_s=timer.result(), stats=stats)
