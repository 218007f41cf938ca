"""The penumbra of soft irregular shadow mapping (Johnson et al. 2009,
sections 2.2, 2.3, 2.5, figure 2c-d): one quad per silhouette record,
binned, rasterized over the grid's columns; each receiver it selects gets
the signed analytic term of the edge (``geom.penumbra_term``).

Penumbra quad of an edge (section 2.2): light points x lie within ``r_L`` of
the centre; for a receiver p at depth z_p occluded by an edge point q at
depth z_q, in face-plane (tangent) units

    |q' - p'| <= r_L k (z_p - z_q) / (z_q (z_p - rho))

with k = sqrt(1 + |p'|^2) and rho the largest depth of a light point in the
face (k = 1, rho = 0 for an area light seen along its own axis, where this
is Parker et al.'s r (1/z_q - 1/z_p)). It grows with z_p, so with z_p <= Z
(the largest receiver depth: of the face, or of the bin when ``bin_refine``)
the quad is the convex hull of two disks around the edge's projected
endpoints (the radius is linear in 1/z, hence along the projected edge).
The wedge test (``wedge_test``) solves the same bound for the smallest depth
a receiver in a given column can have and still be reached. Sun: the
orthographic face gives |q' - p'| <= tan(a/2) (z_p - z_q).
"""
from __future__ import annotations

import math
from collections import namedtuple

import numpy as np
from numba import prange

from ...jit import HOT, inner, kernel
from ...kernels import borrowed, each_dealt_chunk
from .geom import penumbra_term
from .grid import (col_range, col_rect, point_seg_dist2, rect_k, row_range, seg_rect_dist, seg_x_in_band, slice_of,
                   to_view)

# penumbra quad of a (record, face): ``edge_quads``' flag
QUAD_NONE = 0           # no receiver of the face can be reached
QUAD_EDGE = 1           # the convex hull of the two endpoint disks
QUAD_WHOLE_FACE = 2     # unbounded (edge through the light's near ball): every column

Quads = namedtuple("Quads", "ep flag rng")
"""Per (record, face): projected endpoints, QUAD_* flag and column/row range
(``edge_quads``)."""


@inner
def _quad_width(persp, rL, k, rho, tan_a, Z, z):
    """Half width of the penumbra quad at an edge endpoint of depth z for
    receivers no deeper than Z (face-plane units); -1 = unbounded."""
    if z >= Z:
        return 0.0
    if not persp:
        return tan_a * (Z - z)
    if not (Z > rho) or not (z > rho):
        return -1.0
    return rL * k * (Z - z) / (z * (Z - rho)) * (1.0 + 1e-9)


def edge_quads(tv, rec_t, rec_k, faces, face_Z, face_k, face_rho, face_near, face_rnear,
               rL, tan_a, threads=None):
    """Per (record, face): projected endpoints of the edge (clipped to depth
    >= near for perspective faces), whole-face flag, and the global quad's
    column/row range (quad width from the face's largest receiver depth):
    ``_edge_quads`` on Numba's thread count (``kernels.each_dealt_chunk``)."""
    R, F = rec_t.shape[0], faces.shape[0]
    ep = np.zeros((R, F, 6))
    flag = np.zeros((R, F), np.int8)      # QUAD_*
    rng = np.empty((R, F, 4), np.int64)
    each_dealt_chunk(lambda rs: _edge_quads(rs, tv, rec_t, rec_k, faces, face_Z, face_k, face_rho, face_near,
                                            face_rnear, rL, tan_a, ep, flag, rng), R, threads)
    return ep, flag, rng


@kernel(nogil=True, error_model="numpy")
def _edge_quads(rs, tv, rec_t, rec_k, faces, face_Z, face_k, face_rho, face_near, face_rnear, rL, tan_a,
                ep, flag, rng):
    """``edge_quads`` for records ``rs``: a serial ``nogil`` kernel with
    ``kernels.borrowed`` arguments."""
    tv, rec_t, rec_k, faces, face_Z, face_k, face_rho, face_near, face_rnear, ep, flag, rng = borrowed(
        (tv, rec_t, rec_k, faces, face_Z, face_k, face_rho, face_near, face_rnear, ep, flag, rng))
    F = faces.shape[0]
    for r in rs:
        t = rec_t[r]
        k = rec_k[r]
        k1 = (k + 1) % 3
        for f in range(F):
            fp = faces[f]
            rng[r, f, 0] = 1
            rng[r, f, 1] = 0
            rng[r, f, 2] = 1
            rng[r, f, 3] = 0
            ax, ay, az = to_view(fp, tv[t, k, 0], tv[t, k, 1], tv[t, k, 2])
            bx, by, bz = to_view(fp, tv[t, k1, 0], tv[t, k1, 1], tv[t, k1, 2])
            persp = fp[16] == 0.0
            whole = False
            if persp:
                zn = face_near[f]
                if az < zn or bz < zn:
                    # distance from the light centre to the edge (view space)
                    ex, ey, ez = bx - ax, by - ay, bz - az
                    L2 = ex * ex + ey * ey + ez * ez
                    s = 0.0
                    if L2 > 0.0:
                        s = -(ax * ex + ay * ey + az * ez) / L2
                        s = min(max(s, 0.0), 1.0)
                    qx, qy, qz = ax + s * ex, ay + s * ey, az + s * ez
                    if math.sqrt(qx * qx + qy * qy + qz * qz) <= face_rnear[f]:
                        whole = True
                    elif az < zn and bz < zn:
                        continue
                    else:
                        s = (zn - az) / (bz - az)
                        mx, my = ax + s * (bx - ax), ay + s * (by - ay)
                        if az < zn:
                            ax, ay, az = mx, my, zn
                        else:
                            bx, by, bz = mx, my, zn
                if not whole:
                    ax, ay = ax / az, ay / az
                    bx, by = bx / bz, by / bz
            if whole:
                flag[r, f] = QUAD_WHOLE_FACE
                rng[r, f, 0] = 0
                rng[r, f, 1] = int(fp[21]) - 1
                rng[r, f, 2] = 0
                rng[r, f, 3] = int(fp[22]) - 1
                continue
            ep[r, f, 0] = ax
            ep[r, f, 1] = ay
            ep[r, f, 2] = az
            ep[r, f, 3] = bx
            ep[r, f, 4] = by
            ep[r, f, 5] = bz
            Z = face_Z[f]
            wa = _quad_width(persp, rL, face_k[f], face_rho[f], tan_a, Z, az)
            wb = _quad_width(persp, rL, face_k[f], face_rho[f], tan_a, Z, bz)
            if wa < 0.0 or wb < 0.0:
                flag[r, f] = QUAD_WHOLE_FACE
                rng[r, f, 0] = 0
                rng[r, f, 1] = int(fp[21]) - 1
                rng[r, f, 2] = 0
                rng[r, f, 3] = int(fp[22]) - 1
                continue
            if wa <= 0.0 and wb <= 0.0:
                continue
            c0, c1 = col_range(fp, min(ax - wa, bx - wb), max(ax + wa, bx + wb))
            r0, r1 = row_range(fp, min(ay - wa, by - wb), max(ay + wa, by + wb))
            if c0 > c1 or r0 > r1:
                continue
            flag[r, f] = QUAD_EDGE
            rng[r, f, 0] = c0
            rng[r, f, 1] = c1
            rng[r, f, 2] = r0
            rng[r, f, 3] = r1


@inner(forceinline=True)
def _bin_quad(ep, r, f, fp, persp, rL, rho, tan_a, Zb, kb):
    za = ep[r, f, 2]
    zb = ep[r, f, 5]
    wa = _quad_width(persp, rL, kb, rho, tan_a, Zb, za)
    wb = _quad_width(persp, rL, kb, rho, tan_a, Zb, zb)
    return wa, wb


@kernel
def bin_quads(ep, flag, rng, faces, bin_base, nbx, bin_size, binmax, face_rho, face_k, face_par,
              rL, tan_a, refine):
    """Sort penumbra quads into bins. With ``refine`` (section 2.5, first
    optimization) the quad is rebuilt per bin from the bin's largest receiver
    depth and dropped from bins it no longer overlaps."""
    R = ep.shape[0]
    F = ep.shape[1]
    nbins = bin_base[-1]
    cnt = np.zeros(nbins + 1, np.int64)
    for phase in range(2):
        if phase == 1:
            for b in range(nbins):
                cnt[b + 1] += cnt[b]
            pos = cnt[:-1].copy()
            items = np.empty(cnt[nbins], np.int64)
        for r in range(R):
            for f in range(F):
                if flag[r, f] == QUAD_NONE:
                    continue
                fp = faces[f]
                persp = fp[16] == 0.0
                gw = int(fp[21])
                gh = int(fp[22])
                for by in range(rng[r, f, 2] // bin_size, rng[r, f, 3] // bin_size + 1):
                    for bx in range(rng[r, f, 0] // bin_size, rng[r, f, 1] // bin_size + 1):
                        b = bin_base[f] + by * nbx[f] + bx
                        Zb = binmax[b]
                        if not (Zb > -np.inf):
                            continue           # empty bin
                        if refine and flag[r, f] == QUAD_EDGE:
                            c0 = bx * bin_size
                            c1 = min(c0 + bin_size, gw) - 1
                            r0 = by * bin_size
                            r1 = min(r0 + bin_size, gh) - 1
                            x0, x1, y0, y1 = col_rect(fp, c0, c1, r0, r1)
                            kb = 1.0 if face_par[f] else rect_k(x0, x1, y0, y1)
                            wa, wb = _bin_quad(ep, r, f, fp, persp, rL, face_rho[f], tan_a, Zb, kb)
                            if wa >= 0.0 and wb >= 0.0:
                                w = max(wa, wb)
                                if w <= 0.0:
                                    continue
                                d = seg_rect_dist(ep[r, f, 0], ep[r, f, 1], ep[r, f, 3], ep[r, f, 4],
                                                  x0, x1, y0, y1)
                                if d > w:
                                    continue
                        if phase == 0:
                            cnt[b + 1] += 1
                        else:
                            items[pos[b]] = r
                            pos[b] += 1
    return cnt, items


def penumbra_bins(bins, blist, quads, grid, fb, rec, records, occ, lit, mode, refine, wedge, pen, ls, evals,
                  threads=None):
    """Soft shadow kernel (sections 2.3, 2.5): ``_penumbra_bins`` over every
    bin of ``bins.perm`` on Numba's thread count (bins dealt into chunks:
    ``kernels.each_dealt_chunk``). A bin
    writes only its own receivers, so the result does not depend on the
    thread count."""
    each_dealt_chunk(lambda jbs: _penumbra_bins(jbs, bins, blist, quads, grid, fb, rec, records, occ, lit, mode,
                                                refine, wedge, pen, ls, evals), bins.perm.shape[0], threads)


@kernel(opt=HOT, nogil=True, error_model="numpy")
def _penumbra_bins(jbs, bins, blist, quads, grid, fb, rec, records, occ, lit, mode, refine, wedge, pen, ls, evals):
    """Per bin ``bins.perm[jb]``, jb in ``jbs`` (in turn): every quad listed
    in it is rasterized over the bin's columns; the wedge test (second
    optimization) or the quad test selects the receivers, and each gets the
    signed analytic term of the edge.

    bins: Bins; blist: BinList of records; quads: Quads; grid: ReceiverGrid;
    fb: FaceBounds; rec: Receivers; records: Records; occ: Occluders; lit:
    KernelLight; mode: geom.SILHOUETTE_*; refine / wedge: the two overdraw
    reductions; ``pen`` per receiver, ls: LightSamples (updated), ``evals``
    per bin. A serial ``nogil`` kernel run on worker threads (a ``prange``
    one's parfor lowering would dominate its compile time), its arguments
    ``kernels.borrowed`` and ``error_model="numpy"`` as a prange body's."""
    bins, blist, quads, grid, fb, rec, records, occ, lit, pen, ls, evals = borrowed(
        (bins, blist, quads, grid, fb, rec, records, occ, lit, pen, ls, evals))
    perm, bin_face, bin_bx, bin_by, bin_size = bins.perm, bins.face, bins.bx, bins.by, bins.size
    binmax = bins.maxz
    bin_start, bin_items = blist.start, blist.items
    ep, flag = quads.ep, quads.flag
    faces, col_base, gd, zlo, zhi = grid.faces, grid.col_base, grid.gd, grid.zlo, grid.zhi
    logz, cell_start, colmax = grid.logz, grid.cell_start, grid.colmax
    face_Z, face_k, face_rho, face_par = fb.Z, fb.k, fb.rho, fb.par
    Ps, XYZ, RF = rec.Ps, rec.XYZ, rec.RF
    rec_t, rec_k = records.t, records.k
    tv, nv, facing, orient = occ.tv, occ.nv, occ.facing, occ.orient
    cx, cy, cz, is_sun, rL, tan_a = lit.cx, lit.cy, lit.cz, lit.is_sun, lit.rL, lit.tan_a
    for jb in jbs:
        b = perm[jb]
        f = bin_face[b]
        fp = faces[f]
        persp = fp[16] == 0.0
        gw = int(fp[21])
        gh = int(fp[22])
        bc0 = bin_bx[b] * bin_size
        bc1 = min(bc0 + bin_size, gw) - 1
        br0 = bin_by[b] * bin_size
        br1 = min(br0 + bin_size, gh) - 1
        bx0, bx1, by0, by1 = col_rect(fp, bc0, bc1, br0, br1)
        kbin = 1.0 if face_par[f] else rect_k(bx0, bx1, by0, by1)
        Zuse = binmax[b] if refine else face_Z[f]
        kuse = kbin if refine else face_k[f]
        nev = 0
        for e in range(bin_start[b], bin_start[b + 1]):
            r = bin_items[e]
            t = rec_t[r]
            k = rec_k[r]
            whole = flag[r, f] == QUAD_WHOLE_FACE
            ax, ay, az = ep[r, f, 0], ep[r, f, 1], ep[r, f, 2]
            qx, qy, qz = ep[r, f, 3], ep[r, f, 4], ep[r, f, 5]
            zq = min(az, qz)
            c0, c1, r0, r1 = bc0, bc1, br0, br1
            wmax = 0.0
            if not whole:
                wa, wb = _bin_quad(ep, r, f, fp, persp, rL, face_rho[f], tan_a, Zuse, kuse)
                if wa < 0.0 or wb < 0.0:
                    whole = True
                else:
                    wmax = max(wa, wb)
                    q0, q1 = col_range(fp, min(ax - wa, qx - wb), max(ax + wa, qx + wb))
                    s0_, s1_ = row_range(fp, min(ay - wa, qy - wb), max(ay + wa, qy + wb))
                    c0 = max(c0, q0)
                    c1 = min(c1, q1)
                    r0 = max(r0, s0_)
                    r1 = min(r1, s1_)
            for row in range(r0, r1 + 1):
                rc0, rc1 = c0, c1
                if not whole:
                    # rasterize the quad, not its box: columns within wmax of
                    # the part of the edge inside this row's band
                    _, _, y0r, y1r = col_rect(fp, c0, c0, row, row)
                    xa, xb = seg_x_in_band(ax, ay, qx, qy, y0r - wmax, y1r + wmax)
                    if xa > xb:
                        continue
                    q0, q1 = col_range(fp, xa - wmax, xb + wmax)
                    rc0 = max(rc0, q0)
                    rc1 = min(rc1, q1)
                for col in range(rc0, rc1 + 1):
                    column = col_base[f] + row * gw + col
                    cm = colmax[column]
                    if not (cm > -np.inf):
                        continue
                    k0 = 0
                    kc = 1.0
                    if not whole:
                        x0, x1, y0, y1 = col_rect(fp, col, col, row, row)
                        D = seg_rect_dist(ax, ay, qx, qy, x0, x1, y0, y1)
                        if wedge:
                            if persp:
                                kc = 1.0 if face_par[f] else rect_k(x0, x1, y0, y1)
                                a = D * zq / (rL * kc)
                                if a >= 1.0:
                                    continue
                                zs = (zq - a * face_rho[f]) / (1.0 - a)
                            else:
                                zs = zq + D / tan_a
                            zs *= 1.0 - 1e-9
                            if zs > cm:
                                continue
                            k0 = slice_of(zs, zlo[f], zhi[f], gd, logz[f])
                        elif D > wmax:
                            continue
                    s0 = cell_start[column * gd + k0]
                    s1 = cell_start[column * gd + gd]
                    for s in range(s0, s1):
                        if RF[s, 9] <= 0.0:
                            continue
                        if wedge and not whole:
                            # the wedge bound at the receiver's own image point and depth
                            zp = XYZ[s, 2]
                            if not (zp > zq):
                                continue
                            if persp:
                                wz = rL * kc * (zp - zq) / (zq * (zp - face_rho[f]))
                            else:
                                wz = tan_a * (zp - zq)
                            wz *= 1.0 + 1e-9
                            if point_seg_dist2(XYZ[s, 0], XYZ[s, 1], ax, ay, qx, qy) > wz * wz:
                                continue
                        px, py, pz = Ps[s, 0], Ps[s, 1], Ps[s, 2]
                        if is_sun:
                            dx, dy, dz = cx, cy, cz
                        else:
                            dx, dy, dz = cx - px, cy - py, cz - pz
                        nev += 1
                        pen[s] += penumbra_term(px, py, pz, dx, dy, dz, tv, nv, facing[t], orient[t], mode, t, k,
                                                lit, RF, s, ls)
        evals[b] = nev


@kernel(parallel=True)
def penumbra_brute_force(rec, records, occ, lit, mode, pen, ls):
    """Every record against every receiver (no quads): the ground truth the
    quads and both overdraw reductions must reproduce (tests, ablation).
    rec: Receivers; records: Records; occ: Occluders; lit: KernelLight;
    ls: LightSamples."""
    Ps, RF = rec.Ps, rec.RF
    rec_t, rec_k = records.t, records.k
    tv, nv, facing, orient = occ.tv, occ.nv, occ.facing, occ.orient
    cx, cy, cz, is_sun = lit.cx, lit.cy, lit.cz, lit.is_sun
    for s in prange(Ps.shape[0]):
        px, py, pz = Ps[s, 0], Ps[s, 1], Ps[s, 2]
        if RF[s, 9] <= 0.0:
            continue
        if is_sun:
            dx, dy, dz = cx, cy, cz
        else:
            dx, dy, dz = cx - px, cy - py, cz - pz
        acc = 0.0
        for r in range(rec_t.shape[0]):
            acc += penumbra_term(px, py, pz, dx, dy, dz, tv, nv, facing[rec_t[r]], orient[rec_t[r]], mode,
                                 rec_t[r], rec_k[r], lit, RF, s, ls)
        pen[s] = acc
