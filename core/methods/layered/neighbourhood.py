"""The surface around each warped sample pixel, from its warped neighbours
on the same surface: the depth gradient and span that ``plane_depth``
compares with, the slope ``steep_slope`` tests, and the footprint the
``splat="footprint"`` insert covers (``warp_local``)."""
from __future__ import annotations

import math

import numpy as np

from ...jit import HOT, kernel

MAX_FOOTPRINT = 2.0          # longest side (texels) of a warped pixel's footprint splat
SILHOUETTE_EXTENT = 1.5      # footprint reach past a silhouette (neighbour steps; 1/2 inside)
FOOTPRINT_OVERLAP = 0.02     # footprints reach this much past half a step: no cracks between them


@kernel(nogil=True, inline="always")
def _diagonal_neighbour(sobj, wf, wz, fs, r, c, sign, f, ob, z0):
    """Flat index of the neighbour of sample pixel (fs, r, c) along the
    diagonal (1, sign) or (-1, -sign) on the same surface ``ob`` and centre
    face ``f`` with the smaller depth step from ``z0``; -1: none."""
    F, h, w = sobj.shape
    best = np.inf
    out = -1
    for step in (-1, 1):
        rr, cc = r + step, c + sign * step
        if rr < 0 or rr >= h or cc < 0 or cc >= w:
            continue
        m = (fs * h + rr) * w + cc
        if wf[m] != f or sobj[fs, rr, cc] != ob:
            continue
        dz = abs(wz[m] - z0)
        if dz < best:
            best = dz
            out = m
    return out


@kernel(opt=HOT, nogil=True)
def warp_local(sdepth, sobj, wf, wx, wy, wz, cfaces, max_slope, gx, gy, span, foot, diagonals, slope_t):
    """The surface around each warped point, from its warped neighbours on the
    same surface (``sobj``: mesh piece or object id) in the same centre face
    (per sample-map axis the neighbour with the smaller depth step, so a
    silhouette's far side does not count):
      * gx, gy: depth gradient in centre-map texels (the plane through the
        three points; with ``diagonals``, a diagonal neighbour stands in for
        an axis that has none); none where the slope exceeds ``max_slope``
        (depth per lateral unit);
      * span: the depth change across one texel (|gx| + |gy|; on a steeper
        surface the neighbours' depth steps, at most ``max_slope`` texels);
      * slope_t: that depth change per texel in texel widths (the larger
        axis; inf past ``max_slope``), for ``steep_slope``;
      * foot[k] = (a0, a1, b0, b1, s-, s+, t-, t+): the sample pixel's
        footprint in the LDI for ``splat="footprint"``, the parallelogram
        s a + t b, -s- <= s < s+, -t- <= t < t+, with a, b the steps to the
        next pixel along the sample map's +u, +v (central differences over
        the neighbours on the surface; the other axis turned by 90 degrees
        where there is none; at most ``MAX_FOOTPRINT`` texels long), and the
        extents 1/2 (+ ``FOOTPRINT_OVERLAP``) towards a neighbour on the same
        surface or in front of it, ``SILHOUETTE_EXTENT`` towards empty space
        or a surface behind (the pixel is on its object's silhouette as the
        sample sees it)."""
    F, h, w = sobj.shape
    for k in range(F * h * w):
        gx[k] = 0.0
        gy[k] = 0.0
        span[k] = 0.0
        slope_t[k] = 0.0
        foot[k, 0] = 1.0
        foot[k, 1] = 0.0
        foot[k, 2] = 0.0
        foot[k, 3] = 1.0
        foot[k, 4:] = 0.5 + FOOTPRINT_OVERLAP
        f = wf[k]
        if f < 0:
            continue
        fs = k // (h * w)
        r = (k // w) % h
        c = k % w
        ob = sobj[fs, r, c]
        x0, y0, z0 = wx[k], wy[k], wz[k]
        d0 = sdepth[fs, r, c]
        # per sample-map axis: the neighbour with the smaller depth step (for
        # the gradient), the footprint axis (central difference over the
        # neighbours on the surface) and the extent towards each side
        na = -1
        nb = -1
        fa0 = 0.0
        fa1 = 0.0
        fb0 = 0.0
        fb1 = 0.0
        for axis in range(2):
            best = np.inf
            nbest = -1
            cnt = 0
            v0 = 0.0
            v1 = 0.0
            for j in range(2):
                step = 2 * j - 1
                if axis == 0:
                    rr, cc = r, c + step
                    m = k + step
                else:
                    rr, cc = r + step, c
                    m = k + step * w
                col = 4 + 2 * axis + j
                if rr < 0 or rr >= h or cc < 0 or cc >= w or wf[m] < 0:
                    foot[k, col] = SILHOUETTE_EXTENT
                    continue
                if wf[m] != f or sobj[fs, rr, cc] != ob:
                    if sdepth[fs, rr, cc] > d0:
                        foot[k, col] = SILHOUETTE_EXTENT
                    continue
                foot[k, col] = 0.5 + FOOTPRINT_OVERLAP
                v0 += (wx[m] - x0) * step
                v1 += (wy[m] - y0) * step
                cnt += 1
                dz = abs(wz[m] - z0)
                if dz < best:
                    best = dz
                    nbest = m
            if cnt:
                v0 /= cnt
                v1 /= cnt
                ln = math.sqrt(v0 * v0 + v1 * v1)
                if ln > MAX_FOOTPRINT:
                    v0, v1 = v0 * MAX_FOOTPRINT / ln, v1 * MAX_FOOTPRINT / ln
            if axis == 0:
                na, fa0, fa1 = nbest, v0, v1
            else:
                nb, fb0, fb1 = nbest, v0, v1
        # an axis with no neighbour on the surface: for the gradient, the
        # diagonal neighbour with the smaller depth step (a line one texel
        # wide running diagonally -- a chain-link wire, a stem -- has none
        # along the axes, and its raw depths split into layers)
        if diagonals and (na < 0 or nb < 0):
            da = _diagonal_neighbour(sobj, wf, wz, fs, r, c, 1, f, ob, z0)
            db = _diagonal_neighbour(sobj, wf, wz, fs, r, c, -1, f, ob, z0)
            if na < 0 and nb < 0:
                na, nb = da, db
            elif na < 0:
                na = da if da >= 0 else db
            else:
                nb = da if da >= 0 else db
        # an axis with no neighbour on the surface: the other one turned by
        # 90 degrees (sample and centre views have the same handedness)
        if fa0 == 0.0 and fa1 == 0.0:
            fa0, fa1 = (fb1, -fb0) if (fb0 != 0.0 or fb1 != 0.0) else (1.0, 0.0)
        if fb0 == 0.0 and fb1 == 0.0:
            fb0, fb1 = -fa1, fa0
        foot[k, 0], foot[k, 1], foot[k, 2], foot[k, 3] = fa0, fa1, fb0, fb1
        g0 = 0.0
        g1 = 0.0
        if na >= 0 and nb >= 0:
            a0, a1, za = wx[na] - x0, wy[na] - y0, wz[na] - z0
            b0, b1, zb = wx[nb] - x0, wy[nb] - y0, wz[nb] - z0
            det = a0 * b1 - a1 * b0
            if abs(det) > 1e-9 * math.sqrt((a0 * a0 + a1 * a1) * (b0 * b0 + b1 * b1)):
                g0 = (za * b1 - zb * a1) / det
                g1 = (a0 * zb - b0 * za) / det
            else:
                na2 = a0 * a0 + a1 * a1
                if na2 > 0.0:
                    g0, g1 = za * a0 / na2, za * a1 / na2
        elif na >= 0 or nb >= 0:
            m = na if na >= 0 else nb
            a0, a1, za = wx[m] - x0, wy[m] - y0, wz[m] - z0
            na2 = a0 * a0 + a1 * a1
            if na2 > 0.0:
                g0, g1 = za * a0 / na2, za * a1 / na2
        # texel size in scene units at this depth, to turn the gradient into a slope
        fp = cfaces[f]
        tx = (fp[18] - fp[17]) / fp[21]
        ty = (fp[20] - fp[19]) / fp[22]
        if fp[16] == 0.0:
            tx *= z0
            ty *= z0
        if abs(g0) > max_slope * tx or abs(g1) > max_slope * ty:
            raw = 0.0
            if na >= 0:
                raw += abs(wz[na] - z0)
            if nb >= 0:
                raw += abs(wz[nb] - z0)
            span[k] = min(raw, max_slope * (tx + ty))
            slope_t[k] = np.inf
            continue
        gx[k] = g0
        gy[k] = g1
        span[k] = abs(g0) + abs(g1)
        slope_t[k] = max(abs(g0) / tx, abs(g1) / ty)
