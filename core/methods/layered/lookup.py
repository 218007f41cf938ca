"""Procedure Display's per-point kernels: a camera point projected into the
LDI, its depth matched against the layers of the nearest LDI pixel (or of
the four around it, filtered) and that layer's attenuation read
(``display_kernel``): the share of the light samples that saw the layer, or
under the irradiance weights (``sample_weights``) their share of the
point's irradiance; the share of the light samples above its tangent plane
(``horizon_kernel``)."""
from __future__ import annotations

import math
from collections import namedtuple

import numpy as np

from ...jit import HOT, inner, kernel
from ...kernels import borrowed, face_project, pick_face
from .ldi import seen_count

#: the LDI's per-pixel layers: depth, depth span, the light samples that saw
#: each layer (bit sets), the layer count
LayerArrays = namedtuple("LayerArrays", "depth span seen n")
#: how a layer's light samples count: ``irr`` (weight each by its irradiance
#: at the point, else 1 / N each: ``invN``), the light ``lp``, the sample
#: points (or, ``directional``, directions) ``pts``
SampleWeights = namedtuple("SampleWeights", "irr invN lp pts directional")


@inner
def _plane_depth(fp, pvx, pvy, pvz, nvx, nvy, nvz, col, row, d, cos_min):
    """Depth where the centre view's ray through pixel centre (col, row) meets
    the tangent plane through view-space point pv with normal nv; ``d`` when
    the plane is too steep to the ray."""
    x = fp[17] + col / fp[21] * (fp[18] - fp[17])
    y = fp[20] - row / fp[22] * (fp[20] - fp[19])
    if fp[16] == 0.0:
        den = x * nvx + y * nvy - nvz
        if abs(den) < cos_min * math.sqrt(x * x + y * y + 1.0):
            return d
        s = (pvx * nvx + pvy * nvy + pvz * nvz) / den
        return s if s > 0.0 else d
    den = -nvz
    if abs(den) < cos_min:
        return d
    return ((pvx - x) * nvx + (pvy - y) * nvy + pvz * nvz) / den


@inner
def _point_span(fp, pvx, pvy, pvz, nvx, nvy, nvz, d, max_slope):
    """Depth change of the tangent plane (view-space point pv, normal nv)
    across one texel along each axis of face ``fp``, summed; at most
    ``max_slope`` texel widths per axis (the insert side's rule)."""
    tx = (fp[18] - fp[17]) / fp[21]
    ty = (fp[20] - fp[19]) / fp[22]
    if fp[16] == 0.0:
        if d <= 0.0:
            return 0.0
        den = abs(-pvx / d * nvx - pvy / d * nvy - nvz)    # ray (x, y, -1) . n
        num = d * (abs(nvx) * tx + abs(nvy) * ty)
        cap = max_slope * (tx + ty) * d
    else:
        den = abs(nvz)
        num = abs(nvx) * tx + abs(nvy) * ty
        cap = max_slope * (tx + ty)
    if num >= cap * den:
        return cap
    return num / den


@inner
def _point_slope(fp, pvx, pvy, pvz, nvx, nvy, nvz, d):
    """The tangent plane's depth change per texel in texel widths, the
    larger axis (``steep_slope``'s measure on the display side)."""
    if fp[16] == 0.0:
        den = abs(-pvx / d * nvx - pvy / d * nvy - nvz) if d > 0.0 else 0.0
    else:
        den = abs(nvz)
    m = max(abs(nvx), abs(nvy))
    return m / den if den > 0.0 else np.inf


@inner
def _match(ldi_depth, ldi_span, ldi_n, pix, z, sp, eps):
    """(layer, status) for depth z at LDI pixel ``pix``: status 0 = the nearest
    layer within tolerance (eps + half the larger depth span across a texel,
    the point's ``sp`` or the layer's); 1 = in front of every layer; 2 =
    behind or between layers; 3 = the pixel holds no layer."""
    n = ldi_n[pix]
    if n == 0:
        return -1, 3
    best = -1
    bd = np.inf
    for L in range(n):
        dd = abs(ldi_depth[pix, L] - z)
        if dd <= eps + 0.5 * max(sp, ldi_span[pix, L]) and dd < bd:
            bd = dd
            best = L
    if best >= 0:
        return best, 0
    if z < ldi_depth[pix, 0]:
        return 0, 1
    return -1, 2


@inner(forceinline=True, error_model="numpy")
def _weight(lp, pts, directional, s, px, py, pz, n0, n1, n2):
    """Light sample ``s``'s irradiance weight at point p with normal n, as
    the reference's (``sampling.reference_sample``'s w_light times cos_r):
    cos_r cos_l / d^2, cos_r clamped at 0, cos_l an area light's (one-sided,
    it emits along its -Z) clamped at 0; a sphere's ball sample weighs as its
    projection on the disk facing p (the reference's sample, cos_l = 1); a
    sun's direction, cos_r."""
    if directional:
        c = pts[s, 0] * n0 + pts[s, 1] * n1 + pts[s, 2] * n2
        return c if c > 0.0 else 0.0
    qx, qy, qz = pts[s, 0], pts[s, 1], pts[s, 2]
    if lp[0] != 0.0:
        ax, ay, az = lp[1] - px, lp[2] - py, lp[3] - pz
        a2 = ax * ax + ay * ay + az * az
        t = ((qx - lp[1]) * ax + (qy - lp[2]) * ay + (qz - lp[3]) * az) / a2 if a2 > 0.0 else 0.0
        qx, qy, qz = qx - t * ax, qy - t * ay, qz - t * az
    dx, dy, dz = qx - px, qy - py, qz - pz
    d2 = dx * dx + dy * dy + dz * dz
    c = dx * n0 + dy * n1 + dz * n2
    if lp[0] == 0.0:
        cl = dx * lp[10] + dy * lp[11] + dz * lp[12]
        wt = c * cl / (d2 * d2)                      # (c / d) (cl / d) / d^2
        return wt if (c > 0.0 and cl > 0.0 and d2 > 0.0) else 0.0
    wt = c / (d2 * math.sqrt(d2))                    # (c / d) / d^2
    return wt if (c > 0.0 and d2 > 0.0) else 0.0


@inner
def _any_weight(lp, pts, directional, px, py, pz, n0, n1, n2):
    """Whether some light sample has a positive weight at the point."""
    for s in range(pts.shape[0]):
        if _weight(lp, pts, directional, s, px, py, pz, n0, n1, n2) > 0.0:
            return True
    return False


@inner
def _seen_weight(ldi_seen, pix, L, wts):
    """Sum of ``wts`` over the light samples that saw layer ``L`` of ``pix``,
    in sample order (a layer every sample saw sums to their total exactly)."""
    acc = 0.0
    n_s = wts.shape[0]
    for q in range(ldi_seen.shape[2]):
        m = ldi_seen[pix, L, q]
        for b in range(min(64, n_s - 64 * q)):
            acc += wts[64 * q + b] * np.float64((m >> np.uint64(b)) & np.uint64(1))
    return acc


@inner
def _share(ldi_seen, pix, L, sw, px, py, pz, n0, n1, n2, wts, state):
    """Layer ``L`` of ``pix``'s attenuation: its share of the light samples,
    or with ``irr`` its samples' share of the point's summed weight (0 where
    that is 0; a layer every sample saw: 1, what the sum gives). The weights
    are computed on a point's first partly seen layer (``state``[0]: their
    sum, ``state``[1]: whether it is positive; -1 until known): a lit point
    computes them up to its first positive one, an umbra point none."""
    c = seen_count(ldi_seen, pix, L)
    if not sw.irr:
        return c * sw.invN
    lp, pts, directional = sw.lp, sw.pts, sw.directional
    if c == pts.shape[0]:
        if state[1] < 0.0:
            state[1] = 1.0 if _any_weight(lp, pts, directional, px, py, pz, n0, n1, n2) else 0.0
        return state[1]
    if state[0] < 0.0:
        for s in range(pts.shape[0]):
            wts[s] = _weight(lp, pts, directional, s, px, py, pz, n0, n1, n2)
        tot = 0.0
        for s in range(pts.shape[0]):
            tot += wts[s]
        state[0] = tot
        state[1] = 1.0 if tot > 0.0 else 0.0
    if state[0] == 0.0:
        return 0.0
    return _seen_weight(ldi_seen, pix, L, wts) / state[0]


@inner
def _lookup(layers, pix, z, sp, eps, sw, px, py, pz, n0, n1, n2, wts, state):
    """Attenuation at one LDI pixel: the matching layer's (``_share``); the
    nearest layer's if z is in front of every layer; 0 if behind / between;
    -1 if empty."""
    L, st = _match(layers.depth, layers.span, layers.n, pix, z, sp, eps)
    if st == 3:
        return -1.0
    if st == 2:
        return 0.0
    return _share(layers.seen, pix, L, sw, px, py, pz, n0, n1, n2, wts, state)


@kernel(opt=HOT, nogil=True, error_model="numpy")
def display_kernel(idx, P, Nrm, cfaces, h, w, layers, eps, bilinear, plane, cos_min, max_slope, out, bi_slope,
                   sw, wts, state):
    """Procedure Display, lines 2-5, for the points ``idx`` of P (normals
    Nrm) against the LDI's ``layers`` (``LayerArrays``); ``bilinear`` only on
    receivers no steeper than ``bi_slope`` (``_point_slope``; the nearest LDI
    pixel beyond); a layer's samples counted as ``sw`` says
    (``SampleWeights``, ``_share``). A serial ``nogil`` kernel run on worker
    threads by ``display`` (a prange kernel's parfor lowering would cost
    compile time), its arguments ``kernels.borrowed``."""
    P, Nrm, cfaces, layers, out, sw, wts, state = borrowed((P, Nrm, cfaces, layers, out, sw, wts, state))
    for i in idx:
        px, py, pz = P[i, 0], P[i, 1], P[i, 2]
        state[0] = -1.0
        state[1] = -1.0
        f = pick_face(cfaces, px, py, pz)
        if f < 0:
            out[i] = 1.0
            continue
        fp = cfaces[f]
        u, v, d = face_project(fp, px, py, pz)
        pvx = fp[0] * px + fp[1] * py + fp[2] * pz + fp[3]
        pvy = fp[4] * px + fp[5] * py + fp[6] * pz + fp[7]
        pvz = fp[8] * px + fp[9] * py + fp[10] * pz + fp[11]
        n0, n1, n2 = Nrm[i, 0], Nrm[i, 1], Nrm[i, 2]
        nvx = fp[0] * n0 + fp[1] * n1 + fp[2] * n2
        nvy = fp[4] * n0 + fp[5] * n1 + fp[6] * n2
        nvz = fp[8] * n0 + fp[9] * n1 + fp[10] * n2
        sp = _point_span(fp, pvx, pvy, pvz, nvx, nvy, nvz, d, max_slope)
        if not bilinear or _point_slope(fp, pvx, pvy, pvz, nvx, nvy, nvz, d) > bi_slope:
            iu = min(max(int(math.floor(u)), 0), w - 1)
            iv = min(max(int(math.floor(v)), 0), h - 1)
            z = d
            if plane:
                z = _plane_depth(fp, pvx, pvy, pvz, nvx, nvy, nvz, iu + 0.5, iv + 0.5, d, cos_min)
            a = _lookup(layers, (f * h + iv) * w + iu, z, sp, eps, sw, px, py, pz, n0, n1, n2, wts, state)
            out[i] = a if a > 0.0 else 0.0
            continue
        i0 = int(math.floor(u - 0.5))
        j0 = int(math.floor(v - 0.5))
        fx = u - 0.5 - i0
        fy = v - 0.5 - j0
        acc = 0.0
        wsum = 0.0
        for a_ in range(2):
            ci = i0 + a_
            wa = 1.0 - fx if a_ == 0 else fx
            if ci < 0 or ci >= w or wa <= 0.0:
                continue
            for b_ in range(2):
                cj = j0 + b_
                wb = 1.0 - fy if b_ == 0 else fy
                if cj < 0 or cj >= h or wb <= 0.0:
                    continue
                z = d
                if plane:
                    z = _plane_depth(fp, pvx, pvy, pvz, nvx, nvy, nvz, ci + 0.5, cj + 0.5, d, cos_min)
                a = _lookup(layers, (f * h + cj) * w + ci, z, sp, eps, sw, px, py, pz, n0, n1, n2, wts, state)
                if a < 0.0:
                    continue    # no layer at all: no value to filter
                acc += wa * wb * a
                wsum += wa * wb
        out[i] = acc / wsum if wsum > 0.0 else 0.0


@kernel(opt=HOT, nogil=True, error_model="numpy")
def horizon_kernel(idx, P, Nrm, pts, directional, centre, reach, out):
    """Fraction of the light samples above each point's tangent plane (on the
    side of its normal): the light its own surface does not hide. Points whose
    plane clears the samples' bounding sphere (``centre``, ``reach``; for a
    sun, the cone of directions) skip the loop. For the points ``idx`` (as
    ``display_kernel``)."""
    P, Nrm, pts, centre, out = borrowed((P, Nrm, pts, centre, out))
    n_s = pts.shape[0]
    for i in idx:
        n0, n1, n2 = Nrm[i, 0], Nrm[i, 1], Nrm[i, 2]
        if directional:
            h = n0 * centre[0] + n1 * centre[1] + n2 * centre[2]
        else:
            h = (centre[0] - P[i, 0]) * n0 + (centre[1] - P[i, 1]) * n1 + (centre[2] - P[i, 2]) * n2
        if h > reach:
            out[i] = 1.0
            continue
        if h < -reach:
            out[i] = 0.0
            continue
        above = 0
        for s in range(n_s):
            if directional:
                t = pts[s, 0] * n0 + pts[s, 1] * n1 + pts[s, 2] * n2
            else:
                t = (pts[s, 0] - P[i, 0]) * n0 + (pts[s, 1] - P[i, 1]) * n1 + (pts[s, 2] - P[i, 2]) * n2
            if t > 0.0:
                above += 1
        out[i] = above / n_s
