"""The layered depth image (line 6 of procedure Precompute): per LDI pixel a
list of layers sorted by depth, each with a depth, a depth span and the
count of light samples that saw it (``ldi_insert``); ``LDI`` holds the
finished maps of one light."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Dict, List

import numpy as np

from ...jit import HOT, kernel
from ...scene import ViewFace

SPLAT_MIN_WEIGHT = 1e-6      # a neighbour with a smaller bilinear weight gets no splat
LAYERS_START = 8             # initial per-pixel layer capacity (grows on demand)


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
        """Average layers over the non-empty LDI pixels (figure 10 right)."""
        return complexity(self.n_layers)

    def attenuation(self, layer: int = 0) -> np.ndarray:
        """float32[F,h,w] attenuation map of one layer (NaN where absent)."""
        F, h, w = self.shape
        out = np.full(F * h * w, np.nan, np.float32)
        has = self.n_layers > layer
        if layer < self.count.shape[1]:
            out[has] = self.count[has, layer] / self.samples
        return out.reshape(F, h, w)


def complexity(n_layers) -> float:
    """Average of ``n_layers`` over the pixels holding a layer (0 if none)."""
    nz = n_layers[n_layers > 0]
    return float(nz.mean()) if nz.size else 0.0


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
                        for L in range(K):                # Numba's shape-error formatting
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
