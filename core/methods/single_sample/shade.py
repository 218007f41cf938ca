"""V of one pixel (section 3.3: hard test, search, ramp) and the parallel
drivers over the searched pixels and over the hard test of every pixel.
"""
import math

from ...jit import HOT, inner, kernel
from ...kernels import borrowed, each_dealt_chunk, each_range
from .coverage import _coverage
from .gauge import Gauge, _light_axes, _s_of, _shape
from .layer import Layer, _layer_range
from .packed import (NORM_EUCLID, P_AUTO, P_HARD, P_IDTEST, P_IRR, P_JITTER, P_MAXRAD, P_MEET, P_NORM, P_PLANE,
                     P_RBIAS, P_RSCALE, P_RSHRINK, P_SUM)
from .search import SearchPoint, _search
from .tiles import _tile_range
from .warp import _warp, _warp_inline
from .weight import NO_WEIGHTS, corner_weights


@inner
def _shade(P, Nrm, pid_arr, i, faces, finfo, depth, ids, tiles, in_map, prm):
    """V of one pixel (section 3.3 with the search); also returns the search
    box's half size in texels (0 where no search ran) and the texels read."""
    (f, u, v, zr, inner, zb0, planar, A, B, C, tol, pvx, pvy,
     pvz) = _warp(P, Nrm, i, faces, depth, prm)
    if f < 0:
        return 1.0, 0.0, 0
    hard = 0.0 if inner else 1.0
    if prm[P_HARD] == 1.0:
        return hard, 0.0, 0
    fp = faces[f]
    ortho = fp[16] == 1.0
    if not planar or prm[P_PLANE] == 0.0:     # the paper's constant virtual layer P'_z
        A, B, C = 0.0, 0.0, (zr if ortho else 1.0 / zr)
    pid = pid_arr[i]
    pid_in_map = pid >= 0 and pid < in_map.shape[0] and in_map[pid]
    meet = prm[P_MEET]
    auto = prm[P_AUTO] == 1.0
    maxrad = prm[P_MAXRAD]
    off = 1.0 + 0.5 * prm[P_JITTER]
    add_up = prm[P_SUM] == 1.0        # blocker="sum": no inner / outer search
    search_inner = inner and not add_up
    if auto:
        G00, G01, G10, G11, emax = _shape(prm, finfo[f], fp, pvx, pvy, pvz, zr)
        norm = int(prm[P_NORM])
        if search_inner:
            rho_max = _s_of(zb0, zr, ortho)
        else:
            rho_max = _s_of(finfo[f, 6], zr, ortho)
    else:
        G00, G01, G10, G11, emax = 1.0, 0.0, 0.0, 1.0, 1.0
        norm = NORM_EUCLID
        rho_max = min(prm[P_RSCALE] * abs(zr) + prm[P_RBIAS], maxrad)
    if not (rho_max > 0.0):
        return hard, 0.0, 0
    # hierarchical skip (not in the paper): the depth range over the box's
    # tiles bounds every candidate texel in it
    iu = int(math.floor(u))
    iv = int(math.floor(v))
    nrep = 2 if (auto and not search_inner) else 1
    for _rep in range(nrep):
        c = int(math.ceil(min(rho_max * emax + off, maxrad)))
        zbox_lo, zbox_hi, own = _tile_range(tiles[f], iu, iv, c, pid)
        zl_lo, zl_hi = _layer_range(A, B, C, iu, iv, c, ortho)
        if search_inner:
            if zbox_hi < zl_lo - tol:         # no texel at or behind the layer
                return 0.0, 0.0, 0
        else:
            if not (zbox_lo < zl_hi - tol):   # no texel in front of the layer
                return 1.0, 0.0, 0
            if own and prm[P_IDTEST] == 1.0:  # only the receiver's own texels
                return 1.0, 0.0, 0
            if auto:
                rho_max = min(rho_max, _s_of(zbox_lo, zr, ortho))
                if not (rho_max > 0.0):
                    return 1.0, 0.0, 0
    if add_up:
        crad = int(math.ceil(min(rho_max * emax + off, maxrad)))
        irr = prm[P_IRR] == 1.0
        if irr:
            a1x, a1y, a1z, a2x, a2y, a2z = _light_axes(prm, finfo[f], fp, pvx, pvy, pvz)
            wf = corner_weights(prm, finfo[f], pvx, pvy, pvz, a1x, a1y, a1z, a2x, a2y, a2z)
        else:
            wf = NO_WEIGHTS
        cov, nvis = _coverage(depth[f], ids[f], u, v, zr, pid, Layer(A, B, C, ortho, tol),
                              G00, G01, G10, G11, norm, crad, prm[P_IDTEST] == 1.0, irr, wf)
        return 1.0 - cov, rho_max * emax + off, nvis
    rtex = rho_max * emax
    crad = int(math.ceil(min(rtex + off, maxrad)))
    found, rho, zb, nvis = _search(depth[f], ids[f], tiles[f], f, SearchPoint(u, v, inner, pid, pid_in_map),
                                   Layer(A, B, C, ortho, tol), Gauge(G00, G01, G10, G11, norm, emax),
                                   rho_max, crad, prm)
    rtex += off
    if not found:
        return hard, rtex, nvis
    zb_use = zb0 if inner else zb
    if auto:
        rfin = _s_of(zb_use, zr, ortho)
    else:
        rfin = rho_max * prm[P_RSHRINK] * (zr - zb_use)
    # a penumbra wider than the capped box is narrowed to it, so V still
    # reaches 1 (0) at the box's edge instead of jumping there
    rcap = (crad - off) / emax
    if rcap > 0.0 and rfin > rcap:
        rfin = rcap
    q = rho / rfin if rfin > 0.0 else 1.0
    q = min(max(q, 0.0), 1.0)
    if inner:
        return meet * (1.0 - q), rtex, nvis
    return meet + (1.0 - meet) * q, rtex, nvis


_BLOCK = 256     # consecutive pixels per dealt block: neighbours read the same map texels


def shade_all(P, Nrm, pid_arr, sel, faces, finfo, depth, ids, tiles, in_map, prm, out, rad, vis, threads=None):
    """Search the selected pixels (all of them with adaptive sampling off):
    ``_shade_all`` on Numba's thread count (``kernels.each_dealt_chunk``)."""
    each_dealt_chunk(lambda ks: _shade_all(ks, P, Nrm, pid_arr, sel, faces, finfo, depth, ids, tiles, in_map, prm,
                                           out, rad, vis), sel.shape[0], threads, block=_BLOCK)


@kernel(opt=HOT, nogil=True, error_model="numpy")
def _shade_all(ks, P, Nrm, pid_arr, sel, faces, finfo, depth, ids, tiles, in_map, prm, out, rad, vis):
    """``shade_all`` for entries ``ks`` of ``sel``: a serial ``nogil`` kernel
    with ``kernels.borrowed`` arguments (a ``prange`` kernel's parfor
    lowering would dominate its compile time)."""
    P, Nrm, pid_arr, sel, faces, finfo, depth, ids, tiles, in_map, prm, out, rad, vis = borrowed(
        (P, Nrm, pid_arr, sel, faces, finfo, depth, ids, tiles, in_map, prm, out, rad, vis))
    for k in ks:
        i = sel[k]
        val, rt, nv = _shade(P, Nrm, pid_arr, i, faces, finfo, depth, ids, tiles, in_map, prm)
        out[i] = val
        rad[i] = rt
        vis[i] = nv


def hard_all(P, Nrm, hit, faces, depth, ids, prm, hface, hinner, hid, pid_arr, threads=None):
    """Section 4.3's first step on every pixel: the hard test and the id it
    carries (the blocker's where inner, the receiver's where lit).
    ``_hard_range`` over ranges of pixels (``kernels.each_range``, a few per
    thread): no index arrays to build, ``_warp`` inlined."""
    each_range(lambda i0, i1: _hard_range(i0, i1, P, Nrm, hit, faces, depth, ids, prm, hface, hinner, hid, pid_arr),
               P.shape[0], threads, grain=16384, per_worker=4)


@kernel(opt=HOT, nogil=True, error_model="numpy")
def _hard_range(i0, i1, P, Nrm, hit, faces, depth, ids, prm, hface, hinner, hid, pid_arr):
    """``hard_all`` for pixels i0..i1-1."""
    P, Nrm, hit, faces, depth, ids, prm, hface, hinner, hid, pid_arr = borrowed(
        (P, Nrm, hit, faces, depth, ids, prm, hface, hinner, hid, pid_arr))
    for i in range(i0, i1):
        if not hit[i]:
            hface[i] = -2
            hinner[i] = 0
            hid[i] = -1
            continue
        (f, u, v, zr, inner, zb0, planar, A, B, C, tol, pvx, pvy,
         pvz) = _warp_inline(P, Nrm, i, faces, depth, prm)
        hface[i] = f
        hinner[i] = 1 if inner else 0
        if f >= 0 and inner:
            fp = faces[f]
            iu = min(max(int(math.floor(u)), 0), int(fp[21]) - 1)
            iv = min(max(int(math.floor(v)), 0), int(fp[22]) - 1)
            hid[i] = ids[f, iv, iu]
        else:
            hid[i] = pid_arr[i]
