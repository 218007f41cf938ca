"""``blocker="sum"``: the share of the light the blocker texels of a search
box hide, back-projected through the light's shape and added up.
"""
import math

import numpy as np

from ...jit import inner
from .gauge import _s_of
from .layer import _nearer
from .packed import NORM_MAX
from .weight import bilinear_sum, part_weight


COVER_GRID = 8   # blocker="sum": light points per side probing the box's share of the light


@inner
def _overlap(c, hw):
    """Share of the interval [c - hw, c + hw] inside [-1, 1]."""
    if hw <= 0.0:
        return 1.0 if abs(c) <= 1.0 else 0.0
    return min(max((min(c + hw, 1.0) - max(c - hw, -1.0)) / (2.0 * hw), 0.0), 1.0)


@inner
def _overlap_radial(r, hw):
    """Share of [r - hw, r + hw] inside the unit disk's radius."""
    if hw <= 0.0:
        return 1.0 if r <= 1.0 else 0.0
    return min(max((1.0 - (r - hw)) / (2.0 * hw), 0.0), 1.0)


@inner(forceinline=True)
def _part_centre(c, hw):
    """Centre of the part of [c - hw, c + hw] inside [-1, 1] (``c`` where
    they do not meet)."""
    lo, hi = max(c - hw, -1.0), min(c + hw, 1.0)
    return 0.5 * (lo + hi) if hi > lo else c


@inner(forceinline=True)
def _part_centre_radial(x, y, hw):
    """(x, y) moved along its radius r to the middle of the part of
    [r - hw, r + hw] inside the unit disk's radius."""
    r = math.sqrt(x * x + y * y)
    if not (r + hw > 1.0) or not (r > 0.0):
        return x, y
    rc = 0.5 * (max(r - hw, 0.0) + 1.0) if r - hw < 1.0 else 1.0
    return x * (rc / r), y * (rc / r)


@inner
def _coverage(depth_f, id_f, u, v, zr, pid, layer, G00, G01, G10, G11, norm, crad, use_id, irr, wf):
    """``blocker="sum"`` (not in the paper; section 3.4's one-blocker ramp
    cannot add up several blockers): the fraction of the light hidden by the
    blocker texels of the box, added up. A texel at depth z_b and offset d
    from P' hides the light around y = G d / s(z_b) (first order, as the
    gauge) -- the light is |y| <= 1 in its shape's norm (rectangle: max-norm
    on the half axes, else the disk) -- a light area |det G| / s(z_b)^2 of
    the shape's area (4 or pi), times the share of the texel's image inside
    the light (per axis for rectangles, radially for disks: no staircase).
    Texels hidden from the light's centre count as nothing and overlapping
    back-projections twice: the sum is clamped to 1. Where part of the light's back-projection (at
    the blockers' mean s) falls outside the scanned box (the map's border,
    ``max_radius``), the sum is divided by the part inside (``COVER_GRID``^2
    light points): the unseen part is taken to be blocked like the seen one.
    ``irr`` (visibility="irradiance"): each part counts by the light's
    emission towards the receiver at its centre (``weight.part_weight`` on
    ``wf``) over the light's mean emission at those points, and the box's
    share is theirs weighted. Returns (fraction, texels read)."""
    A, B, C, ortho, tol = layer.A, layer.B, layer.C, layer.ortho, layer.tol
    h, w = depth_f.shape
    iu = int(math.floor(u))
    iv = int(math.floor(v))
    det_s = G00 * G11 - G01 * G10
    det = abs(det_s)
    hx = 0.5 * (abs(G00) + abs(G01))      # half extents of a texel's image, per unit s
    hy = 0.5 * (abs(G10) + abs(G11))
    hr = 0.5 * math.sqrt(det)
    area = 4.0 if norm == NORM_MAX else math.pi
    acc = 0.0
    sw = 0.0
    m0, mx, my, mxy = 0.0, 0.0, 0.0, 0.0     # irr: the parts' moments (the bilinear weight's sum)
    nvis = 0
    for t in range(max(iv - crad, 0), min(iv + crad, h - 1) + 1):
        for s in range(max(iu - crad, 0), min(iu + crad, w - 1) + 1):
            nvis += 1
            d = np.float64(depth_f[t, s])
            if not _nearer(d, A * (s + 0.5) + B * (t + 0.5) + C, ortho, tol):
                continue
            if use_id and id_f[t, s] == pid:
                continue
            sc = _s_of(d, zr, ortho)
            if not (sc > 0.0) or not (sc < np.inf):
                continue
            du = (s + 0.5 - u) / sc
            dv = (t + 0.5 - v) / sc
            x = G00 * du + G01 * dv
            y = G10 * du + G11 * dv
            # the share of the texel's back-projection inside the light
            if norm == NORM_MAX:
                part = _overlap(x, hx / sc) * _overlap(y, hy / sc)
            else:
                part = _overlap_radial(math.sqrt(x * x + y * y), hr / sc)
            if part > 0.0:
                wt = part * det / (sc * sc * area)
                acc += wt
                sw += wt * sc
                if irr:
                    if norm == NORM_MAX:
                        xc, yc = _part_centre(x, hx / sc), _part_centre(y, hy / sc)
                    else:
                        xc, yc = _part_centre_radial(x, y, hr / sc)
                    m0 += wt
                    mx += wt * xc
                    my += wt * yc
                    mxy += wt * xc * yc
    if not (acc > 0.0):
        return 0.0, nvis
    # the part of the light whose back-projection at the mean s lies in the box
    s_ref = sw / acc
    n00, n01, n10, n11 = G11 / det_s, -G01 / det_s, -G10 / det_s, G00 / det_s
    s0, s1 = max(iu - crad, 0), min(iu + crad, w - 1) + 1
    t0, t1 = max(iv - crad, 0), min(iv + crad, h - 1) + 1
    n_ball = 0
    n_in = 0
    w_ball = 0.0
    w_in = 0.0
    for a in range(COVER_GRID):
        ya = -1.0 + (2 * a + 1.0) / COVER_GRID
        for b in range(COVER_GRID):
            yb = -1.0 + (2 * b + 1.0) / COVER_GRID
            if norm != NORM_MAX and ya * ya + yb * yb > 1.0:
                continue
            n_ball += 1
            wg = part_weight(wf, ya, yb) if irr else 0.0
            w_ball += wg
            su = u + s_ref * (n00 * ya + n01 * yb)
            sv = v + s_ref * (n10 * ya + n11 * yb)
            if su >= s0 and su < s1 and sv >= t0 and sv < t1:
                n_in += 1
                w_in += wg
    accw = bilinear_sum(wf, m0, mx, my, mxy) if irr else 0.0
    if irr and w_ball > 0.0:
        # sum of (area share x weight) over the light's mean weight, over the box's weighted share
        return min(accw * n_ball / (w_in if w_in > 0.0 else w_ball), 1.0), nvis
    if n_in == 0:
        return min(acc, 1.0), nvis
    return min(acc * n_ball / n_in, 1.0), nvis
