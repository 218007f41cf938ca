"""Rays through alpha mattes on an Embree BVH: a shadow ray's
transmittance, and the first surface a primary ray stops at.

Transmittance (``transmittance``): as Cycles computes a shadow ray through
transparent surfaces, the product of (1 - alpha) over the surfaces it
crosses (a binary matte gives 0 or 1, a filtered edge a fraction). Laine and
Aila 2005, section 4 ("Alpha matte textures"): opaque blockers first, the
alpha-textured ones after. Here: one OCCLUDED query against the opaque
triangles (any hit: 0), then repeated closest-hit queries against the
matte triangles only, each from just past the previous hit
(``sampling.offset_origin`` on the far side), until the ray reaches its end
or its transmittance is 0. A ray that would cross more than MAX_CROSSINGS
matte surfaces counts as blocked, as Cycles does past
``transparent_max_bounces``.

Pass-through (``pass_through``): camera G-buffer and light depth maps keep
the first surface whose alpha reaches a cutoff (a coverage test: a binary
matte's clear texels let the ray through, its solid ones stop it, whatever
the cutoff in (0, 1)). The camera's cutoff is ALPHA_CUTOFF (a filtered
edge or a constant alpha counts as solid from 0.5 up: the receiver Cycles
shows where a card is clear). The light maps' cutoff is an ordered dither
(``DITHER``, a 4 x 4 Bayer matrix over the map's pixels, its levels
permuted per surface passed): a map pixel holds a surface of alpha a
with a share a of the pixels, so filtering map methods see a fractional
shadow (stochastic transparency, Enderton et al. 2010, with an ordered
rather than random threshold), and binary mattes are tested as by the
camera.

A BVH's ``run`` (``embree4.MeshRays``) writes hit distances into the
``dists`` it is given, so every query here gets a copy.
"""
from __future__ import annotations

import math
from collections import namedtuple

import numpy as np

from .alpha import alpha_at
from .jit import inner, kernel
from .sampling import offset_origin

#: matte surfaces a ray may cross (Cycles' transparent_max_bounces, set high
#: for the alpha-aware reference, BLENDER_NOTES "Alpha mattes (checked)");
#: one more stops it (blocked, or the surface a primary ray keeps)
MAX_CROSSINGS = 64
#: a camera ray stops at a surface whose alpha is at least this
ALPHA_CUTOFF = 0.5
#: the light maps' cutoffs: Bayer's 4 x 4 ordered dither, (rank + 0.5) / 16
DITHER = ((np.array([[0, 8, 2, 10], [12, 4, 14, 6], [3, 11, 1, 9], [15, 7, 13, 5]]) + 0.5) / 16).astype(np.float32)


def dither_band(row0: int, row1: int, width: int) -> np.ndarray:
    """float32[(row1 - row0) * width]: the DITHER cutoffs of a band of map rows."""
    return DITHER[np.arange(row0, row1)[:, None] % 4, np.arange(width)[None, :] % 4].reshape(-1)


#: what a ``TriangleScene`` holding matte triangles keeps for these rays: the
#: scene's ``MatteArrays``, its triangles (float32[T,3,3], global ids) and
#: its extent (``sampling.scene_scale``, for ``offset_origin``)
AlphaGeometry = namedtuple("AlphaGeometry", "mattes triangles scale")


@inner
def _surface(triangles, g, uu, vv):
    """Point (float64, from barycentrics on the float32 triangle ``g``) and
    unit geometric normal of a hit."""
    a0, a1, a2 = np.float64(triangles[g, 0, 0]), np.float64(triangles[g, 0, 1]), np.float64(triangles[g, 0, 2])
    e0 = np.float64(triangles[g, 1, 0]) - a0
    e1 = np.float64(triangles[g, 1, 1]) - a1
    e2 = np.float64(triangles[g, 1, 2]) - a2
    f0 = np.float64(triangles[g, 2, 0]) - a0
    f1 = np.float64(triangles[g, 2, 1]) - a1
    f2 = np.float64(triangles[g, 2, 2]) - a2
    px, py, pz = a0 + uu * e0 + vv * f0, a1 + uu * e1 + vv * f1, a2 + uu * e2 + vv * f2
    n0, n1, n2 = e1 * f2 - e2 * f1, e2 * f0 - e0 * f2, e0 * f1 - e1 * f0
    ln = math.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
    if ln > 0:
        n0, n1, n2 = n0 / ln, n1 / ln, n2 / ln
    return px, py, pz, n0, n1, n2


@kernel(nogil=True)
def _step_past(prim, u, v, tri_index, geo, o0, d, tfar0, o, tfar):
    """Move each ray's origin ``o`` just past its hit (local primitive
    ``prim``, barycentrics u, v), onto the side the ray goes on; ``tfar``:
    what is left of the ray that started at ``o0`` and was ``tfar0`` long
    (<= 0: nothing)."""
    for i in range(prim.shape[0]):
        px, py, pz, n0, n1, n2 = _surface(geo.triangles, tri_index[prim[i]], np.float64(u[i]), np.float64(v[i]))
        if n0 * d[i, 0] + n1 * d[i, 1] + n2 * d[i, 2] < 0:
            n0, n1, n2 = -n0, -n1, -n2
        ox, oy, oz = offset_origin(px, py, pz, n0, n1, n2, geo.scale)
        o[i, 0], o[i, 1], o[i, 2] = ox, oy, oz
        tfar[i] = tfar0[i] - ((ox - o0[i, 0]) * d[i, 0] + (oy - o0[i, 1]) * d[i, 1]
                              + (oz - o0[i, 2]) * d[i, 2])


@kernel(nogil=True)
def _cross_mattes(prim, u, v, tri_index, geo, last, trans, ray, o0, d, t0, o, tf):
    """One crossing of ``transmittance``, in place: each ray's transmittance
    ``trans[ray[i]]`` times (1 - alpha) of its hit (``last``: no crossing
    left, a hit blocks it), and the rays that go on (something let through),
    moved just past the hit (``_step_past``) with something left of them,
    compacted to the front of ``ray``, ``o0``, ``d``, ``t0`` (first origins,
    directions, lengths) and ``o``, ``tf`` (origins and lengths left): one
    pass, no NumPy temporaries. Returns how many go on."""
    k = 0
    for i in range(prim.shape[0]):
        if prim[i] < 0:
            continue
        j = ray[i]
        g = tri_index[prim[i]]
        uu, vv = np.float64(u[i]), np.float64(v[i])
        if last:
            trans[j] = 0.0
            continue
        trans[j] *= np.float32(1.0 - alpha_at(geo.mattes, g, uu, vv))
        if not trans[j] > 0.0:
            continue
        px, py, pz, n0, n1, n2 = _surface(geo.triangles, g, uu, vv)
        if n0 * d[i, 0] + n1 * d[i, 1] + n2 * d[i, 2] < 0:
            n0, n1, n2 = -n0, -n1, -n2
        ox, oy, oz = offset_origin(px, py, pz, n0, n1, n2, geo.scale)
        # as _step_past: the offset point in float32, then what is left of the ray
        o[k, 0], o[k, 1], o[k, 2] = ox, oy, oz
        tf[k] = t0[i] - ((ox - o0[i, 0]) * d[i, 0] + (oy - o0[i, 1]) * d[i, 1] + (oz - o0[i, 2]) * d[i, 2])
        if not tf[k] > 0:
            continue
        ray[k] = j
        o0[k, 0], o0[k, 1], o0[k, 2] = o0[i, 0], o0[i, 1], o0[i, 2]
        d[k, 0], d[k, 1], d[k, 2] = d[i, 0], d[i, 1], d[i, 2]
        t0[k] = t0[i]
        k += 1
    return k


@inner
def _cutoff(cut, dither, crossing):
    """The alpha a ray's ``crossing``-th surface must reach to stop it: its
    own ``cut``; with ``dither`` (cut a DITHER level) the level's rank r
    goes to (7 r + 3) mod 16 per surface passed, a permutation of the 16
    levels that decorrelates stacked layers (two 0.5 layers: 4 of 16 pass)."""
    if not dither or crossing == 0:
        return cut
    r = int(cut * 16.0) % 16
    for _ in range(crossing):
        r = (7 * r + 3) % 16
    return (r + 0.5) / 16.0


@kernel(nogil=True)
def clear_hits(prim, u, v, tri_index, mattes, cut, clear):
    """clear[i]: hit i (local primitive, -1 = none) is on a matte whose alpha
    there is below ``cut[i]`` (a primary ray passes through it). Hits on
    triangles without a matte are decided here, without a call of
    ``alpha_at`` (most hits of a light map: the call per hit costs more
    than the rest of this loop)."""
    tri_matte = mattes.tri_matte
    for i in range(prim.shape[0]):
        clear[i] = False
        if prim[i] < 0:
            continue
        g = tri_index[prim[i]]
        if tri_matte[g] >= 0:
            clear[i] = alpha_at(mattes, g, np.float64(u[i]), np.float64(v[i])) < cut[i]


@kernel(nogil=True)
def _record(hp, hu, hv, tri_index, geo, ray, o0, d, prim, u, v, t, cut, crossing, going):
    """Write each re-traced ray's hit (-1: none) into ray ``ray[i]``'s
    (prim, u, v, t) (t: from its first origin ``o0``); it goes on when that
    hit is clear (``_cutoff``; ``crossing``: (dither, surfaces passed))."""
    for i in range(hp.shape[0]):
        j = ray[i]
        prim[j] = hp[i]
        going[i] = False
        if hp[i] < 0:
            continue
        uu, vv = np.float64(hu[i]), np.float64(hv[i])
        u[j], v[j] = uu, vv
        px, py, pz, _, _, _ = _surface(geo.triangles, tri_index[hp[i]], uu, vv)
        t[j] = (px - o0[i, 0]) * d[i, 0] + (py - o0[i, 1]) * d[i, 1] + (pz - o0[i, 2]) * d[i, 2]
        going[i] = alpha_at(geo.mattes, tri_index[hp[i]], uu, vv) < _cutoff(cut[j], crossing[0], crossing[1])


def _run(bvh, o, d, tfar, **kw):
    """The BVH's ``run`` on a copy of ``tfar`` (it writes hit distances into it)."""
    return bvh._scene.run(o, d, dists=np.array(tfar, np.float32, copy=True), **kw)


def _past(bvh, prim, u, v, o0, d, t0):
    """(origins, lengths left) of rays moved just past their hits."""
    o = np.empty_like(o0)
    tf = np.empty_like(t0)
    _step_past(prim, u, v, bvh.tri_index, bvh.alpha, o0, d, t0, o, tf)
    return o, tf


def transmittance(opaque, matte, org, dirs, tfar) -> np.ndarray:
    """float32[n]: the transmittance of each shadow ray (float32 origins,
    unit directions, lengths) through ``opaque`` (a ``TriangleScene`` of
    triangles without a matte) and ``matte`` (one of those with a matte,
    with its ``alpha``)."""
    n = len(org)
    trans = np.ones(n, np.float32)
    if opaque._scene is not None and n:
        trans[_run(opaque, org, dirs, tfar, query="OCCLUDED") != -1] = 0.0
    if matte._scene is None:
        return trans
    ray = np.flatnonzero(trans > 0)
    o0, d, t0 = org[ray], dirs[ray], tfar[ray]
    o, tf = np.empty_like(o0), np.empty_like(t0)
    r = _run(matte, o0, d, t0, output=1) if len(ray) else None
    for crossing in range(MAX_CROSSINGS + 1):
        if r is None:
            break
        n = _cross_mattes(r["primID"], r["u"], r["v"], matte.tri_index, matte.alpha, crossing == MAX_CROSSINGS,
                          trans, ray, o0, d, t0, o, tf)
        r = _run(matte, o[:n], d[:n], tf[:n], output=1) if n else None
    return trans


def pass_through(bvh, rays, prim, u, v, t, cut=None, dither: bool = False) -> np.ndarray:
    """In place: each ray's first hit (local primitive ``prim``, -1 = none,
    barycentrics ``u``, ``v``, distance ``t``) on ``bvh`` (a ``TriangleScene``
    with ``alpha``) becomes the first surface along it whose alpha is at
    least its cutoff (-1: none before its end). ``rays()`` gives the rays
    (float32 origins, unit directions, lengths), asked for only when a hit
    is clear. After MAX_CROSSINGS clear surfaces a ray keeps the last one.
    ``cut``: the cutoff per ray (float32, default ALPHA_CUTOFF); ``dither``:
    ``cut`` holds DITHER levels, permuted per surface passed (``_cutoff``). Returns the indices of the rays that passed
    through something."""
    if cut is None:
        cut = np.full(len(prim), ALPHA_CUTOFF, np.float32)
    clear = np.empty(len(prim), bool)
    clear_hits(prim, u, v, bvh.tri_index, bvh.alpha.mattes, cut, clear)
    ray = np.flatnonzero(clear)
    if not len(ray):
        return ray
    changed = ray
    org, dirs, tfar = rays()
    o0, d, t0 = org[ray], dirs[ray], tfar[ray]
    hp, hu, hv = prim[ray], u[ray], v[ray]
    for crossing in range(1, MAX_CROSSINGS + 1):
        if not len(ray):
            break
        o, tf = _past(bvh, hp, hu, hv, o0, d, t0)
        r = _run(bvh, o, d, np.maximum(tf, 0.0), output=1)
        going = np.empty(len(ray), bool)
        _record(r["primID"], r["u"], r["v"], bvh.tri_index, bvh.alpha, ray, o0, d, prim, u, v, t, cut,
                (bool(dither), crossing), going)
        ray, o0, d, t0 = ray[going], o0[going], d[going], t0[going]
        hp, hu, hv = r["primID"][going], r["u"][going], r["v"][going]
    return changed


@kernel(nogil=True)
def barycentrics(triangles, tri, P, u, v):
    """Embree's (u, v) of points ``P`` (float64[n,3]) on triangles ``tri``
    (the G-buffer keeps positions, not barycentrics)."""
    for i in range(tri.shape[0]):
        g = tri[i]
        a0, a1, a2 = np.float64(triangles[g, 0, 0]), np.float64(triangles[g, 0, 1]), np.float64(triangles[g, 0, 2])
        e = (np.float64(triangles[g, 1, 0]) - a0, np.float64(triangles[g, 1, 1]) - a1,
             np.float64(triangles[g, 1, 2]) - a2)
        f = (np.float64(triangles[g, 2, 0]) - a0, np.float64(triangles[g, 2, 1]) - a1,
             np.float64(triangles[g, 2, 2]) - a2)
        q = (P[i, 0] - a0, P[i, 1] - a1, P[i, 2] - a2)
        ee = e[0] * e[0] + e[1] * e[1] + e[2] * e[2]
        ef = e[0] * f[0] + e[1] * f[1] + e[2] * f[2]
        ff = f[0] * f[0] + f[1] * f[1] + f[2] * f[2]
        qe = q[0] * e[0] + q[1] * e[1] + q[2] * e[2]
        qf = q[0] * f[0] + q[1] * f[1] + q[2] * f[2]
        det = ee * ff - ef * ef
        if det > 0:
            u[i] = (ff * qe - ef * qf) / det
            v[i] = (ee * qf - ef * qe) / det
        else:
            u[i], v[i] = 0.0, 0.0


@kernel(nogil=True)
def gbuffer_hits(prim, u, v, d, tri_index, triangles, tri_object, eye, fwd, pix,
                 position, normal, depth, object_id, triangle_id):
    """Re-traced camera rays -> G-buffer pixels ``pix`` (flat): the surface
    they stopped at (``pixel_rays.gbuffer_list``' conventions: normal
    facing the ray, depth along ``fwd`` from ``eye``; empty: -1, +inf, 0)."""
    for i in range(prim.shape[0]):
        k = pix[i]
        if prim[i] < 0:
            position[k, 0], position[k, 1], position[k, 2] = 0.0, 0.0, 0.0
            normal[k, 0], normal[k, 1], normal[k, 2] = 0.0, 0.0, 0.0
            depth[k] = np.inf
            object_id[k] = -1
            triangle_id[k] = -1
            continue
        g = tri_index[prim[i]]
        px, py, pz, n0, n1, n2 = _surface(triangles, g, np.float64(u[i]), np.float64(v[i]))
        if n0 * d[i, 0] + n1 * d[i, 1] + n2 * d[i, 2] > 0:
            n0, n1, n2 = -n0, -n1, -n2
        position[k, 0], position[k, 1], position[k, 2] = px, py, pz
        normal[k, 0], normal[k, 1], normal[k, 2] = n0, n1, n2
        depth[k] = (px - eye[0]) * fwd[0] + (py - eye[1]) * fwd[1] + (pz - eye[2]) * fwd[2]
        object_id[k] = tri_object[g]
        triangle_id[k] = g
