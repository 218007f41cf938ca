"""Percentage-closer filtering (Reeves, Salesin, Cook 1987), method id ``pcf``.

One depth map from the light centre (``LIGHT_VIEW``). Each camera pixel's
shading region (its footprint on the surface's tangent plane) is mapped into
the depth map; its bounding box, enlarged by ``ResFactor`` and at least
``MinSize`` texels, is split into ns x nt cells (section 3.2 / figure 4: at
least ``MinSamples`` per axis, about ``NumSamples`` in all), each sampled with
jitter (figure 3c); every sample compares the receiver's light-space depth with
the map plus a bias drawn in [Bias0, Bias1]. V = 1 - (samples in shadow) / (ns nt).
Regions outside the map's bounding box of finite depths are lit (3.3); the
map's window is fitted to the visible receivers (not the light's field of
view), so samples past its border read the border texel.

Departures from figure 4, each a fix of the listing rather than a new idea:
  * the listing clamps ``ns`` before computing it in the large-region branch;
    here ns = NumSamples / nt is computed, then clamped;
  * the listing jitters by ``Rand() * js`` (half a cell, one side), which
    shifts every sample by +ds/4; here each sample is jittered over its whole
    cell, as section 2's method (c) describes.
Beyond the paper (its 4.2 trades Moire self-shadowing against shifted shadow
boundaries through Bias): with ``receiver_plane`` each sample compares the map
with the depth of the receiver's tangent plane along the same light ray
(through the sample texel's centre, where the map's own ray went), not with the
region centre's z. A flat receiver then never shadows itself whatever the
region size or slope; Bias0/Bias1 are left for curvature. Off = figure 4.
Sizes are in map texels: ``sres`` is half the width of the footprint's box.
Depth in the map and of the receiver is -z in the light's view space.
Point lights use cube faces: a region that crosses a face edge samples only
the face holding the pixel's centre (texels beyond count as lit).
With ``region="figure4"`` the pass is an *average visibility*-like filter,
not a physical penumbra: its width follows ResFactor and the pixel footprint,
not the light's size (the paper's own limit: its regions anti-alias a point
light's shadow edge).

Beyond the paper, ``region="light"`` (the default; issue 18): the region's
width follows the light's size, as in percentage-closer soft shadows
(Fernando 2005). A blocker search first takes ``BlockerSamples`` jittered
samples over the region that light rays from the receiver can cross: a
planar light of half extent L (in the map's view plane) seen from a receiver
at depth z_r covers, at depth z_b, L (z_r - z_b) / (z_r z_b) view-plane
units around the receiver's own projection (exact for a light parallel to
the view's image plane, as an area light's view is; a sun's orthographic
view: tan(half angle) (z_r - z_b) scene units); the search takes for z_b
the face's nearest depth, then (``search="tiles"``, the default; "face":
the first version) the nearest depth the tiles hold in the region so far,
twice: a texel of depth d can block only within the reach at d, so the
narrowed region still holds every blocker. The samples nearer than the
receiver (the same comparison as the filter's, bias and ``receiver_plane``
included) give the
mean blocker depth, the filter region is the light's extent at that depth
(at least the figure-4 region), and it is sampled like figure 4 with
``PenumbraSamples`` samples. No blocker found: lit. The tile test runs on the
search region, and again on the filter region; both exact.

Beyond the paper, ``pixel_step`` (issue 15; 1 = the paper's region per
pixel; by default 2, and 4 on views of 1280 pixels or more across,
``auto_pixel_step``): the filter runs at the anchor pixels (row and column
multiples of the step), then in levels (``step_levels``: for a step of 4,
spacing 2, then 1): a pixel of a finer lattice between anchors of the
coarser one that lie on its surface (object, normal, tangent plane) takes
their bilinear V when it spans at most ``step_tolerance`` and does not mix
a decided V (umbra 0, lit 1) with another; everywhere else (a silhouette,
a shadow edge sharper than the tolerance) it is filtered itself. A
light-sized region is many pixels wide, so V is smooth between anchors; the
blend averages their sampling noise (RMSE against embree equal or lower at
1080p on grids and sphere_plane; at 128 and 256, the study's, within
0.0011 of one level at a tolerance of 0.1 on the six sample scenes). At 1080p on grids the filter went 0.53 -> 0.28 s from one
level at a step of 2 with a tolerance of 0.1 (the noise of 64 samples alone
spans 0.1 between four anchors: a quarter of the pixels between them were
filtered again). The Preview's ``step_fill="copy"`` shares the block's
first V instead.

The tile test (3.3's tiles, a min / max depth per 8 x 8 block) also keeps a
plane per block (``tile_planes``): a receiver on a surface slanted to the
light is behind the tiles' min depth but on their plane, which decides it
lit without samples (``planar_lit``; the same pass, issue 15).
"""
from __future__ import annotations

import math
from collections import namedtuple
from dataclasses import dataclass
from typing import Optional

import numpy as np
from numba import prange

from ... import views
from ...jit import inner, kernel
from ...kernels import borrowed, each_dealt_chunk, face_project, finite_bbox, pick_face
from ...sampling import stream_start, stream_word
from ..registry import register
from ..base import AVERAGE, GBUFFER, LIGHT_VIEW, Method, MethodResult, PhaseTimer

# Reeves et al.: "In worlds measuring 100 by 100 by 100 units, typical bias
# values we use are (0.3, 0.4)" -> 0.003 and 0.004 of the scene's size.
BIAS0_PER_EXTENT = 0.003
BIAS1_PER_EXTENT = 0.004
# The map holds float32 depths from Embree (hit error ~1e-7 relative): a
# receiver counts as behind a texel only beyond this relative margin, so a
# receiver-plane comparison of a surface with itself is not a coin toss.
DEPTH_REL_EPS = 1.0 + 1e-5


@dataclass
class PCFParams:
    NumSamples: int = 16          # paper: "We normally use a NumSamples of 16"
    ResFactor: float = 3.0        # paper: between 2 and 4 (figure 4 uses 3)
    MinSamples: int = 2           # paper: "typically ... 2 or 3"
    MinSize: float = 2.0          # paper: "MinSize to 2" (texels)
    Bias0: Optional[float] = None # scene units; None = 0.003 x FrameBuffers.light_extent
    Bias1: Optional[float] = None # scene units; None = 0.004 x FrameBuffers.light_extent
    map_size: Optional[int] = None  # depth map's larger side; None = views.default_map_size
    MaxSize: float = 64.0         # cap on the region's half size (texels), for grazing views
    receiver_plane: bool = True   # beyond the paper: compare each sample with the receiver's
                                  # tangent-plane depth at that texel, not the centre's z
    tiles: bool = True            # Reeves et al. 3.3's tile scheme: skip sampling where a tile's
                                  # min/max depth decides the whole region (same result)
    region: str = "light"         # "light": width from the light's size and the blocker / receiver
                                  # depths (PCSS, Fernando 2005; module doc) | "figure4": the paper's
    BlockerSamples: int = 16      # region="light": samples of the blocker search
    PenumbraSamples: int = 64     # region="light": samples of the filter region (NumSamples' role)
    pixel_step: int = 0           # beyond the paper (issue 15): V filtered at the anchor pixels, whose row and
                                  # column are multiples of it; the others take it from them (``step_fill``)
                                  # where they lie on the anchors' surface; 1 = every pixel filtered (the
                                  # paper's shading regions); 0 = by the view's size (``auto_pixel_step``).
                                  # Sub-pixel receivers (a packed G-buffer): the same over the supersampled
                                  # view's pixels they list ("copy": 1)
    step_fill: str = "interpolate"  # pixel_step > 1: "interpolate": a pixel takes its anchors' bilinear V when
                                  # they lie on its surface and their V spans at most ``step_tolerance``, else
                                  # is filtered itself | "copy" (the Preview's): the V of its block's first pixel
    step_tolerance: float = 0.2   # "interpolate": the largest span of the anchors' V that is interpolated
    seed: int = 0


@inner(forceinline=True)
def _grid(sres, tres, NumSamples, MinSamples):
    """Figure 4's ns x nt cells for a region of half sizes ``sres``, ``tres``
    (texels): one per texel up to ``NumSamples`` in all, at least
    ``MinSamples`` per axis."""
    if sres * tres * 4.0 < NumSamples:
        ns = int(sres * 2.0 + 0.5)
        ns = min(max(ns, MinSamples), NumSamples)
        nt = int(tres * 2.0 + 0.5)
        nt = min(max(nt, MinSamples), NumSamples)
    else:
        nt = int(math.sqrt(tres * NumSamples / sres) + 0.5)
        nt = min(max(nt, MinSamples), NumSamples)
        ns = int(NumSamples / nt + 0.5)
        ns = min(max(ns, MinSamples), NumSamples)
    return ns, nt


@inner(forceinline=True)
def _receiver_form(plane, z, u0, u1, v0, v1):
    """The receiver's depth over the texel centres [u0, u1] x [v0, v1] as
    a form the fast sampler compares without a division: (mode, a, b, c, k)
    with mode 0: the constant ``z`` (no plane); 1: a u + b v + c (an
    orthographic face); 2: k / (a u + b v + c) with k > 0 and a u + b v + c
    > 0 (a perspective face; ``plane_depth``'s own value, the sign folded
    into k); 3: ``plane_depth`` per sample (its fallbacks reached somewhere
    in the box). The form holds over the box when it holds at its corners:
    the denominator is affine, so it keeps one sign between them."""
    if plane[0] == 0.0:
        return 0, 0.0, 0.0, 0.0, z
    a, b, c = plane[2], plane[3], plane[4]
    k = plane[5]
    sg = 1.0 if k > 0.0 else -1.0
    for uc in (u0, u1):
        for vc in (v0, v1):
            den = a * uc + b * vc + c
            if plane[1] == 1.0:
                if not (den > 0.0) or not np.isfinite(den):
                    return 3, 0.0, 0.0, 0.0, z
            else:
                d = k / den
                if abs(den) < 1e-12 or not (d > 0.0) or not np.isfinite(d):
                    return 3, 0.0, 0.0, 0.0, z
    if plane[1] == 1.0:
        return 1, a, b, c, 0.0
    return 2, sg * a, sg * b, sg * c, sg * k


@inner(error_model="numpy")
def _region_samples(depth_f, bbox_f, s, t, z, sres, tres, ns, nt, seed, pixel, Bias0, Bias1, plane):
    """``_region_samples``' grid and test at a lower cost per sample (issue
    15): one 32-bit random word per sample split into the two jitters (11
    bits each: 1/2048 of a cell) and the bias (10 bits), and the
    receiver-plane depth compared by a multiplication (``_receiver_form``)
    instead of a division. The same distribution of samples, other
    random numbers."""
    ds = 2.0 * sres / ns
    dt = 2.0 * tres / nt
    s0 = s - sres
    t0 = t - tres
    h, w = depth_f.shape
    u0 = min(max(math.floor(s0), 0.0), w - 1.0) + 0.5
    u1 = min(max(math.floor(s + sres), 0.0), w - 1.0) + 0.5
    v0 = min(max(math.floor(t0), 0.0), h - 1.0) + 0.5
    v1 = min(max(math.floor(t + tres), 0.0), h - 1.0) + 0.5
    mode, a, b, c, k = _receiver_form(plane, z, u0, u1, v0, v1)
    fu = ds * (1.0 / 2048.0)
    fv = dt * (1.0 / 2048.0)
    fb = (Bias1 - Bias0) * (1.0 / 1024.0)
    bu0, bu1, bv0, bv1 = bbox_f[0], bbox_f[1], bbox_f[2], bbox_f[3]
    st = stream_start(seed, pixel)
    n = 0
    acc = 0.0
    for i in range(ns):
        su = s0 + i * ds
        for j in range(nt):
            st, wd = stream_word(st)
            iu = int(math.floor(su + np.float64(wd & np.uint32(2047)) * fu))
            iv = int(math.floor(t0 + j * dt + np.float64((wd >> np.uint32(11)) & np.uint32(2047)) * fv))
            iu = min(max(iu, 0), w - 1)
            iv = min(max(iv, 0), h - 1)
            if iu >= bu0 and iu <= bu1 and iv >= bv0 and iv <= bv1:
                d = np.float64(depth_f[iv, iu])
                thr = d * DEPTH_REL_EPS + (Bias0 + np.float64(wd >> np.uint32(22)) * fb)
                if mode == 2:
                    behind = k > thr * (a * (iu + 0.5) + b * (iv + 0.5) + c)
                elif mode == 1:
                    behind = a * (iu + 0.5) + b * (iv + 0.5) + c > thr
                elif mode == 0:
                    behind = z > thr
                else:
                    behind = plane_depth(plane, iu + 0.5, iv + 0.5, z) > thr
                n += 1 if behind else 0           # no branch: in a penumbra it is a coin toss
                acc += d if behind else 0.0
    return n, acc


@inner
def sample_shadow(depth_f, bbox_f, s, t, z, sres, tres, NumSamples, MinSamples,
                  Bias0, Bias1, seed, pixel, plane):
    """Reeves et al. figure 4 ``SampleShadow``: fraction of the region in
    shadow. ``s, t`` and ``sres, tres`` are already in texels (scaled).
    ``plane`` (from ``receiver_plane``) gives the receiver's depth at each
    sample's texel centre; ``plane[0] == 0`` keeps the paper's constant z."""
    if z < 0.0:
        return 0.0
    lu = math.floor(s - sres)
    hu = math.ceil(s + sres)
    lv = math.floor(t - tres)
    hv = math.ceil(t + tres)
    if lu > bbox_f[1] or hu < bbox_f[0] or lv > bbox_f[3] or hv < bbox_f[2]:
        return 0.0
    ns, nt = _grid(sres, tres, NumSamples, MinSamples)
    inshadow, _ = _region_samples(depth_f, bbox_f, s, t, z, sres, tres, ns, nt, seed, pixel, Bias0, Bias1, plane)
    return inshadow / (ns * nt)


@inner(forceinline=True)
def light_halfwidth(lsize, z, zb):
    """Half extents (texels) of the light as the rays from a receiver at
    depth ``z`` cross depth ``zb``: lsize = (ku, kv, ortho) from
    ``light_reach``; ku (z - zb) / (z zb) for a perspective face, ku (z - zb)
    for an orthographic one (region="light", module doc)."""
    dz = max(z - zb, 0.0)
    if lsize[2] == 1.0:
        return lsize[0] * dz, lsize[1] * dz
    q = dz / (z * max(zb, 1e-30 * z))
    return lsize[0] * q, lsize[1] * q


@inner
def blocker_depth(depth_f, bbox_f, s, t, z, sres, tres, BlockerSamples, Bias0, Bias1, seed, pixel, plane):
    """region="light"'s blocker search (Fernando 2005): the mean map depth of
    the samples (figure 4's grid of about ``BlockerSamples`` jittered cells
    on the region) that the receiver is behind (``sample_shadow``'s test);
    0.0 when there is none."""
    ns, nt = _grid(sres, tres, BlockerSamples, np.int64(1))
    n, acc = _region_samples(depth_f, bbox_f, s, t, z, sres, tres, ns, nt, seed, pixel, Bias0, Bias1, plane)
    return acc / n if n else 0.0


def light_reach(light, faces) -> np.ndarray:
    """float64[F, 3] per face: (ku, kv, ortho), the light's half extents along
    the face's u and v over the texel size (a perspective face: view-plane
    units at unit depth; a sun's orthographic face: tan(half angle) per unit
    of depth), for ``light_halfwidth``. An area light's rectangle (a disk's
    or ellipse's bounding one) is turned into the view's axes; a sphere
    light's facing disk has its radius on both; zero for a light of size zero."""
    out = np.zeros((len(faces), 3), np.float64)
    for k, face in enumerate(faces):
        rot = np.asarray(face.view_from_world, np.float64)[:3, :3]
        l, r, b, t = face.bounds
        tu, tv = (r - l) / face.width, (t - b) / face.height
        if light.kind == "area":
            ax, ay, _ = light.axes
            hx, hy = light.half_size
            ex, ey = rot @ (ax * hx), rot @ (ay * hy)
            half = (abs(ex[0]) + abs(ey[0]), abs(ex[1]) + abs(ey[1]))
        elif light.kind == "sphere":
            half = (light.radius, light.radius)
        else:
            half = (light.sun_spread, light.sun_spread)
        out[k] = (half[0] / tu, half[1] / tv, 1.0 if face.ortho else 0.0)
    return out


def pixel_ray_terms(cp) -> np.ndarray:
    """The camera's rays through float pixel (c, r) as affine functions:
    origin = o0 + c oc + r orr, direction = d0 + c dc + r dr (unnormalised),
    rows (o0, oc, orr, d0, dc, dr) of a float64[6, 3], from ``pack_camera``'s
    layout."""
    R = np.array([cp[0], cp[3], cp[6]])
    U = np.array([cp[1], cp[4], cp[7]])
    B = np.array([cp[2], cp[5], cp[8]])
    eye = np.array([cp[9], cp[10], cp[11]])
    per_c = R * (cp[13] - cp[12]) / cp[17]
    per_r = -U * (cp[15] - cp[14]) / cp[18]
    corner = R * cp[12] + U * cp[15]
    zero = np.zeros(3)
    if cp[16] == 1.0:
        rows = (eye + corner, per_c, per_r, -B, zero, zero)
    else:
        rows = (eye, zero, zero, corner - B, per_c, per_r)
    return np.ascontiguousarray(np.array(rows, np.float64))


@inner
def pixel_footprint(rt, fp, col, row, px, py, pz, nx, ny, nz, u0, v0, max_half):
    """Half extents (in face texels) of the bounding box of camera pixel
    (col, row)'s four corners, carried along their camera rays onto the
    tangent plane through P (normal n) and projected into face ``fp``: the
    shading region of Reeves et al. figure 4 (its "transform pixel region to
    shadow map space"). Corners whose ray misses the plane (grazing) or that
    fall behind the light give ``max_half``. The rays' affine terms ``rt``
    (``pixel_ray_terms``) leave two divisions per corner."""
    su = fp[21] / (fp[18] - fp[17])
    sv = fp[22] / (fp[20] - fp[19])
    hu = 0.0
    hv = 0.0
    for k in range(4):
        c = col + (1.0 if k & 1 else 0.0)
        r = row + (1.0 if k & 2 else 0.0)
        ox = rt[0, 0] + c * rt[1, 0] + r * rt[2, 0]
        oy = rt[0, 1] + c * rt[1, 1] + r * rt[2, 1]
        oz = rt[0, 2] + c * rt[1, 2] + r * rt[2, 2]
        dx = rt[3, 0] + c * rt[4, 0] + r * rt[5, 0]
        dy = rt[3, 1] + c * rt[4, 1] + r * rt[5, 1]
        dz = rt[3, 2] + c * rt[4, 2] + r * rt[5, 2]
        den = dx * nx + dy * ny + dz * nz
        if abs(den) < 1e-12 * (abs(dx) + abs(dy) + abs(dz)):
            return max_half, max_half
        t = ((px - ox) * nx + (py - oy) * ny + (pz - oz) * nz) / den
        if not (t > 0.0):
            return max_half, max_half
        x = ox + t * dx
        y = oy + t * dy
        z = oz + t * dz
        vx = fp[0] * x + fp[1] * y + fp[2] * z + fp[3]
        vy = fp[4] * x + fp[5] * y + fp[6] * z + fp[7]
        if fp[16] == 0.0:
            depth = -(fp[8] * x + fp[9] * y + fp[10] * z + fp[11])
            if not (depth > 0.0):
                return max_half, max_half
            inv = 1.0 / depth
            vx *= inv
            vy *= inv
        u = (vx - fp[17]) * su
        v = (fp[20] - vy) * sv
        if not (np.isfinite(u) and np.isfinite(v)):
            return max_half, max_half
        hu = max(hu, abs(u - u0))
        hv = max(hv, abs(v - v0))
    return min(hu, max_half), min(hv, max_half)


NO_PLANE = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)   # figure 4's constant receiver depth


@inner
def receiver_plane(fp, px, py, pz, nx, ny, nz):
    """The receiver's tangent plane in face ``fp``'s view space, as a function
    of the texel position (u, v), packed for ``plane_depth``:
    (1, ortho, A, B, C, K) with depth = K / (A u + B v + C) for a perspective
    face and depth = A u + B v + C for an orthographic one (the view-space
    plane n.x = n.p along the ray through the texel, solved once per pixel, so
    each sample costs one division). ``NO_PLANE`` (the point's own depth
    everywhere) when the plane holds the orthographic view direction."""
    vx = fp[0] * px + fp[1] * py + fp[2] * pz + fp[3]
    vy = fp[4] * px + fp[5] * py + fp[6] * pz + fp[7]
    vz = fp[8] * px + fp[9] * py + fp[10] * pz + fp[11]
    mx = fp[0] * nx + fp[1] * ny + fp[2] * nz
    my = fp[4] * nx + fp[5] * ny + fp[6] * nz
    mz = fp[8] * nx + fp[9] * ny + fp[10] * nz
    npv = mx * vx + my * vy + mz * vz
    # view-space x = l + u (r - l) / w, y = t - v (t - b) / h
    A = mx * (fp[18] - fp[17]) / fp[21]
    B = -my * (fp[20] - fp[19]) / fp[22]
    C = mx * fp[17] + my * fp[20]
    if fp[16] == 1.0:
        if abs(mz) < 1e-12:        # the view direction lies in the plane
            return NO_PLANE
        return (1.0, 1.0, A / mz, B / mz, (C - npv) / mz, 0.0)
    return (1.0, 0.0, A, B, C - mz, npv)


@inner(forceinline=True)
def plane_depth(pl, uc, vc, z):
    """Depth of the receiver's tangent plane along the ray through texel
    centre (uc, vc); ``z`` (the point's own depth) where the ray runs along
    the plane (grazing) or meets it behind the light."""
    if pl[1] == 1.0:
        d = pl[2] * uc + pl[3] * vc + pl[4]
    else:
        den = pl[2] * uc + pl[3] * vc + pl[4]
        if abs(den) < 1e-12:
            return z
        d = pl[5] / den
    if not (d > 0.0) or not np.isfinite(d):
        return z
    return d


TILE = 8
PLANAR_BLOCKS = 16   # blocks a region may span for ``planar_lit``
SEARCH_STEPS = 2     # search="tiles": narrowing steps of the blocker search region (``search_region``)
AUTO_STEP4_SIDE = 1280  # ``auto_pixel_step``: views at least this wide (or tall) take anchors 4 pixels apart
PIXEL_TILE = 32      # camera pixels per side of a tile of ``pcf_kernel`` (``filter_pixels``)
PIXEL_STEP_COS = 0.95   # ``pixel_step``: normals at most ~18 degrees apart share a V
PIXEL_STEP_SLOPE = 0.2  # ``step_fill="interpolate"``: a pixel lies on an anchor's surface when its offset from
                        # the anchor leaves the anchor's tangent plane by at most this fraction of its length
PIXEL_BLOCK = 1024   # entries of a packed G-buffer dealt together to a chunk of ``pcf_kernel``

# argument groups of ``pcf_kernel``
CameraPixels = namedtuple("CameraPixels", "P Nrm hit obj width rays pixel")
"""G-buffer positions, normals, hit flags and object ids (row-major, ``width`` wide), the
camera's per-pixel ray terms (``pixel_ray_terms``) and, for a packed G-buffer
(``GBuffer.pixel``), each entry's camera pixel (int64[N]; empty: entry i is
pixel i)."""
ShadowMap = namedtuple("ShadowMap", "faces depth bbox tiles planes lsize zmin")
"""Packed light-view faces, their depth maps, finite-depth boxes, the
per-tile depth min / max as sparse tables (``tile_tables``) and planes
(``tile_planes``), per face the light's reach
(``light_reach``: float64[F, 3]) and nearest depth (float64[F])."""
Filter = namedtuple("Filter", "ResFactor MinSize MaxSize NumSamples MinSamples Bias0 Bias1 seed use_plane use_tiles "
                              "light_region BlockerSamples PenumbraSamples pixel_step interpolate step_tolerance")
"""The filter's parameters (the paper's names), ``receiver_plane``, ``tiles``
and ``region="light"``'s switch, sample counts and search-region steps
(``search``: SEARCH_STEPS, or 0 for "face"), ``pixel_step``, whether its
other pixels are interpolated (``step_fill``) and ``step_tolerance``."""


@kernel(nogil=True)
def tile_minmax(depth):
    """Per face, per TILE x TILE block: min and max map depth (Reeves et al.
    3.3's tile scheme, "a maximum z value with each tile"). Serial: a few ms
    for a 1920 map, less than a parfor's compile."""
    F, h, w = depth.shape
    th = (h + TILE - 1) // TILE
    tw = (w + TILE - 1) // TILE
    lo = np.full((F, th, tw), np.inf, np.float32)
    hi = np.full((F, th, tw), -np.inf, np.float32)
    for k in range(F * th):
        f = k // th
        ty = k % th
        for tx in range(tw):
            a, b = np.inf, -np.inf
            for r in range(ty * TILE, min(h, ty * TILE + TILE)):
                for c in range(tx * TILE, min(w, tx * TILE + TILE)):
                    d = depth[f, r, c]
                    a = min(a, d)
                    b = max(b, d)
            lo[f, ty, tx] = a
            hi[f, ty, tx] = b
    return lo, hi


@kernel(nogil=True)
def tile_planes(depth, ortho):
    """Per face, per full TILE x TILE block: the least-squares plane through
    its texels, float64[F, th, tw, 4] (a, b, c, r): at texel centre (u, v)
    the map holds w = a (u - cu) + b (v - cv) + c within r, (cu, cv) the
    block's centre, w = 1 / depth on a perspective face (a plane's 1 / depth
    is affine in the texel position), w = depth on an orthographic one
    (``ortho[f]``). r = inf for blocks that hold an empty texel or run past
    the map (``region_decided``'s planar test skips them)."""
    F, h, w = depth.shape
    th = (h + TILE - 1) // TILE
    tw = (w + TILE - 1) // TILE
    out = np.empty((F, th, tw, 4), np.float64)
    sxx = 0.0
    for k in range(TILE):
        x = k + 0.5 - 0.5 * TILE
        sxx += x * x
    sxx *= TILE
    for f in range(F):
        for ty in range(th):
            for tx in range(tw):
                out[f, ty, tx, 0], out[f, ty, tx, 1], out[f, ty, tx, 2], out[f, ty, tx, 3] = 0.0, 0.0, 0.0, np.inf
                if (ty + 1) * TILE > h or (tx + 1) * TILE > w:
                    continue
                sw = 0.0
                sxw = 0.0
                syw = 0.0
                full = True
                for r in range(TILE):
                    for c in range(TILE):
                        d = np.float64(depth[f, ty * TILE + r, tx * TILE + c])
                        if not (d > 0.0 and d < np.inf):
                            full = False
                            break
                        v = d if ortho[f] else 1.0 / d
                        sw += v
                        sxw += (c + 0.5 - 0.5 * TILE) * v
                        syw += (r + 0.5 - 0.5 * TILE) * v
                    if not full:
                        break
                if not full:
                    continue
                a = sxw / sxx
                b = syw / sxx
                c0 = sw / (TILE * TILE)
                res = 0.0
                for r in range(TILE):
                    for c in range(TILE):
                        d = np.float64(depth[f, ty * TILE + r, tx * TILE + c])
                        v = d if ortho[f] else 1.0 / d
                        res = max(res, abs(v - (a * (c + 0.5 - 0.5 * TILE) + b * (r + 0.5 - 0.5 * TILE) + c0)))
                out[f, ty, tx, 0], out[f, ty, tx, 1], out[f, ty, tx, 2], out[f, ty, tx, 3] = a, b, c0, res
    return out


def _levels(n: int) -> int:
    """Sparse-table levels over n tiles: 2^k <= n for k < levels."""
    return max(1, int(n).bit_length())


def tile_tables(lo, hi, span=None):
    """Sparse tables of the per-tile min / max (``tile_minmax``): float32[F,
    KY, KX, th, tw, 2], entry [f, ky, kx, y, x] the (min, max) over the tiles
    [y, y + 2^ky) x [x, x + 2^kx), so ``tile_range`` reads the min / max over
    any block of tiles in four lookups (the same values as a loop over the
    tiles: min and max are exact); blocks of at most ``span`` tiles a side
    (default: any). Each entry's min sits beside its max, so a lookup reads
    one cache line for both (issue 15: the lookups missed the cache, 28 % of
    the filter's time)."""
    F, th, tw = lo.shape
    ky, kx = _levels(th), _levels(tw)
    if span is not None:
        ky, kx = min(ky, _levels(span)), min(kx, _levels(span))
    tt = np.empty((F, ky, kx, th, tw, 2), np.float32)
    _fill_tables(lo, hi, tt)
    return tt


@kernel(nogil=True)
def _fill_tables(lo, hi, tt):
    """``tile_tables``' levels: along x, then along y (entries whose block
    runs past the grid repeat the last valid one; ``tile_range`` never reads
    them). Scalar loops only: a slice assignment here compiled Numba's
    broadcasting machinery, 3 s of pcf's cold start (issue 15)."""
    F, KY, KX, th, tw, _ = tt.shape
    for f in range(F):
        for y in range(th):
            for x in range(tw):
                tt[f, 0, 0, y, x, 0] = lo[f, y, x]
                tt[f, 0, 0, y, x, 1] = hi[f, y, x]
        for kx in range(1, KX):
            step = 1 << (kx - 1)
            for y in range(th):
                for x in range(tw):
                    x2 = min(x + step, tw - 1)
                    tt[f, 0, kx, y, x, 0] = min(tt[f, 0, kx - 1, y, x, 0], tt[f, 0, kx - 1, y, x2, 0])
                    tt[f, 0, kx, y, x, 1] = max(tt[f, 0, kx - 1, y, x, 1], tt[f, 0, kx - 1, y, x2, 1])
        for ky in range(1, KY):
            step = 1 << (ky - 1)
            for kx in range(KX):
                for y in range(th):
                    y2 = min(y + step, th - 1)
                    for x in range(tw):
                        tt[f, ky, kx, y, x, 0] = min(tt[f, ky - 1, kx, y, x, 0], tt[f, ky - 1, kx, y2, x, 0])
                        tt[f, ky, kx, y, x, 1] = max(tt[f, ky - 1, kx, y, x, 1], tt[f, ky - 1, kx, y2, x, 1])


@inner(forceinline=True)
def _floor_log2(n):
    k = 0
    while (2 << k) <= n:
        k += 1
    return k


@inner
def tile_range(tt, ty0, ty1, tx0, tx1):
    """(min, max) map depth over the tiles [ty0, ty1] x [tx0, tx1] of one
    face's sparse tables (``tile_tables``): four overlapping power-of-two
    blocks that cover the range exactly."""
    ky = _floor_log2(ty1 - ty0 + 1)
    kx = _floor_log2(tx1 - tx0 + 1)
    ya, yb = ty0, ty1 - (1 << ky) + 1
    xa, xb = tx0, tx1 - (1 << kx) + 1
    dmin = min(min(tt[ky, kx, ya, xa, 0], tt[ky, kx, ya, xb, 0]), min(tt[ky, kx, yb, xa, 0], tt[ky, kx, yb, xb, 0]))
    dmax = max(max(tt[ky, kx, ya, xa, 1], tt[ky, kx, ya, xb, 1]), max(tt[ky, kx, yb, xa, 1], tt[ky, kx, yb, xb, 1]))
    return dmin, dmax


@inner(forceinline=True)
def _texel_box(w, h, s, t, sres, tres):
    """The texels [u0, u1) x [v0, v1) a region's samples can read (clamped
    to the map; at least one texel)."""
    u0 = max(0.0, math.floor(s - sres))
    u1 = min(float(w), math.ceil(s + sres))
    v0 = max(0.0, math.floor(t - tres))
    v1 = min(float(h), math.ceil(t + tres))
    if u1 <= u0:
        u0, u1 = min(u0, w - 1.0), min(u0, w - 1.0) + 1.0
    if v1 <= v0:
        v0, v1 = min(v0, h - 1.0), min(v0, h - 1.0) + 1.0
    return u0, u1, v0, v1


@inner
def region_decided(tt, planes, ortho, w, h, s, t, z, sres, tres, plane, Bias0, Bias1):
    """The tile test: 0.0 when every sample of the region must be lit, 1.0
    when every one must be in shadow, -1.0 when samples must be taken. Exact:
    the receiver's depth over the region lies between its values at the
    region's corners (a linear-fractional function of the texel position).
    ``tt``: one face's sparse tables (``tile_tables``), so the
    test costs the same for a region of any size; ``planes``: its blocks'
    planes (``tile_planes``) for ``planar_lit`` where the min / max do not
    decide (a receiver on a surface slanted to the light)."""
    u0, u1, v0, v1 = _texel_box(w, h, s, t, sres, tres)
    zlo, zhi = z, z
    if plane[0] != 0.0:
        for cu in (u0, u1):
            for cv in (v0, v1):
                zc = plane_depth(plane, cu, cv, -1.0)
                if zc < 0.0:
                    return -1.0
                zlo = min(zlo, zc)
                zhi = max(zhi, zc)
    dmin, dmax = tile_range(tt, int(v0) // TILE, (int(v1) - 1) // TILE,
                            int(u0) // TILE, (int(u1) - 1) // TILE)
    if zhi <= dmin * DEPTH_REL_EPS + Bias0:
        return 0.0
    if dmax < np.inf and zlo > dmax * DEPTH_REL_EPS + Bias1:
        return 1.0
    if planar_lit(tt, planes, ortho, u0, u1, v0, v1, z, zhi, plane, Bias0):
        return 0.0
    return -1.0


@inner(error_model="numpy")
def planar_lit(tt, planes, ortho, u0, u1, v0, v1, z, zhi, plane, Bias0):
    """Whether no sample of texels [u0, u1) x [v0, v1) can be behind the map
    (``region_decided``'s lit case), block by block (at most PLANAR_BLOCKS):
    a block passes its min depth test, or its plane (``tile_planes``) stays
    within half the smallest margin (Bias0 + the relative epsilon) of the
    receiver's tangent plane (``plane``; ``z`` everywhere without one) over
    the texel centres it shares with the region. On a perspective face both
    1 / depth are affine in the texel position, so their difference peaks at
    a corner, and zs - d = zs d (1/d - 1/zs) <= zhi dmax (that peak + r);
    on an orthographic one the depths themselves are affine. Exact, as the
    min / max test: only a receiver on (or in front of) the blocks' surfaces
    passes, where every sample would be lit."""
    ty0, ty1 = int(v0) // TILE, (int(v1) - 1) // TILE
    tx0, tx1 = int(u0) // TILE, (int(u1) - 1) // TILE
    if (ty1 - ty0 + 1) * (tx1 - tx0 + 1) > PLANAR_BLOCKS:
        return False
    if plane[0] == 0.0:
        ra, rb, rc = 0.0, 0.0, (z if ortho else 1.0 / z)
    elif plane[1] == 1.0:
        ra, rb, rc = plane[2], plane[3], plane[4]
    else:
        ra, rb, rc = plane[2] / plane[5], plane[3] / plane[5], plane[4] / plane[5]
    half = 0.5 * TILE
    for ty in range(ty0, ty1 + 1):
        for tx in range(tx0, tx1 + 1):
            dmin = tt[0, 0, ty, tx, 0]
            if zhi <= dmin * DEPTH_REL_EPS + Bias0:
                continue
            pa, pb, pc, pr = planes[ty, tx, 0], planes[ty, tx, 1], planes[ty, tx, 2], planes[ty, tx, 3]
            if not (pr < np.inf):
                return False
            cu0 = max(u0, float(tx * TILE)) + 0.5
            cu1 = min(u1, float(tx * TILE + TILE)) - 0.5
            cv0 = max(v0, float(ty * TILE)) + 0.5
            cv1 = min(v1, float(ty * TILE + TILE)) - 0.5
            peak = -np.inf
            for cu in (cu0, cu1):
                for cv in (cv0, cv1):
                    fit = pa * (cu - tx * TILE - half) + pb * (cv - ty * TILE - half) + pc
                    rec = ra * cu + rb * cv + rc
                    peak = max(peak, rec - fit if ortho else fit - rec)
            peak += pr
            excess = peak if ortho else zhi * np.float64(tt[0, 0, ty, tx, 1]) * max(peak, 0.0)
            if not (excess <= 0.5 * (Bias0 + dmin * (DEPTH_REL_EPS - 1.0))):
                return False
    return True


@inner
def search_region(tt, w, h, s, t, z, lsize, zmin, sres, tres, MaxSize, steps):
    """region="light"'s blocker search region (half sizes, texels): the
    light's reach (``light_halfwidth``) at the nearest depth ``zmin`` of the
    face, at least the figure-4 region (``sres``, ``tres``), at most
    ``MaxSize``; then ``steps`` times (``search="tiles"``) the reach at the
    nearest depth the tiles hold inside the region so far. Exact: a texel of
    depth d blocks a ray from the receiver to the light only within the
    reach at d, which shrinks as d grows, so every such texel stays inside."""
    zs = zmin
    ws, wt = light_halfwidth(lsize, z, zs)
    ws = min(max(ws, sres), MaxSize)
    wt = min(max(wt, tres), MaxSize)
    for _ in range(steps):
        u0, u1, v0, v1 = _texel_box(w, h, s, t, ws, wt)
        dmin, _ = tile_range(tt, int(v0) // TILE, (int(v1) - 1) // TILE,
                             int(u0) // TILE, (int(u1) - 1) // TILE)
        if not (dmin > zs):
            break
        zs = dmin
        ws2, wt2 = light_halfwidth(lsize, z, min(zs, z))
        ws = min(max(ws2, sres), ws)
        wt = min(max(wt2, tres), wt)
    return ws, wt


def filter_pixels(cam, smap, flt, out, height, threads=None) -> None:
    """V into ``out`` for every camera pixel (``pcf_kernel``) on Numba's
    thread count, the job's cancel token checked before each chunk
    (``kernels.each_dealt_chunk``): a dense G-buffer (``height`` rows of
    ``cam.width``) in tiles of PIXEL_TILE x PIXEL_TILE pixels, whose regions
    lie close together in the map (rows of a 1080p frame sweep the whole
    map: samples then miss the cache), dealt over the chunks (sky and ground
    differ widely in cost); a packed one in blocks of PIXEL_BLOCK entries.
    step_fill="interpolate": one pass per level of ``step_levels``."""
    packed = cam.pixel.shape[0] > 0
    tile = 0 if packed else PIXEL_TILE
    n = out.shape[0] if packed else -(-cam.width // PIXEL_TILE) * -(-height // PIXEL_TILE)
    block = PIXEL_BLOCK if packed else 1
    for stage in step_levels(flt.pixel_step, flt.interpolate):
        each_dealt_chunk(lambda idx: pcf_kernel(idx, tile, height, stage, cam, smap, flt, out), n, threads,
                         block=block)


def auto_pixel_step(width: int, height: int) -> int:
    """``pixel_step=0``'s step for a ``width`` x ``height`` view: 4 from
    AUTO_STEP4_SIDE pixels on its larger side (a light-sized penumbra spans
    twice the pixels of a view half the size), else 2."""
    return 4 if max(width, height) >= AUTO_STEP4_SIDE else 2


def step_levels(pixel_step: int, interpolate: bool):
    """``pcf_kernel``'s stages, in order: step_fill="interpolate" with
    ``pixel_step`` 2^k > 1: the anchor lattice's spacing 2^k, then each
    finer spacing down to 1 (2^k, ..., 2, 1); otherwise one stage, 0 (every
    pixel; "copy": the block's first pixel before the others)."""
    if pixel_step > 1 and interpolate:
        return [pixel_step >> k for k in range(int(pixel_step).bit_length())]
    return [0]


@kernel(nogil=True, error_model="numpy")
def pcf_kernel(idx, tile, height, stage, cam, smap, flt, out):
    """V into out[i] for every camera pixel i (row-major, ``cam.width`` wide)
    in the tiles ``idx`` of ``tile`` x ``tile`` pixels (row-major over the
    ``height``-row image), or, with ``tile`` 0, every entry i in ``idx`` (a
    packed G-buffer: entry i is pixel ``cam.pixel[i]``), where
    ``cam.hit[i]``; other pixels are left as they are. ``stage`` (a dense
    G-buffer, pixel_step > 1, step_fill="interpolate"; ``step_levels``):
    a spacing s; s = pixel_step filters the anchors (row and column
    multiples of s); a smaller s does the pixels of the s-lattice that are
    not on the 2s-lattice (every 2s-lattice pixel is done by then): the
    blend of their 2s-lattice anchors (``_interpolated``) where it can, else
    filtered. 0: every pixel (step_fill="copy": the block's first pixel,
    done before the others of its tile, is shared). A serial ``nogil``
    kernel with ``kernels.borrowed`` arguments (issue 15: no parfor to
    compile), run on worker threads by ``filter_pixels``; each pixel's V
    depends on its own stream and its anchors only, so the result does not
    depend on the order, the chunks or the thread count. cam: CameraPixels;
    smap: ShadowMap; flt: Filter."""
    cam, smap, flt, out = borrowed((cam, smap, flt, out))
    W = cam.width
    tw = (W + tile - 1) // tile if tile else 1
    step = flt.pixel_step if tile or flt.interpolate else 1
    for k in idx:
        if tile:
            ra, ca = (k // tw) * tile, (k % tw) * tile
            rb, cb = min(ra + tile, height), min(ca + tile, W)
        else:                         # a packed entry: one "row" of one
            ra, rb, ca, cb = 0, 1, k, k + 1
        for r in range(ra, rb):
            for c in range(ca, cb):
                i = r * W + c if tile else c
                if step > 1 and cam.hit[i]:
                    pr, pc = (r, c) if tile else (cam.pixel[i] // W, cam.pixel[i] % W)   # its view pixel
                    if stage == 0:
                        if pr % step or pc % step:
                            j = (r - r % step) * W + (c - c % step)     # the block's first pixel: done before
                            if _same_surface(cam, i, j):
                                out[i] = out[j]
                                continue
                    elif pr % stage or pc % stage:
                        continue                  # a finer level's pixel
                    elif stage < step:
                        up = 2 * stage            # this level's anchors: the coarser lattice, done before
                        if (pr % up == 0 and pc % up == 0) or _interpolated(cam, out, i, pr, pc, up, height,
                                                                           flt.step_tolerance):
                            continue
                _pcf_pixel(i, cam, smap, flt, out)     # inlined by LLVM


@inner(forceinline=True)
def _on_anchor_surface(cam, i, j):
    """``step_fill="interpolate"``: anchor j's V stands for pixel i's surface
    (``_same_surface``, and i's offset from j within PIXEL_STEP_SLOPE of j's
    tangent plane: not the same object seen again behind a fold)."""
    if not _same_surface(cam, i, j):
        return False
    dx, dy, dz = cam.P[i, 0] - cam.P[j, 0], cam.P[i, 1] - cam.P[j, 1], cam.P[i, 2] - cam.P[j, 2]
    off = abs(dx * cam.Nrm[j, 0] + dy * cam.Nrm[j, 1] + dz * cam.Nrm[j, 2])
    return off <= PIXEL_STEP_SLOPE * math.sqrt(dx * dx + dy * dy + dz * dz)


@inner(forceinline=True)
def _entry(cam, p):
    """The entry of view pixel ``p``: itself in a dense G-buffer; in a packed
    one (``cam.pixel``, ascending) its index, or -1 when it is not listed."""
    n = cam.pixel.shape[0]
    if n == 0:
        return p
    lo, hi = 0, n                 # a binary search (np.searchsorted's overload cost 0.5 s to compile)
    while lo < hi:
        mid = (lo + hi) >> 1
        if cam.pixel[mid] < p:
            lo = mid + 1
        else:
            hi = mid
    if lo < n and cam.pixel[lo] == p:
        return lo
    return -1


@inner(forceinline=True)
def _interpolated(cam, out, i, r, c, step, height, tol):
    """``step_fill="interpolate"``: out[i] = the bilinear blend of the
    anchors around view pixel (r, c) (those of non-zero weight: 2 on an
    anchor row or column, else 4) that are entries (a packed G-buffer's
    sub-pixel receivers: listed) on its surface (``_on_anchor_surface``),
    their weights renormalised, when there are at least 2 of them holding
    at least half the weight (a pixel beside a silhouette blends the
    anchors on its own side: issue 15, a tenth of the pixels between
    anchors on grids at 1080p) and their V spans at most ``tol`` without
    mixing a decided V (0: umbra, 1: lit, exact) with another; False (out[i]
    untouched) otherwise, or past the view's last anchor row or column."""
    W = cam.width
    r0, c0 = r - r % step, c - c % step
    fr, fc = (r - r0) / step, (c - c0) / step
    r1 = r0 + step if r > r0 else r0
    c1 = c0 + step if c > c0 else c0
    if r1 >= height or c1 >= W:
        return False
    lo, hi, acc, wsum, used = np.inf, -np.inf, 0.0, 0.0, 0
    for q in range(4):
        wr = fr if q & 2 else 1.0 - fr
        wc = fc if q & 1 else 1.0 - fc
        if wr * wc == 0.0:
            continue
        j = _entry(cam, (r1 if q & 2 else r0) * W + (c1 if q & 1 else c0))
        if j < 0 or not _on_anchor_surface(cam, i, j):
            continue
        v = np.float64(out[j])
        lo, hi = min(lo, v), max(hi, v)
        acc += wr * wc * v
        wsum += wr * wc
        used += 1
    if used < 2 or wsum < 0.5:
        return False
    if hi - lo > tol or (hi > lo and (lo == 0.0 or hi == 1.0)):
        return False            # a sharp edge, or the border of a decided umbra or lit region
    out[i] = acc / wsum
    return True


@inner(forceinline=True)
def _same_surface(cam, i, j):
    """``pixel_step``: pixel j's V stands for pixel i's (both hit the same
    object, normals within PIXEL_STEP_COS)."""
    if not cam.hit[j] or cam.obj[i] != cam.obj[j]:
        return False
    dot = cam.Nrm[i, 0] * cam.Nrm[j, 0] + cam.Nrm[i, 1] * cam.Nrm[j, 1] + cam.Nrm[i, 2] * cam.Nrm[j, 2]
    return dot >= PIXEL_STEP_COS


@inner(forceinline=True)
def _pcf_pixel(i, cam, smap, flt, out):
    """``pcf_kernel``'s body for pixel i (inlined: a call costs 15-25 % of
    the filter). The helpers here are inlined by LLVM (``forceinline``):
    Numba types each once, where ``inline="always"`` re-typed its body at
    every call site (issue 15: pcf's compile CPU 16.5-16.9 -> 13.6-14.3 s in
    one process, the filter as fast)."""
    P, Nrm, hit, width, rays = cam.P, cam.Nrm, cam.hit, cam.width, cam.rays
    faces, depth, bbox, tiles = smap.faces, smap.depth, smap.bbox, smap.tiles
    ResFactor, MinSize, MaxSize, NumSamples = flt.ResFactor, flt.MinSize, flt.MaxSize, flt.NumSamples
    MinSamples, Bias0, Bias1, seed = flt.MinSamples, flt.Bias0, flt.Bias1, flt.seed
    use_plane, use_tiles = flt.use_plane, flt.use_tiles
    if not hit[i]:
        return
    j = cam.pixel[i] if cam.pixel.shape[0] else i    # the camera pixel: footprint and seed
    px, py, pz = P[i, 0], P[i, 1], P[i, 2]
    f = pick_face(faces, px, py, pz)
    if f < 0:
        out[i] = 1.0
        return
    s, t, z = face_project(faces[f], px, py, pz)
    if ResFactor > 0.0:
        hs, ht = pixel_footprint(rays, faces[f], float(j % width), float(j // width), px, py, pz,
                                 Nrm[i, 0], Nrm[i, 1], Nrm[i, 2], s, t, MaxSize)
    else:
        hs, ht = 0.0, 0.0
    sres = max(hs * ResFactor, MinSize)
    tres = max(ht * ResFactor, MinSize)
    sres = min(sres, MaxSize)
    tres = min(tres, MaxSize)
    if use_plane:
        plane = receiver_plane(faces[f], px, py, pz, Nrm[i, 0], Nrm[i, 1], Nrm[i, 2])
    else:
        plane = NO_PLANE
    lsize = smap.lsize[f]
    light = flt.light_region and z > 0.0 and (lsize[0] > 0.0 or lsize[1] > 0.0)
    if light:
        # the blocker search region (PCSS): the light's reach at the nearest depth it can hold
        ws, wt = search_region(tiles[f], depth.shape[2], depth.shape[1], s, t, z, lsize, smap.zmin[f],
                               sres, tres, MaxSize, SEARCH_STEPS)
    else:
        ws, wt = sres, tres
    if use_tiles and z >= 0.0:
        known = region_decided(tiles[f], smap.planes[f], faces[f, 16] == 1.0, depth.shape[2],
                               depth.shape[1], s, t, z, ws, wt, plane, Bias0, Bias1)
        if known >= 0.0:
            out[i] = 1.0 - known
            return
    if light:
        zb = blocker_depth(depth[f], bbox[f], s, t, z, ws, wt, flt.BlockerSamples, Bias0, Bias1,
                           seed + 1, j, plane)
        if not (zb > 0.0):
            out[i] = 1.0
            return
        ps, pt = light_halfwidth(lsize, z, zb)
        sres = min(max(ps, sres), MaxSize)
        tres = min(max(pt, tres), MaxSize)
        NumSamples = flt.PenumbraSamples
        if use_tiles:     # the filter region's own tile test (exact, as the search region's)
            known = region_decided(tiles[f], smap.planes[f], faces[f, 16] == 1.0, depth.shape[2],
                                   depth.shape[1], s, t, z, sres, tres, plane, Bias0, Bias1)
            if known >= 0.0:
                out[i] = 1.0 - known
                return
    out[i] = 1.0 - sample_shadow(depth[f], bbox[f], s, t, z, sres, tres, NumSamples,
                                 MinSamples, Bias0, Bias1, seed, j, plane)


@kernel(parallel=True)
def hard_shadow_kernel(P, faces, depth, bias, out):
    """Williams' hard test at each point: 0 where depth > map + bias, else 1;
    points outside every face are lit. Reference for the zero-region case."""
    for i in prange(P.shape[0]):
        f = pick_face(faces, P[i, 0], P[i, 1], P[i, 2])
        out[i] = 1.0
        if f < 0:
            continue
        s, t, z = face_project(faces[f], P[i, 0], P[i, 1], P[i, 2])
        if z < 0.0:
            continue
        iu = int(math.floor(s))
        iv = int(math.floor(t))
        if z > depth[f, iv, iu] + bias:
            out[i] = 0.0


def resolved_bias(params: PCFParams, extent: float):
    b0 = params.Bias0 if params.Bias0 is not None else BIAS0_PER_EXTENT * extent
    b1 = params.Bias1 if params.Bias1 is not None else BIAS1_PER_EXTENT * extent
    return float(b0), float(max(b1, b0))


def scene_extent(scene) -> float:
    lo, hi = scene.bounds()
    e = float(np.max(hi - lo))
    return e if e > 0 and np.isfinite(e) else 1.0


@register
class PercentageCloserFiltering(Method):
    id = "pcf"
    paper = "Reeves, Salesin, Cook 1987"
    passes = {"pcf": AVERAGE}
    needs = frozenset({GBUFFER, LIGHT_VIEW})
    Params = PCFParams

    def run(self, buffers, light, params: PCFParams) -> MethodResult:
        timer = PhaseTimer()
        g = buffers.gbuffer
        W, H = buffers.width, buffers.height          # the camera's view (g may be packed)
        n = g.hit.size
        lv = buffers.light_view(light, params.map_size)
        with timer("filter"):
            out = np.ones(n, np.float32)
            if len(lv.faces) and g.hit.any():
                b0, b1 = resolved_bias(params, buffers.light_extent(light))
                res, minsize, minsamp = float(params.ResFactor), float(params.MinSize), int(params.MinSamples)
                if light.is_zero_size:   # hard shadows only (DESIGN.md)
                    res, minsize, minsamp = 0.0, 0.0, 1
                tlo, thi = tile_minmax(lv.depth)
                tt = tile_tables(tlo, thi, int(2.0 * params.MaxSize + 2.0) // TILE + 2)
                if params.region not in ("light", "figure4"):
                    raise ValueError(f"pcf: unknown region {params.region!r} (light | figure4)")
                step = int(params.pixel_step) or auto_pixel_step(W, H)
                if step < 1 or PIXEL_TILE % step:
                    raise ValueError(f"pcf: pixel_step {params.pixel_step!r} must be a power of 2 dividing "
                                     f"{PIXEL_TILE}")
                if params.step_fill not in ("interpolate", "copy"):
                    raise ValueError(f"pcf: unknown step_fill {params.step_fill!r} (interpolate | copy)")
                lsize = light_reach(light, lv.faces)
                if light.is_zero_size:
                    lsize[:] = 0.0
                zmin = np.array([float(np.min(lo, initial=np.inf)) for lo in tlo], np.float64)
                pixel = np.zeros(0, np.int64) if g.pixel is None else np.ascontiguousarray(g.pixel, np.int64)
                rays = pixel_ray_terms(views.pack_camera(buffers.scene.camera, W, H))
                cam = CameraPixels(g.position.reshape(-1, 3), g.normal.reshape(-1, 3), g.hit.reshape(-1),
                                   g.object_id.reshape(-1), W, rays, pixel)
                faces = lv.packed_faces()
                planes = tile_planes(lv.depth, faces[:, 16] == 1.0)
                smap = ShadowMap(faces, lv.depth, finite_bbox(lv.depth), tt, planes, lsize, zmin)
                flt = Filter(res, minsize, float(params.MaxSize), int(params.NumSamples), minsamp,
                             b0, b1, int(params.seed), bool(params.receiver_plane), bool(params.tiles),
                             params.region == "light", max(1, int(params.BlockerSamples)),
                             max(1, int(params.PenumbraSamples)), step, params.step_fill == "interpolate",
                             float(params.step_tolerance))
                filter_pixels(cam, smap, flt, out, H)
        return MethodResult(passes={"pcf": out.reshape(g.shape)}, time_s=timer.result(),
                            stats={"map": [lv.depth.shape[0], lv.depth.shape[1], lv.depth.shape[2]]})
