"""The tile test (Reeves et al. 3.3's tiles): per TILE x TILE block of the
depth map its min / max depth (``tile_minmax``) in sparse tables that give
the min / max over any block of tiles in four lookups (``tile_tables``,
``tile_range``), and its least-squares plane (``tile_planes``); from them,
whether a region's samples must all be lit or all in shadow
(``region_decided``, ``planar_lit``), exactly."""
from __future__ import annotations

import math

import numpy as np

from ...jit import inner, kernel
from .receiver import DEPTH_REL_EPS, plane_depth

TILE = 8             # texels per side of a tile
PLANAR_BLOCKS = 16   # blocks a region may span for ``planar_lit``


@kernel(nogil=True)
def tile_minmax(depth):
    """Per face, per TILE x TILE block: min and max map depth (Reeves et al.
    3.3's tile scheme, "a maximum z value with each tile"). Serial: a
    parfor would cost more to compile than this loop takes to run."""
    F, h, w = depth.shape
    th = (h + TILE - 1) // TILE
    tw = (w + TILE - 1) // TILE
    lo = np.full((F, th, tw), np.inf, np.float32)
    hi = np.full((F, th, tw), -np.inf, np.float32)
    for k in range(F * th):
        f = k // th
        ty = k % th
        for tx in range(tw):
            a, b = np.inf, -np.inf
            for r in range(ty * TILE, min(h, ty * TILE + TILE)):
                for c in range(tx * TILE, min(w, tx * TILE + TILE)):
                    d = depth[f, r, c]
                    a = min(a, d)
                    b = max(b, d)
            lo[f, ty, tx] = a
            hi[f, ty, tx] = b
    return lo, hi


@kernel(nogil=True)
def tile_planes(depth, ortho):
    """Per face, per full TILE x TILE block: the least-squares plane through
    its texels, float64[F, th, tw, 4] (a, b, c, r): at texel centre (u, v)
    the map holds w = a (u - cu) + b (v - cv) + c within r, (cu, cv) the
    block's centre, w = 1 / depth on a perspective face (a plane's 1 / depth
    is affine in the texel position), w = depth on an orthographic one
    (``ortho[f]``). r = inf for blocks that hold an empty texel or run past
    the map (``region_decided``'s planar test skips them)."""
    F, h, w = depth.shape
    th = (h + TILE - 1) // TILE
    tw = (w + TILE - 1) // TILE
    out = np.empty((F, th, tw, 4), np.float64)
    sxx = 0.0
    for k in range(TILE):
        x = k + 0.5 - 0.5 * TILE
        sxx += x * x
    sxx *= TILE
    for f in range(F):
        for ty in range(th):
            for tx in range(tw):
                out[f, ty, tx, 0], out[f, ty, tx, 1], out[f, ty, tx, 2], out[f, ty, tx, 3] = 0.0, 0.0, 0.0, np.inf
                if (ty + 1) * TILE > h or (tx + 1) * TILE > w:
                    continue
                sw = 0.0
                sxw = 0.0
                syw = 0.0
                full = True
                for r in range(TILE):
                    for c in range(TILE):
                        d = np.float64(depth[f, ty * TILE + r, tx * TILE + c])
                        if not (d > 0.0 and d < np.inf):
                            full = False
                            break
                        v = d if ortho[f] else 1.0 / d
                        sw += v
                        sxw += (c + 0.5 - 0.5 * TILE) * v
                        syw += (r + 0.5 - 0.5 * TILE) * v
                    if not full:
                        break
                if not full:
                    continue
                a = sxw / sxx
                b = syw / sxx
                c0 = sw / (TILE * TILE)
                res = 0.0
                for r in range(TILE):
                    for c in range(TILE):
                        d = np.float64(depth[f, ty * TILE + r, tx * TILE + c])
                        v = d if ortho[f] else 1.0 / d
                        res = max(res, abs(v - (a * (c + 0.5 - 0.5 * TILE) + b * (r + 0.5 - 0.5 * TILE) + c0)))
                out[f, ty, tx, 0], out[f, ty, tx, 1], out[f, ty, tx, 2], out[f, ty, tx, 3] = a, b, c0, res
    return out


def _levels(n: int) -> int:
    """Sparse-table levels over n tiles: 2^k <= n for k < levels."""
    return max(1, int(n).bit_length())


def tile_tables(lo, hi, span=None):
    """Sparse tables of the per-tile min / max (``tile_minmax``): float32[F,
    KY, KX, th, tw, 2], entry [f, ky, kx, y, x] the (min, max) over the tiles
    [y, y + 2^ky) x [x, x + 2^kx), so ``tile_range`` reads the min / max over
    any block of tiles in four lookups (the same values as a loop over the
    tiles: min and max are exact); blocks of at most ``span`` tiles a side
    (default: any). Each entry's min sits beside its max, so a lookup reads
    one cache line for both."""
    F, th, tw = lo.shape
    ky, kx = _levels(th), _levels(tw)
    if span is not None:
        ky, kx = min(ky, _levels(span)), min(kx, _levels(span))
    tt = np.empty((F, ky, kx, th, tw, 2), np.float32)
    _fill_tables(lo, hi, tt)
    return tt


@kernel(nogil=True)
def _fill_tables(lo, hi, tt):
    """``tile_tables``' levels: along x, then along y (entries whose block
    runs past the grid repeat the last valid one; ``tile_range`` never reads
    them). Scalar loops only: a slice assignment here would compile Numba's
    broadcasting machinery, a large part of a cold start."""
    F, KY, KX, th, tw, _ = tt.shape
    for f in range(F):
        for y in range(th):
            for x in range(tw):
                tt[f, 0, 0, y, x, 0] = lo[f, y, x]
                tt[f, 0, 0, y, x, 1] = hi[f, y, x]
        for kx in range(1, KX):
            step = 1 << (kx - 1)
            for y in range(th):
                for x in range(tw):
                    x2 = min(x + step, tw - 1)
                    tt[f, 0, kx, y, x, 0] = min(tt[f, 0, kx - 1, y, x, 0], tt[f, 0, kx - 1, y, x2, 0])
                    tt[f, 0, kx, y, x, 1] = max(tt[f, 0, kx - 1, y, x, 1], tt[f, 0, kx - 1, y, x2, 1])
        for ky in range(1, KY):
            step = 1 << (ky - 1)
            for kx in range(KX):
                for y in range(th):
                    y2 = min(y + step, th - 1)
                    for x in range(tw):
                        tt[f, ky, kx, y, x, 0] = min(tt[f, ky - 1, kx, y, x, 0], tt[f, ky - 1, kx, y2, x, 0])
                        tt[f, ky, kx, y, x, 1] = max(tt[f, ky - 1, kx, y, x, 1], tt[f, ky - 1, kx, y2, x, 1])


@inner(forceinline=True)
def _floor_log2(n):
    """floor(log2 n) for n >= 1."""
    k = 0
    while (2 << k) <= n:
        k += 1
    return k


@inner
def tile_range(tt, ty0, ty1, tx0, tx1):
    """(min, max) map depth over the tiles [ty0, ty1] x [tx0, tx1] of one
    face's sparse tables (``tile_tables``): four overlapping power-of-two
    blocks that cover the range exactly."""
    ky = _floor_log2(ty1 - ty0 + 1)
    kx = _floor_log2(tx1 - tx0 + 1)
    ya, yb = ty0, ty1 - (1 << ky) + 1
    xa, xb = tx0, tx1 - (1 << kx) + 1
    dmin = min(min(tt[ky, kx, ya, xa, 0], tt[ky, kx, ya, xb, 0]), min(tt[ky, kx, yb, xa, 0], tt[ky, kx, yb, xb, 0]))
    dmax = max(max(tt[ky, kx, ya, xa, 1], tt[ky, kx, ya, xb, 1]), max(tt[ky, kx, yb, xa, 1], tt[ky, kx, yb, xb, 1]))
    return dmin, dmax


@inner(forceinline=True)
def _texel_box(w, h, s, t, sres, tres):
    """The texels [u0, u1) x [v0, v1) a region's samples can read (clamped
    to the map; at least one texel)."""
    u0 = max(0.0, math.floor(s - sres))
    u1 = min(float(w), math.ceil(s + sres))
    v0 = max(0.0, math.floor(t - tres))
    v1 = min(float(h), math.ceil(t + tres))
    if u1 <= u0:
        u0, u1 = min(u0, w - 1.0), min(u0, w - 1.0) + 1.0
    if v1 <= v0:
        v0, v1 = min(v0, h - 1.0), min(v0, h - 1.0) + 1.0
    return u0, u1, v0, v1


@inner
def region_decided(tt, planes, ortho, w, h, s, t, z, sres, tres, plane, Bias0, Bias1):
    """The tile test: 0.0 when every sample of the region must be lit, 1.0
    when every one must be in shadow, -1.0 when samples must be taken. Exact:
    the receiver's depth over the region lies between its values at the
    region's corners (a linear-fractional function of the texel position).
    ``tt``: one face's sparse tables (``tile_tables``), so the
    test costs the same for a region of any size; ``planes``: its blocks'
    planes (``tile_planes``) for ``planar_lit`` where the min / max do not
    decide (a receiver on a surface slanted to the light)."""
    u0, u1, v0, v1 = _texel_box(w, h, s, t, sres, tres)
    zlo, zhi = z, z
    if plane[0] != 0.0:
        for cu in (u0, u1):
            for cv in (v0, v1):
                zc = plane_depth(plane, cu, cv, -1.0)
                if zc < 0.0:
                    return -1.0
                zlo = min(zlo, zc)
                zhi = max(zhi, zc)
    dmin, dmax = tile_range(tt, int(v0) // TILE, (int(v1) - 1) // TILE,
                            int(u0) // TILE, (int(u1) - 1) // TILE)
    if zhi <= dmin * DEPTH_REL_EPS + Bias0:
        return 0.0
    if dmax < np.inf and zlo > dmax * DEPTH_REL_EPS + Bias1:
        return 1.0
    if planar_lit(tt, planes, ortho, u0, u1, v0, v1, z, zhi, plane, Bias0):
        return 0.0
    return -1.0


@inner(error_model="numpy")
def planar_lit(tt, planes, ortho, u0, u1, v0, v1, z, zhi, plane, Bias0):
    """Whether no sample of texels [u0, u1) x [v0, v1) can be behind the map
    (``region_decided``'s lit case), block by block (at most PLANAR_BLOCKS):
    a block passes its min depth test, or its plane (``tile_planes``) stays
    within half the smallest margin (Bias0 + the relative epsilon) of the
    receiver's tangent plane (``plane``; ``z`` everywhere without one) over
    the texel centres it shares with the region. On a perspective face both
    1 / depth are affine in the texel position, so their difference peaks at
    a corner, and zs - d = zs d (1/d - 1/zs) <= zhi dmax (that peak + r);
    on an orthographic one the depths themselves are affine. Exact, as the
    min / max test: only a receiver on (or in front of) the blocks' surfaces
    passes, where every sample would be lit."""
    ty0, ty1 = int(v0) // TILE, (int(v1) - 1) // TILE
    tx0, tx1 = int(u0) // TILE, (int(u1) - 1) // TILE
    if (ty1 - ty0 + 1) * (tx1 - tx0 + 1) > PLANAR_BLOCKS:
        return False
    if plane[0] == 0.0:
        ra, rb, rc = 0.0, 0.0, (z if ortho else 1.0 / z)
    elif plane[1] == 1.0:
        ra, rb, rc = plane[2], plane[3], plane[4]
    else:
        ra, rb, rc = plane[2] / plane[5], plane[3] / plane[5], plane[4] / plane[5]
    half = 0.5 * TILE
    for ty in range(ty0, ty1 + 1):
        for tx in range(tx0, tx1 + 1):
            dmin = tt[0, 0, ty, tx, 0]
            if zhi <= dmin * DEPTH_REL_EPS + Bias0:
                continue
            pa, pb, pc, pr = planes[ty, tx, 0], planes[ty, tx, 1], planes[ty, tx, 2], planes[ty, tx, 3]
            if not (pr < np.inf):
                return False
            cu0 = max(u0, float(tx * TILE)) + 0.5
            cu1 = min(u1, float(tx * TILE + TILE)) - 0.5
            cv0 = max(v0, float(ty * TILE)) + 0.5
            cv1 = min(v1, float(ty * TILE + TILE)) - 0.5
            peak = -np.inf
            for cu in (cu0, cu1):
                for cv in (cv0, cv1):
                    fit = pa * (cu - tx * TILE - half) + pb * (cv - ty * TILE - half) + pc
                    rec = ra * cu + rb * cv + rc
                    peak = max(peak, rec - fit if ortho else fit - rec)
            peak += pr
            excess = peak if ortho else zhi * np.float64(tt[0, 0, ty, tx, 1]) * max(peak, 0.0)
            if not (excess <= 0.5 * (Bias0 + dmin * (DEPTH_REL_EPS - 1.0))):
                return False
    return True
