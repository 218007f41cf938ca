"""Coherence-based ray tracing of depth images (Agrawala, Ramamoorthi, Heirich,
Moll 2000, section 5), method id ``depth_raytrace``.

Precompute (independent of the number of light samples): reference shadow
maps from a few points on the light - the 4 corners of a rectangle, documented
boundary points for the other shapes (``maps.reference_eyes``) - rendered
with the skeleton's Embree depth renderer, and per map the min / max depth
quadtrees and the connectedness quadtree (gap bias).

Per camera G-buffer point: one shadow ray per stratum of the light's unit
square, to a jittered point on the light's true shape (the reference's
``sampling.light_sample`` with the same counter hash, so the two sample the
same points), from the point moved off its surface by
``sampling.offset_origin``. Each ray is traced through the depth images
(``trace``: hierarchical epipolar traversal, floors and walls, the
accelerations of 5.1.1-5.1.2 behind switches). With ``coherence`` only the
cells the coherent sampler of 5.2 asks for are traced (``coherence``);
points are visited in a serpentine order inside ``tile`` x ``tile`` tiles,
tiles run in parallel, each with its own state, so the result does not depend
on the thread count.

Passes: ``depth_raytrace`` = equation 2 (average visibility);
``depth_raytrace_irr`` = equation 1's ratio (the same cells weighted by
cos theta_r cos theta_l / r^2, as ``embree_irr``).

``tracer="embree"`` drives Embree shadow rays against the real triangles with
the same coherent sampler (the paper: "a standard geometric ray tracer might
incorporate our coherence-based sampling method"), batching the queued rays
of all tiles per wave, so the two ideas can be measured apart.

Stats: ``rays_per_pixel`` (rays actually traced, averaged over the shaded
pixels; the paper reports 79.86 of 256 on its dragon), reference map count
and texels, and the time split ``reference_maps`` / ``trace``. The
depth-image tracer also accounts for its rays (per shaded pixel): traced in
full for lack of a prediction (``full_trace_points`` - first point of a tile
or a reset - and ``full_trace_rays_per_pixel``), queued by Predict (edge and
border cells, ``predicted_rays_per_pixel``) or by the flood fill
(``flood_fill_rays_per_pixel``); the three add up to ``rays_per_pixel``.
``prediction_errors_per_pixel`` and ``blockers_per_pixel`` (blocker points
projected by Predict) complete the picture.

Why rays grow faster than the perimeter argument (section 6: "in the limit"
4x samples -> 2x rays; the paper measured "a little more than 3x"): on
``grids`` at 512^2, 1024 vs 256 samples, rays per pixel grow 2.85x: the
border cells 2.07x (4N - 4), the full traces 4x (they are area), the interior
cells Predict queues 3.6x, the flood fill 3.1x, prediction errors 3.2x. A
blocker's projection on the light moves by (H / h - 1) x the step between
neighbouring points: for the lowest lattice (h = 1.2, light at 7.5) 0.17
light units per pixel, 3.7 cells of a 32 x 32 grid (1.8 of 16 x 16). The
cells a shadow edge sweeps between two points hold no blocker yet, and the
blockers that do exist were traced at one jittered sample per cell, so the
predicted edges lag and are ragged by about the step - a band whose width is
fixed in light units, i.e. area, not perimeter. Section 5.2.1's remedy is
denser surface sampling (the paper's REYES micropolygons, about 3 per pixel);
at this image size the asymptotic regime is not reached for that lattice.
(Tried and left out: closing one-cell holes in the predicted image, 4 %
fewer rays at 1024 samples, a departure for little.)

Departures / choices, each documented where it is made:
  * bias: a floor is the texel depth plus a bias in texel footprints and a
    slope term (section 6.1 only says a user bias is needed);
  * normal offset: ray origins also move ``normal_offset`` texel footprints
    x (1 - cos theta) along the normal (``normal_offsets``): a point on a
    face seen edge-on from the light (the side of a thin bar) otherwise
    shares its texel with the bar's top and shadows itself;
  * a ray leaving the point into its own surface (cos theta_r <= 0) is
    blocked without tracing (``coherence``);
  * gap bias in texel footprints by default (scene units if given);
  * hierarchical connectedness is off while coherence is on (5.2.2: the
    coherent sampler needs the blocker point);
  * the unresolved parts of a ray after the last image count as unblocked;
  * cube faces (wide point / spot / area lights) overlap by 3 texels and the
    outermost texel ring of every face is not traced (``maps``);
  * reset of the prediction when the previous point is farther than
    ``reset_pixels`` camera-pixel footprints (5.2.1 gives no value);
  * a sun's orthographic views are fitted to the geometry the receivers'
    rays can pass behind, not to every receiver (``fit_window``, ``window``;
    the paper leaves view placement open, footnote 4): on
    ``sun_pillars`` a texel drops from 5.7 to 1.1 cm, RMSE 0.027 -> 0.007
    (penumbra 0.067 -> 0.020); ``fit_window="receivers"`` is the first
    version, bit for bit;
  * the maps of a sun with those windows are at least ``sun_min_map``
    (1024, the paper's size, section 6) on a side, up to 4 x the map_scale
    side (issue 17; the warm-up's 8-pixel run keeps 64-texel maps): the texel then
    follows the blockers' extent, not the output's pixels, and map_scale x a
    small output quantised the pillars' silhouettes into their penumbrae.
    ``sun_pillars`` 256 x 256, 256 samples, against 1024-sample ``embree``,
    pixels seeing the whole sun / every pixel it reaches: 0.0074 / 0.0096
    (penumbra 0.0195 / 0.0226) -> 0.0067 / 0.0090 (0.0134 / 0.0175), +20 %
    CPU; the paper says these artifacts "are easy to control by generating
    higher resolution reference images" (5.1). Of what remains over every
    reached pixel, 40 % sits in 21 pixels of faces edge-on to the sun
    (cos 0.002) at the ends of the geometry, where rays under the face's
    plane escape past its edge in the reference and count as blocked here.
    ``sun_min_map=0``: map_scale alone, the first version.

Known failure (the stress suite's ``huge_area_light``: a 50-unit light 2
units above a 20-unit occluder; +0.20 too bright, the irradiance pass +0.40
RMSE): a reference image from the far corner sees the occluder at under 3
degrees, so its slope-scaled floor bias (up to ``gap_texels`` footprints)
swallows the thin sliver of the ray hidden just under the occluder; that
image then finds the ray in front of every floor and, ranked first, proves
it clear (``clear_miss`` / ``occlusion_intervals`` trust any image), though
the corners on the occluder's side would report the hit. Turning the bias
down trades this for self-shadowing (slope_bias 0: RMSE 0.30); padding the
casters' box or walls across planar texels changed nothing. A fix would give
a ray within the bias band of a floor a third state (unknown, carried to the
next image) rather than "in front".

Speed (measured on this 2-core machine, CPU seconds, 128^2, 256 samples,
warm JIT): ``grids`` embree 0.36 s, this method 1.11 s with coherence (145
rays per pixel), 1.30 s without; ``sphere_plane`` embree 0.27 s, 0.42 s
(65 rays per pixel), 1.09 s. A ray through the depth images costs 0.26-0.53
us here against 0.06-0.14 us for an Embree ray, so coherence narrows but
does not close the gap on these scenes (see ``benchmark_table``).
"""
from __future__ import annotations

import math
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from typing import Dict, List, Optional, Sequence

import numba
import numpy as np
from numba import prange

from ... import sampling, views
from ...jit import inner, kernel
from ...kernels import borrowed, each_dealt_chunk, each_range, face_project, pick_face
from ...sampling import strata
from ...scene import Light
from ..registry import register
from .coherence import (M_BLK, M_ERR, M_FLOOD, M_FULL, M_FULLRAYS, M_QH, M_QT, M_RAYS, M_SEEDED, M_SIZE,
                        Points, Sampler, TileState, absorb, begin_point, blocker_capacity, finish_point,
                        tile_row)
from .maps import ReferenceMaps, build_reference_maps
from .trace import LN, MAXI, ReferenceImages, TraceScratch, TraceSwitches, trace_ray
from ..base import (AVERAGE, GBUFFER, IRRADIANCE, LIGHT_SAMPLE_VIEWS, SHADOW_GEOMETRY, SHADOW_TRIANGLES,
                   Method, MethodResult, PhaseTimer)


SUN_MIN_MAP_REACH = 4     # sun_min_map raises a map side at most this many times


@dataclass
class DepthRaytraceParams:
    samples: int = 256            # light samples per pixel (section 6: "the equivalent of 256")
    seed: int = 0
    # reference images (5.1)
    map_scale: float = 2.0        # map side / output side: the paper's 1024^2 maps for 512^2 images
    map_size: Optional[int] = None  # overrides map_scale
    fit_window: str = "blockers"  # sun: windows fitted to what can block ("receivers": the first version; ``window``)
    sun_min_map: int = 1024       # sun, fit_window="blockers": map side at least this (the paper's 1024^2
                                  # maps, section 6; issue 17); 0: map_scale alone (the first version)
    ref_points: int = 4           # boundary points for disk / ellipse / sun (rectangle: its 4 corners)
    shadow_bias: Optional[float] = None  # scene units; None = bias_texels + slope_bias terms
    bias_texels: float = 0.5      # constant part, in texel footprints at the texel's depth
    slope_bias: float = 1.0       # x the depth change across half a texel
    gap_bias: Optional[float] = None     # scene units; None = gap_texels footprints
    gap_texels: float = 8.0       # connected while |dZ| < gap_texels texel footprints
    normal_offset: float = 1.5    # ray origins move this many texel footprints x (1 - cos theta) along the normal
    # accelerations (5.1.1, 5.1.2)
    hierarchical_connectedness: bool = True
    minmax_clipping: bool = True
    rank_images: bool = True
    clear_miss: bool = True
    occlusion_intervals: bool = True
    # coherence-based sampling (5.2)
    coherence: bool = True
    subgrid: int = 3              # "typically 3x3" high-resolution grid per light cell
    subgrid_shortcut: bool = True
    reset_pixels: float = 4.0     # tolerance, in camera pixel footprints at the point
    reset_distance: Optional[float] = None  # tolerance in scene units (overrides reset_pixels)
    tile: int = 16                # coherent order: serpentine scan inside tile x tile blocks
    tracer: str = "depth"         # "depth" (reference images) | "embree" (real triangles)


# ---------------------------------------------------------------------------
@inner(forceinline=True)
def _slab(o, d, lo, hi, tmin, tmax):
    """One axis of the slab test: [tmin, tmax] restricted to lo <= o + t d <= hi
    (empty: tmin > tmax)."""
    if d == 0.0:
        if o < lo or o > hi:
            return 1.0, 0.0
        return tmin, tmax
    t1 = (lo - o) / d
    t2 = (hi - o) / d
    if t1 > t2:
        t1, t2 = t2, t1
    if t1 > tmin:
        tmin = t1
    if t2 < tmax:
        tmax = t2
    return tmin, tmax


@inner(forceinline=True)
def _segment_end(ox, oy, oz, ex, ey, ez, lo, hi):
    """t where o + t (E - o) leaves the casters' box (<= 1 - 1e-7); 0 if the
    segment misses the box. (Axes unrolled: half the time of a loop over
    tuples.)"""
    tmin, tmax = _slab(ox, ex - ox, lo[0], hi[0], 0.0, 1.0 - 1e-7)
    tmin, tmax = _slab(oy, ey - oy, lo[1], hi[1], tmin, tmax)
    tmin, tmax = _slab(oz, ez - oz, lo[2], hi[2], tmin, tmax)
    if tmin > tmax:
        return 0.0
    return tmax


@kernel(nogil=True)
def _depth_tiles(tiles, tile_ptr, pts, noff, smp, blo, bhi, refs, sw, out_avg, out_irr, rays):
    """The depth-image driver: for each tile ``ti`` of ``tiles`` (in turn;
    ``_trace_tiles`` runs chunks of tiles on threads) a fresh state, every
    point of ``tile_ptr[ti]:tile_ptr[ti + 1]`` (``_tile_points``), and
    ``rays[ti]``: the tile's ``misc`` (M_*). pts: Points; noff: normal offset
    per point; smp: Sampler; blo, bhi: the casters' box; refs:
    trace.ReferenceImages; sw: trace.TraceSwitches.
    A serial ``nogil`` kernel, not a ``prange`` one: the parfor lowering of
    this fully inlined tracer was most of the method's compile time (issue
    15)."""
    nx, ny, S = smp.nx, smp.ny, smp.S
    C = nx * ny
    F = refs.fp.shape[0]
    cap = C * S * S + C
    for k in range(tiles.shape[0]):
        ti = tiles[k]
        origin = np.empty(3)
        tgt = np.empty((C, 3))
        wts = np.empty(C)
        subi = np.empty(C, np.int32)
        back = np.zeros(C, np.uint8)
        blk = np.empty((cap, 3))
        stamp = np.zeros(C * S * S, np.int64)
        vis = np.zeros(C, np.uint8)
        cst = np.zeros(C, np.uint8)
        queue = np.empty(C, np.int32)
        pred = np.zeros(C, np.uint8)
        prevp = np.zeros(3)
        misc = np.zeros(M_SIZE, np.int64)
        ws_line = np.empty((max(F, 1), LN))
        ws_order = np.empty(max(F, 1), np.int64)
        ws_key = np.empty(max(F, 1))
        U = np.empty((MAXI, 2))
        U2 = np.empty((MAXI, 2))
        ts = TileState(origin, tgt, wts, subi, back, blk, stamp, vis, cst, queue, pred, prevp, misc)
        ws = TraceScratch(ws_line, ws_order, ws_key, U, U2)
        _tile_points(tile_ptr[ti], tile_ptr[ti + 1], pts, noff, smp, blo, bhi, refs, sw, ts, ws,
                     out_avg, out_irr)
        for j in range(M_SIZE):     # not rays[ti, :] = misc: a slice copy compiles Numba's shape-error message
            rays[ti, j] = misc[j]


@inner(error_model="numpy")
def _tile_points(i0, i1, pts, noff, smp, blo, bhi, refs, sw, ts, ws, out_avg, out_irr):
    """Points ``i0:i1`` of one tile (state ``ts``, trace scratch ``ws``):
    their queued rays traced through the reference images, the points
    shaded into ``out_avg`` / ``out_irr``. Every array argument is
    ``kernels.borrowed`` (the caller owns them) and ``error_model="numpy"``,
    as Numba compiled this loop when it was a ``prange`` body: the inlined
    tracer copies array variables at every call, at an atomic reference
    count each otherwise."""
    pts, noff, smp, blo, bhi, refs, ts, ws = borrowed((pts, noff, smp, blo, bhi, refs, ts, ws))
    out_avg, out_irr = borrowed((out_avg, out_irr))
    P = pts.P
    nx, ny, coherent = smp.nx, smp.ny, smp.coherent
    F = refs.fp.shape[0]
    origin, tgt, wts, blk, vis, cst, queue, prevp, misc = (ts.origin, ts.tgt, ts.wts, ts.blk, ts.vis, ts.cst,
                                                           ts.queue, ts.prevp, ts.misc)
    for i in range(i0, i1):
        begin_point(smp, pts, i, noff[i], ts)
        ox, oy, oz = origin[0], origin[1], origin[2]
        while misc[M_QH] < misc[M_QT]:
            c = queue[misc[M_QH]]
            misc[M_QH] += 1
            ex, ey, ez = tgt[c, 0], tgt[c, 1], tgt[c, 2]
            t_end = _segment_end(ox, oy, oz, ex, ey, ez, blo, bhi)
            blocked = False
            th = 0.0
            if F > 0 and t_end > 0.0:
                blocked, th = trace_ray(refs, ox, oy, oz, ex, ey, ez, t_end, sw, ws)
            absorb(c, blocked, ox + th * (ex - ox), oy + th * (ey - oy), oz + th * (ez - oz),
                   nx, ny, coherent, blk, vis, cst, queue, misc)
        a, r = finish_point(P, i, nx, ny, wts, vis, prevp, misc)
        out_avg[i] = a
        out_irr[i] = r


def _trace_tiles(tile_ptr, pts, noff, smp, blo, bhi, refs, sw, out_avg, out_irr, rays, threads=None):
    """``_depth_tiles`` over every tile on Numba's thread count, the tiles
    dealt into chunks (``kernels.each_dealt_chunk``: tiles differ widely in
    cost, neighbours alike). Each tile has its own state and writes its own
    points, so the result is the same for any thread count."""
    each_dealt_chunk(lambda tiles: _depth_tiles(tiles, tile_ptr, pts, noff, smp, blo, bhi, refs, sw,
                                                out_avg, out_irr, rays), len(tile_ptr) - 1, threads)


def normal_offsets(P, Nrm, lp, faces, factor, threads=None):
    """Normal offset per point: ``factor`` texel footprints (of the first
    reference face holding the point, at its depth) x (1 - cos theta), theta
    the angle between the normal and the direction to the light's centre. A point on a surface
    seen edge-on from the light shares its texel with whatever the texel shows
    (the top of a thin bar, for a point on the bar's side); moving it off the
    surface by about a texel takes it out of that texel. Surfaces facing the
    light move little. Ranges of points on Numba's thread count (``kernels.each_range``)."""
    out = np.zeros(P.shape[0])
    if factor == 0.0 or faces.shape[0] == 0:
        return out
    each_range(lambda i0, i1: _normal_offsets(i0, i1, P, Nrm, lp, faces, factor, out), P.shape[0], threads)
    return out


@kernel(nogil=True)
def _normal_offsets(i0, i1, P, Nrm, lp, faces, factor, out):
    """``normal_offsets`` for points i0..i1-1 into ``out``."""
    for i in range(i0, i1):
        px, py, pz = P[i, 0], P[i, 1], P[i, 2]
        f = pick_face(faces, px, py, pz)
        if f < 0:
            continue
        _u, _v, d = face_project(faces[f], px, py, pz)
        foot = faces[f, 24] * d if faces[f, 16] == 0.0 else faces[f, 24]
        if lp[0] == 2.0:
            lx, ly, lz = lp[10], lp[11], lp[12]
        else:
            lx, ly, lz = lp[1] - px, lp[2] - py, lp[3] - pz
            ll = math.sqrt(lx * lx + ly * ly + lz * lz)
            if ll == 0.0:
                continue
            lx /= ll
            ly /= ll
            lz /= ll
        c = Nrm[i, 0] * lx + Nrm[i, 1] * ly + Nrm[i, 2] * lz
        s = 1.0 - min(1.0, abs(c))
        if foot > 0.0:
            out[i] = factor * foot * s


# ---------------------------------------------------------------------------
# Embree wave driver: the same sampler, the queued rays of every tile per call
@kernel(parallel=True)
def _wave_emit(tile_ptr, cursor, phase, pts, smp, tiles, r_cell, cnt):
    """Embree waves, first half: per tile, begin its next point if needed and
    move its queued cells into ``r_cell[ti, :cnt[ti]]``. pts: Points; smp:
    Sampler; tiles: TileState of every tile (first axis: the tile)."""
    queue, misc = tiles.queue, tiles.misc
    nt = tile_ptr.shape[0] - 1
    for ti in prange(nt):
        cnt[ti] = 0
        if cursor[ti] >= tile_ptr[ti + 1]:
            continue
        if phase[ti] == 0:
            begin_point(smp, pts, cursor[ti], 0.0, tile_row(tiles, ti))
            phase[ti] = 1
        j = 0
        m = misc[ti]
        while m[M_QH] < m[M_QT]:
            r_cell[ti, j] = queue[ti, m[M_QH]]
            m[M_QH] += 1
            j += 1
        cnt[ti] = j


@kernel(parallel=True)
def _wave_pack(cnt, off, origin, tgt, r_cell, is_sun, org, dirs, tfar):
    nt = cnt.shape[0]
    for ti in prange(nt):
        o = origin[ti]
        for j in range(cnt[ti]):
            k = off[ti] + j
            c = r_cell[ti, j]
            dx = tgt[ti, c, 0] - o[0]
            dy = tgt[ti, c, 1] - o[1]
            dz = tgt[ti, c, 2] - o[2]
            d = math.sqrt(dx * dx + dy * dy + dz * dz)
            if d > 0.0:
                dx /= d
                dy /= d
                dz /= d
            org[k, 0] = o[0]
            org[k, 1] = o[1]
            org[k, 2] = o[2]
            dirs[k, 0] = dx
            dirs[k, 1] = dy
            dirs[k, 2] = dz
            tfar[k] = np.float32(1e30) if is_sun else d * (1.0 - 1e-6)


@kernel(parallel=True)
def _wave_absorb(tile_ptr, cursor, phase, P, smp, tiles, cnt, off, r_cell, hit_t, org, dirs,
                  out_avg, out_irr):
    """Embree waves, second half: the hits ``hit_t`` of the rays ``org + t dirs``
    (tile ti's at ``off[ti]:off[ti] + cnt[ti]``) absorbed; finished points
    shaded. smp: Sampler; tiles: TileState of every tile."""
    nx, ny, coherent = smp.nx, smp.ny, smp.coherent
    wts, blk, vis, cst, queue = tiles.wts, tiles.blk, tiles.vis, tiles.cst, tiles.queue
    prevp, misc = tiles.prevp, tiles.misc
    nt = tile_ptr.shape[0] - 1
    for ti in prange(nt):
        if cursor[ti] >= tile_ptr[ti + 1] or phase[ti] == 0:
            continue
        for j in range(cnt[ti]):
            k = off[ti] + j
            t = hit_t[k]
            blocked = t < np.inf
            bx = org[k, 0] + t * dirs[k, 0] if blocked else 0.0
            by = org[k, 1] + t * dirs[k, 1] if blocked else 0.0
            bz = org[k, 2] + t * dirs[k, 2] if blocked else 0.0
            absorb(r_cell[ti, j], blocked, bx, by, bz, nx, ny, coherent, blk[ti], vis[ti], cst[ti],
                   queue[ti], misc[ti])
        if misc[ti, M_QH] >= misc[ti, M_QT]:
            i = cursor[ti]
            a, r = finish_point(P, i, nx, ny, wts[ti], vis[ti], prevp[ti], misc[ti])
            out_avg[i] = a
            out_irr[i] = r
            cursor[ti] += 1
            phase[ti] = 0


def _embree_waves(tri_scene, tile_ptr, P, Nrm, pix, tol, lp, nx, ny, seed, scale, big,
                  coherent, S, shortcut, threads=None):
    nt = len(tile_ptr) - 1
    C = nx * ny
    cap = blocker_capacity(C, S)
    n = len(P)
    out_avg = np.ones(n, np.float64)
    out_irr = np.ones(n, np.float64)
    cursor = tile_ptr[:-1].astype(np.int64).copy()
    phase = np.zeros(nt, np.int64)
    origin = np.zeros((nt, 3))
    tgt = np.zeros((nt, C, 3))
    wts = np.zeros((nt, C))
    subi = np.zeros((nt, C), np.int32)
    back = np.zeros((nt, C), np.uint8)
    blk = np.zeros((nt, cap, 3))
    stamp = np.zeros((nt, C * S * S), np.int64)
    vis = np.zeros((nt, C), np.uint8)
    cst = np.zeros((nt, C), np.uint8)
    queue = np.zeros((nt, C), np.int32)
    pred = np.zeros((nt, C), np.uint8)
    prevp = np.zeros((nt, 3))
    misc = np.zeros((nt, M_SIZE), np.int64)
    r_cell = np.zeros((nt, C), np.int32)
    cnt = np.zeros(nt, np.int64)
    pts = Points(P, Nrm, pix, tol)
    smp = Sampler(lp, seed, scale, nx, ny, S, coherent, shortcut, big)
    tiles = TileState(origin, tgt, wts, subi, back, blk, stamp, vis, cst, queue, pred, prevp, misc)
    is_sun = bool(lp[0] == 2.0)
    workers = max(1, int(threads or numba.get_num_threads()))
    pool = ThreadPoolExecutor(max_workers=workers) if workers > 1 else None
    waves = 0
    try:
        while (cursor < tile_ptr[1:]).any():
            _wave_emit(tile_ptr, cursor, phase, pts, smp, tiles, r_cell, cnt)
            off = np.zeros(nt, np.int64)
            np.cumsum(cnt[:-1], out=off[1:])
            m = int(cnt.sum())
            org = np.empty((m, 3), np.float32)
            dirs = np.empty((m, 3), np.float32)
            tfar = np.empty(m, np.float32)
            _wave_pack(cnt, off, origin, tgt, r_cell, is_sun, org, dirs, tfar)
            hit_t = np.full(m, np.inf)
            if m:
                if pool is not None and m >= 8192:
                    parts = np.array_split(np.arange(m), workers)

                    def run(ix):
                        tri, t, _, _ = tri_scene.intersect(org[ix], dirs[ix], tfar[ix])
                        return ix, np.where(tri >= 0, t, np.inf)
                    for ix, tt in pool.map(run, parts):
                        hit_t[ix] = tt
                else:
                    tri, t, _, _ = tri_scene.intersect(org, dirs, tfar)
                    hit_t = np.where(tri >= 0, t, np.inf)
            _wave_absorb(tile_ptr, cursor, phase, P, smp, tiles, cnt, off, r_cell, hit_t, org, dirs,
                         out_avg, out_irr)
            waves += 1
    finally:
        if pool is not None:
            pool.shutdown()
    return out_avg, out_irr, int(misc[:, M_RAYS].sum()), waves


# ---------------------------------------------------------------------------
def coherent_order(idx: np.ndarray, width: int, tile: int):
    """Hit pixel ids -> (order, tile_ptr): pixels grouped by tile x tile block,
    serpentine rows inside each block (consecutive points are neighbours)."""
    rows = idx // width
    cols = idx % width
    T = max(1, int(tile))
    ntx = (width + T - 1) // T
    tid = (rows // T) * ntx + cols // T
    lr = rows % T
    lc = cols % T
    key = lr * T + np.where(lr % 2 == 0, lc, T - 1 - lc)
    order = np.lexsort((key, tid))
    tids = tid[order]
    starts = np.flatnonzero(np.r_[True, tids[1:] != tids[:-1]]) if len(tids) else np.zeros(0, np.int64)
    tile_ptr = np.r_[starts, len(tids)].astype(np.int64)
    return order, tile_ptr


def camera_footprint(buffers) -> np.ndarray:
    """Camera pixel footprint (scene units) at each pixel's depth, float64[H*W]."""
    cam = buffers.scene.camera
    W, H = buffers.width, buffers.height
    xmin, xmax, _, _ = views.camera_viewplane(cam, W, H)
    per = (xmax - xmin) / W
    if cam.kind == "ORTHO":
        return np.full(W * H, per)
    d = buffers.gbuffer.depth.reshape(-1).astype(np.float64)
    return np.where(np.isfinite(d), d * per, 0.0)


def casters_box(casters, scale):
    """Box around the finite vertices of the shadow-casting triangles
    ``casters``, padded (None when there are none)."""
    if not len(casters):
        return None
    v = casters.reshape(-1, 3).astype(np.float64)
    v = v[np.isfinite(v).all(1)]
    if not len(v):
        return None
    pad = 1e-6 * scale
    return v.min(0) - pad, v.max(0) + pad


def resolve_map_size(params: DepthRaytraceParams, W: int, H: int, light: Optional[Light] = None) -> int:
    """The reference maps' side: ``map_size``, else ``map_scale`` x the
    output's larger side -- for a sun whose windows hold only the blockers
    (``fit_window="blockers"``) at least ``sun_min_map`` (up to
    ``SUN_MIN_MAP_REACH`` times that side): there the texel follows the
    blockers' extent, not the output's pixels, and a small output's maps
    quantised the pillars' silhouettes into the penumbra."""
    if params.map_size:
        return int(params.map_size)
    side = max(8, int(round(float(params.map_scale) * max(W, H))))
    if light is not None and light.kind == "sun" and params.fit_window == "blockers":
        # at most SUN_MIN_MAP_REACH x the map_scale side: a tiny output (the warm-up's
        # 8 px) keeps tiny maps
        side = max(side, min(int(params.sun_min_map), SUN_MIN_MAP_REACH * side))
    return side


@register
class DepthRaytrace(Method):
    id = "depth_raytrace"
    paper = "Agrawala, Ramamoorthi, Heirich, Moll 2000, section 5"
    passes = {"depth_raytrace": AVERAGE, "depth_raytrace_irr": IRRADIANCE}
    needs = frozenset({GBUFFER, SHADOW_GEOMETRY, SHADOW_TRIANGLES, LIGHT_SAMPLE_VIEWS})
    packed = True                # shades each receiver of a packed G-buffer on its own
    Params = DepthRaytraceParams
    physical = True

    def run(self, buffers, light, params: DepthRaytraceParams, maps: Optional[ReferenceMaps] = None
            ) -> MethodResult:
        """``maps`` lets a caller reuse reference maps built by ``build_maps``
        (they do not depend on the sample count)."""
        timer = PhaseTimer()
        g = buffers.gbuffer
        H, W = g.shape
        out_a = np.ones(H * W, np.float32)
        out_i = np.ones(H * W, np.float32)
        idx = np.flatnonzero(g.hit.reshape(-1))
        ns = 1 if light.is_zero_size else max(1, int(params.samples))
        nx, ny = strata(ns)
        C = nx * ny
        coherent = bool(params.coherence) and C > 1
        S = max(1, int(params.subgrid))
        stats: Dict[str, object] = {"samples": C, "strata": [nx, ny], "pixels": int(len(idx)),
                                    "tracer": params.tracer, "coherence": coherent}
        box = casters_box(buffers.shadow_triangles[0], buffers.scale)
        if len(idx) == 0 or box is None:
            stats["rays_per_pixel"] = 0.0
            return MethodResult({"depth_raytrace": out_a.reshape(H, W),
                                 "depth_raytrace_irr": out_i.reshape(H, W)}, timer.result(), stats)
        with timer("order"):
            gid = g.seed_ids(idx)             # pixels of the view (a packed G-buffer's sub-pixels)
            order, tile_ptr = coherent_order(gid, buffers.width, params.tile)
            sel = idx[order]
            P = np.ascontiguousarray(g.position.reshape(-1, 3)[sel], np.float64)
            Nrm = np.ascontiguousarray(g.normal.reshape(-1, 3)[sel], np.float64)
            pix = np.ascontiguousarray(gid[order], np.int64)
            if params.reset_distance is not None:
                tol = np.full(len(sel), float(params.reset_distance))
            else:
                tol = float(params.reset_pixels) * camera_footprint(buffers)[sel]
            lp = sampling.pack_light(light)
            big = 4.0 * buffers.scale
        if params.tracer == "embree":
            tri = buffers.shadow_scene
            with timer("trace"):
                va, vi, rays, waves = _embree_waves(tri, tile_ptr, P, Nrm, pix, tol, lp, nx, ny,
                                                    int(params.seed), float(buffers.scale), big,
                                                    coherent, S, bool(params.subgrid_shortcut))
            stats["waves"] = waves
        elif params.tracer == "depth":
            if maps is None:
                with timer("reference_maps"):
                    maps = buffers.frame_memo("depth_raytrace.maps", light, params,
                                              lambda: self.build_maps(buffers, light, params))
            stats["reference_faces"] = maps.face_count
            stats["reference_eyes"] = int(len(maps.eyes))
            stats["map_texels"] = maps.map_texels
            hier = bool(params.hierarchical_connectedness) and not coherent
            va = np.ones(len(sel))
            vi = np.ones(len(sel))
            rays_t = np.zeros((len(tile_ptr) - 1, M_SIZE), np.int64)
            with timer("trace"):
                noff = normal_offsets(P, Nrm, lp, maps.faces, float(params.normal_offset))
                smp = Sampler(lp, int(params.seed), float(buffers.scale), nx, ny, S, coherent,
                              bool(params.subgrid_shortcut), big)
                refs = ReferenceImages(maps.faces, maps.offs, maps.dims, maps.mn, maps.mx, maps.conn, maps.zp)
                sw = TraceSwitches(hier, bool(params.minmax_clipping), bool(params.rank_images),
                                   bool(params.clear_miss), bool(params.occlusion_intervals))
                _trace_tiles(tile_ptr, Points(P, Nrm, pix, tol), noff, smp, box[0], box[1], refs, sw, va, vi,
                             rays_t)
            rays = int(rays_t[:, M_RAYS].sum())
            n_pts = max(1, len(sel))
            stats["full_trace_points"] = int(rays_t[:, M_FULL].sum())
            stats["full_trace_rays_per_pixel"] = float(rays_t[:, M_FULLRAYS].sum() / n_pts)
            stats["predicted_rays_per_pixel"] = float(rays_t[:, M_SEEDED].sum() / n_pts)
            stats["flood_fill_rays_per_pixel"] = float(rays_t[:, M_FLOOD].sum() / n_pts)
            stats["prediction_errors_per_pixel"] = float(rays_t[:, M_ERR].sum() / n_pts)
            stats["blockers_per_pixel"] = float(rays_t[:, M_BLK].sum() / n_pts)
            stats["hierarchical_connectedness_used"] = hier
        else:
            raise ValueError(f"depth_raytrace: unknown tracer {params.tracer!r}")
        out_a[sel] = np.clip(va, 0.0, 1.0)
        out_i[sel] = np.clip(vi, 0.0, 1.0)
        t = timer.result()
        stats["rays"] = rays
        stats["rays_per_pixel"] = float(rays / len(sel))
        stats["precompute_s"] = float(t.get("reference_maps", 0.0))
        stats["trace_s"] = float(t.get("trace", 0.0))
        return MethodResult(passes={"depth_raytrace": out_a.reshape(H, W),
                                    "depth_raytrace_irr": out_i.reshape(H, W)},
                            time_s=t, stats=stats)

    @staticmethod
    def build_maps(buffers, light, params: DepthRaytraceParams) -> ReferenceMaps:
        W, H = buffers.width, buffers.height
        return build_reference_maps(buffers, light, resolve_map_size(params, W, H, light), params.ref_points,
                                    params.shadow_bias, params.bias_texels, params.slope_bias,
                                    params.gap_bias, params.gap_texels, fit_window=params.fit_window)


# ---------------------------------------------------------------------------
# the paper's figure 10 (middle) as a table
NO_ACCEL = dict(hierarchical_connectedness=False, minmax_clipping=False, rank_images=False,
                clear_miss=False, occlusion_intervals=False, coherence=False)
ACCEL = dict(coherence=False)
ACCEL_COHERENCE = dict()


def benchmark_table(buffers, light, sample_counts: Sequence[int] = (64, 256, 1024), seed: int = 0,
                    configs=None, embree: bool = True, embree_coherent: bool = False,
                    repeats: int = 1) -> List[dict]:
    """Figure 10 (middle): per sample count, the tracing time without the
    accelerations, with them, and with them plus coherence; rays per pixel;
    speed-ups; and the ``embree`` reference's time at the same count.
    Reference maps are built once (they do not depend on the sample count)
    and their time reported separately. Times are wall seconds, the best of
    ``repeats`` (warm JIT: call once at a small size first); ``*_cpu_s`` is
    the process CPU time of the last repeat (all threads), a figure that a
    machine shared with other work disturbs less."""
    from ..embree_ref import EmbreeReference
    m = DepthRaytrace()
    configs = configs or {"no_accel": NO_ACCEL, "accel": ACCEL, "accel_coherence": ACCEL_COHERENCE}
    base = DepthRaytraceParams(seed=seed)
    buffers.gbuffer
    buffers.shadow_scene
    t0 = time.perf_counter()
    maps = m.build_maps(buffers, light, base)
    t_maps = time.perf_counter() - t0
    rows = []
    ref = EmbreeReference()
    for n in sample_counts:
        row = {"samples": int(n), "precompute_s": t_maps, "pixels": int(buffers.gbuffer.hit.sum())}
        outs = {}
        for name, over in configs.items():
            p = replace(base, samples=int(n), **over)
            best = None
            for _ in range(max(1, repeats)):
                c0 = time.process_time()
                r = m.run(buffers, light, p, maps=maps)
                cpu = time.process_time() - c0
                tt = r.time_s["trace"] + r.time_s.get("order", 0.0)
                best = tt if best is None else min(best, tt)
            row[f"{name}_s"] = best
            row[f"{name}_cpu_s"] = cpu
            row[f"{name}_rays_per_pixel"] = r.stats["rays_per_pixel"]
            outs[name] = r.passes["depth_raytrace"]
        if embree:
            rp = ref.make_params({"samples": int(n), "seed": seed})
            best = None
            for _ in range(max(1, repeats)):
                c0 = time.process_time()
                rr = ref.run(buffers, light, rp)
                cpu = time.process_time() - c0
                best = rr.time_s["total"] if best is None else min(best, rr.time_s["total"])
            row["embree_s"] = best
            row["embree_cpu_s"] = cpu
            refimg = rr.passes["embree"]
            for name in outs:
                d = (outs[name].astype(np.float64) - refimg)[buffers.gbuffer.hit]
                row[f"{name}_rmse"] = float(np.sqrt(np.mean(d * d))) if d.size else 0.0
        if embree_coherent:
            p = replace(base, samples=int(n), tracer="embree")
            r = m.run(buffers, light, p)
            row["embree_coherent_s"] = r.time_s["trace"] + r.time_s.get("order", 0.0)
            row["embree_coherent_rays_per_pixel"] = r.stats["rays_per_pixel"]
        if "no_accel_s" in row and "accel_s" in row:
            row["speedup_accel"] = row["no_accel_s"] / max(row["accel_s"], 1e-12)
        if "no_accel_s" in row and "accel_coherence_s" in row:
            row["speedup_accel_coherence"] = row["no_accel_s"] / max(row["accel_coherence_s"], 1e-12)
        if "embree_s" in row:
            for name in configs:
                row[f"{name}_vs_embree"] = row["embree_s"] / max(row[f"{name}_s"], 1e-12)
                row[f"{name}_vs_embree_incl_maps"] = row["embree_s"] / max(row[f"{name}_s"] + t_maps, 1e-12)
        rows.append(row)
    return rows


def format_table(rows: List[dict]) -> str:
    """Markdown version of ``benchmark_table``'s rows."""
    head = ("| samples | no accel (s) | accel (s) | accel+coherence (s) | rays/pixel | "
            "speed-up accel | speed-up accel+coh | embree (s) | vs embree (incl. maps) |")
    lines = [head, "|" + "---|" * 9]
    for r in rows:
        lines.append("| {samples} | {a:.3f} | {b:.3f} | {c:.3f} | {rp:.1f} | {s1:.2f}x | {s2:.2f}x | {e} | {v} |".format(
            samples=r["samples"], a=r.get("no_accel_s", float("nan")), b=r.get("accel_s", float("nan")),
            c=r.get("accel_coherence_s", float("nan")), rp=r.get("accel_coherence_rays_per_pixel", float("nan")),
            s1=r.get("speedup_accel", float("nan")), s2=r.get("speedup_accel_coherence", float("nan")),
            e=f"{r['embree_s']:.3f}" if "embree_s" in r else "-",
            v=(f"{r['accel_coherence_vs_embree']:.2f}x ({r['accel_coherence_vs_embree_incl_maps']:.2f}x)"
               if "accel_coherence_vs_embree" in r else "-")))
    return "\n".join(lines)
