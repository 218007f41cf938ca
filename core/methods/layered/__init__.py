"""Layered attenuation maps (Agrawala, Ramamoorthi, Heirich, Moll 2000,
section 4), method id ``layered``, pass ``layered``: each camera point's
irradiance ratio (equation 1 with / without V) or average visibility
(equation 2), read from a layered depth image (LDI) built once per light
from N light samples, each layer holding the set of samples that saw it.

Parameters (``LayeredParams``):
  samples      256          N light samples (the paper: "typically 64")
  epsilon      None         depth tolerance, scene units; None: EPSILON_PER_EXTENT x
                            ``FrameBuffers.light_extent`` (visible receivers and light)
  map_size     None         LDI and sample maps' larger side; None: the frame's map size
  warp         "auto"       equation 3's shift where it holds, else projective; "projective"
  splat        "footprint"  a warped sample pixel's LDI pixels; "neighbours"
  bilinear     True         filter the four nearest LDI pixels' attenuations
  steep_slope  10.0         texel widths of depth per texel past which a surface keeps the
                            4-neighbour splat and the nearest LDI pixel; inf: none does
  plane_depth  True         compare depths at LDI pixel centres on the surface's plane
  horizon      True         samples below the receiver's tangent plane are blocked
  surfaces     "mesh"       one surface: a connected mesh piece; "object": an object
  diagonals    None         a diagonal neighbour for a gradient axis with none; None: on
                            where a shadow caster has an alpha matte, else off
  seed         0            the samples' jitter
  visibility   "irradiance" the pass: the irradiance ratio; "average": equation 2

Precompute (procedure Precompute): N stratified, jittered points of the
light (section 3), one set for every pixel, each rendered as a depth +
surface-id map (lines 1-3, ``samples``), its pixels warped into the view
from the light's centre (line 5, ``warp``: equation 3, dp = -dv / z, for a
planar light, else projective) and inserted into the LDI (line 6, ``ldi``):
within tolerance of a layer the sample joins the layer's set (a bitmask of
ceil(N / 64) words, its popcount the paper's count), else it opens a layer.
Display (procedure Display, ``lookup``): a camera point is projected into
the LDI (line 3) and matched against its LDI pixel's layers (line 4); the
matching layer's attenuation is V, no match is 0 (the umbra, figure 6). The
attenuation: "average", count / N (line 7); "irradiance", sum over the set
of w_s / sum over all samples of w_s, w_s = cos_r cos_l / d^2 of sample s at
the point (the reference's weights; a sun's: cos_r), 0 where that sum is 0.

Departures (the paper's version in brackets):
  * visibility: count / N composites only where every sample weighs alike;
    weighted at the receiver, unshadowed x V = shadowed ["average"].
  * splat: a sample pixel covers the LDI pixel centres in its warped
    footprint, 1.5 steps past its surface's silhouette (``neighbourhood``);
    the four neighbours overestimate object size (section 4) and fill
    one-texel gaps: thin occluders lose their shadows [splat="neighbours"].
  * bilinear: section 6.1's remedy for insufficient attenuation-map sampling
    (figure 11 right); LDI pixels with no layer are left out [False].
  * steep_slope: a texel of a surface seen nearly edge-on spans many epsilons
    and footprints of different samples split it into layers; there the
    paper's splat and display hold [moot under them].
  * plane_depth: depths compared at LDI pixel centres through the surface
    gradient (splats) and tangent plane (camera points), tolerance epsilon +
    half the depth change across a texel: section 6.1's insufficient depth
    sampling, its "adaptive biases" [False: a sloped plane shadows itself].
  * horizon: V <= the share of samples above the tangent plane; the LDI
    cannot resolve a curved object's terminator [False]. Average only: the
    weights give a sample below the plane 0 already, and the unweighted share
    would darken points the light above their plane reaches.
  * surfaces: a connected mesh piece is one surface in the gradient,
    footprint and silhouette tests, so an object's leaves stay apart
    ["object"]; diagonals: a one-texel diagonal line (a wire) takes its
    gradient from a diagonal neighbour [False: none].
  * A point in front of every layer (undersampled) takes the nearest layer's
    attenuation (one sample: the shadow-map test); outside the LDI: lit.

Lights (``samples``): a sphere's samples fill its ball with density
~ 1 / sqrt(1 - |x|^2 / r^2), which projects along every direction to the
uniform disk (error O((r / d)^2)); a sun's are directions, each an
orthographic view; cube faces, spheres and suns warp projectively; a light
of size zero is one sample: the shadow-map test with bias epsilon.
"""
from __future__ import annotations

import math
import time
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Dict, Optional

import numba
import numpy as np

from ... import sampling
from ...kernels import each_dealt_chunk
from ...scene import Light
from ..base import (DEFAULT_LIGHT_SAMPLES, IRRADIANCE, GBUFFER, LIGHT_SAMPLE_VIEWS, MESH_PIECES,
                    PRECOMPUTE, SHADOW_GEOMETRY, Method, MethodResult, PhaseTimer)
from ..registry import register
from .ldi import LAYERS_START, LDI, complexity, ldi_insert, seen_words
from .lookup import LayerArrays, SampleWeights, display_kernel, horizon_kernel
from .neighbourhood import warp_local
from .samples import centre_faces, sample_plans, sample_points
from .warp import warp_projective, warp_shift

EPSILON_PER_EXTENT = 0.002   # default depth tolerance, x the light's extent
MAX_SLOPE = 30.0             # |d depth / d lateral| beyond which depths stay raw (88 degrees)


@dataclass
class LayeredParams:
    samples: int = DEFAULT_LIGHT_SAMPLES   # N light samples (the paper: "typically 64")
    epsilon: Optional[float] = None  # depth tolerance (scene units); None: EPSILON_PER_EXTENT x light extent
    map_size: Optional[int] = None   # LDI and sample maps' larger side; None: views.default_map_size
    bilinear: bool = True          # filter the 4 neighbouring attenuations; False: the nearest LDI pixel
    plane_depth: bool = True       # compare depths at LDI pixel centres; False: raw depths
    horizon: bool = True           # samples below the receiver's tangent plane count as blocked
    warp: str = "auto"             # "auto": equation 3's shift for planar lights, else projective | "projective"
    splat: str = "footprint"       # "footprint": the warped pixel's footprint | "neighbours": 4 neighbours
    steep_slope: float = 10.0      # surfaces steeper than this (depth per texel, in texel widths) keep
                                   # the 4-neighbour splat and the nearest LDI pixel; inf: never
    surfaces: str = "mesh"         # one surface in the sample maps' id tests: "mesh" (connected
                                   # mesh pieces) | "object" (object ids)
    diagonals: Optional[bool] = None  # a diagonal neighbour for a gradient axis with none; None: on
                                   # where a shadow caster has an alpha matte, else off
    seed: int = 0

    visibility: str = "irradiance"   # the pass: "irradiance" (the ratio that composites, eq. 1) | "average" (eq. 2)

def resolved_epsilon(params: LayeredParams, extent: float) -> float:
    """``epsilon``, or EPSILON_PER_EXTENT times ``extent`` (``precompute``
    passes ``FrameBuffers.light_extent``)."""
    if params.epsilon is not None:
        return float(params.epsilon)
    return EPSILON_PER_EXTENT * float(extent)


def resolved_diagonals(params: LayeredParams, shadow_scene) -> bool:
    """``diagonals``, with None resolved: on where the shadow casters carry
    alpha mattes (their wires and stems run one texel wide in any
    direction), else off."""
    if params.diagonals is not None:
        return bool(params.diagonals)
    return shadow_scene.alpha is not None


def precompute(buffers, light: Light, params: LayeredParams,
               render_workers: Optional[int] = None) -> Optional[LDI]:
    """Procedure Precompute: the LDI with per-layer counts from N light samples
    (None when no visible receiver lies in the light's view). ``render_workers``
    threads render sample maps (Embree) ahead (None: Numba's thread count - 1,
    at least 1; 0: rendered in the main thread, in turn); this thread warps
    and inserts them in sample order, so the LDI is the same for any count."""
    if params.splat not in ("neighbours", "footprint"):
        raise ValueError(f"layered: unknown splat {params.splat!r} (neighbours | footprint)")
    if params.warp not in ("auto", "projective"):
        raise ValueError(f"layered: unknown warp {params.warp!r} (auto | projective)")
    if params.surfaces not in ("mesh", "object"):
        raise ValueError(f"layered: unknown surfaces {params.surfaces!r} (mesh | object)")
    ms = int(params.map_size or buffers.map_size_for(light))
    receivers = buffers.receivers()
    bounds = buffers.bounds()
    centre = centre_faces(light, receivers, bounds, ms)
    eps = resolved_epsilon(params, buffers.light_extent(light))
    N = 1 if light.is_zero_size else max(1, int(params.samples))
    if not centre:
        return None
    lp = sampling.pack_light(light)
    uv = sampling.light_sample_set(lp, N, int(params.seed))
    pts = sample_points(lp, uv, int(params.seed))
    plans, mode = sample_plans(light, centre, receivers, bounds, ms, pts, params.warp)
    F, h, w = len(centre), centre[0].height, centre[0].width
    npix = F * h * w
    ldi_depth = np.zeros((npix, LAYERS_START), np.float64)
    ldi_span = np.zeros((npix, LAYERS_START), np.float64)
    ldi_seen = np.zeros((npix, LAYERS_START, seen_words(N)), np.uint64)
    ldi_n = np.zeros(npix, np.int32)
    cfaces = np.ascontiguousarray(np.stack([f.packed() for f in centre]))
    shadow = buffers.shadow_scene      # built here, not in the render threads
    footprint = params.splat == "footprint"
    diagonals = resolved_diagonals(params, shadow)
    labels = buffers.mesh_pieces if params.surfaces == "mesh" else None

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
        nonlocal ldi_depth, ldi_span, ldi_seen
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
            ldi_depth, ldi_span, ldi_seen = ldi_insert(
                ldi_depth, ldi_span, ldi_seen, ldi_n, wf, wx, wy, wz, gx, gy, span,
                foot, footprint, h, w, s, eps, slope_t, float(params.steep_slope))
        done = s + 1
        if done == len(plans) or (done & (done - 1)) == 0:
            by_n[str(done)] = complexity(ldi_n)

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
    return LDI(centre, ldi_depth, ldi_span, ldi_seen, ldi_n, N, eps, mode, by_n,
               np.ascontiguousarray(pts, np.float64), lp, light.kind == "sun",
               np.asarray(ctr, np.float64), float(reach), render_s, insert_s)


def display(ldi: LDI, P: np.ndarray, Nrm: np.ndarray, params: LayeredParams) -> np.ndarray:
    """Procedure Display: V (float64[n]) for world points P with normals Nrm."""
    F, h, w = ldi.shape
    out = np.empty(len(P), np.float64)
    if len(P) == 0:
        return out
    cfaces = np.ascontiguousarray(np.stack([f.packed() for f in ldi.faces]))
    P = np.ascontiguousarray(P, np.float64)
    Nrm = np.ascontiguousarray(Nrm, np.float64)
    irr = params.visibility == IRRADIANCE
    layers = LayerArrays(ldi.depth, ldi.span, ldi.seen, ldi.n_layers)
    sw = SampleWeights(irr, 1.0 / ldi.samples, ldi.light, ldi.points, ldi.directional)
    args = (P, Nrm, cfaces, h, w, layers, ldi.epsilon, bool(params.bilinear) and ldi.samples > 1,
            bool(params.plane_depth), 1.0 / math.sqrt(1.0 + MAX_SLOPE * MAX_SLOPE),
            MAX_SLOPE if params.plane_depth else 0.0, out, float(params.steep_slope), sw)
    each_dealt_chunk(lambda idx: display_kernel(idx, *args, np.empty(ldi.samples), np.empty(2)), len(P))
    if params.horizon and not irr:     # under the weights a sample below the tangent plane weighs 0
        hz = np.empty(len(P), np.float64)
        each_dealt_chunk(lambda idx: horizon_kernel(idx, P, Nrm, ldi.points, ldi.directional, ldi.centre,
                                                    ldi.reach, hz), len(P))
        np.minimum(out, hz, out=out)
    return np.clip(out, 0.0, 1.0)


@register
class LayeredAttenuationMaps(Method):
    id = "layered"
    paper = "Agrawala, Ramamoorthi, Heirich, Moll 2000, section 4"
    passes = {"layered": IRRADIANCE}
    needs = frozenset({GBUFFER, SHADOW_GEOMETRY, LIGHT_SAMPLE_VIEWS, MESH_PIECES, PRECOMPUTE})
    packed = True                # shades each receiver of a packed G-buffer on its own
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
            ldi = buffers.precomputed("layered.ldi", light, params,
                                     lambda: precompute(buffers, light, params)) if len(idx) else None
        stats: Dict[str, object] = {"ldi": [0, 0, 0]}
        if ldi is not None:
            with timer("display"):
                P = g.position.reshape(-1, 3)[idx]
                Nrm = g.normal.reshape(-1, 3)[idx]
                out[idx] = display(ldi, P, Nrm, params).astype(np.float32)
            F, h, w = ldi.shape
            stats = {"samples": ldi.samples, "epsilon": ldi.epsilon, "warp": ldi.warp,
                     "splat": params.splat,
                     "diagonals": resolved_diagonals(params, buffers.shadow_scene), "ldi": [F, h, w],
                     "depth_complexity": ldi.depth_complexity(),
                     "depth_complexity_by_samples": ldi.complexity_by_samples,
                     "max_layers": int(ldi.n_layers.max(initial=0)),
                     "nonempty_pixels": int((ldi.n_layers > 0).sum()), "ldi_bytes": ldi.nbytes(),
                     "render_s": ldi.render_s, "warp_insert_s": ldi.warp_insert_s}
        return MethodResult(passes={"layered": out.reshape(H, W)}, time_s=timer.result(), stats=stats)
