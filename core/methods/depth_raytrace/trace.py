"""Tracing one shadow ray through depth images (Agrawala et al. 2000, 5.1).

The shadow ray X(t) = o + t (E - o), t in [0, t_end], is clipped to each
reference face's window (x, y and depth are linear in t in view space, so the
clip is four linear inequalities) and projected: its *epipolar ray* is the
2D segment from (u0, v0) to (u1, v1) in texel coordinates, parametrised by
s in [0, 1]. Along it, texel coordinates are affine in s, and so is the depth
*key* - -1/depth for a perspective face (1/z is affine in screen space),
depth for an orthographic one. The quadtrees store keys, so the overlap test,
node exits and min / max clipping need no division; s and t convert into each
other only where an interval starts or ends (perspective-correct
interpolation).

Traversal (section 5.1's Trace, coarse to fine): the ray is walked front to
back along its epipolar line; at each position the node at the current level
k is tested against the min / max quadtrees (the overlap test between the
epipolar depth interval [Zenter, Zexit] over the node and the node's
[min, max]). A node the ray passes entirely in front of or entirely behind is
skipped and the walk climbs a level; a node it overlaps is refined (k - 1);
at the leaves the exact test uses floors and walls:

  * floor: the texel's floor (depth + bias) lies within the ray's depth
    interval over the texel -> hit;
  * walls: the walk keeps the ray's side of the surface (in front / behind).
    The side can only change at a texel edge (else a floor was crossed); a
    change across an edge between *connected* texels (depths within the gap
    bias) is a wall hit; between unconnected texels the ray passes a
    silhouette gap and an *occlusion interval* opens or closes.

Accelerations (each a switch for the ablation):
  * ``hier`` - hierarchical connectedness (5.1.1): a node whose texels form one
    connected surface and whose min / max interval lies inside the ray's
    epipolar depth interval must be crossed: blocked without descending. Its
    hit point is only known to lie in the node (the paper disables it when the
    coherent sampler needs blocker points; so does the method).
  * ``clip`` - min / max clipping (5.1.1): on entering a node the ray is
    advanced past the part of it in front of (or behind) every floor of the
    node, at every level, and once per image against the root's range.
  * ``rank`` - reference images sorted by the length (in texels) of the
    clipped epipolar ray (5.1.2, Chang's ranking).
  * ``clear_miss`` - an image in which the ray never passes behind geometry
    (and never leaves the image) proves it unblocked (5.1.2).
  * ``occl`` - only the occlusion intervals of the previous images (plus the
    parts they did not cover) are traced in the next image (5.1.2). This
    subsumes the clear miss: an empty interval list ends the ray.
Without ``occl`` the whole ray is traced in every image until one reports a
hit (and, with ``clear_miss``, until one reports a clear miss). A ray still
unresolved after every image is unblocked (the paper: "until either an
intersection is found or we pass through all the shadow maps").

The per-face functions are inlined at Numba IR level (``inline="always"``):
as separate calls, passing the seven arrays cost about as much as a short
traversal.
"""
from __future__ import annotations

import math
from collections import namedtuple

import numpy as np

from ...jit import inner, kernel
from .maps import FP_FOOT, FP_GAPABS, FP_GAPTEX, FP_K, FP_MNROOT, FP_MXROOT

MAXI = 48            # occlusion intervals kept per ray (extra ones merge: conservative)
LN = 12              # per-face line record: u0 v0 du dv k0 dk tlo thi w0 w1 inv_du inv_dv
INF = np.inf

# argument groups of ``trace_ray`` (built by the package's ``__init__``)
ReferenceImages = namedtuple("ReferenceImages", "fp offs dims kmn kmx conn zp")
"""The reference images as the tracer reads them (``maps.ReferenceMaps``):
packed faces, quadtree level offsets and sizes, min / max key quadtrees,
connectedness bits and the biased depths."""
TraceSwitches = namedtuple("TraceSwitches", "hier clip rank clear_miss occl")
"""The accelerations of 5.1.1 / 5.1.2 (see above)."""
TraceScratch = namedtuple("TraceScratch", "line order key U U2")
"""Per-thread scratch: F x LN line records, F face order and keys, two
MAXI x 2 interval lists."""


@kernel(inline="always")
def _push(ivs, n, a, b):
    """Append [a, b] to the sorted interval list, merging touching ones."""
    if not (b > a):
        return n
    if n > 0 and a <= ivs[n - 1, 1] * (1.0 + 1e-12) + 1e-300:
        if b > ivs[n - 1, 1]:
            ivs[n - 1, 1] = b
        return n
    if n < ivs.shape[0]:
        ivs[n, 0] = a
        ivs[n, 1] = b
        return n + 1
    ivs[n - 1, 1] = b
    return n


@kernel(inline="always")
def connected_depths(za, zb, persp, foot, gap_abs, gap_tex):
    if not (za < INF) or not (zb < INF):
        return False
    zmin = za if za < zb else zb
    g = gap_abs + gap_tex * (foot * zmin if persp else foot)
    return abs(za - zb) < g


@kernel(inline="always")
def _enter_side(side, state, crossed, s, occ0, zp, o0, W, piu, piv, iu, iv, persp, foot, gap_abs, gap_tex,
                Lf, ivs, niv):
    """The walk enters, at s, a stretch where the ray is on ``side`` of the
    floors (0 in front, 1 behind; ``state`` the side so far, -1 unknown). A
    change of side inside a texel, or across the edge (``crossed``) between
    connected texels, is a floor or wall hit; across a silhouette gap it
    opens (behind) or closes (in front) an occlusion interval, appended to
    ``ivs``. Returns (hit, state, occ0, niv)."""
    if state < 0:
        return False, side, (s if side == 1 else occ0), niv
    if side == state:
        return False, state, occ0, niv
    if not crossed or connected_depths(np.float64(zp[o0 + piv * W + piu]), np.float64(zp[o0 + iv * W + iu]),
                                       persp, foot, gap_abs, gap_tex):
        return True, state, occ0, niv
    if side == 1:
        occ0 = s
    else:
        niv = _push(ivs, niv, s_to_t(Lf, occ0), s_to_t(Lf, s))
    return False, side, occ0, niv


@kernel(inline="always")
def _clampi(x, lo, hi):
    if not (x == x):       # nan
        return lo
    if x < lo:
        return lo
    if x > hi:
        return hi
    return int(x)


@kernel(inline="always")
def s_to_t(Lf, s):
    """Epipolar parameter -> ray parameter (perspective-correct)."""
    w0 = Lf[8]
    w1 = Lf[9]
    den = (1.0 - s) * w1 + s * w0
    lam = s * w0 / den if den != 0.0 else s
    return Lf[6] + (Lf[7] - Lf[6]) * lam


@kernel(inline="always")
def t_to_s(Lf, t):
    span = Lf[7] - Lf[6]
    if span <= 0.0:
        return 0.0
    lam = (t - Lf[6]) / span
    w0 = Lf[8]
    w1 = Lf[9]
    den = (1.0 - lam) * w0 + lam * w1
    return lam * w1 / den if den != 0.0 else lam


@kernel(inline="always")
def _lin_clip(lo, hi, A, B):
    """Restrict [lo, hi] to A + t B >= 0."""
    if B > 0.0:
        tt = -A / B
        if tt > lo:
            lo = tt
    elif B < 0.0:
        tt = -A / B
        if tt < hi:
            hi = tt
    elif A < 0.0:
        hi = -1.0
        lo = 1.0
    return lo, hi


@kernel(inline="always")
def face_line(fp, f, ox, oy, oz, ex, ey, ez, t_end, Lf):
    """The ray's epipolar line in face f, clipped to the window: fills ``Lf``
    (see LN) and returns True, or False when the ray misses the face."""
    vox = fp[f, 0] * ox + fp[f, 1] * oy + fp[f, 2] * oz + fp[f, 3]
    voy = fp[f, 4] * ox + fp[f, 5] * oy + fp[f, 6] * oz + fp[f, 7]
    voz = fp[f, 8] * ox + fp[f, 9] * oy + fp[f, 10] * oz + fp[f, 11]
    vex = fp[f, 0] * ex + fp[f, 1] * ey + fp[f, 2] * ez + fp[f, 3]
    vey = fp[f, 4] * ex + fp[f, 5] * ey + fp[f, 6] * ez + fp[f, 7]
    vez = fp[f, 8] * ex + fp[f, 9] * ey + fp[f, 10] * ez + fp[f, 11]
    ax = vox
    bx = vex - vox
    ay = voy
    by = vey - voy
    az = -voz
    bz = voz - vez
    persp = fp[f, 16] == 0.0
    if persp:
        aw = az
        bw = bz
    else:
        aw = 1.0
        bw = 0.0
    L = fp[f, 17]
    R = fp[f, 18]
    B = fp[f, 19]
    T = fp[f, 20]
    # the outermost texel ring is not used: a ray crossing a surface there
    # (between two cube faces, say) would be judged on a floor sampled up to
    # a texel away; faces that tile directions overlap (see maps)
    mu = (R - L) / fp[f, 21]
    mv = (T - B) / fp[f, 22]
    lo = 0.0
    hi = t_end
    lo, hi = _lin_clip(lo, hi, ax - (L + mu) * aw, bx - (L + mu) * bw)
    lo, hi = _lin_clip(lo, hi, (R - mu) * aw - ax, (R - mu) * bw - bx)
    lo, hi = _lin_clip(lo, hi, ay - (B + mv) * aw, by - (B + mv) * bw)
    lo, hi = _lin_clip(lo, hi, (T - mv) * aw - ay, (T - mv) * bw - by)
    if persp:
        lo, hi = _lin_clip(lo, hi, az - 1e-9 * max(abs(az), abs(az + bz)), bz)
    if not (lo < hi):
        return False
    w0 = aw + lo * bw
    w1 = aw + hi * bw
    if not (w0 > 0.0) or not (w1 > 0.0):
        return False
    iw0 = 1.0 / w0
    iw1 = 1.0 / w1
    su = fp[f, 21] / (R - L)
    sv = fp[f, 22] / (T - B)
    u0 = ((ax + lo * bx) * iw0 - L) * su
    v0 = (T - (ay + lo * by) * iw0) * sv
    u1 = ((ax + hi * bx) * iw1 - L) * su
    v1 = (T - (ay + hi * by) * iw1) * sv
    if persp:
        k0 = -iw0
        k1 = -iw1
    else:
        k0 = az + lo * bz
        k1 = az + hi * bz
    Lf[0] = u0
    Lf[1] = v0
    Lf[2] = u1 - u0
    Lf[3] = v1 - v0
    Lf[4] = k0
    Lf[5] = k1 - k0
    Lf[6] = lo
    Lf[7] = hi
    Lf[8] = w0
    Lf[9] = w1
    Lf[10] = 1.0 / Lf[2] if Lf[2] != 0.0 else INF
    Lf[11] = 1.0 / Lf[3] if Lf[3] != 0.0 else INF
    return True


@inner(forceinline=True, error_model="numpy")
def trace_face(fp, offs, dims, kmn, kmx, conn, zp, f, Lf, sA, sB, hier, clip, ivs, niv, st0, st1):
    """Walk the epipolar segment s in [sA, sB] through face f.

    ``st0`` / ``st1``: the ray's side just before sA / just after sB when
    the root clip knows it (0 in front of every floor, 1 behind, -1 unknown):
    the side can only change there by touching the nearest / farthest floor,
    which is a hit.

    Returns (hit, t_hit, niv): on a hit, the ray parameter of the floor / wall
    crossing (hierarchical connectedness: the middle of the node's range);
    otherwise the unknown intervals (occluded, or not examined), appended to
    ``ivs`` in ray parameters, and their new count."""
    persp = fp[f, 16] == 0.0
    W = int(fp[f, 21])
    H = int(fp[f, 22])
    K = int(fp[f, FP_K])
    foot = fp[f, FP_FOOT]
    gap_abs = fp[f, FP_GAPABS]
    gap_tex = fp[f, FP_GAPTEX]
    o0 = offs[f, 0]
    u0 = Lf[0]
    v0 = Lf[1]
    du = Lf[2]
    dv = Lf[3]
    k0 = Lf[4]
    dk = Lf[5]
    idu = Lf[10]
    idv = Lf[11]
    idk = 1.0 / dk if dk != 0.0 else INF
    su = 1 if du > 0.0 else (-1 if du < 0.0 else 0)
    sv = 1 if dv > 0.0 else (-1 if dv < 0.0 else 0)

    sp = sA + 1e-7 * (sB - sA)
    iu = _clampi(math.floor(u0 + sp * du), 0, W - 1)
    iv = _clampi(math.floor(v0 + sp * dv), 0, H - 1)
    k = 0
    state = st0
    crossed = False
    piu = 0
    piv = 0
    occ0 = sA
    s = sA
    finished = False
    maxit = 16 * (W + H) * (K + 2) + 64
    it = 0
    while it < maxit:
        it += 1
        sz = 1 << k
        nu0 = (iu >> k) << k
        nu1 = min(nu0 + sz, W)
        nv0 = (iv >> k) << k
        nv1 = min(nv0 + sz, H)
        se = sB
        ex = 0
        if su > 0:
            tu = ((nu1 - u0) * idu)
        elif su < 0:
            tu = ((nu0 - u0) * idu)
        else:
            tu = INF
        if sv > 0:
            tv = ((nv1 - v0) * idv)
        elif sv < 0:
            tv = ((nv0 - v0) * idv)
        else:
            tv = INF
        if tu < se:
            se = tu
            ex = 1
        if tv < se:
            se = tv
            ex = 2
        elif ex == 1 and tv == se:
            ex = 3
        if se < s:
            se = s
        ka = k0 + s * dk
        kb = k0 + se * dk
        if ka <= kb:
            klo = ka
            khi = kb
        else:
            klo = kb
            khi = ka
        S = 0
        if k == 0:
            kz = np.float64(kmn[o0 + iv * W + iu])
            if kz < INF:
                if klo <= kz and kz <= khi:
                    sh = s
                    if dk != 0.0:
                        sh = min(max((kz - k0) * idk, s), se)
                    return True, s_to_t(Lf, sh), niv
                S = 0 if ka < kz else 1
        else:
            idx = offs[f, k] + (iv >> k) * dims[f, k, 0] + (iu >> k)
            nmn = np.float64(kmn[idx])
            nmx = np.float64(kmx[idx])
            if khi < nmn:
                S = 0
            elif klo > nmx:
                S = 1
            else:
                if hier and conn[idx] == 1 and klo <= nmn and khi >= nmx:
                    return True, s_to_t(Lf, 0.5 * (s + se)), niv
                if clip and dk != 0.0:
                    sn = s
                    Sc = 0
                    if ka < nmn:
                        sn = (nmn - k0) * idk
                    elif ka > nmx:
                        sn = (nmx - k0) * idk
                        Sc = 1
                    if sn > s:
                        if sn > se:
                            sn = se
                        # region Sc over [s, sn]
                        hit, state, occ0, niv = _enter_side(Sc, state, crossed, s, occ0, zp, o0, W, piu, piv,
                                                            iu, iv, persp, foot, gap_abs, gap_tex, Lf, ivs, niv)
                        if hit:
                            return True, s_to_t(Lf, s), niv
                        crossed = False
                        s = sn
                        iu = _clampi(math.floor(u0 + s * du), nu0, nu1 - 1)
                        iv = _clampi(math.floor(v0 + s * dv), nv0, nv1 - 1)
                k -= 1
                continue
        # region S over [s, se]
        hit, state, occ0, niv = _enter_side(S, state, crossed, s, occ0, zp, o0, W, piu, piv, iu, iv,
                                            persp, foot, gap_abs, gap_tex, Lf, ivs, niv)
        if hit:
            return True, s_to_t(Lf, s), niv
        crossed = False
        # advance to the next node
        if ex == 0 or se >= sB:
            s = sB
            finished = True
            break
        if ex & 1:
            if su > 0:
                oiu = nu1 - 1
                niu = nu1
            else:
                oiu = nu0
                niu = nu0 - 1
        else:
            oiu = _clampi(math.floor(u0 + se * du), nu0, nu1 - 1)
            niu = oiu
        if ex & 2:
            if sv > 0:
                oiv = nv1 - 1
                niv_ = nv1
            else:
                oiv = nv0
                niv_ = nv0 - 1
        else:
            oiv = _clampi(math.floor(v0 + se * dv), nv0, nv1 - 1)
            niv_ = oiv
        s = se
        if niu < 0 or niu >= W or niv_ < 0 or niv_ >= H:
            break
        piu = oiu
        piv = oiv
        iu = niu
        iv = niv_
        crossed = True
        if k < K and ((iu >> (k + 1)) != (oiu >> (k + 1)) or (iv >> (k + 1)) != (oiv >> (k + 1))):
            k += 1
    if finished and st1 >= 0 and state >= 0 and state != st1:
        return True, s_to_t(Lf, sB), niv
    if state == 1:
        niv = _push(ivs, niv, s_to_t(Lf, occ0), s_to_t(Lf, sB))
    elif not finished and s < sB:
        niv = _push(ivs, niv, s_to_t(Lf, s), s_to_t(Lf, sB))
    return False, 0.0, niv


@kernel(inline="always")
def _band(k0, dk, klo, khi, a, b):
    """s-range inside [a, b] where klo <= k0 + s dk <= khi, plus the side of
    the parts before / after it (0 in front, 1 behind)."""
    if dk == 0.0:
        if k0 < klo:
            return b, b, 0, 0
        if k0 > khi:
            return a, a, 1, 1
        return a, b, 0, 0
    s1 = (klo - k0) / dk
    s2 = (khi - k0) / dk
    if dk > 0.0:      # depth grows: in front first, behind last
        lo = max(a, s1)
        hi = min(b, s2)
        sb, sa = 0, 1
    else:
        lo = max(a, s2)
        hi = min(b, s1)
        sb, sa = 1, 0
    if not (lo < hi):
        km = k0 + 0.5 * (a + b) * dk
        side = 0 if km < klo else 1
        return b, b, side, side
    return lo, hi, sb, sa


@inner(forceinline=True, error_model="numpy")
def _trace_piece(fp, offs, dims, kmn, kmx, conn, zp, f, Lf, a, b, hier, clip, out, n):
    """Trace the ray-parameter piece [a, b] in face f: parts outside the
    window are unknown; with ``clip`` the root range drops the parts in front
    of every floor and marks the parts behind every floor unknown."""
    if not (b > a):
        return False, 0.0, n
    lo = max(a, Lf[6])
    hi = min(b, Lf[7])
    if not (lo < hi):
        return False, 0.0, _push(out, n, a, b)
    n = _push(out, n, a, lo)
    sA = t_to_s(Lf, lo)
    sB = t_to_s(Lf, hi)
    after = False
    st0 = -1
    st1 = -1
    if clip:
        mnr = fp[f, FP_MNROOT]
        if not (mnr < INF):
            return False, 0.0, _push(out, n, hi, b)
        blo, bhi, sb, sa = _band(Lf[4], Lf[5], mnr, fp[f, FP_MXROOT], sA, sB)
        if sb == 1:
            n = _push(out, n, lo, s_to_t(Lf, blo))
        after = sa == 1
        if blo > sA:
            st0 = sb
        if bhi < sB:
            st1 = sa
        sA = blo
        sB = bhi
    if sA < sB:
        hit, th, n = trace_face(fp, offs, dims, kmn, kmx, conn, zp, f, Lf, sA, sB, hier, clip, out, n, st0, st1)
        if hit:
            return True, th, n
    if after:
        n = _push(out, n, s_to_t(Lf, sB), hi)
    return False, 0.0, _push(out, n, hi, b)


@inner(forceinline=True, error_model="numpy")
def trace_ray(refs, ox, oy, oz, ex, ey, ez, t_end, sw, ws):
    """Is the segment o + t (E - o), t in [0, t_end], blocked in the
    reference images? Returns (blocked, t_hit).
    refs: ReferenceImages; sw: TraceSwitches; ws: TraceScratch."""
    fp, offs, dims, kmn, kmx, conn, zp = refs.fp, refs.offs, refs.dims, refs.kmn, refs.kmx, refs.conn, refs.zp
    hier, clip, rank, clear_miss, occl = sw.hier, sw.clip, sw.rank, sw.clear_miss, sw.occl
    ws_line, ws_order, ws_key, U, U2 = ws.line, ws.order, ws.key, ws.U, ws.U2
    F = fp.shape[0]
    if not (t_end > 0.0):
        return False, 0.0
    nf = 0
    for f in range(F):
        Lf = ws_line[f]
        if not face_line(fp, f, ox, oy, oz, ex, ey, ez, t_end, Lf):
            continue
        if rank:
            a = 0.0
            b = 1.0
            if clip:
                mnr = fp[f, FP_MNROOT]
                if not (mnr < INF):
                    b = a
                else:
                    a, b, _s0, _s1 = _band(Lf[4], Lf[5], mnr, fp[f, FP_MXROOT], 0.0, 1.0)
            key = (b - a) * math.sqrt(Lf[2] * Lf[2] + Lf[3] * Lf[3]) if b > a else 0.0
            # insertion sort, shortest epipolar ray first
            j = nf
            while j > 0 and ws_key[j - 1] > key:
                ws_key[j] = ws_key[j - 1]
                ws_order[j] = ws_order[j - 1]
                j -= 1
            ws_key[j] = key
            ws_order[j] = f
        else:
            ws_order[nf] = f
        nf += 1
    nu = 1
    U[0, 0] = 0.0
    U[0, 1] = t_end
    for q in range(nf):
        f = ws_order[q]
        Lf = ws_line[f]
        n2 = np.int64(0)     # not the literal 0: _trace_piece would compile twice
        m = nu if occl else 1
        for j in range(m):
            a = U[j, 0] if occl else 0.0
            b = U[j, 1] if occl else t_end
            hit, th, n2 = _trace_piece(fp, offs, dims, kmn, kmx, conn, zp, f, Lf, a, b, hier, clip, U2, n2)
            if hit:
                return True, th
        if occl:
            for j in range(n2):
                U[j, 0] = U2[j, 0]
                U[j, 1] = U2[j, 1]
            nu = n2
            if nu == 0:
                return False, 0.0
        elif clear_miss and n2 == 0:
            return False, 0.0
    return False, 0.0
