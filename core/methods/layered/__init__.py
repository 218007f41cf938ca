"""Layered attenuation maps (Agrawala, Ramamoorthi, Heirich, Moll 2000,
section 4), method id ``layered``, pass ``layered`` (average visibility, eq. 2).

Precompute (section 4, "procedure Precompute"):
  1-3. ``samples`` (the paper's "typically 64"; 256 for its figures)
       stratified, jittered points on the light's real shape -- one set for
       every pixel, as the paper does (``sampling.light_sample_set`` +
       ``sampling.light_sample``) -- each rendered as a depth + object-id map
       by the skeleton's Embree renderer (``FrameBuffers.sample_view``),
       looking the way the view from the light's centre looks;
  5.   each map warped into the view from the light's centre: for a planar
       (area) light whose centre view is one perspective face parallel to
       it, the paper's pure disparity shift dp = -dv / z (equation 3, in
       texels: the sample map shares the centre map's texel grid, padded by
       whole texels to hold every receiver); otherwise a general projective
       warp (each pixel unprojected to world space, projected into the centre
       face that holds it);
  6.   inserted into a layered depth image (LDI) with depth tolerance
       ``epsilon``: each layer holds a depth and an integer count; a warped
       point within tolerance of a layer increments it, else opens a new
       layer (kept sorted by depth). Splatting (``splat="neighbours"``, the
       paper's): each fractional point goes to its four neighbouring pixels
       (those with a non-zero bilinear weight: a point exactly on a pixel
       centre goes to that pixel alone), and a layer is incremented at most
       once per light sample;
  7.   attenuation = count / N.

Display ("procedure Display"): each camera pixel is projected into the LDI,
the layers of its nearest LDI pixel are searched for its depth within
tolerance, and that layer's attenuation is V. No layer matches -> 0 (umbra:
the point is behind or between what the light samples saw, figure 6's black
and magenta). ``bilinear`` (default since issue 17) filters the attenuation
of the four neighbouring LDI pixels instead (figure 11 right; a pixel
holding no layer at all has no value and is left out of the weights; not
with one light sample, whose display stays the shadow-map test).

Beyond the paper (each switchable; the defaults marked):
  * ``plane_depth`` (default on): depths are compared at LDI pixel centres.
    The paper inserts each warped point into its neighbours with the point's
    own depth and compares the camera point's own depth; on a surface sloped
    to the light both are off by the slope times up to ~1.5 texels, which no
    scene-sized epsilon absorbs without merging real layers (the paper's
    "insufficient depth sampling", section 6.1, and its future-work
    "adaptive biases"). Here each splat carries the depth extrapolated to its
    pixel's centre along the surface gradient (estimated in LDI space from
    the warped neighbour pixels on the same object, the smaller one-sided
    step per axis so silhouettes do not count), the camera point is compared
    at the same centre through its tangent plane (G-buffer normal), and the
    tolerance is epsilon + half the surface's depth change across one texel
    (the larger of the point's and the layer's; slopes capped at
    ``MAX_SLOPE``). Off: the paper's raw comparison with epsilon alone (a
    lone plane tilted 60 degrees to the light then shadows itself all over,
    mean V 0.50; at 30 degrees half its pixels; torus_plane RMSE 0.107 vs
    0.045 with horizon off as well).
  * ``horizon`` (default on): light samples below the receiver's tangent
    plane count as blocked, V = min(V_LDI, fraction of samples above). The
    LDI cannot resolve a curved object's terminator (its layers there come
    from the silhouette seen by the samples, fully lit); the reference's
    rays into the surface are blocked by it. Measured RMSE on the torus's
    own pixels: 0.146 -> 0.047, the sphere's 0.145 -> 0.063.
  * ``splat="footprint"`` (default since issue 17; the paper's is
    ``"neighbours"``; ``"auto"``, the default before, takes footprint only
    where a shadow caster has an alpha matte, see below): each sample pixel
    covers the LDI pixel centres inside its warped footprint, the
    parallelogram spanned by half the steps to its neighbours -- one pixel
    under an identity or pure-shift warp,
    several where the warp magnifies -- and 1.5 steps past its object's
    silhouette (towards empty space or a surface behind it; never past an
    occluder in front), so the last texels of an open surface stay covered.
    The paper notes its 4-neighbour splat "can slightly overestimate object
    size, making the shadows appear somewhat lighter": it lets each sample see
    a receiver up to a texel into its shadow, V too light by half a texel over
    the penumbra's width -- small on a ground plane (+0.017 on a 30-texel
    penumbra) but it fills in the shadows of thin occluders (GRIDS' bars are
    about one texel wide). RMSE against ``embree`` (128 x 128 pixels, 256
    samples), 4-neighbour / footprint: GRIDS 0.163 / 0.055 at 256-texel maps,
    torus_plane 0.045 / 0.023 and sphere_plane 0.040 / 0.020 at 128.
    Section 4's own limit, "layered attenuation maps fill thin gaps", is
    this splat's overestimate: on issue 17's foliage (256 x 256, 64
    samples, against 1024-sample embree, pixels seeing the whole light /
    every pixel the light reaches) 0.060 / 0.074 -> 0.037 / 0.054.
  * ``bilinear`` (default since issue 17; the paper's display takes the
    nearest LDI pixel): section 6.1's remedy for "insufficient attenuation
    map sampling", the four neighbouring attenuations filtered, as
    percentage-closer filtering does. On issue 17's measure (above) with
    the footprint splat, nearest -> bilinear: foliage 0.037 -> 0.033
    (every reached pixel 0.054 -> 0.050), sun_pillars 0.086 -> 0.070,
    grids 0.046 -> 0.035, sphere_plane 0.0098 -> 0.0063, torus_plane 0.011
    -> 0.0048, leaf_cards 0.035 -> 0.029; CPU within 3 %.
  * ``steep_slope`` (default 10; inf: footprint splat and bilinear display
    everywhere, the first version): surfaces steeper than that to the light
    (depth changing by more than 10 texel widths across a texel: 84
    degrees) keep the paper's ways, a sample pixel there the 4-neighbour
    splat and a receiver the nearest LDI pixel. Seen that edge-on a texel
    of ground spans many epsilons of depth, and the footprints of
    different samples cover an LDI pixel centre from points up to a texel
    apart, so one surface splits into layers and the display's plane depth
    at the centre matches a thin one: the stress suite's grazing_area (a
    light 2 degrees above the ground, 48 px) had a band of V = 0 across the
    ground, RMSE 0.273 (bilinear display everywhere: 0.181), against 0.168
    with the paper's splat and display; now 0.164. On the six sample
    scenes it changes RMSE by under 0.001.
  * ``splat="auto"`` (the default from issue 18 to 17): footprint when the
    shadow casters carry alpha mattes (``TriangleScene.alpha``), neighbours otherwise (so
    scenes without mattes are as before). Mattes make one-texel gaps and
    occluders everywhere -- a chain-link fence's wires and holes, a leaf's
    tip, and the ordered dither (``alpha_rays.DITHER``) that keeps a surface
    of alpha a in a share a of a sample map's pixels, solid and clear texels
    side by side -- and the 4-neighbour splat spreads a receiver seen
    through a clear texel over the solid ones around it (a 0.5 veil reads
    as nearly clear). Measured on leaf_cards (256 x 256, 256 samples,
    against 1024-sample embree): neighbours 0.081 RMSE (+0.014, too light),
    footprint 0.045 (0.032 with ``diagonals``); the same scene made opaque:
    0.047 / 0.023.
  * ``diagonals`` (default: on where a shadow caster has an alpha matte):
    the surface gradient of a sample pixel with no neighbour on its surface
    along an axis takes the diagonal neighbour (the smaller depth step)
    instead. A line one texel wide running
    diagonally in the sample map (a chain-link wire, a thin stem) has no
    axis neighbour on it, got no gradient and no span, so its raw depths at
    the LDI pixel centres split into two or three layers on a surface
    oblique to the light, each with part of the count (wires seen by the
    camera at V 0.2 - 0.8 where the reference has 1). On leaf_cards'
    fence pixels RMSE 0.32 -> 0.19 (footprint splat). Off: axes only. On
    the scenes without mattes it changed RMSE by at most 0.001 either way
    (256 x 256, 256 samples: grids, sphere_plane, torus_plane; foliage
    0.0699 -> 0.0711 with the neighbours splat, 0.0505 -> 0.0499 with
    footprint), so they keep it off and stay as before.
  * ``surfaces="mesh"`` (default; ``"object"``: object ids, as before
    issue 17): the sample maps carry each triangle's connected mesh piece
    (``surfaces.mesh_pieces``) where they carried its object id, so the
    gradient, footprint and silhouette tests above treat only texels of one
    piece as one surface. A shrub's 3,000 leaves are one object: with object
    ids two leaves side by side in a sample map join into one sloped
    surface (a huge depth span that merges layers across leaves, footprints
    stretched across the gap between them), the paper's "thin gaps" filled.
    Measured on foliage (256 x 256, 256 samples, footprint splat): RMSE
    0.061 -> 0.037, on the leaves' own pixels 0.33 -> 0.20.
  * A camera point *in front of* every layer of its pixel (nearer to the
    light than anything the samples saw there: a surface the samples
    undersampled) takes the nearest layer's attenuation instead of 0. With
    one sample this makes the display exactly the shadow-map test "lit iff
    depth <= map + epsilon".
  * A point outside the LDI's window (outside a spot cone) is lit (1).

epsilon: ``EPSILON_PER_EXTENT`` (0.002) times the largest side of the box
around the visible receivers and the light (at most the scene's bounding
box side; ``FrameBuffers.light_extent``) when not given (the ``pcf`` method's rule, Reeves et al.'s 0.3 in a
100-unit world, scaled down since depths are compared at pixel centres: on
torus_plane and sphere_plane 0.0005 to 0.01 of the extent changed RMSE by
< 0.002). It
is how close an occluder may come to its receiver before the two share a
layer: a contact shadow loses its last epsilon.

Lights other than a planar area light (DESIGN.md light domains):
  * the centre view is ``views.light_view_faces``' fitted to the visible
    receivers, except: a sun's window is not padded by its angle (the LDI is
    only looked up at receivers), and a point light whose receivers fit in
    60 degrees gets one fitted perspective face rather than 90-degree cube
    faces;
  * area lights whose receivers need cube faces: each sample renders the
    cube faces around it; projective warp, face to face;
  * sphere (point / spot with radius r): the domain is a disk of radius r
    through the centre facing each shaded point, which no single point set
    reproduces. The samples are drawn in the ball of radius r with density
    ~ 1 / sqrt(1 - |x|^2 / r^2) (the first three coordinates of a uniform
    point on the 3-sphere): its parallel projection along *every* direction
    is the uniform disk of radius r, so every shaded point sees the samples
    spread uniformly over its own facing disk up to the perspective of a
    point at distance d (error O((r / d)^2)). Their (x, y) is the stratified
    jittered disk in the light's local XY plane (across a spot's axis), the
    third coordinate takes a hashed angle. Sample views face as the centre
    view does; projective warp;
  * sun (directions in a cone of half-angle angle / 2): each sample is a
    direction and its view is orthographic along it, fitted to the
    receivers; projective warp into the central orthographic view;
  * a light of size zero: one sample, the centre view itself, identity warp:
    the shadow-map (Williams) test with bias epsilon, exactly;
  * a light too large for a padded sample view (padding over a map size, or
    receivers behind the sample's image plane) gets a view fitted from the
    sample point and the projective warp.

Cost: the precompute renders the N maps (Embree) on ``render_workers``
threads ahead of the main thread, which warps and inserts each (Numba,
serial, in sample order so the LDI is the same for any thread count); the
display is one parallel pass over the camera pixels and does not depend on
N. The stats give the LDI's average depth complexity over its non-empty
pixels (figure 10 right) after 1, 2, 4, ... and N samples, and the summed
render and warp + insert times.
"""
from __future__ import annotations

import dataclasses
import math
import time
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Dict, List, Optional

import numba
import numpy as np

from ... import sampling, views
from ...jit import HOT, inner, kernel
from ...kernels import borrowed, each_dealt_chunk, face_project, pick_face
from ...sampling import concentric_disk, light_sample, rand01
from ...scene import Light, ViewFace
from ..surfaces import mesh_pieces
from ..registry import register
from ..base import AVERAGE, GBUFFER, LIGHT_SAMPLE_VIEWS, SHADOW_GEOMETRY, Method, MethodResult, PhaseTimer

EPSILON_PER_EXTENT = 0.002   # default depth tolerance, x the scene's largest side
MAX_SLOPE = 30.0             # |d depth / d lateral| beyond which depths stay raw (88 degrees)
SPLAT_MIN_WEIGHT = 1e-6      # a neighbour with a smaller bilinear weight gets no splat
MAX_FOOTPRINT = 2.0          # longest side (texels) of a warped pixel's footprint splat
SILHOUETTE_EXTENT = 1.5      # footprint reach past a silhouette (neighbour steps; 1/2 inside)
FOOTPRINT_OVERLAP = 0.02     # footprints reach this much past half a step: no cracks between them
LAYERS_START = 8             # initial per-pixel layer capacity (grows on demand)
PAD_TEXELS = 2               # texels of a sample map beyond the receivers it must see
PAD_CAP = 1.0                # at most this many map sizes of padding per side (else a fitted view)


@dataclass
class LayeredParams:
    samples: int = 64              # N light samples (paper: "typically 64", 256 for its figures)
    epsilon: Optional[float] = None  # depth tolerance (scene units); None = 0.002 x scene extent
    map_size: Optional[int] = None   # LDI and sample maps' larger side; None = views.default_map_size
    bilinear: bool = True          # figure 11 right: filter the 4 neighbouring attenuations (issue 17:
                                   # default, nearest on receivers steeper than steep_slope); False:
                                   # the paper's display, the nearest LDI pixel
    plane_depth: bool = True       # compare depths at LDI pixel centres (see module doc)
    horizon: bool = True           # samples below the receiver's tangent plane count as blocked
    warp: str = "auto"             # auto: eq. 3 shift for planar lights, else projective
    splat: str = "footprint"       # "footprint" (unbiased, see doc; issue 17) | "neighbours" (the
                                   # paper's 4) | "auto": footprint where a shadow caster has an
                                   # alpha matte, else neighbours (the default before issue 17)
    steep_slope: float = 10.0      # surfaces steeper than this to the light (depth change per texel,
                                   # in texel widths: 84 degrees) keep the paper's ways: sample pixels
                                   # the 4-neighbour splat, receivers the nearest LDI pixel; inf:
                                   # footprint / bilinear everywhere (grazing light: stress
                                   # grazing_area 0.27 / 0.18)
    surfaces: str = "mesh"         # what counts as one surface in the sample maps' id test:
                                   # "mesh" (connected mesh pieces) | "object" (object ids)
    diagonals: Optional[bool] = None  # the surface gradient takes a diagonal neighbour where an
                                   # axis has none (thin diagonal lines; module doc); None: on where
                                   # a shadow caster has an alpha matte (as splat="auto"), else off
    seed: int = 0


# --------------------------------------------------------------------------
# light samples
@kernel
def sample_points(lp, uv, seed):
    """World points (area, sphere) or unit directions towards the light (sun)
    for the unit-square samples ``uv`` (float64[n, 2])."""
    n = uv.shape[0]
    out = np.empty((n, 3))
    for s in range(n):
        u, v = uv[s, 0], uv[s, 1]
        if lp[0] == 1.0:
            # sphere: density ~ 1/sqrt(1 - r^2) in the ball (a 3-sphere's
            # projection), whose projection along any axis is the uniform disk
            dx, dy = concentric_disk(u, v)
            hz = math.sqrt(max(0.0, 1.0 - dx * dx - dy * dy)) * \
                math.cos(2.0 * math.pi * rand01(seed, np.int64(0), s, np.int64(2)))
            r = lp[16]
            for k in range(3):
                out[s, k] = lp[1 + k] + r * (dx * lp[4 + k] + dy * lp[7 + k] + hz * lp[10 + k])
        else:
            x, y, z, _, _ = light_sample(lp, 0.0, 0.0, 0.0, u, v)
            out[s, 0], out[s, 1], out[s, 2] = x, y, z
    return out


# --------------------------------------------------------------------------
# warps (line 5 of Precompute)
@kernel(opt=HOT, nogil=True)
def warp_shift(sdepth, kx, ky, ax, ay, wf, wx, wy, wz):
    """Equation 3 for a sample map on the centre map's texel grid (same
    rotation, window padded by ``kx``, ``ky`` whole texels on the left / top):
    u_c = u_s - kx + ax / z, v_c = v_s - ky - ay / z, with (ax, ay) the
    sample's offset from the centre in the view's x, y over the texel size.
    Face f of the sample map warps into face f of the centre map."""
    F, h, w = sdepth.shape
    for k in range(F * h * w):
        f = k // (h * w)
        r = (k // w) % h
        c = k % w
        d = np.float64(sdepth[f, r, c])
        if not (d > 0.0 and d < np.inf):
            wf[k] = -1
            continue
        wf[k] = f
        wx[k] = c + 0.5 - kx + ax / d
        wy[k] = r + 0.5 - ky - ay / d
        wz[k] = d


@inner
def _unproject(fp, r, c, d):
    """World point seen at pixel (r, c) of packed face ``fp`` at depth ``d``."""
    x = fp[17] + (c + 0.5) / fp[21] * (fp[18] - fp[17])
    y = fp[20] - (r + 0.5) / fp[22] * (fp[20] - fp[19])
    if fp[16] == 0.0:
        vx, vy = x * d, y * d
    else:
        vx, vy = x, y
    vx -= fp[3]
    vy -= fp[7]
    vz = -d - fp[11]
    # world = R^T (v - T): the view rotation is orthonormal
    X = fp[0] * vx + fp[4] * vy + fp[8] * vz
    Y = fp[1] * vx + fp[5] * vy + fp[9] * vz
    Z = fp[2] * vx + fp[6] * vy + fp[10] * vz
    return X, Y, Z


@kernel(opt=HOT, nogil=True)
def warp_projective(sfaces, sdepth, cfaces, wf, wx, wy, wz):
    """General warp: unproject each sample pixel to world space and project it
    into the centre face that holds it (-1: outside the centre view)."""
    F, h, w = sdepth.shape
    for k in range(F * h * w):
        f = k // (h * w)
        r = (k // w) % h
        c = k % w
        d = np.float64(sdepth[f, r, c])
        wf[k] = -1
        if not (d < np.inf) or (sfaces[f, 16] == 0.0 and not (d > 0.0)):
            continue
        X, Y, Z = _unproject(sfaces[f], r, c, d)
        g = pick_face(cfaces, X, Y, Z)
        if g < 0:
            continue
        u, v, dd = face_project(cfaces[g], X, Y, Z)
        if not (np.isfinite(u) and np.isfinite(v) and np.isfinite(dd)):
            continue
        wf[k] = g
        wx[k] = u
        wy[k] = v
        wz[k] = dd


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
    same object in the same centre face (per sample-map axis the neighbour
    with the smaller depth step, so a silhouette's far side does not count):
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


# --------------------------------------------------------------------------
# the layered depth image (line 6 of Precompute)
@kernel(opt=HOT, nogil=True)
def ldi_insert(ldi_depth, ldi_span, ldi_count, ldi_last, ldi_n, wf, wx, wy, wz, gx, gy, span,
               foot, footprint, h, w, sample, eps, slope_t, foot_slope):
    """Insert one warped sample map: splat each point to the (up to four)
    neighbouring pixels with a non-zero bilinear weight (with ``footprint``:
    to the pixel centres in its footprint, unless its ``slope_t`` exceeds
    ``foot_slope``); join the nearest layer
    within tolerance (``eps`` + half the larger depth span across a texel of
    the point's and the layer's surface), incrementing its count at most once
    per sample, or open a new layer (layers kept sorted by depth). Returns the
    arrays, reallocated when a pixel needs more layers than they hold."""
    for k in range(wf.shape[0]):
        f = wf[k]
        if f < 0:
            continue
        x, y, z = wx[k], wy[k], wz[k]
        # the footprint splat, except on a surface steeper than ``foot_slope``
        # (NaN, inf <= inf: footprint)
        fpk = footprint and not (slope_t[k] > foot_slope)
        if fpk:
            a0, a1, b0, b1 = foot[k, 0], foot[k, 1], foot[k, 2], foot[k, 3]
            sm, sp_, tm, tp = foot[k, 4], foot[k, 5], foot[k, 6], foot[k, 7]
            det = a0 * b1 - a1 * b0
            es = max(sm, sp_)
            et = max(tm, tp)
            hx = es * abs(a0) + et * abs(b0)
            hy = es * abs(a1) + et * abs(b1)
            if abs(det) < 1e-6 * (abs(a0) + abs(a1)) * (abs(b0) + abs(b1)):
                a0, a1, b0, b1, det = 1.0, 0.0, 0.0, 1.0, 1.0
                hx, hy = es, et
            ci0 = math.ceil(x - hx - 0.5)
            ci1 = math.floor(x + hx - 0.5)
            cj0 = math.ceil(y - hy - 0.5)
            cj1 = math.floor(y + hy - 0.5)
        else:
            ci0 = math.floor(x - 0.5)
            cj0 = math.floor(y - 0.5)
            ci1 = ci0 + 1
            cj1 = cj0 + 1
        for ci in range(max(ci0, 0), min(ci1, w - 1) + 1):
            for cj in range(max(cj0, 0), min(cj1, h - 1) + 1):
                dx = ci + 0.5 - x
                dy = cj + 0.5 - y
                if fpk:
                    s_ = (dx * b1 - dy * b0) / det
                    t_ = (a0 * dy - a1 * dx) / det
                    if s_ < -sm or s_ >= sp_ or t_ < -tm or t_ >= tp:
                        continue
                elif abs(dx) >= 1.0 - SPLAT_MIN_WEIGHT or abs(dy) >= 1.0 - SPLAT_MIN_WEIGHT:
                    continue    # the four neighbours with a non-zero bilinear weight
                zc = z + gx[k] * dx + gy[k] * dy
                if not (zc > 0.0 or zc <= 0.0):
                    continue
                pix = (f * h + cj) * w + ci
                n = ldi_n[pix]
                best = -1
                bd = np.inf
                sp = span[k]
                for L in range(n):
                    dd = abs(ldi_depth[pix, L] - zc)
                    if dd <= eps + 0.5 * max(sp, ldi_span[pix, L]) and dd < bd:
                        bd = dd
                        best = L
                if best >= 0:
                    if sp > ldi_span[pix, best]:
                        ldi_span[pix, best] = sp
                    if ldi_last[pix, best] != sample:
                        ldi_last[pix, best] = sample
                        ldi_count[pix, best] += 1
                    continue
                K = ldi_depth.shape[1]
                if n == K:
                    nd = np.empty((ldi_depth.shape[0], 2 * K), ldi_depth.dtype)
                    ns = np.zeros((ldi_depth.shape[0], 2 * K), ldi_span.dtype)
                    nc = np.zeros((ldi_depth.shape[0], 2 * K), ldi_count.dtype)
                    nl = np.full((ldi_depth.shape[0], 2 * K), -1, ldi_last.dtype)
                    for q in range(ldi_depth.shape[0]):   # element loops: a slice copy compiles
                        for L in range(K):                # Numba's shape-error formatting (issue 15)
                            nd[q, L] = ldi_depth[q, L]
                            ns[q, L] = ldi_span[q, L]
                            nc[q, L] = ldi_count[q, L]
                            nl[q, L] = ldi_last[q, L]
                    ldi_depth, ldi_span, ldi_count, ldi_last = nd, ns, nc, nl
                pos = 0
                while pos < n and ldi_depth[pix, pos] < zc:
                    pos += 1
                for L in range(n, pos, -1):
                    ldi_depth[pix, L] = ldi_depth[pix, L - 1]
                    ldi_span[pix, L] = ldi_span[pix, L - 1]
                    ldi_count[pix, L] = ldi_count[pix, L - 1]
                    ldi_last[pix, L] = ldi_last[pix, L - 1]
                ldi_depth[pix, pos] = zc
                ldi_span[pix, pos] = sp
                ldi_count[pix, pos] = 1
                ldi_last[pix, pos] = sample
                ldi_n[pix] = n + 1
    return ldi_depth, ldi_span, ldi_count, ldi_last


# --------------------------------------------------------------------------
# display
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


@inner
def _lookup(ldi_depth, ldi_span, ldi_count, ldi_n, pix, z, sp, eps, invN):
    """Attenuation at one LDI pixel: the matching layer's; the nearest layer's
    if z is in front of every layer; 0 if behind / between; -1 if empty."""
    L, st = _match(ldi_depth, ldi_span, ldi_n, pix, z, sp, eps)
    if st == 3:
        return -1.0
    if st == 2:
        return 0.0
    return ldi_count[pix, L] * invN


@kernel(opt=HOT, nogil=True, error_model="numpy")
def display_kernel(idx, P, Nrm, cfaces, h, w, ldi_depth, ldi_span, ldi_count, ldi_n, invN, eps,
                   bilinear, plane, cos_min, max_slope, out, bi_slope):
    """Procedure Display, lines 2-5, for the points ``idx`` of P (normals
    Nrm); ``bilinear`` only on receivers no steeper than ``bi_slope``
    (``_point_slope``; the nearest LDI pixel beyond). A serial ``nogil``
    kernel run on worker threads by ``display`` (issue 15: a prange one's
    parfor lowering was most of its compile time), its arguments
    ``kernels.borrowed``."""
    P, Nrm, cfaces, ldi_depth, ldi_span, ldi_count, ldi_n, out = borrowed(
        (P, Nrm, cfaces, ldi_depth, ldi_span, ldi_count, ldi_n, out))
    for i in idx:
        px, py, pz = P[i, 0], P[i, 1], P[i, 2]
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
            a = _lookup(ldi_depth, ldi_span, ldi_count, ldi_n, (f * h + iv) * w + iu, z, sp, eps, invN)
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
                a = _lookup(ldi_depth, ldi_span, ldi_count, ldi_n, (f * h + cj) * w + ci, z, sp, eps, invN)
                if a < 0.0:
                    continue    # no layer at all: no value to filter
                acc += wa * wb * a
                wsum += wa * wb
        out[i] = acc / wsum if wsum > 0.0 else 0.0


# --------------------------------------------------------------------------
# orchestration
@dataclass
class LDI:
    """The precomputed layered attenuation maps of one light."""

    faces: List[ViewFace]           # the view from the light's centre
    depth: np.ndarray               # float64[F*h*w, K] layer depths (sorted)
    span: np.ndarray                # float64[F*h*w, K] surface depth change across a texel
    count: np.ndarray               # int32[F*h*w, K] light samples seeing each layer
    n_layers: np.ndarray            # int32[F*h*w]
    samples: int                    # N
    epsilon: float
    warp: str
    complexity_by_samples: Dict[str, float]
    points: np.ndarray = None       # float64[N,3] sample points (sun: unit directions to it)
    directional: bool = False       # sun: ``points`` are directions
    centre: np.ndarray = None       # light centre (sun: mean direction) for the horizon bound
    reach: float = 0.0              # samples' bounding radius (sun: sin of the cone half-angle)
    render_s: float = 0.0           # summed Embree render time (worker threads)
    warp_insert_s: float = 0.0      # summed warp + insert time (main thread)

    @property
    def shape(self):
        return len(self.faces), self.faces[0].height, self.faces[0].width

    def depth_complexity(self) -> float:
        return _complexity(self.n_layers)

    def attenuation(self, layer: int = 0) -> np.ndarray:
        """float32[F,h,w] attenuation map of one layer (NaN where absent)."""
        F, h, w = self.shape
        out = np.full(F * h * w, np.nan, np.float32)
        has = self.n_layers > layer
        if layer < self.count.shape[1]:
            out[has] = self.count[has, layer] / self.samples
        return out.reshape(F, h, w)


def _complexity(n_layers) -> float:
    nz = n_layers[n_layers > 0]
    return float(nz.mean()) if nz.size else 0.0


def scene_extent(scene) -> float:
    lo, hi = scene.bounds()
    e = float(np.max(hi - lo))
    return e if e > 0 and np.isfinite(e) else 1.0


def resolved_epsilon(params: LayeredParams, scene, extent: Optional[float] = None) -> float:
    """``epsilon``, or EPSILON_PER_EXTENT times ``extent`` (default: the
    scene's largest side; ``precompute`` passes ``FrameBuffers.light_extent``)."""
    if params.epsilon is not None:
        return float(params.epsilon)
    return EPSILON_PER_EXTENT * (scene_extent(scene) if extent is None else float(extent))


def _inside_face(face: ViewFace, pts: np.ndarray) -> np.ndarray:
    u, v, d = views.project_to_face(face, pts)
    ok = np.isfinite(u) & np.isfinite(v) & (u >= 0) & (v >= 0) & (u < face.width) & (v < face.height)
    return ok & ((d > 0) | face.ortho)


def _padded_sample_face(cf: ViewFace, eye_c: np.ndarray, q: np.ndarray, rec: np.ndarray):
    """The centre face moved to sample point ``q`` (same rotation, same texel
    grid), its window grown by whole texels until it holds the receivers
    ``rec`` as seen from ``q``. Returns the face, the left / top pads in
    texels and the offset of ``q`` in the view's x, y, z over the texel size
    (z: in scene units), or None when that would take more than
    ``PAD_CAP`` map sizes of padding or a receiver lies behind ``q``'s image
    plane (a light large against its distance to the receivers)."""
    rot = np.asarray(cf.view_from_world, np.float64)[:3, :3].T
    vfw = views.view_from_world(rot, q)
    l, r, b, t = cf.bounds
    tx = (r - l) / cf.width
    ty = (t - b) / cf.height
    kl = kr = kb = kt = 0
    if len(rec):
        p = rec @ vfw[:3, :3].T + vfw[:3, 3]
        d = -p[:, 2]
        if not (d > 0).all():
            return None
        xs = p[:, 0] / d
        ys = p[:, 1] / d
        pads = np.array([(l - xs.min()) / tx, (xs.max() - r) / tx, (b - ys.min()) / ty,
                         (ys.max() - t) / ty])
        if not np.isfinite(pads).all() or pads.max() > PAD_CAP * max(cf.width, cf.height):
            return None
        kl, kr, kb, kt = (max(0, int(math.ceil(x)) + PAD_TEXELS) for x in pads)
    face = ViewFace(vfw, False, (l - kl * tx, r + kr * tx, b - kb * ty, t + kt * ty),
                    cf.width + kl + kr, cf.height + kb + kt, "ldi-sample")
    dv = np.asarray(cf.view_from_world, np.float64)[:3, :3] @ (np.asarray(q, np.float64) - eye_c)
    return face, kl, kt, dv[0] / tx, dv[1] / ty, dv[2]


def _sun_sample_light(light: Light, direction: np.ndarray) -> Light:
    """A copy of the sun shining along -direction, with no angle (its view is
    fitted to the receivers only)."""
    m = np.eye(4)
    m[:3, :3] = views.look_rotation(-np.asarray(direction, np.float64))
    m[:3, 3] = light.world_from_light[:3, 3]
    return dataclasses.replace(light, world_from_light=m, angle=0.0)


def centre_faces(light: Light, receivers, bounds, map_size) -> List[ViewFace]:
    """The view from the light's centre that holds the LDI, fitted to the
    visible receivers (only they are looked up): ``views.light_view_faces``,
    except that a sun's window is not padded by its angle (the padding is for
    filters reaching past the receivers) and a point light whose receivers fit
    in 60 degrees gets one fitted perspective face instead of 90-degree cube
    faces (four times the texels on them at the same map size)."""
    if light.kind == "sun":
        return views.light_view_faces(dataclasses.replace(light, angle=0.0), receivers, bounds, map_size)
    if light.kind == "sphere" and not light.is_spot and len(receivers):
        d = receivers - light.position
        n = np.linalg.norm(d, axis=1)
        ok = n > 0
        if ok.any():
            d = d[ok] / n[ok, None]
            m = d.mean(axis=0)
            if np.linalg.norm(m) > 0:
                m /= np.linalg.norm(m)
                if (d @ m).min() >= math.cos(views.MAX_SINGLE_VIEW_HALF_ANGLE):
                    face = views.fit_perspective_face(light.position, m, receivers[ok], map_size)
                    if face is not None:
                        return [face]
    return views.light_view_faces(light, receivers, bounds, map_size)


def _sample_plans(light: Light, centre: List[ViewFace], receivers, bounds, map_size, pts, warp):
    """Per light sample: (faces, eye, mode, shift params). mode 0 = equation 3
    shift, 1 = projective."""
    plans = []
    eye_c = light.position
    if light.is_zero_size:
        return [(centre, eye_c, 0, (0, 0, 0.0, 0.0))], "identity"
    single_persp = len(centre) == 1 and not centre[0].ortho and light.kind != "sun"
    if single_persp:
        rec = receivers[_inside_face(centre[0], receivers)]
        shift_ok = light.kind == "area" and warp != "projective"
        fwd = -np.asarray(centre[0].view_from_world, np.float64)[2, :3]
        for q in pts:
            got = _padded_sample_face(centre[0], eye_c, q, rec)
            if got is None:
                face = views.fit_perspective_face(q, fwd, rec, map_size, label="ldi-sample")
                plans.append(([face] if face is not None else [], q, 1, None))
                continue
            face, kl, kt, ax, ay, az = got
            if shift_ok and abs(az) <= 1e-9 * max(1.0, float(np.linalg.norm(q - eye_c))):
                plans.append(([face], q, 0, (kl, kt, ax, ay)))
            else:
                plans.append(([face], q, 1, None))
        modes = {p[2] for p in plans}
        mode = {frozenset({0}): "planar shift (eq. 3)", frozenset({1}): "projective"}.get(
            frozenset(modes), "planar shift (eq. 3) + projective")
        return plans, mode
    for q in pts:
        if light.kind == "sun":
            faces = views.light_view_faces(_sun_sample_light(light, q), receivers, bounds, map_size)
            eye = light.position
        else:
            faces = views.light_view_faces(light, receivers, bounds, map_size, eye=q)
            eye = q
        plans.append((faces, eye, 1, None))
    return plans, "projective"


def resolved_splat(params: LayeredParams, shadow_scene) -> str:
    """``splat``, with "auto" resolved: "footprint" when the shadow casters
    carry alpha mattes (``shadow_scene.alpha``), else "neighbours"."""
    if params.splat != "auto":
        return params.splat
    return "footprint" if shadow_scene.alpha is not None else "neighbours"


def resolved_diagonals(params: LayeredParams, shadow_scene) -> bool:
    """``diagonals``, with None resolved: on when the shadow casters carry
    alpha mattes, else off."""
    if params.diagonals is not None:
        return bool(params.diagonals)
    return shadow_scene.alpha is not None


def precompute(buffers, light: Light, params: LayeredParams,
               render_workers: Optional[int] = None) -> Optional[LDI]:
    """Procedure Precompute: the LDI with per-layer counts from N light samples
    (None when no visible receiver lies in the light's view). ``render_workers``
    threads render sample maps ahead (None: Numba's thread count - 1, at least
    1; 0: rendered in the main thread, in turn)."""
    if params.splat not in ("auto", "neighbours", "footprint"):
        raise ValueError(f"layered: unknown splat {params.splat!r} (auto | neighbours | footprint)")
    if params.warp not in ("auto", "projective"):
        raise ValueError(f"layered: unknown warp {params.warp!r} (auto | projective)")
    if params.surfaces not in ("mesh", "object"):
        raise ValueError(f"layered: unknown surfaces {params.surfaces!r} (mesh | object)")
    scene = buffers.scene
    ms = int(params.map_size or buffers.map_size_for(light))
    receivers = buffers.receivers()
    bounds = scene.bounds()
    centre = centre_faces(light, receivers, bounds, ms)
    eps = resolved_epsilon(params, scene, buffers.light_extent(light))
    N = 1 if light.is_zero_size else max(1, int(params.samples))
    if not centre:
        return None
    lp = sampling.pack_light(light)
    uv = sampling.light_sample_set(lp, N, int(params.seed))
    pts = sample_points(lp, uv, int(params.seed))
    plans, mode = _sample_plans(light, centre, receivers, bounds, ms, pts, params.warp)
    F, h, w = len(centre), centre[0].height, centre[0].width
    npix = F * h * w
    ldi_depth = np.zeros((npix, LAYERS_START), np.float64)
    ldi_span = np.zeros((npix, LAYERS_START), np.float64)
    ldi_count = np.zeros((npix, LAYERS_START), np.int32)
    ldi_last = np.full((npix, LAYERS_START), -1, np.int32)
    ldi_n = np.zeros(npix, np.int32)
    cfaces = np.ascontiguousarray(np.stack([f.packed() for f in centre]))
    shadow = buffers.shadow_scene      # built here, not in the render threads
    footprint = resolved_splat(params, shadow) == "footprint"
    diagonals = resolved_diagonals(params, shadow)
    labels = mesh_pieces(scene) if params.surfaces == "mesh" else None

    def render(i):
        faces, eye, _, _ = plans[i]
        t = time.perf_counter()
        lv = buffers.sample_view(faces, eye, labels)
        return lv, time.perf_counter() - t

    workers = render_workers if render_workers is not None else max(1, numba.get_num_threads() - 1)
    render_s = 0.0
    insert_s = 0.0
    by_n: Dict[str, float] = {}

    def consume(s, lv):
        nonlocal ldi_depth, ldi_span, ldi_count, ldi_last
        faces, _, m, shift = plans[s]
        if len(faces):
            depth = np.ascontiguousarray(lv.depth)
            n = depth.size
            wf = np.empty(n, np.int32)
            wx = np.empty(n, np.float64)
            wy = np.empty(n, np.float64)
            wz = np.empty(n, np.float64)
            if m == 0:
                kl, kt, ax, ay = shift
                warp_shift(depth, float(kl), float(kt), float(ax), float(ay), wf, wx, wy, wz)
            else:
                warp_projective(lv.packed_faces(), depth, cfaces, wf, wx, wy, wz)
            gx = np.empty(n, np.float64)
            gy = np.empty(n, np.float64)
            span = np.empty(n, np.float64)
            foot = np.empty((n, 8), np.float64)
            slope_t = np.empty(n, np.float64)
            warp_local(depth, np.ascontiguousarray(lv.object_id), wf, wx, wy, wz, cfaces,
                       MAX_SLOPE, gx, gy, span, foot, diagonals, slope_t)
            if not params.plane_depth:
                gx[:] = 0.0
                gy[:] = 0.0
                span[:] = 0.0
            ldi_depth, ldi_span, ldi_count, ldi_last = ldi_insert(
                ldi_depth, ldi_span, ldi_count, ldi_last, ldi_n, wf, wx, wy, wz, gx, gy, span,
                foot, footprint, h, w, s, eps, slope_t, float(params.steep_slope))
        done = s + 1
        if done == len(plans) or (done & (done - 1)) == 0:
            by_n[str(done)] = _complexity(ldi_n)

    if workers <= 0:
        for s in range(len(plans)):
            lv, dt = render(s)
            render_s += dt
            t = time.perf_counter()
            consume(s, lv)
            insert_s += time.perf_counter() - t
    else:
        with ThreadPoolExecutor(max_workers=workers) as pool:
            ahead = 2 * workers
            pending = deque(pool.submit(render, i) for i in range(min(ahead, len(plans))))
            nxt = len(pending)
            for s in range(len(plans)):
                lv, dt = pending.popleft().result()
                render_s += dt
                if nxt < len(plans):
                    pending.append(pool.submit(render, nxt))
                    nxt += 1
                t = time.perf_counter()
                consume(s, lv)
                insert_s += time.perf_counter() - t
    if light.kind == "sun":
        axis = -light.direction
        ctr, reach = axis, math.sin(light.sun_half_angle) + 1e-12
    else:
        ctr = light.position
        reach = float(np.linalg.norm(pts - ctr, axis=1).max(initial=0.0)) * (1 + 1e-9) + 1e-300
    return LDI(centre, ldi_depth, ldi_span, ldi_count, ldi_n, N, eps, mode, by_n,
               np.ascontiguousarray(pts, np.float64), light.kind == "sun",
               np.asarray(ctr, np.float64), float(reach), render_s, insert_s)


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


def display(ldi: LDI, P: np.ndarray, Nrm: np.ndarray, params: LayeredParams) -> np.ndarray:
    """Procedure Display: V (float64[n]) for world points P with normals Nrm."""
    F, h, w = ldi.shape
    out = np.empty(len(P), np.float64)
    if len(P) == 0:
        return out
    cfaces = np.ascontiguousarray(np.stack([f.packed() for f in ldi.faces]))
    P = np.ascontiguousarray(P, np.float64)
    Nrm = np.ascontiguousarray(Nrm, np.float64)
    args = (P, Nrm, cfaces, h, w, ldi.depth, ldi.span, ldi.count, ldi.n_layers, 1.0 / ldi.samples,
            ldi.epsilon, bool(params.bilinear) and ldi.samples > 1, bool(params.plane_depth),
            1.0 / math.sqrt(1.0 + MAX_SLOPE * MAX_SLOPE), MAX_SLOPE if params.plane_depth else 0.0, out,
            float(params.steep_slope))
    each_dealt_chunk(lambda idx: display_kernel(idx, *args), len(P))
    if params.horizon:
        hz = np.empty(len(P), np.float64)
        each_dealt_chunk(lambda idx: horizon_kernel(idx, P, Nrm, ldi.points, ldi.directional, ldi.centre,
                                                    ldi.reach, hz), len(P))
        np.minimum(out, hz, out=out)
    return np.clip(out, 0.0, 1.0)


@register
class LayeredAttenuationMaps(Method):
    id = "layered"
    paper = "Agrawala, Ramamoorthi, Heirich, Moll 2000, section 4"
    passes = {"layered": AVERAGE}
    needs = frozenset({GBUFFER, SHADOW_GEOMETRY, LIGHT_SAMPLE_VIEWS})
    Params = LayeredParams
    physical = True

    def run(self, buffers, light, params: LayeredParams) -> MethodResult:
        timer = PhaseTimer()
        g = buffers.gbuffer
        H, W = g.shape
        buffers.receivers()
        buffers.shadow_scene          # shared buffers are built outside this method's phases
        out = np.ones(H * W, np.float32)
        idx = np.flatnonzero(g.hit.reshape(-1))
        with timer("precompute"):
            ldi = buffers.frame_memo("layered.ldi", light, params,
                                     lambda: precompute(buffers, light, params)) if len(idx) else None
        stats: Dict[str, object] = {"ldi": [0, 0, 0]}
        if ldi is not None:
            with timer("display"):
                P = g.position.reshape(-1, 3)[idx]
                Nrm = g.normal.reshape(-1, 3)[idx]
                out[idx] = display(ldi, P, Nrm, params).astype(np.float32)
            F, h, w = ldi.shape
            stats = {"samples": ldi.samples, "epsilon": ldi.epsilon, "warp": ldi.warp,
                     "splat": resolved_splat(params, buffers.shadow_scene),
                     "diagonals": resolved_diagonals(params, buffers.shadow_scene), "ldi": [F, h, w],
                     "depth_complexity": ldi.depth_complexity(),
                     "depth_complexity_by_samples": ldi.complexity_by_samples,
                     "max_layers": int(ldi.n_layers.max(initial=0)),
                     "nonempty_pixels": int((ldi.n_layers > 0).sum()),
                     "render_s": ldi.render_s, "warp_insert_s": ldi.warp_insert_s}
        return MethodResult(passes={"layered": out.reshape(H, W)}, time_s=timer.result(), stats=stats)
