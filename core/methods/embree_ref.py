"""Monte Carlo shadow rays against the real triangles, method id ``embree``:
the reference every other method is measured against. Two passes from one
set of rays:

  * ``embree``: average visibility, Agrawala et al. equation 2,
    V_avg = (1/N) sum_i v_i;
  * ``embree_irr``: the irradiance ratio, equation 1 with / without V,
    V_irr = sum_i w_i v_i / sum_i w_i, w_i = cos(theta_r) cos(theta_l) / d^2
    (sun: w_i = cos(theta_r)); theta_r at the receiver (normal facing the
    camera), theta_l at the light (area: its -Z emitting side; sphere: the
    disk facing the point, as its sampling does). Where sum w_i = 0 (the
    light cannot reach the point) V_irr = 0; the error measures exclude
    those pixels.

v_i in [0, 1] is a ray's transmittance: 0 or 1 past opaque triangles, the
product of (1 - alpha) through alpha mattes (``alpha_rays.transmittance``).

Parameters:

  ==========  =======  ==================================================
  samples     256      shadow rays per pixel (1 for a light of size zero,
                       unless the receiver stands for the whole shutter)
  seed        0        seed of the counter hash that jitters the samples
  ==========  =======  ==================================================

Sampling: ``samples`` strata of the light's unit square (``sampling.strata``,
nx x ny), one jittered point in each, mapped onto the light's domain
(DESIGN.md "Light domains"); the jitter is a counter hash of (seed, pixel,
stratum) (``sampling.reference_sample``), so every pixel draws its own,
decorrelated samples and any method that shoots "the reference's own
samples" draws the same ones. Rays start at the G-buffer point moved off its
surface by ``sampling.offset_origin`` (Wächter & Binder, scaled to the scene
extent). A receiver taken at a shutter time (``GBuffer.time``: a filtered
frame with motion blur) traces its rays at that time, against the occluders
where they are then (``core/motion.py``); one that stands for the whole
shutter (``GBuffer.over_shutter``: a still camera's pixel centres) traces
each ray at its own time, stratified over the shutter jointly with the
light strata (``camera_samples.ray_times``).

Rays are generated, traced (``core/embree4``'s kernels, which release the GIL)
and reduced in batches of about ``RAYS_PER_BATCH``, one worker thread per
Numba thread; a pixel's rays depend only on the seed and the pixel, so any
thread count gives the same bits.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from .. import camera_samples, sampling
from ..jit import HOT, kernel
from ..kernels import each_in_threads, each_range
from ..sampling import L_AX, L_AY, L_AZ, L_CX, L_HX, L_HY, L_SHAPE, offset_origin, reference_sample, strata
from .registry import register
from .base import AVERAGE, DEFAULT_LIGHT_SAMPLES, GBUFFER, IRRADIANCE, SHADOW_GEOMETRY, Method, MethodResult, PhaseTimer

SUN_TFAR = np.float32(1e30)
RAYS_PER_BATCH = 1 << 18


@dataclass
class EmbreeParams:
    samples: int = DEFAULT_LIGHT_SAMPLES   # shadow rays per pixel (stratified, jittered)
    seed: int = 0


@kernel(opt=HOT, nogil=True)
def generate_shadow_rays(P, Nrm, pix, lp, ns, seed, scale, org, dirs, tfar, w):
    """Fill float32 ray arrays for pixels ``P`` (float64[n,3]) with normals
    ``Nrm`` and global pixel ids ``pix``: ray i*ns+s goes to stratum s."""
    nx, ny = strata(ns)
    for i in range(P.shape[0]):
        px, py, pz = P[i, 0], P[i, 1], P[i, 2]
        n0, n1, n2 = Nrm[i, 0], Nrm[i, 1], Nrm[i, 2]
        ox, oy, oz = offset_origin(px, py, pz, n0, n1, n2, scale)
        for s in range(ns):
            _, _, _, _, _, is_dir, dx, dy, dz, dist, wt = reference_sample(
                lp, seed, pix[i], s, nx, ny, px, py, pz, ox, oy, oz, n0, n1, n2)
            k = i * ns + s
            cos_r = dx * n0 + dy * n1 + dz * n2
            if cos_r < 0.0:
                cos_r = 0.0
            org[k, 0] = ox
            org[k, 1] = oy
            org[k, 2] = oz
            dirs[k, 0] = dx
            dirs[k, 1] = dy
            dirs[k, 2] = dz
            tfar[k] = dist * (1.0 - 1e-6) if not is_dir else dist
            w[k] = wt * cos_r


@kernel(opt=HOT, nogil=True)
def reduce_visibility(trans, w, ns, v_avg, v_irr):
    """trans: each ray's transmittance (0 or 1 past opaque triangles, the
    product of (1 - alpha) through mattes) -> per-pixel V (eq. 2, eq. 1
    ratio). A ray with nothing let through adds nothing (its weight is not
    multiplied by 0)."""
    n = v_avg.shape[0]
    for i in range(n):
        lit = 0.0
        wl = 0.0
        wt = 0.0
        for s in range(ns):
            k = i * ns + s
            wt += w[k]
            if trans[k] != 0.0:
                lit += trans[k]
                wl += w[k] * trans[k]
        v_avg[i] = lit / ns
        v_irr[i] = wl / wt if wt > 0.0 else 0.0


def trace_visibility(tri_scene, P, Nrm, pix, light, samples, seed, scale, threads=None, time=None,
                     over_shutter=None):
    """V_avg and V_irr (float32[n]) for points P with normals Nrm, their
    shadow rays at the points' shutter ``time`` (float32[n]; None: the
    frame), those of the points ``over_shutter`` marks (bool[n]; None:
    none) each at its own time over the shutter (``camera_samples.ray_times``;
    with ``time`` None every point must be marked)."""
    if over_shutter is not None and time is None and not over_shutter.all():
        raise ValueError("points that do not stand for the shutter need their time")
    lp = sampling.pack_light(light)
    n = len(P)
    ns = int(samples)
    v_avg = np.ones(n, np.float32)
    v_irr = np.ones(n, np.float32)
    if n == 0:
        return v_avg, v_irr, 0
    per = max(1, RAYS_PER_BATCH // ns)
    chunks = [(s, min(n, s + per)) for s in range(0, n, per)]
    P = np.ascontiguousarray(P, np.float64)
    Nrm = np.ascontiguousarray(Nrm, np.float64)
    pix = np.ascontiguousarray(pix, np.int64)

    def work(c):
        a, b = c
        m = (b - a) * ns
        org = np.empty((m, 3), np.float32)
        dirs = np.empty((m, 3), np.float32)
        tfar = np.empty(m, np.float32)
        w = np.empty(m, np.float64)
        generate_shadow_rays(P[a:b], Nrm[a:b], pix[a:b], lp, ns, seed, scale, org, dirs, tfar, w)
        t = None if time is None else np.repeat(time[a:b], ns)
        if over_shutter is not None and over_shutter[a:b].any():
            spread = np.repeat(over_shutter[a:b], ns)
            own = camera_samples.ray_times(pix[a:b], ns, seed)
            t = own if t is None else np.where(spread, own, t)
        reduce_visibility(tri_scene.transmittance(org, dirs, tfar, t), w, ns, v_avg[a:b], v_irr[a:b])

    each_in_threads(work, chunks, max(1, int(threads or numba.get_num_threads())))
    return v_avg, v_irr, n * ns


@kernel(opt=HOT, nogil=True)
def unshadowed_range(i0, i1, P, Nrm, pix, lp, ns, seed, scale, out):
    """out[i] for i in [i0, i1): the mean of the reference's weights w_s over
    its ``ns`` light samples of pixel ``pix[i]`` (as ``generate_shadow_rays``
    forms them; nothing is traced)."""
    nx, ny = strata(ns)
    for i in range(i0, i1):
        px, py, pz = P[i, 0], P[i, 1], P[i, 2]
        n0, n1, n2 = Nrm[i, 0], Nrm[i, 1], Nrm[i, 2]
        ox, oy, oz = offset_origin(px, py, pz, n0, n1, n2, scale)
        acc = 0.0
        for s in range(ns):
            _, _, _, _, _, _, dx, dy, dz, _, wt = reference_sample(
                lp, seed, pix[i], s, nx, ny, px, py, pz, ox, oy, oz, n0, n1, n2)
            cos_r = dx * n0 + dy * n1 + dz * n2
            if cos_r > 0.0:
                acc += wt * cos_r
        out[i] = acc / ns


#: corners of the polygon standing in for a round area light in ``area_irradiance_range``
ROUND_CORNERS = 32


@kernel(nogil=True)
def area_irradiance_range(i0, i1, P, Nrm, lp, out):
    """out[i] for i in [i0, i1): an area light's unshadowed irradiance at
    point P[i] (normal Nrm[i]) in closed form, pi F / A, the mean of the
    reference's weights over the light's area: F is Lambert's
    point-to-polygon form factor, (1 / 2 pi) sum_i beta_i (n . g_i), of the
    light's part above the point's tangent plane (the polygon clipped there;
    a disk or ellipse is a ``ROUND_CORNERS``-gon of the same area), 0 on the
    side the light does not emit to (its +Z)."""
    k = ROUND_CORNERS if lp[L_SHAPE] == 1.0 else 4
    cx, cy, cz = lp[L_CX], lp[L_CX + 1], lp[L_CX + 2]
    ax = np.empty((k, 3))
    if k == 4:
        corners = ((-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0))
        for j in range(4):
            for d in range(3):
                ax[j, d] = lp[L_HX] * corners[j][0] * lp[L_AX + d] + lp[L_HY] * corners[j][1] * lp[L_AY + d]
        area = 4.0 * lp[L_HX] * lp[L_HY]
    else:
        grow = math.sqrt(2.0 * math.pi / (k * math.sin(2.0 * math.pi / k)))   # the k-gon's area = the ellipse's
        for j in range(k):
            t = 2.0 * math.pi * j / k
            for d in range(3):
                ax[j, d] = grow * (lp[L_HX] * math.cos(t) * lp[L_AX + d] + lp[L_HY] * math.sin(t) * lp[L_AY + d])
        area = math.pi * lp[L_HX] * lp[L_HY]
    poly = np.empty((k + 2, 3))
    for i in range(i0, i1):
        n0, n1, n2 = Nrm[i, 0], Nrm[i, 1], Nrm[i, 2]
        rx, ry, rz = cx - P[i, 0], cy - P[i, 1], cz - P[i, 2]
        out[i] = 0.0
        if area <= 0.0 or rx * lp[L_AZ] + ry * lp[L_AZ + 1] + rz * lp[L_AZ + 2] <= 0.0:
            continue                                  # not on the side the light emits to
        m = 0                                         # Sutherland-Hodgman: the part above the tangent plane
        for j in range(k):
            a0, a1, a2 = rx + ax[j, 0], ry + ax[j, 1], rz + ax[j, 2]
            b0, b1, b2 = rx + ax[(j + 1) % k, 0], ry + ax[(j + 1) % k, 1], rz + ax[(j + 1) % k, 2]
            da = a0 * n0 + a1 * n1 + a2 * n2
            db = b0 * n0 + b1 * n1 + b2 * n2
            if da > 0.0:
                poly[m, 0], poly[m, 1], poly[m, 2] = a0, a1, a2
                m += 1
            if (da > 0.0) != (db > 0.0):
                t = da / (da - db)
                poly[m, 0], poly[m, 1], poly[m, 2] = a0 + t * (b0 - a0), a1 + t * (b1 - a1), a2 + t * (b2 - a2)
                m += 1
        if m < 3:
            continue
        total = 0.0
        for j in range(m):
            a0, a1, a2 = poly[j, 0], poly[j, 1], poly[j, 2]
            b0, b1, b2 = poly[(j + 1) % m, 0], poly[(j + 1) % m, 1], poly[(j + 1) % m, 2]
            la = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
            lb = math.sqrt(b0 * b0 + b1 * b1 + b2 * b2)
            if la == 0.0 or lb == 0.0:
                continue
            c0, c1, c2 = a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0
            s = math.sqrt(c0 * c0 + c1 * c1 + c2 * c2)
            if s > 0.0:
                beta = math.atan2(s / (la * lb), (a0 * b0 + a1 * b1 + a2 * b2) / (la * lb))
                total += beta * (n0 * c0 + n1 * c1 + n2 * c2) / s
        out[i] = 0.5 * abs(total) / area           # pi F / A, F = |total| / (2 pi)


def unshadowed_irradiance(P, Nrm, pix, light, samples, seed, scale) -> np.ndarray:
    """float64[n]: the light's direct irradiance at points P (normals Nrm)
    without occlusion, up to one constant factor per light (the mean of the
    reference's weights w_s over the light): in closed form for an area light
    (``area_irradiance_range``), else the mean over ``samples`` of the
    reference's own light samples (``unshadowed_range``). ``pixel_filter``
    weights the irradiance ratio's footprint with it (E0)."""
    lp = sampling.pack_light(light)
    n, ns = len(P), max(1, int(samples))
    out = np.zeros(n, np.float64)
    P = np.ascontiguousarray(P, np.float64)
    Nrm = np.ascontiguousarray(Nrm, np.float64)
    pix = np.ascontiguousarray(pix, np.int64)
    if light.kind == "area" and not light.is_zero_size:
        each_range(lambda a, b: area_irradiance_range(a, b, P, Nrm, lp, out), n)
    else:
        each_range(lambda a, b: unshadowed_range(a, b, P, Nrm, pix, lp, ns, int(seed), float(scale), out), n)
    return out


@register
class EmbreeReference(Method):
    id = "embree"
    paper = "reference: Monte Carlo shadow rays against the real triangles"
    passes = {"embree": AVERAGE, "embree_irr": IRRADIANCE}
    needs = frozenset({GBUFFER, SHADOW_GEOMETRY})
    packed = True                # shades each receiver of a packed G-buffer on its own
    runs_on_instances = True     # a G-buffer and shadow rays
    shutter_time = True          # each shadow ray at its receiver's time
    Params = EmbreeParams
    physical = True

    def subpixel_overrides(self, params, share: int):
        """Each sub-pixel receiver its share of the light samples (at least one)."""
        return {"samples": max(1, -(-int(params.samples) // max(1, int(share))))}

    def run(self, buffers, light, params: EmbreeParams) -> MethodResult:
        timer = PhaseTimer()
        g = buffers.gbuffer
        H, W = g.shape
        with timer("select"):
            idx, P, Nrm = g.hit_points()
        spread = g.spread(idx)
        ns = max(1, int(params.samples))
        if light.is_zero_size and (spread is None or not spread.any()):   # one ray finds a point's hard shadow
            ns = 1
        with timer("trace"):
            va, vi, rays = trace_visibility(buffers.shadow_scene_for(light), P, Nrm, g.seed_ids(idx), light, ns,
                                            int(params.seed), buffers.scale, time=g.times(idx),
                                            over_shutter=spread)
        out_a = np.ones(H * W, np.float32)
        out_i = np.ones(H * W, np.float32)
        out_a[idx] = va
        out_i[idx] = vi
        t = timer.result()
        return MethodResult(
            passes={"embree": out_a.reshape(H, W), "embree_irr": out_i.reshape(H, W)},
            time_s=t,
            stats={"rays": int(rays), "samples": ns,
                   "rays_per_s": float(rays / t["trace"]) if t.get("trace") else 0.0})
