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
  samples     64       shadow rays per pixel (1 for a light of size zero)
  seed        0        seed of the counter hash that jitters the samples
  ==========  =======  ==================================================

Sampling: ``samples`` strata of the light's unit square (``sampling.strata``,
nx x ny), one jittered point in each, mapped onto the light's domain
(DESIGN.md "Light domains"); the jitter is a counter hash of (seed, pixel,
stratum) (``sampling.reference_sample``), so every pixel draws its own,
decorrelated samples and any method that shoots "the reference's own
samples" draws the same ones. Rays start at the G-buffer point moved off its
surface by ``sampling.offset_origin`` (Wächter & Binder, scaled to the scene
extent).

Rays are generated, traced (embreex's ``run()``, which releases the GIL)
and reduced in batches of about ``RAYS_PER_BATCH``, one worker thread per
Numba thread; a pixel's rays depend only on the seed and the pixel, so any
thread count gives the same bits.
"""
from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from .. import sampling
from ..jit import HOT, kernel
from ..kernels import each_in_threads
from ..sampling import offset_origin, reference_sample, strata
from .registry import register
from .base import AVERAGE, GBUFFER, IRRADIANCE, SHADOW_GEOMETRY, Method, MethodResult, PhaseTimer

SUN_TFAR = np.float32(1e30)
RAYS_PER_BATCH = 1 << 18


@dataclass
class EmbreeParams:
    samples: int = 64      # shadow rays per pixel (stratified, jittered)
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


def trace_visibility(tri_scene, P, Nrm, pix, light, samples, seed, scale, threads=None):
    """V_avg and V_irr (float32[n]) for points P with normals Nrm."""
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
        reduce_visibility(tri_scene.transmittance(org, dirs, tfar), w, ns, v_avg[a:b], v_irr[a:b])

    each_in_threads(work, chunks, max(1, int(threads or numba.get_num_threads())))
    return v_avg, v_irr, n * ns


def unshadowed_irradiance(P, Nrm, pix, light, samples, seed, scale) -> np.ndarray:
    """float64[n]: the light's direct irradiance at points P (normals Nrm)
    without occlusion, up to one constant factor per light: the mean of the
    reference's weights w_i over ``samples`` of its own light samples
    (``generate_shadow_rays``; nothing is traced). ``pixel_filter`` weights
    the irradiance ratio's footprint with it (E0)."""
    lp = sampling.pack_light(light)
    n, ns = len(P), max(1, int(samples))
    out = np.zeros(n, np.float64)
    per = max(1, RAYS_PER_BATCH // ns)
    P = np.ascontiguousarray(P, np.float64)
    Nrm = np.ascontiguousarray(Nrm, np.float64)
    pix = np.ascontiguousarray(pix, np.int64)
    for a in range(0, n, per):
        b = min(n, a + per)
        m = (b - a) * ns
        org, dirs = np.empty((m, 3), np.float32), np.empty((m, 3), np.float32)
        tfar, w = np.empty(m, np.float32), np.empty(m, np.float64)
        generate_shadow_rays(P[a:b], Nrm[a:b], pix[a:b], lp, ns, int(seed), scale, org, dirs, tfar, w)
        out[a:b] = w.reshape(b - a, ns).mean(axis=1)
    return out


@register
class EmbreeReference(Method):
    id = "embree"
    paper = "reference: Monte Carlo shadow rays against the real triangles"
    passes = {"embree": AVERAGE, "embree_irr": IRRADIANCE}
    needs = frozenset({GBUFFER, SHADOW_GEOMETRY})
    packed = True                # shades each receiver of a packed G-buffer on its own
    Params = EmbreeParams
    physical = True

    def run(self, buffers, light, params: EmbreeParams) -> MethodResult:
        timer = PhaseTimer()
        g = buffers.gbuffer
        H, W = g.shape
        with timer("select"):
            idx, P, Nrm = g.hit_points()
        ns = 1 if light.is_zero_size else max(1, int(params.samples))
        with timer("trace"):
            va, vi, rays = trace_visibility(buffers.shadow_scene_for(light), P, Nrm, g.seed_ids(idx), light, ns,
                                            int(params.seed), buffers.scale)
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
