"""V per receiver from its relations l_i -> r_j: the average of the paper
(Agrawala et al. equation 2) or the irradiance ratio (equation 1 with and
without V), the pass that composites (``visibility``).

* average: V = (1 / S) sum_i v_i; from a mask, 1 - blocked / S.
* irradiance: V = sum_i w_i v_i / sum_i w_i with the ``embree`` reference's
  weights (``sampling.reference_sample`` times cos_r):
  w_i = cos_r cos_l / d^2 from the receiver point (the reference's ray
  origin) to sample l_i, cos_r at the receiver's normal (clamped at 0),
  cos_l at the light (area: its one-sided -Z emission, clamped at 0; sphere:
  the disk faces the point, 1; sun: w_i = cos_r). ``sample_weights`` forms
  them without square roots or branches, equal to the reference's up to
  rounding.

v_i is 0 or 1 past opaque blockers, a transmittance through alpha mattes
(``alpha_blockers``). Either way a receiver in full umbra is 0 and one
without a mask (nothing blocks it) is 1, so the weights are evaluated only
for receivers with a mask, and the switches that free or never allocate
masks change no bit. Where no weight is positive (the receiver faces away
from every sample: the light does not reach it) the ratio is undefined and
V is the average; the frame sets such pixels to 1.

The receivers carry their normals (``cast.Receivers.N``) only for the
irradiance ratio: no normals (zero rows) selects the average.
"""
from __future__ import annotations

import math

import numpy as np

from ...jit import inner, kernel
from ...sampling import L_AZ, L_KIND
from ...scene import KIND_AREA, KIND_SUN
from .light import receiver_samples


@inner(forceinline=True)
def _popcount(x):
    x = x - ((x >> np.uint64(1)) & np.uint64(0x5555555555555555))
    x = (x & np.uint64(0x3333333333333333)) + ((x >> np.uint64(2)) & np.uint64(0x3333333333333333))
    x = (x + (x >> np.uint64(4))) & np.uint64(0x0F0F0F0F0F0F0F0F)
    return int((x * np.uint64(0x0101010101010101)) >> np.uint64(56))


@inner(forceinline=True)
def sample_weights(lp, P, ox, oy, oz, n0, n1, n2, wts):
    """wts[i]: the reference's irradiance weight cos_r cos_l / d^2 of light
    sample P[:, i] (``light.receiver_samples``: points with w = 1, a sun's
    unit directions with w = 0) seen from (ox, oy, oz) with normal n (packed
    light ``lp``). With v = l_i - o: cos_r = n.v / |v|, an area light's
    cos_l = z.v / |v| (its axis z, the back of its -Z emission clamped to
    0), so w = (n.v)(z.v) / |v|^4; a sphere's disk faces the point, w =
    n.v / |v|^3; a sun's w = n.d. No branch in the loops: they vectorize."""
    S = P.shape[1]
    kind = lp[L_KIND]
    if kind == KIND_SUN:
        for i in range(S):
            wts[i] = max(P[0, i] * n0 + P[1, i] * n1 + P[2, i] * n2, 0.0)
    elif kind == KIND_AREA:
        zx, zy, zz = lp[L_AZ], lp[L_AZ + 1], lp[L_AZ + 2]
        for i in range(S):
            vx, vy, vz = P[0, i] - ox, P[1, i] - oy, P[2, i] - oz
            d2 = vx * vx + vy * vy + vz * vz
            cr = max(vx * n0 + vy * n1 + vz * n2, 0.0)
            cl = max(vx * zx + vy * zy + vz * zz, 0.0)
            wts[i] = cr * cl / max(d2 * d2, 1e-300)
    else:                                # sphere
        for i in range(S):
            vx, vy, vz = P[0, i] - ox, P[1, i] - oy, P[2, i] - oz
            d2 = vx * vx + vy * vy + vz * vz
            cr = max(vx * n0 + vy * n1 + vz * n2, 0.0)
            wts[i] = cr / max(d2 * math.sqrt(d2), 1e-300)


@kernel(nogil=True)
def chunk_visibility(smp, rec, fu, slot, pool, S, out):
    """V per receiver from its mask of blocked samples (module docstring):
    full umbra (mask released) 0; no mask 1; else 1 - blocked / S, or with
    normals ``rec.N`` the weighted share of the samples not blocked.
    smp: light.LightSamples; rec: cast.Receivers."""
    weighted = rec.N.shape[0] > 0
    pts, N, lp = rec.pts, rec.N, smp.lp
    P = np.empty((4, S if weighted else 0))
    wts = np.empty(S if weighted else 0)
    for r in range(fu.shape[0]):
        if fu[r]:
            out[r] = 0.0
        elif slot[r] < 0:
            out[r] = 1.0
        elif not weighted:
            c = 0
            for w in range(pool.shape[1]):
                c += _popcount(pool[slot[r], w])
            out[r] = 1.0 - c / S
        else:
            sl = slot[r]
            receiver_samples(smp, rec, r, P)
            sample_weights(lp, P, pts[r, 0], pts[r, 1], pts[r, 2], N[r, 0], N[r, 1], N[r, 2], wts)
            c = 0
            lit = 0.0
            tot = 0.0
            for i in range(S):
                b = (pool[sl, i >> 6] >> np.uint64(i & 63)) & np.uint64(1)
                c += np.int64(b)
                tot += wts[i]
                lit += wts[i] * (1.0 - np.float64(b))
            out[r] = lit / tot if tot > 0.0 else 1.0 - c / S
