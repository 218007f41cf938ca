"""The Embree wave driver of ``depth_raytrace`` (``tracer="embree"``): the
coherent sampler (``coherence``) over Embree shadow rays against the real
triangles, as the paper suggests ("a standard geometric ray tracer might
incorporate our coherence-based sampling method"). Every tile advances one
point at a time; the rays all tiles have queued are traced in one batch per
wave (``_wave_emit``, ``_wave_pack``, an Embree call, ``_wave_absorb``).
"""
from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor

import numba
import numpy as np
from numba import prange

from ...jit import kernel
from .coherence import (M_QH, M_QT, M_RAYS, M_SIZE, Points, Sampler, TileState, absorb, begin_point,
                        blocker_capacity, finish_point, tile_row)


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


def embree_waves(tri_scene, tile_ptr, P, Nrm, pix, tol, lp, nx, ny, seed, scale, big,
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
