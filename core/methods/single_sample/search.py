"""The ring-ordered box search for the nearest blocker or lit texel
(sections 3.3, 4.2, 4.3).
"""
import math
from collections import namedtuple

import numpy as np

from ...jit import inner
from ...sampling import rand01
from .layer import _nearer
from .packed import NORM_L1, P_EDGE, P_IDTEST, P_JITTER, P_SEED
from .tiles import TILE, _tile_hopeless


SearchPoint = namedtuple("SearchPoint", "u v inner pid pid_in_map")
"""The receiver in the map: texel coordinates, depth, inner (own-object lit
texel) or outer (blocker) search, its object id and whether that id is in
the map."""


@inner
def _search(depth_f, id_f, tiles_f, fidx, pt, layer, gauge, rho_max, crad, prm):
    """Ring-ordered axis-aligned box scan (sections 4.2, 4.3, figure 4).

    Returns (found, rho, z, texels read): the candidate texel nearest to P'
    in the gauge, its rho and depth. pt: SearchPoint; layer: Layer; gauge:
    Gauge. Under the constant layer, texels of a tile that cannot hold a
    candidate (``tiles._tile_hopeless``) are passed over unread: the same
    texels are candidates, in the same order, and a failed search (which
    scans the whole box) reads far fewer texels."""
    u, v, inner, pid, pid_in_map = pt.u, pt.v, pt.inner, pt.pid, pt.pid_in_map
    A, B, C, ortho, tol = layer.A, layer.B, layer.C, layer.ortho, layer.tol
    G00, G01, G10, G11, norm, emax = gauge.G00, gauge.G01, gauge.G10, gauge.G11, gauge.norm, gauge.emax
    h, w = depth_f.shape
    iu = int(math.floor(u))
    iv = int(math.floor(v))
    edge = prm[P_EDGE] == 1.0
    jit = prm[P_JITTER]
    seed = int(prm[P_SEED])
    use_id = prm[P_IDTEST] == 1.0
    tskip = A == 0.0 and B == 0.0    # the layer is C at every texel
    cb0, ca0, ch0 = -1, -1, False
    cb1, ca1, ch1 = -1, -1, False
    off = (1.0 if edge else 0.5) + 0.5 * jit
    best = np.inf
    best_z = 0.0
    found = False
    nvis = 0
    for c in range(0, crad + 1):
        lb = (c - off) / emax
        if lb < 0.0:
            lb = 0.0
        if lb > rho_max:
            break
        if found and lb > best:
            break
        t0 = iv - c
        t1 = iv + c
        for t in range(max(t0, 0), min(t1, h - 1) + 1):
            full = t == t0 or t == t1
            step = 1 if full else 2 * c
            s0 = iu - c
            s1 = iu + c
            if full:
                s0 = max(s0, 0)
                s1 = min(s1, w - 1)
            tb = t // TILE
            s_next = s0
            while s_next <= s1:
                s = s_next
                s_next = s + step
                if s < 0 or s >= w:
                    continue
                if tskip:
                    # two cached tiles: the ring's left and right side (or the row's current tile)
                    ta = s // TILE
                    if s < iu:
                        if tb != cb0 or ta != ca0:
                            cb0, ca0 = tb, ta
                            ch0 = _tile_hopeless(tiles_f, tb, ta, inner, C, ortho, tol, pid, pid_in_map, use_id)
                        hopeless = ch0
                    else:
                        if tb != cb1 or ta != ca1:
                            cb1, ca1 = tb, ta
                            ch1 = _tile_hopeless(tiles_f, tb, ta, inner, C, ortho, tol, pid, pid_in_map, use_id)
                        hopeless = ch1
                    if hopeless:
                        if full:
                            s_next = (ta + 1) * TILE    # the rest of the tile's texels on this row
                        continue
                nvis += 1
                d = np.float64(depth_f[t, s])
                # the layer at this texel: z_l = lv (ortho) or 1 / lv (perspective,
                # +inf where lv <= 0); "d < z_l - tol" is "(d + tol) lv < 1" there
                nearer = _nearer(d, A * (s + 0.5) + B * (t + 0.5) + C, ortho, tol)
                if inner:    # nearest lit texel of the receiver's own object
                    if nearer:
                        continue
                    if pid_in_map and id_f[t, s] != pid:
                        continue
                else:        # nearest blocker of another object
                    if not nearer:
                        continue
                    if use_id and id_f[t, s] == pid:
                        continue
                du = s + 0.5 - u
                dv = t + 0.5 - v
                if jit > 0.0:
                    key = (fidx * h + t) * w + s
                    du += jit * (rand01(seed, key, np.int64(0), np.int64(0)) - 0.5)
                    dv += jit * (rand01(seed, key, np.int64(0), np.int64(1)) - 0.5)
                if edge:
                    du = math.copysign(max(abs(du) - 0.5, 0.0), du)
                    dv = math.copysign(max(abs(dv) - 0.5, 0.0), dv)
                x = G00 * du + G01 * dv
                y = G10 * du + G11 * dv
                if norm == NORM_L1:
                    rho = abs(x) + abs(y)
                else:
                    rho = math.sqrt(x * x + y * y)
                if rho > rho_max:
                    continue
                if rho < best:
                    best = rho
                    best_z = d
                    found = True
    return found, best, best_z, nvis
