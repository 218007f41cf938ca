"""The depth-image driver of ``depth_raytrace`` (Agrawala et al. 2000,
section 5): the shaded points in coherent order, what each needs before its
rays (reset tolerance, normal offset, the casters' box that ends a ray), and
the loop over tiles that traces their queued rays through the reference
images (``trace``) with the coherent sampler (``coherence``).

Points are visited in a serpentine order inside ``tile`` x ``tile`` blocks
of the image (``coherent_order``: consecutive points are neighbours, as in
the paper's scan-line shading); every tile has its own sampler state and
writes only its own points, so tiles run on worker threads and the result
does not depend on the thread count.
"""
from __future__ import annotations

import math

import numpy as np

from ... import views
from ...jit import inner, kernel
from ...kernels import borrowed, each_dealt_chunk, each_range, face_project, pick_face
from .coherence import M_QH, M_QT, M_SIZE, TileState, absorb, begin_point, finish_point
from .trace import LN, MAXI, TraceScratch, trace_ray


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
    segment misses the box. (Axes unrolled: Numba's loop over tuples is
    slower.)"""
    tmin, tmax = _slab(ox, ex - ox, lo[0], hi[0], 0.0, 1.0 - 1e-7)
    tmin, tmax = _slab(oy, ey - oy, lo[1], hi[1], tmin, tmax)
    tmin, tmax = _slab(oz, ez - oz, lo[2], hi[2], tmin, tmax)
    if tmin > tmax:
        return 0.0
    return tmax


@kernel(nogil=True)
def _depth_tiles(tiles, tile_ptr, pts, noff, smp, blo, bhi, refs, sw, out_avg, out_irr, rays):
    """The depth-image driver: for each tile ``ti`` of ``tiles`` (in turn;
    ``trace_tiles`` runs chunks of tiles on threads) a fresh state, every
    point of ``tile_ptr[ti]:tile_ptr[ti + 1]`` (``_tile_points``), and
    ``rays[ti]``: the tile's ``misc`` (M_*). pts: Points; noff: normal offset
    per point; smp: Sampler; blo, bhi: the casters' box; refs:
    trace.ReferenceImages; sw: trace.TraceSwitches.
    A serial ``nogil`` kernel, not a ``prange`` one: the parfor lowering of
    this fully inlined tracer would dominate the method's compile time."""
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
    ``kernels.borrowed`` (the caller owns them: the inlined tracer copies
    array variables at every call, otherwise at an atomic reference count
    each), and ``error_model="numpy"`` as a ``prange`` body's."""
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


def trace_tiles(tile_ptr, pts, noff, smp, blo, bhi, refs, sw, out_avg, out_irr, rays, threads=None):
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
    cam = buffers.camera
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
