"""Light samples, sample groups and their bounding polygons for hierarchical
penumbra casting (Laine & Aila 2005, sections 3.1, 3.2 and 3.4), and the
light's setup for one casting (``light_setup``).

Samples lie on a jittered grid of ``nx x ny`` strata with the ``embree``
reference's strata and unit-square-to-light maps (``sampling.light_sample``).
A group G_k is a block of strata; Delta_Gk bounds the image of the whole
block, so it bounds the group's samples in every sample set (section 3.4),
the reference's per-pixel sets included. A mask's bits are ordered group by
group; ``bit2s`` maps a bit to its stratum ``s = ix + iy * nx``.

Light kinds (DESIGN.md "Light domains"):

* area: the block's image under the square map (a rectangle) or the
  concentric disk map (an annular sector in a convex polygon circumscribed
  about its arc); Delta_L is the rectangle, or an octagon around the disk.
* sun: samples are directions (w = 0); polygons are built in the tangent
  plane of the sun's axis, where a concentric-map sector stays a sector, so
  a convex polygon there is a convex cone of directions.
* sphere (radius r): each receiver's disk facing it is the disk facing the
  mean direction w0 turned by the minimal rotation w0 -> w_r (the reference's
  distribution; only the in-disk rotation differs). A rotation of at most
  theta moves a disk point by at most 2 r sin(theta/2) in the disk plane and
  r sin(theta) along w0: Delta_Gk and Delta_L are boxes in the w0 frame
  grown by those amounts (section 3.4's convex bounding volumes). With
  ``shared_samples_with_reference`` every group is bounded by the sphere's cube.
"""
from __future__ import annotations

import math
from collections import namedtuple
from dataclasses import dataclass
from typing import Optional

import numpy as np

from ... import sampling
from ...jit import inner, kernel
from ...sampling import concentric_disk, light_sample, rand01, strata, stratum_uv

MAXV = 16
MAXE = 16

MODE_FIXED = 0      # sample positions shared by all receivers of one set
MODE_SPHERE = 1     # c + M_r q: per-receiver rotation of a fixed disk set
MODE_SHARED = 2     # the reference's own per-pixel samples (sampling.light_sample)

SET_KEY = 1 << 40   # pixel slot of rand01 used for the sample sets (beyond any pixel id)

LightSamples = namedtuple("LightSamples", "mode SP Q centre lp seed bit2s nx ny")
"""The light's sample table for the kernels: ``mode`` (MODE_*), the fixed
sets SP[set, bit] (homogeneous) or the sphere's disk sets Q[set, bit] around
``centre``, and for MODE_SHARED the reference's inputs (packed light ``lp``,
``seed``, strata ``nx x ny``, bit -> stratum ``bit2s``)."""


def group_layout(n_samples: int, group_size: int):
    """Strata grid (nx, ny), groups (gx, gy) and the group of each stratum.

    Groups are blocks of about ``group_size`` strata, as square as the grid
    allows (paper: 32 samples per group on a jittered grid)."""
    nx, ny = strata(n_samples)
    target = max(1, int(round(n_samples / max(1, group_size))))
    best = None
    for gx in range(1, nx + 1):
        for gy in range(1, ny + 1):
            g = gx * gy
            if g > target:
                continue
            bx, by = nx / gx, ny / gy
            score = (target - g, abs(math.log(bx / by)))
            if best is None or score < best[0]:
                best = (score, gx, gy)
    _, gx, gy = best
    ix = np.arange(nx)
    iy = np.arange(ny)
    gxi = ix * gx // nx
    gyi = iy * gy // ny
    group_of = (gxi[None, :] + gx * gyi[:, None]).reshape(-1)     # stratum s = ix + iy*nx
    order = np.argsort(group_of, kind="stable")                    # bit -> stratum
    G = gx * gy
    starts = np.searchsorted(group_of[order], np.arange(G + 1)).astype(np.int64)
    blocks = np.zeros((G, 4))                                      # u0, u1, v0, v1
    for g in range(G):
        kx, ky = g % gx, g // gx
        cols = ix[gxi == kx]
        rows = iy[gyi == ky]
        blocks[g] = (cols.min() / nx, (cols.max() + 1) / nx, rows.min() / ny, (rows.max() + 1) / ny)
    return nx, ny, G, order.astype(np.int64), starts, blocks


# --------------------------------------------------------------------------
# 2D bounds of a block's image
def _concentric_phi(a, b):
    """Angle of the concentric map's image of square point (a, b) in [-1,1]^2."""
    if a == 0.0 and b == 0.0:
        return 0.0
    if abs(a) > abs(b):
        r, phi = a, (math.pi / 4.0) * (b / a)
    else:
        r, phi = b, (math.pi / 2.0) - (math.pi / 4.0) * (a / b)
    if r < 0:
        phi += math.pi
    return phi


def _wrap(x):
    return (x + math.pi) % (2 * math.pi) - math.pi


def block_sector(u0, u1, v0, v1):
    """Annular sector (rmin, rmax, phi0, phi1) in the unit disk holding the
    concentric image of the block, or None when it is not a proper sector
    (the block holds the centre, or spans about half the disk or more)."""
    a0, a1, b0, b1 = 2 * u0 - 1, 2 * u1 - 1, 2 * v0 - 1, 2 * v1 - 1
    corners = [(a0, b0), (a1, b0), (a1, b1), (a0, b1)]
    rmax = max(max(abs(a), abs(b)) for a, b in corners)
    da = 0.0 if a0 <= 0.0 <= a1 else min(abs(a0), abs(a1))
    db = 0.0 if b0 <= 0.0 <= b1 else min(abs(b0), abs(b1))
    rmin = max(da, db)                       # L-inf distance of the block to the centre
    if rmin <= 0.0:
        return None
    # the concentric map sends square rays (b/a = const) to disk rays and keeps
    # the angular order: the angular range is spanned by the corners
    pc = _concentric_phi(0.5 * (a0 + a1), 0.5 * (b0 + b1))
    rel = [_wrap(_concentric_phi(a, b) - pc) for a, b in corners]
    lo, hi = min(rel), max(rel)
    if hi - lo > 0.9 * math.pi:
        return None
    return rmin, rmax, pc + lo, pc + hi


def sector_polygon(rmin, rmax, phi0, phi1):
    """Convex polygon (k x 2) holding the annular sector: inner chord, outer
    side circumscribed about the arc (tangents every <= pi/8)."""
    span = phi1 - phi0
    m = max(1, int(math.ceil(span / (math.pi / 8) - 1e-9)))
    d = span / m
    R = rmax / math.cos(0.5 * d)
    pts = [(rmin * math.cos(phi0), rmin * math.sin(phi0))]
    for k in range(m + 1):
        a = phi0 + k * d
        pts.append((R * math.cos(a), R * math.sin(a)))
    pts.append((rmin * math.cos(phi1), rmin * math.sin(phi1)))
    return np.array(pts)


def disk_polygon(radius):
    """Regular octagon circumscribed about the disk."""
    R = radius / math.cos(math.pi / 8)
    a = (np.arange(8) + 0.5) * (math.pi / 4)
    return np.stack([R * np.cos(a), R * np.sin(a)], 1)


def block_polygon_2d(u0, u1, v0, v1, disk: bool, radial=None):
    """Convex 2D polygon bounding the image of block [u0,u1]x[v0,v1] under the
    square map (disk=False: a rectangle in [-1,1]^2) or the concentric map,
    with radii optionally remapped by the monotone ``radial``."""
    radial = radial or (lambda r: r)
    if not disk:
        a0, a1, b0, b1 = 2 * u0 - 1, 2 * u1 - 1, 2 * v0 - 1, 2 * v1 - 1
        return np.array([[a0, b0], [a1, b0], [a1, b1], [a0, b1]], float)
    sec = block_sector(u0, u1, v0, v1)
    if sec is None:
        return disk_polygon(radial(1.0))
    rmin, rmax, p0, p1 = sec
    return sector_polygon(radial(rmin), radial(rmax), p0, p1)


def _dedupe_ring(pts, tol):
    out = []
    for p in pts:
        if not out or np.abs(p - out[-1]).max() > tol:
            out.append(p)
    while len(out) > 1 and np.abs(out[0] - out[-1]).max() <= tol:
        out.pop()
    return np.array(out)


def polygon_to_homog(poly2, origin, ex, ey, w, tol):
    """2D polygon in the frame (origin, ex, ey) -> homogeneous ring and edges."""
    pts = np.asarray(origin)[None, :] + poly2[:, :1] * ex[None, :] + poly2[:, 1:2] * ey[None, :]
    pts = _dedupe_ring(pts, tol)
    n = len(pts)
    V = np.zeros((MAXV, 4))
    E = np.zeros((MAXE, 2), np.int64)
    V[:n, :3] = pts
    V[:n, 3] = w
    ne = 0 if n < 2 else (1 if n == 2 else n)
    for e in range(ne):
        E[e] = (e, (e + 1) % n)
    return V, n, E, ne


_BOX_EDGES = np.array([[0, 1], [2, 3], [4, 5], [6, 7], [0, 2], [1, 3], [4, 6], [5, 7],
                       [0, 4], [1, 5], [2, 6], [3, 7]], np.int64)


def box_to_homog(lo, hi, origin, frame, tol):
    """Box [lo, hi] in the orthonormal frame (rows of ``frame``) around ``origin``."""
    V = np.zeros((MAXV, 4))
    E = np.zeros((MAXE, 2), np.int64)
    ext = np.asarray(hi) - np.asarray(lo)
    if np.all(np.abs(ext) <= tol):
        V[0, :3] = origin + (0.5 * (np.asarray(lo) + hi)) @ frame
        V[0, 3] = 1.0
        return V, 1, E, 0
    for k in range(8):
        c = np.array([hi[0] if k & 1 else lo[0], hi[1] if k & 2 else lo[1], hi[2] if k & 4 else lo[2]])
        V[k, :3] = origin + c @ frame
        V[k, 3] = 1.0
    E[:12] = _BOX_EDGES
    return V, 8, E, 12


# --------------------------------------------------------------------------
# sample tables
@kernel
def fixed_sample_table(lp, nsets, nx, ny, bit2s, seed, key):
    """SP[set, bit, 4]: homogeneous sample of every set (area: points, sun:
    directions), jittered in its stratum with rand01(seed, key + set, s, dim)."""
    S = nx * ny
    out = np.empty((nsets, S, 4))
    for j in range(nsets):
        for i in range(S):
            s = bit2s[i]
            u, v = stratum_uv(seed, key + j, s, nx, ny)
            x, y, z, is_dir, _ = light_sample(lp, 0.0, 0.0, 0.0, u, v)
            out[j, i, 0] = x
            out[j, i, 1] = y
            out[j, i, 2] = z
            out[j, i, 3] = 0.0 if is_dir else 1.0
    return out


@kernel
def sphere_disk_table(nsets, nx, ny, bit2s, seed, key, radius, e1, e2):
    """Q[set, bit, 3]: disk offsets r (dx e1 + dy e2) in the w0 frame."""
    S = nx * ny
    out = np.empty((nsets, S, 3))
    for j in range(nsets):
        for i in range(S):
            s = bit2s[i]
            u, v = stratum_uv(seed, key + j, s, nx, ny)
            dx, dy = concentric_disk(u, v)
            for a in range(3):
                out[j, i, a] = radius * (dx * e1[a] + dy * e2[a])
    return out


@kernel
def min_rotations(P, centre, w0):
    """Per receiver: the 3x3 minimal rotation taking w0 to the unit direction
    from the point to the light centre (Rodrigues), row-major, and its angle."""
    n = P.shape[0]
    M = np.empty((n, 9))
    ang = np.zeros(n)
    for i in range(n):
        wx, wy, wz = centre[0] - P[i, 0], centre[1] - P[i, 1], centre[2] - P[i, 2]
        d = math.sqrt(wx * wx + wy * wy + wz * wz)
        for a in range(9):
            M[i, a] = 0.0
        M[i, 0] = M[i, 4] = M[i, 8] = 1.0
        if d == 0.0:
            continue
        wx /= d
        wy /= d
        wz /= d
        c = w0[0] * wx + w0[1] * wy + w0[2] * wz
        c = min(1.0, max(-1.0, c))
        kx = w0[1] * wz - w0[2] * wy
        ky = w0[2] * wx - w0[0] * wz
        kz = w0[0] * wy - w0[1] * wx
        s = math.sqrt(kx * kx + ky * ky + kz * kz)
        ang[i] = math.atan2(s, c)
        if s < 1e-15:
            if c > 0.0:
                continue
            # opposite: rotate by pi about any axis perpendicular to w0
            if abs(w0[0]) < 0.9:
                kx, ky, kz = 0.0, -w0[2], w0[1]
            else:
                kx, ky, kz = w0[2], 0.0, -w0[0]
            s = math.sqrt(kx * kx + ky * ky + kz * kz)
            kx /= s
            ky /= s
            kz /= s
            sn, cs = 0.0, -1.0
        else:
            kx /= s
            ky /= s
            kz /= s
            sn, cs = s, c
        t = 1.0 - cs
        M[i, 0] = cs + kx * kx * t
        M[i, 1] = kx * ky * t - kz * sn
        M[i, 2] = kx * kz * t + ky * sn
        M[i, 3] = ky * kx * t + kz * sn
        M[i, 4] = cs + ky * ky * t
        M[i, 5] = ky * kz * t - kx * sn
        M[i, 6] = kz * kx * t - ky * sn
        M[i, 7] = kz * ky * t + kx * sn
        M[i, 8] = cs + kz * kz * t
    return M, ang


@inner(forceinline=True)
def _sphere_point(Q, M, centre, j, i, r):
    """Disk sample ``Q[j, i]`` turned by receiver ``r``'s rotation M[r], around the centre."""
    qx, qy, qz = Q[j, i, 0], Q[j, i, 1], Q[j, i, 2]
    return (centre[0] + M[r, 0] * qx + M[r, 1] * qy + M[r, 2] * qz,
            centre[1] + M[r, 3] * qx + M[r, 4] * qy + M[r, 5] * qz,
            centre[2] + M[r, 6] * qx + M[r, 7] * qy + M[r, 8] * qz, 1.0)


@inner(forceinline=True)
def _shared_point(lp, seed, pix, s, nx, ny, px, py, pz):
    """The reference's sample in stratum ``s`` of pixel ``pix`` seen from G-buffer point p."""
    u, v = stratum_uv(seed, pix, s, nx, ny)
    x, y, z, is_dir, _ = light_sample(lp, px, py, pz, u, v)
    return x, y, z, (0.0 if is_dir else 1.0)


@kernel(inline="always")   # per relation: a call would cost the tuples' reference counts
def sample_point(smp, i, r, rec):
    """Homogeneous position of bit ``i`` of receiver ``r``'s light sample set
    (smp: LightSamples; rec: cast.Receivers, whose set_id, pix, Pg and M are read)."""
    if smp.mode == MODE_FIXED:
        SP = smp.SP
        j = rec.set_id[r]
        return SP[j, i, 0], SP[j, i, 1], SP[j, i, 2], SP[j, i, 3]
    if smp.mode == MODE_SPHERE:
        return _sphere_point(smp.Q, rec.M, smp.centre, rec.set_id[r], i, r)
    Pg = rec.Pg
    return _shared_point(smp.lp, smp.seed, rec.pix[r], smp.bit2s[i], smp.nx, smp.ny, Pg[r, 0], Pg[r, 1], Pg[r, 2])


@inner
def receiver_samples(smp, rec, r, P):
    """``sample_point`` of every bit of receiver ``r`` into P (float64[4, S]:
    rows x, y, z, w), the tables taken out of the tuples once, not per bit."""
    S = P.shape[1]
    if smp.mode == MODE_FIXED:
        SP = smp.SP
        j = rec.set_id[r]
        for i in range(S):
            for a in range(4):
                P[a, i] = SP[j, i, a]
    elif smp.mode == MODE_SPHERE:
        Q, M, centre = smp.Q, rec.M, smp.centre
        j = rec.set_id[r]
        for i in range(S):
            P[0, i], P[1, i], P[2, i], P[3, i] = _sphere_point(Q, M, centre, j, i, r)
    else:
        lp, bit2s, pix = smp.lp, smp.bit2s, rec.pix[r]
        px, py, pz = rec.Pg[r, 0], rec.Pg[r, 1], rec.Pg[r, 2]
        for i in range(S):
            P[0, i], P[1, i], P[2, i], P[3, i] = _shared_point(lp, smp.seed, pix, bit2s[i], smp.nx, smp.ny,
                                                               px, py, pz)


@kernel
def all_sample_points(smp, rows, S, rec):
    """float64[len(rows), S, 4]: every sample of the given receivers, bit order
    (smp: LightSamples; rec: cast.Receivers)."""
    out = np.empty((rows.shape[0], S, 4))
    P = np.empty((4, S))
    for k in range(rows.shape[0]):
        receiver_samples(smp, rec, rows[k], P)
        for i in range(S):
            for a in range(4):
                out[k, i, a] = P[a, i]
    return out


@kernel
def assign_sets(pix, nsets, seed):
    """Section 3.4: one light sample set per receiver, by a hash of its pixel."""
    out = np.empty(pix.shape[0], np.int64)
    for i in range(pix.shape[0]):
        out[i] = min(nsets - 1, int(rand01(seed, pix[i], np.int64(0), np.int64(7)) * nsets))
    return out


# --------------------------------------------------------------------------
# the light's side of one casting
@dataclass
class LightSetup:
    """Sample mode (MODE_*), S samples on an nx x ny grid in G groups
    (``group_layout``), ``nsets`` sample sets; Delta_L (homogeneous vertices
    DVL[:nvl], edges DEL[:nel]) and Delta_Gk (DVg[k, :nvg[k]], DEg[k, :neg[k]]);
    the sample tables SP (MODE_FIXED) or Q (MODE_SPHERE, with the mean
    direction w0 and the largest rotation theta from it); the light's centre
    and packed parameters ``lp``."""

    mode: int
    S: int
    nx: int
    ny: int
    G: int
    nsets: int
    bit2s: np.ndarray
    g_start: np.ndarray
    DVL: np.ndarray
    nvl: int
    DEL: np.ndarray
    nel: int
    DVg: np.ndarray
    nvg: np.ndarray
    DEg: np.ndarray
    neg: np.ndarray
    SP: np.ndarray
    Q: np.ndarray
    centre: np.ndarray
    lp: np.ndarray
    theta: float = 0.0
    w0: Optional[np.ndarray] = None


def light_setup(light, samples: int, group_size: int, sample_sets: int, shared: bool, seed: int,
                Pg: np.ndarray, tol: float) -> LightSetup:
    """The groups, bounding polygons / volumes and sample tables of ``light``
    for receivers at G-buffer positions ``Pg``: ``samples`` in groups of about
    ``group_size``, ``sample_sets`` sets (one for a zero-size light or with
    ``shared``: the reference's own per-pixel samples)."""
    S = 1 if light.is_zero_size else max(1, int(samples))
    nx, ny, G, bit2s, g_start, blocks = group_layout(S, max(1, int(group_size)))
    shared = bool(shared)
    nsets = 1 if (light.is_zero_size or shared) else max(1, int(sample_sets))
    lp = sampling.pack_light(light)
    seed = int(seed)
    centre = light.position.astype(np.float64)
    ax, ay, az = light.axes
    DVg = np.zeros((G, MAXV, 4))
    DEg = np.zeros((G, MAXE, 2), np.int64)
    nvg = np.zeros(G, np.int64)
    neg = np.zeros(G, np.int64)
    SP = np.zeros((1, 1, 4))
    Q = np.zeros((1, 1, 3))
    theta = 0.0
    w0 = None
    if light.kind == "area":
        mode = MODE_SHARED if shared else MODE_FIXED
        disk = light.is_round
        hx, hy = light.half_size
        ex, ey = ax * hx, ay * hy
        full = disk_polygon(1.0) if disk else block_polygon_2d(0, 1, 0, 1, False)
        DVL, nvl, DEL, nel = polygon_to_homog(full, centre, ex, ey, 1.0, tol)
        for g in range(G):
            poly = block_polygon_2d(*blocks[g], disk)
            DVg[g], nvg[g], DEg[g], neg[g] = polygon_to_homog(poly, centre, ex, ey, 1.0, tol)
    elif light.kind == "sun":
        mode = MODE_SHARED if shared else MODE_FIXED
        cosmax = lp[sampling.L_COSMAX]
        if cosmax < 0.05:
            # a cone this wide has no tangent-plane polygon: no culling volumes
            DVL, nvl, DEL, nel = np.zeros((MAXV, 4)), 0, np.zeros((MAXE, 2), np.int64), 0
        else:
            def radial(rho):
                c = 1.0 - rho * rho * (1.0 - cosmax)
                return math.sqrt(max(0.0, 1.0 - c * c)) / c
            full = disk_polygon(radial(1.0))
            DVL, nvl, DEL, nel = polygon_to_homog(full, az, ax, ay, 0.0, 1e-15)
            for g in range(G):
                poly = block_polygon_2d(*blocks[g], True, radial)
                DVg[g], nvg[g], DEg[g], neg[g] = polygon_to_homog(poly, az, ax, ay, 0.0, 1e-15)
    else:  # sphere
        r = float(light.radius)
        if shared:
            mode = MODE_SHARED
            DVL, nvl, DEL, nel = box_to_homog([-r] * 3, [r] * 3, centre, np.eye(3), tol)
            for g in range(G):
                DVg[g], nvg[g], DEg[g], neg[g] = DVL, nvl, DEL, nel
        else:
            mode = MODE_SPHERE
            d = centre[None, :] - Pg
            dn = np.linalg.norm(d, axis=1)
            ok = dn > 0
            mean = (d[ok] / dn[ok, None]).sum(0) if ok.any() else np.zeros(3)
            if np.linalg.norm(mean) > 1e-9 * max(1, ok.sum()):
                w0 = mean / np.linalg.norm(mean)
            else:
                w0 = az.copy()
            e1, e2 = sampling.orthonormal_basis(*w0)
            e1, e2 = np.array(e1), np.array(e2)
            frame = np.stack([e1, e2, w0])
            _, ang = min_rotations(np.ascontiguousarray(Pg), centre, w0)
            theta = float(ang.max()) if len(ang) else 0.0
            dlt = 2.0 * r * math.sin(0.5 * min(theta, math.pi))
            dz = r * (math.sin(theta) if theta < 0.5 * math.pi else 1.0)
            DVL, nvl, DEL, nel = box_to_homog([-r, -r, -dz], [r, r, dz], centre, frame, tol)
            for g in range(G):
                poly = block_polygon_2d(*blocks[g], True) * r
                lo = np.maximum(poly.min(0) - dlt, -r)
                hi = np.minimum(poly.max(0) + dlt, r)
                DVg[g], nvg[g], DEg[g], neg[g] = box_to_homog([lo[0], lo[1], -dz], [hi[0], hi[1], dz],
                                                              centre, frame, tol)
            Q = sphere_disk_table(nsets, nx, ny, bit2s, seed, SET_KEY, r, e1, e2)
    if mode == MODE_FIXED:
        SP = fixed_sample_table(lp, nsets, nx, ny, bit2s, seed, SET_KEY)
    return LightSetup(mode, S, nx, ny, G, nsets, bit2s, g_start, DVL, int(nvl), DEL, int(nel),
                      DVg, nvg, DEg, neg, SP, Q, centre, lp, theta, w0)
