"""Single sample soft shadows (Brabec & Seidel 2002), method id ``single_sample``.

One depth map and one object-ID map from the light centre (``LIGHT_VIEW``)
and the camera G-buffer with object ids (``GBUFFER``). Every camera pixel is
warped into the light view at float precision (P'_x, P'_y, P'_z; P'_z is the
depth along the face's axis), then (section 3.3):

* hard test (section 3.2): the texel under P' is nearer than the receiver ->
  *inner* (umbra side), else *outer* (lit side);
* outer: search the nearest *blocker* texel (nearer than the receiver's layer
  and a different object id); inner: the nearest *lit* texel (at or behind
  the layer and the receiver's own id); radius r_max = r_scale |P'_z| + r_bias
  rescaled by r_shrink and the blocker-receiver depth difference;
* the two halves meet at ``meet`` = 0.5:
  outer V = meet + (1 - meet) clamp(r / r_max),  inner V = meet (1 - clamp(r / r_max));
  a failed search gives 1 (outer) or 0 (inner), as in the listing.

Search as section 4.2 / 4.3 does it: an axis-aligned box scanned in square
rings around P' (so it stops as soon as no nearer texel can exist), the
distance measured from the float P' (figure 4), texels optionally jittered
(``jitter``, section 4.3, for very low-resolution maps). Before scanning, the
least / largest depth and the single object id of the 8x8 tiles under the
box (not in the paper; ``tile_skip``) rule out boxes that cannot hold a
candidate, and tighten the outer box to s(least depth under it).

Adaptive sampling (section 4.3, ``adaptive``): the hard test and its id (the
blocker's where inner, the receiver's where lit) on every pixel; in every
``block``-th column, groups of ``block`` + 1 pixels with both ends searched;
where hard results and ids (and, conservatively, the light-view face) agree
over the group the inner pixels are interpolated linearly, else the middle
is searched and both halves are treated the same way; then every row fills
the gaps between those columns. The subdivision depends only on the hard
test, so it is walked twice: once to mark the pixels to search (all
searched in one parallel pass), once to interpolate. ``stats["searched"]``
counts the searched pixels, ``stats["texels_read"]`` the texels scanned.

Departures from the printed listing (each keeps the paper's stated intent):

* the listing's return values ``0.5 clamp(r/r_max)`` (inner) and
  ``1 - 0.5 clamp(r/r_max)`` (outer) run the wrong way: they are 1 next to a
  blocker and jump to the failure values 0 / 1 at r_max, against section
  3.2's f = r / r_max "rises from 0 (no illumination) to 1". The formulas
  above are section 3.2's f folded at ``meet``: continuous at r_max and at
  the hard edge;
* the inner rescale uses the depth of the blocker over P (the hard test's
  texel): the listing's ``depth_light[s,t] - P'_z`` is the *lit* texel's own
  depth, about P'_z on any receiver facing the light, which would make r_max
  0 and every umbra 0.5; section 3.2 describes the rescale as "the distance
  between occluder and receiver";
* searches use the paper's constant virtual layer P'_z (``layer="constant"``,
  default); ``layer="plane"`` tests texels against the receiver's tangent
  plane extended over the search box instead, so on a receiver tilted to
  the light the nearer side's own texels still count as lit in the inner
  search. Measured on the sample scenes it changes RMSE by under 2% (slightly
  worse), so the paper's layer stays the default;
* the hard test compares the map with the receiver's tangent plane at the
  texel centre, less a slope-scaled tolerance of ``bias_texels`` texels of the
  receiver's depth slope and world texel size plus float32 precision: the
  offset scheme is in units of the map's own sampling, not per scene;
* with ``edge_distance`` (default) r is the distance from P' to the texel's
  square rather than to its centre, so inner and outer both reach ``meet`` at
  the texel boundary of the hard test (the paper's "ring" artifact, section 5,
  is the half-texel jump the centre distance leaves there).

Beyond the paper (its section 6 future work): ``auto_radius`` (default) takes
the radius from the light's real size. A blocker at depth z_b and texel
offset d from P' blocks part of the light iff d lies in the light's shape
scaled by s(z_b) = 1/z_b - 1/P'_z (perspective faces; s = P'_z - z_b for a
sun's orthographic face): similar triangles, to first order in the light's
size, with the shape projected into the face along the ray from P. So r is
measured in a norm of the light's own shape and r_max = s(blocker depth).
``ramp`` picks the norm:

* ``"slope"`` (default): the ramp has the true slope of V at the hard edge
  of a straight occluder edge (full width = light area / the light's chord
  through its centre along the edge): the 1-norm on the half axes for
  squares and rectangles (exact for edges along an axis), the Euclidean /
  elliptic norm scaled by 4/pi for disks, ellipses, spheres and suns;
* ``"extent"``: the ramp spans the whole penumbra (Parker's outer hull: the
  max-norm for rectangles, the plain Euclidean / elliptic norm otherwise).
  Its tails are too long: measured RMSE against ``embree`` is 10-30% higher.

The search box is the unit ball scaled by s(nearest depth under the box) for
outer searches, by s(blocker over P) for inner ones, capped at
``max_radius`` texels; a penumbra wider than the cap is narrowed to it (V
still reaches 0 / 1 at the box edge; ``stats["clipped"]`` counts those
pixels). In this mode r_scale, r_bias and r_shrink are unused: the paper's
linear r_scale |P'_z| + r_bias with a constant r_shrink cannot express
1/z_b - 1/P'_z. ``auto_radius=False`` is the paper's formula with its raw
knobs, in texels (the same narrowing applies when r_shrink asks for a
radius beyond the search box).

Lights (the paper assumes a point light with a size knob):

* area lights: the light's rectangle / ellipse (its real half sizes and axes,
  projected into the face along the ray from P);
* point / spot lights of radius r: the disk of radius r facing P (DESIGN.md's
  light domain). Point lights use cube faces: P is searched in the face that
  holds it (``kernels.pick_face``), texels beyond that face's border count as
  neither blocker nor lit;
* sun: the orthographic view along the sun; the cone of half-angle angle/2
  around the sun direction has a disk cross-section of radius
  tan(angle/2) (P'_z - z_b) at the blocker's depth.

Several blockers (issue 17; section 3.4's single ramp from the nearest
texel cannot add them up): ``blocker="sum"`` replaces the inner / outer
searches by the light each blocker texel in the box hides, back-projected
through the light's real shape and added up (``_coverage``; clamped to 1,
renormalised where the box is clipped; with ``auto_radius`` off, the
paper's knobs, the nearest blocker). Exact for disjoint planar blockers
(two half-planes each hiding half of the light: V = 0 where the paper's
ramp says 0.5 or more); it still sees only what the light's centre sees.
``surfaces="mesh"`` gives every connected mesh piece its own id
(``surfaces.mesh_pieces``; "object": object ids, the paper's grouping), so a
shrub's leaves, one object, shadow each other. Measured on foliage (256 x
256): RMSE 0.075 (paper) -> 0.044 (sum + mesh).

The receiver's own surface (issue 17; ``horizon``, default on): the id
test keeps a receiver from shadowing itself, so a surface turned partly
away from the light (a leaf at a steep angle, a curved object's
terminator) got the light below its tangent plane as lit. V is multiplied
by the share of the light above that plane (``horizon.horizon_share``,
closed forms; computed only where V > 0), as if the blockers hid the light
above and below it alike. On issue 17's foliage (256 x 256, against 1024-sample
embree) 2 % of the pixels the light reaches do not see the whole light and
held 79 % of the squared error: RMSE over every pixel the light reaches
0.080 -> 0.046; over the pixels that see the whole light (issue 17's
measure) 0.037, unchanged. ``horizon=False`` is the paper's.

A light of size zero gives exactly the hard test (no search, no horizon). Pixels outside
every face of the view, behind a perspective eye, or with no G-buffer hit
get V = 1. The pass is average-visibility-like (AVERAGE) but not physical:
the attenuation is a linear ramp from the nearest texel, the umbra of an
occluder is never lit through, and an object never soft-shadows itself
(id test; its hard self-shadows stay).
"""
from __future__ import annotations

import math
from collections import namedtuple
from dataclasses import dataclass
from typing import Optional

import numpy as np

from ...jit import HOT, inner, kernel
from ...kernels import borrowed, each_dealt_chunk, each_range, face_project
from ...sampling import rand01
from ..registry import register
from ..horizon import scale_by_horizon
from ..surfaces import mesh_pieces
from ..base import AVERAGE, GBUFFER, LIGHT_VIEW, Method, MethodResult, PhaseTimer

# packed parameter layout for the kernels
(P_AUTO, P_MEET, P_RSCALE, P_RBIAS, P_RSHRINK, P_MAXRAD, P_JITTER, P_EDGE, P_PLANE, P_IDTEST,
 P_BIAS, P_RATIO, P_SEED, P_KIND, P_RADIUS, P_SUNTAN, P_NORM, P_HARD, P_TOLREL, P_TOLABS,
 P_GSCALE, P_TILES, P_SUM) = range(23)
N_PRM = 23
# relative float32 precision allowance of stored depths (Embree hit distances
# are float32; a few ULPs of the depth and of the largest coordinate)
TOL_REL = 4e-6
TOL_ABS_PER_COORD = 2e-6
TILE = 8   # texels per side of the depth-range tiles that skip hopeless search boxes
COVER_GRID = 8   # blocker="sum": light points per side probing the box's share of the light
# search gauge norms (``prm[P_NORM]``, ``Gauge.norm``)
NORM_EUCLID = 0     # 2-norm: disk-like lights
NORM_MAX = 1        # max-norm: the unit ball is the rectangle
NORM_L1 = 2         # 1-norm: the diamond on the half axes


@dataclass
class SingleSampleParams:
    # raw knobs of section 3.2 (used when auto_radius is False); the paper
    # gives no values except the 20-texel r_max of its torus scene (section 5)
    r_scale: float = 2.0          # texels per scene unit of |P'_z|
    r_bias: float = 0.0           # texels (footnote 2: a minimum penumbra width)
    r_shrink: float = 0.25        # per scene unit of blocker-receiver depth
    max_radius: float = 64.0      # search box half size cap, texels of a 256-texel map, scaled
                                  # with the map's side (section 5 used r_max = 20 at 256x256)
    meet: float = 0.5             # section 3.3: inner and outer penumbra meet at 0.5
    auto_radius: bool = True      # radius from the light's real size (section 6 future work)
    adaptive: Optional[bool] = None  # section 4.3 interpolation over 4x4 blocks; None: on for the
                                  # ramps ("nearest", "ratio"), off for "sum" (not linear there)
    block: int = 4                # section 4.3: groups of 5 pixels, every 4th column
    jitter: float = 0.0           # section 4.3: blocker texel jitter (texels; 0 = off)
    edge_distance: bool = True    # distance to the texel's square (else its centre, figure 4)
    layer: str = "constant"       # "constant" (P'_z, section 3.2) | "plane" (receiver's tangent plane)
    id_test: bool = True          # section 3.2: blockers must have another object id
    bias_texels: float = 0.5      # hard-test tolerance, texels of receiver slope + texel size
    blocker: str = "sum"          # "sum" (adds up the light every blocker texel hides; needs
                                  # auto_radius, else "nearest") | "nearest" (paper) | "ratio"
                                  # (min r / r_max over blockers)
    surfaces: str = "mesh"        # what one id is: "mesh" (connected mesh pieces) | "object" (paper)
    ramp: str = "slope"           # auto_radius: "slope" (true slope at the edge) | "extent" (whole penumbra)
    tile_skip: bool = True        # skip search boxes the 8x8 tiles' depth range rules out (not in the paper)
    horizon: bool = True          # V x the share of the light above the receiver's tangent plane (issue 17;
                                  # False: the paper, an object never shadows itself softly)
    map_size: Optional[int] = None  # light map's larger side; None = views.default_map_size
    seed: int = 0                 # jitter hash seed


# --------------------------------------------------------------------------
# per-pixel setup
@inner
def _light_axes(prm, finfo, fp, pvx, pvy, pvz):
    """The light's two half axes in the face's view coordinates:
    area: per face; sphere: the disk facing P; sun: tan(angle/2) along x, y."""
    kind = prm[P_KIND]
    if kind == 0.0:
        return finfo[0], finfo[1], finfo[2], finfo[3], finfo[4], finfo[5]
    if kind == 1.0:
        r = prm[P_RADIUS]
        n = math.sqrt(pvx * pvx + pvy * pvy + pvz * pvz)
        if n == 0.0:
            return r, 0.0, 0.0, 0.0, r, 0.0
        dx, dy, dz = pvx / n, pvy / n, pvz / n
        # any unit vector perpendicular to d, then d x b1
        if abs(dx) < 0.9:
            ax, ay, az = 0.0, -dz, dy          # e_x x d
        else:
            ax, ay, az = dz, 0.0, -dx          # e_y x d
        an = math.sqrt(ax * ax + ay * ay + az * az)
        ax, ay, az = ax / an, ay / an, az / an
        bx = dy * az - dz * ay
        by = dz * ax - dx * az
        bz = dx * ay - dy * ax
        return r * ax, r * ay, r * az, r * bx, r * by, r * bz
    t = prm[P_SUNTAN]
    return t, 0.0, 0.0, 0.0, t, 0.0


@kernel(inline="always")
def _face_of(faces, px, py, pz):
    """``kernels.pick_face`` and the point's projection into that face:
    (face, u, v, depth), face -1 (and zeros) outside every face."""
    for f in range(faces.shape[0]):
        u, v, d = face_project(faces[f], px, py, pz)
        if u >= 0.0 and v >= 0.0 and u < faces[f, 21] and v < faces[f, 22] and (d > 0.0 or faces[f, 16] == 1.0):
            return f, u, v, d
    return -1, 0.0, 0.0, 0.0


def _warp_py(P, Nrm, i, faces, depth, prm):
    """Warp pixel i into the light view (section 3.2) and run the hard test.

    Returns (face, u, v, zr, inner, z_map, planar, A, B, C, tol, pvx, pvy, pvz):
    the receiver's tangent plane over the map is 1/z (perspective) or z
    (orthographic) = A sc + B tc + C in texel coordinates (sc, tc); ``tol``
    is the hard test's tolerance; face < 0 means "not in the light view".
    Compiled twice from this one source: ``_warp`` (a function of its own,
    called per searched pixel) and ``_warp_inline`` (inlined into the hard
    test over every pixel, ``_hard_range``: a call per pixel cost a third
    of that loop)."""
    px, py, pz = P[i, 0], P[i, 1], P[i, 2]
    f, u, v, zr = _face_of(faces, px, py, pz)
    if f < 0:
        return -1, 0.0, 0.0, 0.0, False, 0.0, False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    fp = faces[f]
    if not (zr > 0.0) or not np.isfinite(u) or not np.isfinite(v) or not np.isfinite(zr):
        return -1, 0.0, 0.0, 0.0, False, 0.0, False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    w = int(fp[21])
    h = int(fp[22])
    ortho = fp[16] == 1.0
    l, t = fp[17], fp[20]
    ku = fp[21] / (fp[18] - l)
    kv = fp[22] / (t - fp[19])
    pvx = fp[0] * px + fp[1] * py + fp[2] * pz + fp[3]
    pvy = fp[4] * px + fp[5] * py + fp[6] * pz + fp[7]
    pvz = fp[8] * px + fp[9] * py + fp[10] * pz + fp[11]
    nx0, ny0, nz0 = Nrm[i, 0], Nrm[i, 1], Nrm[i, 2]
    nvx = fp[0] * nx0 + fp[1] * ny0 + fp[2] * nz0
    nvy = fp[4] * nx0 + fp[5] * ny0 + fp[6] * nz0
    nvz = fp[8] * nx0 + fp[9] * ny0 + fp[10] * nz0
    d0 = nvx * pvx + nvy * pvy + nvz * pvz
    A = 0.0
    B = 0.0
    C = zr if ortho else 1.0 / zr
    planar = False
    if ortho:
        if abs(nvz) > 1e-9:
            A = nvx / (ku * nvz)
            B = -nvy / (kv * nvz)
            C = (nvx * l + nvy * t - d0) / nvz
            planar = True
    elif abs(d0) > 1e-12 * zr * math.sqrt(pvx * pvx + pvy * pvy + pvz * pvz):
        A = nvx / (ku * d0)
        B = -nvy / (kv * d0)
        C = (nvx * l + nvy * t - nvz) / d0
        planar = True
    if planar:   # re-anchor so the plane passes exactly through P'
        C += (zr if ortho else 1.0 / zr) - (A * u + B * v + C)
    # slope-scaled tolerance: the receiver's depth change across a texel
    # plus the texel's world size, in units of bias_texels
    if ortho:
        dzu, dzv = A, B
        texel_world = 1.0 / ku
    else:
        dzu, dzv = -A * zr * zr, -B * zr * zr
        texel_world = zr / ku
    tol = prm[P_TOLREL] * zr + prm[P_TOLABS] + prm[P_BIAS] * (math.sqrt(dzu * dzu + dzv * dzv) + texel_world)
    tol = min(tol, 0.1 * zr)
    # hard test at the texel under P', against the plane at its centre
    iu = min(max(int(math.floor(u)), 0), w - 1)
    iv = min(max(int(math.floor(v)), 0), h - 1)
    zt = zr
    if planar:
        lv = A * (iu + 0.5) + B * (iv + 0.5) + C
        if ortho:
            zt = lv
        elif lv > 0.0:
            zt = 1.0 / lv
    zmap = np.float64(depth[f, iv, iu])
    inner = zmap < zt - tol
    return f, u, v, zr, inner, zmap, planar, A, B, C, tol, pvx, pvy, pvz


_warp = kernel(_warp_py)
_warp_inline = kernel(cache=False, inline="always")(_warp_py)


@inner
def _shape(prm, finfo_f, fp, pvx, pvy, pvz, zr):
    """The light's shape in the map (auto_radius): G maps texel offsets to
    the light's shape coordinates per unit of s(z_b) (gauge ``prm[P_NORM]``),
    ``emax`` the largest texel half extent of its unit ball."""
    ortho = fp[16] == 1.0
    ku = fp[21] / (fp[18] - fp[17])
    kv = fp[22] / (fp[20] - fp[19])
    a1x, a1y, a1z, a2x, a2y, a2z = _light_axes(prm, finfo_f, fp, pvx, pvy, pvz)
    if ortho:
        tx, ty = 0.0, 0.0
    else:
        tx, ty = pvx / zr, pvy / zr
    # o -> o_xy - o_d t_P with o_d = -o_z (first order in the light's size),
    # then to texel offsets: du = ku dx, dv = -kv dy
    n00 = ku * (a1x + a1z * tx)
    n01 = ku * (a2x + a2z * tx)
    n10 = -kv * (a1y + a1z * ty)
    n11 = -kv * (a2y + a2z * ty)
    fro = math.sqrt(n00 * n00 + n01 * n01 + n10 * n10 + n11 * n11)
    if not (fro > 0.0) or not np.isfinite(fro):
        return 1.0, 0.0, 0.0, 1.0, 1.0
    det = n00 * n11 - n01 * n10
    if abs(det) < 1e-6 * fro * fro:    # seen edge-on: keep a sliver of width
        n00 += 1e-3 * fro
        n11 += 1e-3 * fro
        det = n00 * n11 - n01 * n10
    gs = prm[P_GSCALE]
    norm = prm[P_NORM]
    if norm == NORM_MAX:
        eu = abs(n00) + abs(n01)
        ev = abs(n10) + abs(n11)
    elif norm == NORM_L1:
        eu = max(abs(n00), abs(n01))
        ev = max(abs(n10), abs(n11))
    else:
        eu = math.sqrt(n00 * n00 + n01 * n01)
        ev = math.sqrt(n10 * n10 + n11 * n11)
    return gs * n11 / det, -gs * n01 / det, -gs * n10 / det, gs * n00 / det, max(eu, ev) / gs


@inner
def _s_of(zb, zr, ortho):
    """Penumbra scale of a blocker at depth zb over a receiver at zr:
    1/zb - 1/zr (perspective), zr - zb (orthographic)."""
    if ortho:
        return zr - zb
    if zb <= 0.0:
        return np.inf
    return 1.0 / zb - 1.0 / zr


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
def _layer_range(A, B, C, iu, iv, c, ortho):
    """Least and largest depth of the layer over the texel centres of that
    box (1/z, or z, is affine in texel coordinates: extremes at the corners)."""
    lo = np.inf
    hi = -np.inf
    for k in range(4):
        sc = iu + 0.5 + (c if k & 1 else -c)
        tc = iv + 0.5 + (c if k & 2 else -c)
        lv = A * sc + B * tc + C
        lo = min(lo, lv)
        hi = max(hi, lv)
    if ortho:
        return lo, hi
    zlo = 1.0 / hi if hi > 0.0 else np.inf
    zhi = 1.0 / lo if lo > 0.0 else np.inf
    return zlo, zhi


@inner
def _nearer(d, lv, ortho, tol):
    """Is map depth ``d`` in front of the layer, whose value at the texel is
    ``lv``: z_l = lv (orthographic) or 1 / lv (perspective, +inf where
    lv <= 0); "d < z_l - tol" is "(d + tol) lv < 1" there."""
    if ortho:
        return d < lv - tol
    if lv > 0.0:
        return (d + tol) * lv < 1.0
    return d < np.inf


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


@inner
def _coverage(depth_f, id_f, u, v, zr, pid, layer, G00, G01, G10, G11, norm, crad, use_id):
    """``blocker="sum"`` (not in the paper; section 3.4's one-blocker ramp
    cannot add up several blockers): the fraction of the light hidden by the
    blocker texels of the box, added up. A texel at depth z_b and offset d
    from P' hides the light around y = G d / s(z_b) (first order, as the
    gauge) -- the light is |y| <= 1 in its shape's norm (rectangle: max-norm
    on the half axes, else the disk) -- a light area |det G| / s(z_b)^2 of
    the shape's area (4 or pi), times the share of the texel's image inside
    the light (per axis for rectangles, radially for disks: no staircase). Texels hidden from the
    light's centre count as nothing and overlapping back-projections twice:
    the sum is clamped to 1. Where part of the light's back-projection (at
    the blockers' mean s) falls outside the scanned box (the map's border,
    ``max_radius``), the sum is divided by the part inside (``COVER_GRID``^2
    light points): the unseen part is taken to be blocked like the seen one.
    Returns (fraction, texels read)."""
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
    if not (acc > 0.0):
        return 0.0, nvis
    # the part of the light whose back-projection at the mean s lies in the box
    s_ref = sw / acc
    n00, n01, n10, n11 = G11 / det_s, -G01 / det_s, -G10 / det_s, G00 / det_s
    s0, s1 = max(iu - crad, 0), min(iu + crad, w - 1) + 1
    t0, t1 = max(iv - crad, 0), min(iv + crad, h - 1) + 1
    n_ball = 0
    n_in = 0
    for a in range(COVER_GRID):
        ya = -1.0 + (2 * a + 1.0) / COVER_GRID
        for b in range(COVER_GRID):
            yb = -1.0 + (2 * b + 1.0) / COVER_GRID
            if norm != NORM_MAX and ya * ya + yb * yb > 1.0:
                continue
            n_ball += 1
            su = u + s_ref * (n00 * ya + n01 * yb)
            sv = v + s_ref * (n10 * ya + n11 * yb)
            if su >= s0 and su < s1 and sv >= t0 and sv < t1:
                n_in += 1
    if n_in == 0:
        return min(acc, 1.0), nvis
    return min(acc * n_ball / n_in, 1.0), nvis


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


# argument groups of ``_search``
SearchPoint = namedtuple("SearchPoint", "u v zr inner pid pid_in_map")
"""The receiver in the map: texel coordinates, depth, inner (own-object lit
texel) or outer (blocker) search, its object id and whether that id is in
the map."""
Layer = namedtuple("Layer", "A B C ortho tol")
"""The virtual layer P'_z per texel (s, t): A s + B t + C is its depth
(orthographic face) or 1 / depth (perspective), with the depth tolerance."""
Gauge = namedtuple("Gauge", "G00 G01 G10 G11 norm emax")
"""The search gauge: texel offset -> rho by the matrix G and the norm
(NORM_*), ``emax`` its largest stretch."""


@inner
def _search(depth_f, id_f, tiles_f, fidx, pt, layer, gauge, rho_max, crad, prm, zscale_max):
    """Ring-ordered axis-aligned box scan (sections 4.2, 4.3, figure 4).

    Returns (found, rho, z) of the selected texel: the nearest in the gauge
    (``blocker="nearest"``), or for outer searches with ``blocker="ratio"``
    the one with the least rho / r_max(z). pt: SearchPoint; layer: Layer;
    gauge: Gauge. With ``tile_skip`` and the constant layer, texels of a
    tile that cannot hold a candidate (``_tile_hopeless``) are passed over
    unread: the same texels are candidates, in the same order (issue 15:
    failed searches read most of the texels)."""
    u, v, zr, inner, pid, pid_in_map = pt.u, pt.v, pt.zr, pt.inner, pt.pid, pt.pid_in_map
    A, B, C, ortho, tol = layer.A, layer.B, layer.C, layer.ortho, layer.tol
    G00, G01, G10, G11, norm, emax = gauge.G00, gauge.G01, gauge.G10, gauge.G11, gauge.norm, gauge.emax
    h, w = depth_f.shape
    iu = int(math.floor(u))
    iv = int(math.floor(v))
    edge = prm[P_EDGE] == 1.0
    jit = prm[P_JITTER]
    seed = int(prm[P_SEED])
    use_id = prm[P_IDTEST] == 1.0
    auto = prm[P_AUTO] == 1.0
    ratio = prm[P_RATIO] == 1.0 and not inner
    tskip = prm[P_TILES] == 1.0 and A == 0.0 and B == 0.0    # the layer is C at every texel
    cb0, ca0, ch0 = -1, -1, False
    cb1, ca1, ch1 = -1, -1, False
    off = (1.0 if edge else 0.5) + 0.5 * jit
    best = np.inf
    best_key = np.inf
    best_z = 0.0
    found = False
    nvis = 0
    for c in range(0, crad + 1):
        lb = (c - off) / emax
        if lb < 0.0:
            lb = 0.0
        if lb > rho_max:
            break
        if found:
            if ratio:
                if lb / zscale_max > best_key:
                    break
            elif lb > best:
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
                if norm == NORM_MAX:
                    rho = max(abs(x), abs(y))
                elif norm == NORM_L1:
                    rho = abs(x) + abs(y)
                else:
                    rho = math.sqrt(x * x + y * y)
                if rho > rho_max:
                    continue
                if ratio:
                    if auto:
                        sc = _s_of(d, zr, ortho)
                    else:
                        sc = rho_max * prm[P_RSHRINK] * (zr - d)
                    k = rho / sc if sc > 0.0 else np.inf
                    if not found or k < best_key:
                        best_key = k
                        best = rho
                        best_z = d
                        found = True
                elif rho < best:
                    best = rho
                    best_z = d
                    found = True
    return found, best, best_z, nvis


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
    nrep = 0 if prm[P_TILES] == 0.0 else (2 if (auto and not search_inner) else 1)
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
        cov, nvis = _coverage(depth[f], ids[f], u, v, zr, pid, Layer(A, B, C, ortho, tol),
                              G00, G01, G10, G11, norm, crad, prm[P_IDTEST] == 1.0)
        return 1.0 - cov, rho_max * emax + off, nvis
    if inner:
        zs_max = 1.0
    elif auto:
        zs_max = rho_max
    else:
        zs_max = rho_max * prm[P_RSHRINK] * (zr - finfo[f, 6])
    rtex = rho_max * emax
    crad = int(math.ceil(min(rtex + off, maxrad)))
    found, rho, zb, nvis = _search(depth[f], ids[f], tiles[f], f, SearchPoint(u, v, zr, inner, pid, pid_in_map),
                                   Layer(A, B, C, ortho, tol), Gauge(G00, G01, G10, G11, norm, emax),
                                   rho_max, crad, prm, zs_max)
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
    with ``kernels.borrowed`` arguments (issue 15: a prange one's parfor
    lowering was most of its compile time)."""
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


@inner
def _same(hface, hinner, hid, idx0, stride, a, b):
    """Section 4.3's group criterion over pixels a..b: equal hard results and
    ids (and, conservatively, the same light-view face)."""
    i0 = idx0 + a * stride
    for k in range(a + 1, b + 1):
        j = idx0 + k * stride
        if hinner[j] != hinner[i0] or hid[j] != hid[i0] or hface[j] != hface[i0]:
            return False
    return True


@inner
def _walk(hface, hinner, hid, need, out, idx0, stride, marks, ends, interpolate):
    """Section 4.3 along one column or row: groups [marks[k], marks[k+1]]
    (5 pixels for blocks of 4). Where the group criterion holds the inner
    pixels are interpolated linearly between the ends, else the middle pixel
    is searched and both halves are treated the same way.

    The subdivision depends on the hard test and ids only, so the walk runs
    twice: first (``interpolate`` False) it marks the pixels to search in
    ``need`` (the group ends too if ``ends``), then, once those are searched,
    it interpolates ``out`` along the same subdivision."""
    stack = np.empty((64, 2), np.int64)
    for g in range(marks.shape[0] - 1):
        a0 = marks[g]
        b0 = marks[g + 1]
        if ends and not interpolate:
            need[idx0 + a0 * stride] = True
            need[idx0 + b0 * stride] = True
        stack[0, 0] = a0
        stack[0, 1] = b0
        sp = 1
        while sp > 0:
            sp -= 1
            a = stack[sp, 0]
            b = stack[sp, 1]
            if b - a <= 1:
                continue
            if _same(hface, hinner, hid, idx0, stride, a, b):
                if interpolate:
                    ja = idx0 + a * stride
                    jb = idx0 + b * stride
                    for k in range(a + 1, b):
                        out[idx0 + k * stride] = out[ja] + (out[jb] - out[ja]) * ((k - a) / (b - a))
                continue
            m = (a + b) // 2
            if not interpolate:
                need[idx0 + m * stride] = True
            if sp + 2 > stack.shape[0]:
                grown = np.empty((2 * stack.shape[0], 2), np.int64)
                for q in range(sp):    # element copy: a slice assignment's shape-error path costs 2.6 s to compile
                    grown[q, 0] = stack[q, 0]
                    grown[q, 1] = stack[q, 1]
                stack = grown
            stack[sp, 0] = a
            stack[sp, 1] = m
            stack[sp + 1, 0] = m
            stack[sp + 1, 1] = b
            sp += 2


def _marks(n: int, step: int) -> np.ndarray:
    """Group ends along a line of n pixels: every ``step``-th and the last."""
    m = list(range(0, n, step))
    if m[-1] != n - 1 or len(m) == 1:
        m.append(n - 1)
    return np.asarray(m, np.int64)


def adaptive_walk(hface, hinner, hid, need, out, H, W, colmarks, rowmarks, interpolate, threads=None):
    """Section 4.3: every ``block``-th column first (groups along y, their
    ends searched), then every row between those columns (groups along x).
    Each phase over ranges of lines on Numba's thread count
    (``kernels.each_range``, ``_walk_lines``): lines write disjoint pixels."""
    each_range(lambda k0, k1: _walk_lines(k0, k1, hface, hinner, hid, need, out, W, colmarks, rowmarks, True,
                                          interpolate), colmarks.shape[0], threads, grain=16, per_worker=2)
    each_range(lambda k0, k1: _walk_lines(k0, k1, hface, hinner, hid, need, out, W, colmarks, rowmarks, False,
                                          interpolate), H, threads, grain=64, per_worker=2)


@kernel(opt=HOT, nogil=True)
def _walk_lines(k0, k1, hface, hinner, hid, need, out, W, colmarks, rowmarks, columns, interpolate):
    """``adaptive_walk``'s columns colmarks[k0:k1] (``columns``) or rows k0..k1-1."""
    hface, hinner, hid, need, out, colmarks, rowmarks = borrowed((hface, hinner, hid, need, out, colmarks, rowmarks))
    marks = rowmarks if columns else colmarks
    stride = W if columns else 1
    for k in range(k0, k1):
        idx0 = colmarks[k] if columns else k * W
        # ``columns`` rather than a literal True / False: one compile of _walk, not one per value
        _walk(hface, hinner, hid, need, out, idx0, stride, marks, columns, interpolate)


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


# --------------------------------------------------------------------------
def pack_params(params: SingleSampleParams, light, hard_only: bool, coord_mag: float) -> np.ndarray:
    prm = np.zeros(N_PRM, np.float64)
    prm[P_AUTO] = 1.0 if params.auto_radius else 0.0
    prm[P_MEET] = min(max(float(params.meet), 0.0), 1.0)
    prm[P_RSCALE] = float(params.r_scale)
    prm[P_RBIAS] = float(params.r_bias)
    prm[P_RSHRINK] = float(params.r_shrink)
    prm[P_MAXRAD] = max(float(params.max_radius), 0.0)
    prm[P_JITTER] = min(max(float(params.jitter), 0.0), 1.0)
    prm[P_EDGE] = 1.0 if params.edge_distance else 0.0
    if params.layer not in ("plane", "constant"):
        raise ValueError(f"single_sample: layer must be 'plane' or 'constant', not {params.layer!r}")
    if params.blocker not in ("nearest", "ratio", "sum"):
        raise ValueError(f"single_sample: blocker must be 'nearest', 'ratio' or 'sum', not {params.blocker!r}")
    prm[P_PLANE] = 1.0 if params.layer == "plane" else 0.0
    prm[P_IDTEST] = 1.0 if params.id_test else 0.0
    prm[P_BIAS] = max(float(params.bias_texels), 0.0)
    prm[P_RATIO] = 1.0 if params.blocker == "ratio" else 0.0
    add_up = params.blocker == "sum" and params.auto_radius   # the light's real shape
    prm[P_SUM] = 1.0 if add_up else 0.0
    prm[P_SEED] = float(int(params.seed) & 0x7FFFFFFF)
    prm[P_KIND] = light.kind_code
    prm[P_RADIUS] = float(light.radius)
    prm[P_SUNTAN] = light.sun_spread
    if params.ramp not in ("slope", "extent"):
        raise ValueError(f"single_sample: ramp must be 'slope' or 'extent', not {params.ramp!r}")
    rect = light.kind == "area" and not light.is_round
    if params.ramp == "extent" or add_up:   # the ramp spans the whole penumbra
        prm[P_NORM] = NORM_MAX if rect else NORM_EUCLID
        prm[P_GSCALE] = 1.0
    else:                                # the ramp has the true slope at V = meet
        prm[P_NORM] = NORM_L1 if rect else NORM_EUCLID
        prm[P_GSCALE] = 1.0 if rect else 4.0 / math.pi
    prm[P_HARD] = 1.0 if (hard_only or light.is_zero_size) else 0.0
    prm[P_TILES] = 1.0 if params.tile_skip else 0.0
    prm[P_TOLREL] = TOL_REL
    prm[P_TOLABS] = TOL_ABS_PER_COORD * coord_mag
    return prm


def resolved_adaptive(params: SingleSampleParams) -> bool:
    """``adaptive``, or when None: on for the paper's ramps, off for
    ``blocker="sum"`` (section 4.3's criterion, equal hard results and ids,
    is made for a ramp from the nearest texel; the summed V is not linear
    between the group's ends: torus_plane's ground RMSE 0.015 -> 0.048)."""
    if params.adaptive is not None:
        return bool(params.adaptive)
    return not (params.blocker == "sum" and params.auto_radius)


def face_info(lv, light) -> np.ndarray:
    """Per face: the area light's half axes in view coordinates (6) and the
    nearest finite depth in the face (the nearest possible blocker)."""
    F = len(lv.faces)
    out = np.zeros((F, 8), np.float64)
    ax, ay, _ = light.axes
    hx, hy = light.half_size
    for k, face in enumerate(lv.faces):
        R = np.asarray(face.view_from_world, np.float64)[:3, :3]
        if light.kind == "area":
            out[k, 0:3] = R @ ax * hx
            out[k, 3:6] = R @ ay * hy
        d = lv.depth[k]
        fin = d[np.isfinite(d)]
        out[k, 6] = float(fin.min()) if fin.size else np.inf
    return out


def _coord_mag(scene, light) -> float:
    """Largest coordinate magnitude of the scene and the light (float32 ULPs)."""
    t = scene.triangles
    m = float(np.abs(t).max()) if t.size else 0.0
    m = m if np.isfinite(m) else float(np.abs(t[np.isfinite(t)]).max(initial=0.0))
    return max(m, float(np.abs(light.position).max()))


def single_sample_visibility(buffers, light, params: SingleSampleParams, hard_only: bool = False,
                             timer: PhaseTimer | None = None):
    """V float32[H,W] and stats. ``hard_only`` runs only the hard test."""
    timer = timer or PhaseTimer()
    g = buffers.gbuffer
    H, W = g.shape
    out = np.ones(H * W, np.float64)
    adaptive = resolved_adaptive(params) and g.pixel is None   # the walk needs an image: a packed
                                                               # G-buffer (sub-pixel receivers) is searched
    stats = {"searched": 0, "pixels": int(g.hit.sum()), "adaptive": adaptive,
             "searched_fraction": 0.0, "mean_search_radius_texels": 0.0, "clipped": 0,
             "texels_read": 0, "faces": 0, "map": [0, 0, 0], "hard_only": False}
    if params.surfaces not in ("object", "mesh"):
        raise ValueError(f"single_sample: surfaces must be 'object' or 'mesh', not {params.surfaces!r}")
    labels = mesh_pieces(buffers.scene) if params.surfaces == "mesh" else None
    if labels is None:
        lv = buffers.light_view(light, params.map_size)
    else:
        lv = buffers.light_view(light, params.map_size, key="centre:mesh", tri_label=labels)
    if not len(lv.faces) or not g.hit.any():     # nothing the light view can see: lit
        return out.reshape(H, W).astype(np.float32), stats
    with timer("setup"):
        P = np.ascontiguousarray(g.position.reshape(-1, 3), np.float64)
        Nrm = np.ascontiguousarray(g.normal.reshape(-1, 3))
        hit = np.ascontiguousarray(g.hit.reshape(-1))
        faces = lv.packed_faces()
        finfo = face_info(lv, light)
        if labels is None:
            pid = np.ascontiguousarray(g.object_id.reshape(-1), np.int32)
            casts = np.array([o.casts_shadow for o in buffers.scene.objects], bool)
        else:             # the receiver's mesh piece; a piece casts iff its object does
            tri = g.triangle_id.reshape(-1)
            pid = np.ascontiguousarray(np.where(tri >= 0, labels[np.maximum(tri, 0)], -1), np.int32)
            casts = np.zeros(len(labels), bool)
            casts[labels] = buffers.scene.tri_casts_shadow
        nobj = max(len(casts), int(pid.max(initial=-1)) + 1, 1)
        in_map = np.zeros(nobj, np.bool_)
        in_map[:len(casts)] = casts
        prm = pack_params(params, light, hard_only, _coord_mag(buffers.scene, light))
        prm[P_MAXRAD] *= max(lv.depth.shape[1], lv.depth.shape[2]) / 256.0
        depth = np.ascontiguousarray(lv.depth, np.float32)
        ids = np.ascontiguousarray(lv.object_id, np.int32)
        rad = np.zeros(H * W, np.float64)
        vis = np.zeros(H * W, np.int64)
    n_hit = int(hit.sum())
    if prm[P_HARD] == 1.0 or not adaptive:
        with timer("hard" if prm[P_HARD] == 1.0 else "search"):
            tiles = tile_depth_range(depth, ids) if prm[P_HARD] == 0.0 else np.zeros((1, 1, 1, 3))
            sel = np.flatnonzero(hit).astype(np.int64)
            shade_all(P, Nrm, pid, sel, faces, finfo, depth, ids, tiles, in_map, prm, out, rad, vis)
        stats["searched"] = 0 if prm[P_HARD] == 1.0 else int(len(sel))
    else:
        with timer("hard"):
            hface = np.empty(H * W, np.int32)
            hinner = np.empty(H * W, np.int8)
            hid = np.empty(H * W, np.int32)
            hard_all(P, Nrm, hit, faces, depth, ids, prm, hface, hinner, hid, pid)
            b = max(1, int(params.block))
            colmarks = _marks(W, b)
            rowmarks = _marks(H, b)
            need = np.zeros(H * W, np.bool_)
            adaptive_walk(hface, hinner, hid, need, out, H, W, colmarks, rowmarks, False)
        with timer("search"):
            tiles = tile_depth_range(depth, ids)
            sel = np.flatnonzero(need & hit).astype(np.int64)
            shade_all(P, Nrm, pid, sel, faces, finfo, depth, ids, tiles, in_map, prm, out, rad, vis)
        with timer("interpolate"):
            adaptive_walk(hface, hinner, hid, need, out, H, W, colmarks, rowmarks, True)
        stats["searched"] = int(len(sel))
    if params.horizon and prm[P_HARD] == 0.0:
        with timer("horizon"):
            scale_by_horizon(light, P, Nrm, hit, out)
    out[~np.isfinite(out)] = 1.0
    np.clip(out, 0.0, 1.0, out=out)
    rad_sel = rad[sel]                # rad and vis are 0 but where searched (sel: hit pixels, in order)
    searched_rad = np.minimum(rad_sel[rad_sel > 0], prm[P_MAXRAD])
    stats.update({
        "searched_fraction": float(stats["searched"] / n_hit) if n_hit else 0.0,
        "mean_search_radius_texels": float(searched_rad.mean()) if searched_rad.size else 0.0,
        "clipped": int((rad_sel > prm[P_MAXRAD]).sum()),
        "texels_read": int(vis[sel].sum()),
        "faces": len(lv.faces),
        "map": [int(s) for s in lv.depth.shape],
        "hard_only": bool(prm[P_HARD] == 1.0),
    })
    return out.reshape(H, W).astype(np.float32), stats


@register
class SingleSampleSoftShadows(Method):
    id = "single_sample"
    paper = "Brabec, Seidel 2002"
    passes = {"single_sample": AVERAGE}
    needs = frozenset({GBUFFER, LIGHT_VIEW})
    Params = SingleSampleParams

    def run(self, buffers, light, params: SingleSampleParams) -> MethodResult:
        timer = PhaseTimer()
        v, stats = single_sample_visibility(buffers, light, params, timer=timer)
        return MethodResult(passes={"single_sample": v}, time_s=timer.result(), stats=stats)
