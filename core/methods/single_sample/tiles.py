"""Depth-range tiles of the light map: per 8 x 8 texels the least and largest
depth and the one object id, which rule out search boxes and ring texels
that cannot hold a candidate.
"""
import numpy as np

from ...jit import inner, kernel
from .layer import _nearer


TILE = 8   # texels per side of the depth-range tiles that skip hopeless search boxes


@kernel
def tile_depth_range(depth, ids):
    """float64[F, ceil(h/TILE), ceil(w/TILE), 3]: per tile the least and the
    largest depth (+inf counts: an empty texel is behind everything) and the
    object id every texel shows (-2 if they differ)."""
    F, h, w = depth.shape
    th = (h + TILE - 1) // TILE
    tw = (w + TILE - 1) // TILE
    out = np.empty((F, th, tw, 3))
    for k in range(F * th):
        f = k // th
        b = k % th
        for a in range(tw):
            lo = np.inf
            hi = -np.inf
            oid = ids[f, b * TILE, a * TILE]
            for t in range(b * TILE, min((b + 1) * TILE, h)):
                for s in range(a * TILE, min((a + 1) * TILE, w)):
                    z = depth[f, t, s]
                    lo = min(lo, z)
                    hi = max(hi, z)
                    if ids[f, t, s] != oid:
                        oid = -2
            out[f, b, a, 0] = lo
            out[f, b, a, 1] = hi
            out[f, b, a, 2] = oid
    return out


@inner
def _tile_range(tiles_f, iu, iv, c, pid):
    """Over the tiles covering texels [iu-c, iu+c] x [iv-c, iv+c]: least and
    largest depth, and whether every texel shows object ``pid``."""
    th, tw = tiles_f.shape[0], tiles_f.shape[1]
    a0 = max(iu - c, 0) // TILE
    a1 = min((iu + c) // TILE, tw - 1)
    b0 = max(iv - c, 0) // TILE
    b1 = min((iv + c) // TILE, th - 1)
    zmin = np.inf
    zmax = -np.inf
    own = True
    for b in range(b0, b1 + 1):
        for a in range(a0, a1 + 1):
            zmin = min(zmin, tiles_f[b, a, 0])
            zmax = max(zmax, tiles_f[b, a, 1])
            if tiles_f[b, a, 2] != pid:
                own = False
    return zmin, zmax, own


@inner
def _tile_hopeless(tiles_f, tb, ta, inner, lv, ortho, tol, pid, pid_in_map, use_id):
    """Under a constant layer ``lv``: no texel of tile (tb, ta) can be the
    search's candidate, by the tile's depth range and id (``_nearer`` is
    monotonic in the depth, so its nearest / farthest texel decides): an
    outer search needs a nearer texel of another object, an inner one a
    texel at or behind the layer of the receiver's own."""
    oid = tiles_f[tb, ta, 2]
    if inner:
        if pid_in_map and oid != -2.0 and oid != pid:
            return True
        return _nearer(tiles_f[tb, ta, 1], lv, ortho, tol)      # its farthest texel is in front: all are
    if use_id and oid == pid:
        return True
    return not _nearer(tiles_f[tb, ta, 0], lv, ortho, tol)      # its nearest texel is not in front: none is
