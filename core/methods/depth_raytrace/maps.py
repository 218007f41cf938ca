"""Reference shadow maps for ``depth_raytrace`` (Agrawala et al. 2000, section 5.1).

* Which points on the light the reference images are taken from
  (``reference_eyes``): "we typically use views from the exterior vertices of
  the light" - the 4 corners of a square / rectangle. For the curved shapes the
  paper gives no rule; the documented choice here is the light's extreme
  points along its own axes, which play the role of the exterior vertices:

    - disk / ellipse: ``ref_points`` points on the boundary at angles
      2 pi k / ref_points from the local +X axis (default 4: the ends of both
      axes);
    - sphere (point / spot light of radius r): the 6 vertices of the octahedron
      c +- r X, c +- r Y, c +- r Z in the light's frame. Its sampled disk
      turns to face each shaded point, so no fixed set of points lies on it;
      these are the extreme points of the sphere that holds every such disk;
    - sun of angular diameter a: ``ref_points`` orthographic views along
      directions on the cone's boundary (half-angle a/2) at azimuths
      2 pi k / ref_points;
    - a light of size zero: its centre (hard shadows).

* Each eye's faces come from ``views.light_view_faces`` and are rendered with
  the skeleton's Embree depth renderer ``FrameBuffers.sample_view``. The
  window is fitted to the visible receivers *and* to the shadow-casting
  vertices inside the bounding box of receivers and light: an occluder the
  camera does not see (off screen, hidden) still has to be in the map for the
  rays that cross it. A sun's orthographic windows are fitted to what the
  receivers' rays can pass behind instead (``window``).

* Per map: the floor depths with the shadow bias added (``Zp``), the min / max
  depth quadtrees and the connectedness quadtree (section 5.1.1, "Hierarchical
  Connectedness"), flattened into one array per quantity with per-face level
  offsets so one Numba kernel walks every face.

Bias (section 6.1: "both methods require the user to specify a value for
shadow bias"): a floor sits at ``Z + bias``, bias = ``shadow_bias`` (scene
units) if given, else ``bias_texels`` texel footprints at that depth plus
``slope_bias`` x the depth change across half a texel estimated from the
neighbours (the smaller one-sided difference per axis, so a silhouette does
not inflate it, capped at the gap threshold). A receiver anywhere inside a
texel of a plane is then in front of its own floor.

Gap bias (section 5.1): two adjacent texels are connected when their floors
differ by less than ``gap_bias`` (scene units) if given, else ``gap_texels``
texel footprints at the nearer depth - a surface tilted up to
atan(gap_texels) away from facing the eye stays connected; separate objects
farther apart in depth than that are not.
"""
from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Optional

import numba
import numpy as np

from ... import views
from ...jit import inner, kernel
from ...scene import Light, ViewFace
from .window import blocker_points

# packed face layout: ViewFace.packed() (24) then these
FP_FOOT = 24      # texel footprint: per unit depth (perspective) or absolute (ortho)
FP_K = 25         # number of quadtree levels above the leaves (root = level K)
FP_MNROOT = 26    # root key range
FP_MXROOT = 27
FP_GAPABS = 28    # absolute gap bias (scene units)
FP_GAPTEX = 29    # gap bias in texel footprints
FP_EYE = 30       # index of the reference eye
FP_SIZE = 32

_FIT_CASTERS = 1 << 15


@dataclass
class ReferenceMaps:
    eyes: np.ndarray          # float64[E,3] (sun: a point far along each view direction)
    faces: np.ndarray         # float64[F, FP_SIZE]
    offs: np.ndarray          # int64[F, KMAX+1]: start of level k of face f in the flat arrays
    dims: np.ndarray          # int64[F, KMAX+1, 2]: (width, height) of level k
    mn: np.ndarray            # float32[...] min floor key per node (level 0: the floor's key)
    mx: np.ndarray            # float32[...] max floor key per node
    conn: np.ndarray          # uint8[...] connectedness per node
    zp: np.ndarray            # float32[...] level-0 floor depths Z + bias (+inf empty), same offsets
    raw_depth: list           # per eye: float32[F_e,h,w] as rendered (for tests / debugging)
    face_count: int
    map_texels: int


# ---------------------------------------------------------------------------
# reference eyes
def reference_eyes(light: Light, ref_points: int = 4):
    """[(eye point, Light used for the faces)] - see the module docstring."""
    c = light.position
    ax, ay, az = light.axes
    if light.is_zero_size:
        return [(c, light)]
    n = max(3, int(ref_points))
    if light.kind == "area":
        hx, hy = light.half_size
        if not light.is_round:
            pts = [c + sx * hx * ax + sy * hy * ay for sx, sy in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
        else:
            pts = [c + hx * math.cos(2 * math.pi * k / n) * ax + hy * math.sin(2 * math.pi * k / n) * ay
                   for k in range(n)]
        return [(p, light) for p in pts]
    if light.kind == "sphere":
        r = light.radius
        return [(c + s * r * a, light) for a in (ax, ay, az) for s in (1.0, -1.0)]
    # sun: boundary directions of the cone; each a rotated copy of the light
    half = light.sun_half_angle
    out = []
    for k in range(n):
        phi = 2 * math.pi * k / n
        to_sun = math.cos(half) * az + math.sin(half) * (math.cos(phi) * ax + math.sin(phi) * ay)
        rot = views.look_rotation(-to_sun, ay)
        mm = np.eye(4)
        mm[:3, :3] = rot
        mm[:3, 3] = c
        sun_k = Light(light.name, "sun", mm, blender_type="SUN", angle=light.angle)
        out.append((c, sun_k))
    return out


def fit_points(buffers, light: Light, casters: np.ndarray) -> np.ndarray:
    """Receivers plus shadow-casting vertices inside the box around the
    receivers and the light (subsampled)."""
    rec = buffers.receivers()
    if len(rec) == 0 or len(casters) == 0 or light.kind == "sun":
        return rec
    ext = max(light.extent, 0.0)
    lo = np.minimum(rec.min(0), light.position - ext)
    hi = np.maximum(rec.max(0), light.position + ext)
    inside = np.all((casters >= lo) & (casters <= hi), axis=1)
    pts = casters[inside]
    if len(pts) > _FIT_CASTERS:
        pts = pts[:: int(math.ceil(len(pts) / _FIT_CASTERS))]
    return np.concatenate([rec, pts]) if len(pts) else rec


# ---------------------------------------------------------------------------
# pyramid build
@inner
def _footprint(persp, foot, z):
    return foot * z if persp else foot


@inner
def _connected(za, zb, persp, foot, gap_abs, gap_tex):
    if not (za < np.inf) or not (zb < np.inf):
        return False
    zmin = min(za, zb)
    g = gap_abs + gap_tex * _footprint(persp, foot, zmin)
    return abs(za - zb) < g


@kernel
def _biased(depth, persp, foot, bias_abs, bias_tex, slope_bias, gap_abs, gap_tex, out):
    """Floors: Z + bias (see module docstring)."""
    h, w = depth.shape
    for i in range(h):
        for j in range(w):
            z = np.float64(depth[i, j])
            if not (z < np.inf):
                out[i, j] = np.inf
                continue
            fp = _footprint(persp, foot, z)
            s = 0.0
            # per axis: the smaller one-sided difference over finite neighbours
            for axis in range(2):
                best = np.inf
                for sgn in (-1, 1):
                    ii = i + sgn if axis == 1 else i
                    jj = j + sgn if axis == 0 else j
                    if ii >= 0 and ii < h and jj >= 0 and jj < w:
                        zn = np.float64(depth[ii, jj])
                        if zn < np.inf:
                            d = abs(zn - z)
                            if d < best:
                                best = d
                if best < np.inf:
                    s += best
            cap = gap_abs + gap_tex * fp
            s = min(0.5 * s, cap)
            out[i, j] = np.float32(z + bias_abs + bias_tex * fp + slope_bias * s)


@kernel
def _build_levels(zp, persp, foot, gap_abs, gap_tex, offs, dims, mn, mx, conn, zflat):
    """Min / max / connectedness quadtrees of one face (levels 0..K).

    The quadtrees hold *keys*, not depths: -1/Z for a perspective face, Z for
    an orthographic one (+inf where empty). Both increase with depth, and
    along the image of a straight ray the key is affine in the image-plane
    parameter (1/z is affine in screen space), which is what lets the
    traversal run without divisions."""
    h, w = zp.shape
    o0 = offs[0]
    # level 0
    rc = np.zeros((h, w), np.bool_)   # connected to the right neighbour
    dc = np.zeros((h, w), np.bool_)   # connected to the neighbour below
    for i in range(h):
        for j in range(w):
            z = zp[i, j]
            zflat[o0 + i * w + j] = z
            if z < np.inf:
                key = np.float32(-1.0 / np.float64(z)) if persp else z
            else:
                key = np.float32(np.inf)
            mn[o0 + i * w + j] = key
            mx[o0 + i * w + j] = key
            conn[o0 + i * w + j] = 1 if z < np.inf else 0
            if j + 1 < w:
                rc[i, j] = _connected(np.float64(z), np.float64(zp[i, j + 1]), persp, foot, gap_abs, gap_tex)
            if i + 1 < h:
                dc[i, j] = _connected(np.float64(z), np.float64(zp[i + 1, j]), persp, foot, gap_abs, gap_tex)
    K = offs.shape[0] - 1
    for k in range(1, K + 1):
        pw, ph = dims[k - 1, 0], dims[k - 1, 1]
        cw, ch = dims[k, 0], dims[k, 1]
        po, co = offs[k - 1], offs[k]
        nrc = np.zeros((ch, cw), np.bool_)
        ndc = np.zeros((ch, cw), np.bool_)
        for i in range(ch):
            for j in range(cw):
                lo = np.inf
                hi = -np.inf
                c = True
                for di in range(2):
                    for dj in range(2):
                        ii = 2 * i + di
                        jj = 2 * j + dj
                        if ii < ph and jj < pw:
                            q = po + ii * pw + jj
                            if mn[q] < lo:
                                lo = mn[q]
                            if mx[q] > hi:
                                hi = mx[q]
                            if conn[q] == 0:
                                c = False
                # internal edges between the children
                i0, j0 = 2 * i, 2 * j
                if j0 + 1 < pw:
                    if not rc[i0, j0]:
                        c = False
                    if i0 + 1 < ph and not rc[i0 + 1, j0]:
                        c = False
                if i0 + 1 < ph:
                    if not dc[i0, j0]:
                        c = False
                    if j0 + 1 < pw and not dc[i0, j0 + 1]:
                        c = False
                # edges to the right / lower neighbour node
                jr = min(j0 + 1, pw - 1)
                r_ok = rc[i0, jr] and (i0 + 1 >= ph or rc[i0 + 1, jr])
                ib = min(i0 + 1, ph - 1)
                d_ok = dc[ib, j0] and (j0 + 1 >= pw or dc[ib, j0 + 1])
                nrc[i, j] = r_ok
                ndc[i, j] = d_ok
                mn[co + i * cw + j] = lo
                mx[co + i * cw + j] = hi
                conn[co + i * cw + j] = 1 if c else 0
        rc = nrc
        dc = ndc


CUBE_OVERLAP_TEXELS = 3.0


def _overlapping(face: ViewFace) -> ViewFace:
    """Cube faces tile the directions edge to edge; the tracer does not use a
    face's outermost texel ring, so each cube face is widened by a few texels
    to overlap its neighbours."""
    if not face.label.startswith("cube"):
        return face
    l, r, b, t = face.bounds
    pu = CUBE_OVERLAP_TEXELS * (r - l) / face.width
    pv = CUBE_OVERLAP_TEXELS * (t - b) / face.height
    return ViewFace(face.view_from_world, face.ortho, (l - pu, r + pu, b - pv, t + pv), face.width,
                    face.height, face.label)


def _levels(w: int, h: int):
    K = 0
    while (1 << K) < max(w, h):
        K += 1
    dims = [((w + (1 << k) - 1) >> k, (h + (1 << k) - 1) >> k) for k in range(K + 1)]
    return K, dims


def _sun_blockers(buffers, light: Light, pts: np.ndarray, casters: np.ndarray, bounds, map_size: int, bias):
    """(fit points, pad) of a sun's windows (``window``): the blocker texels
    of one view along the sun's centre direction fitted to ``pts`` (the
    receivers), padded by 2 of its texels; (pts, None) - the receivers'
    window - when nothing can be blocked."""
    faces = views.light_view_faces(light, pts, bounds, map_size)
    if not faces:
        return pts, None
    face = faces[0]
    depth = buffers.sample_view(faces, light.position).depth[0]
    l, r, b, t = face.bounds
    foot = 0.5 * ((r - l) / face.width + (t - b) / face.height)
    floors = np.empty(depth.shape, np.float32)
    _biased(depth, False, foot, *bias, floors)
    g = buffers.gbuffer
    blk = blocker_points(face, depth, floors, g.position[g.hit], light.sun_half_angle, casters)
    if not len(blk):
        return pts, None
    return blk, 2.0 * foot


def build_reference_maps(buffers, light: Light, map_size: int, ref_points: int,
                         bias_abs: Optional[float], bias_texels: float, slope_bias: float,
                         gap_abs: Optional[float], gap_texels: float,
                         threads: Optional[int] = None) -> ReferenceMaps:
    """The reference maps of ``light`` (module docstring), ``map_size`` on a
    side; a sun's orthographic windows fitted to the geometry the receivers'
    rays can pass behind (``window``)."""
    buffers.shadow_scene      # built here, not in the render threads
    eyes = reference_eyes(light, ref_points)
    casters = buffers.shadow_triangles[0].reshape(-1, 3).astype(np.float64)
    pts = fit_points(buffers, light, casters)
    bounds = buffers.bounds()
    ga = float(gap_abs) if gap_abs is not None else 0.0
    gt = 0.0 if gap_abs is not None else float(gap_texels)
    ba = float(bias_abs) if bias_abs is not None else 0.0
    bt = 0.0 if bias_abs is not None else float(bias_texels)
    sb = 0.0 if bias_abs is not None else float(slope_bias)
    pad = None
    if light.kind == "sun" and len(pts):
        pts, pad = _sun_blockers(buffers, light, pts, buffers.shadow_triangles[0], bounds, map_size,
                                 (ba, bt, sb, ga, gt))
    face_lists = [[_overlapping(f) for f in views.light_view_faces(lt, pts, bounds, map_size, eye, pad)]
                  for eye, lt in eyes]

    def render(k):
        eye, _ = eyes[k]
        return buffers.sample_view(face_lists[k], eye)

    workers = max(1, min(len(eyes), int(threads or numba.get_num_threads())))
    if workers > 1:
        with ThreadPoolExecutor(max_workers=workers) as pool:
            lvs = list(pool.map(render, range(len(eyes))))
    else:
        lvs = [render(k) for k in range(len(eyes))]

    # eye points (a sun's are its position: its views are orthographic)
    eye_pts = np.array([e for e, _ in eyes], np.float64).reshape(-1, 3)
    faces = []
    for e, lv in enumerate(lvs):
        for fi, face in enumerate(lv.faces):
            faces.append((e, fi, face))
    F = len(faces)
    KMAX = 0
    for _, _, face in faces:
        KMAX = max(KMAX, _levels(face.width, face.height)[0])
    fp = np.zeros((F, FP_SIZE), np.float64)
    offs = np.zeros((F, KMAX + 1), np.int64)
    dims = np.ones((F, KMAX + 1, 2), np.int64)
    total = 0
    for n, (e, fi, face) in enumerate(faces):
        K, dl = _levels(face.width, face.height)
        for k in range(KMAX + 1):
            kk = min(k, K)
            dims[n, k] = dl[kk]
            offs[n, k] = total + sum(a * b for a, b in dl[:kk])
        total += sum(a * b for a, b in dl)
        fp[n, :24] = face.packed()
        l, r, b, t = face.bounds
        fp[n, FP_FOOT] = 0.5 * ((r - l) / face.width + (t - b) / face.height)
        fp[n, FP_K] = K
        fp[n, FP_EYE] = e
    mn = np.empty(total, np.float32)
    mx = np.empty(total, np.float32)
    conn = np.empty(total, np.uint8)
    zflat = np.full(total, np.inf, np.float32)
    for n, (e, fi, face) in enumerate(faces):
        persp = not face.ortho
        depth = lvs[e].depth[fi]
        foot = fp[n, FP_FOOT]
        zp = np.empty(depth.shape, np.float32)
        _biased(depth, persp, foot, ba, bt, sb, ga, gt, zp)
        K = int(fp[n, FP_K])
        _build_levels(zp, persp, foot, ga, gt, offs[n, :K + 1].copy(), dims[n, :K + 1].copy(), mn, mx, conn,
                      zflat)
        root = offs[n, K]
        lo, hi = float(mn[root]), float(mx[root])
        if lo < np.inf and not hi > lo:      # one depth over the window: a ray crossing it still needs a band
            hi = lo + 1e-6 * max(abs(lo), 1.0)
        fp[n, FP_MNROOT] = lo
        fp[n, FP_MXROOT] = hi
        fp[n, FP_GAPABS] = ga
        fp[n, FP_GAPTEX] = gt
    return ReferenceMaps(eye_pts, fp, offs, dims, mn, mx, conn, zflat, [lv.depth for lv in lvs], F,
                         int(sum(f.width * f.height for _, _, f in faces)))
