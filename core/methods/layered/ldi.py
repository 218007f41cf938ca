"""The layered depth image (line 6 of procedure Precompute): per LDI pixel a
list of layers sorted by depth, each with a depth, a depth span and the set
of light samples that saw it, a bitmask of ceil(N / 64) words (``ldi_insert``;
its popcount is the paper's count, ``seen_count``); ``LDI`` holds the
finished maps of one light."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Dict, List

import numpy as np

from ...jit import HOT, inner, kernel
from ...scene import ViewFace

SPLAT_MIN_WEIGHT = 1e-6      # a neighbour with a smaller bilinear weight gets no splat
LAYERS_START = 8             # initial per-pixel layer capacity (grows on demand)


@dataclass
class LDI:
    """The precomputed layered attenuation maps of one light."""

    faces: List[ViewFace]           # the view from the light's centre
    depth: np.ndarray               # float64[F*h*w, K] layer depths (sorted)
    span: np.ndarray                # float64[F*h*w, K] surface depth change across a texel
    seen: np.ndarray                # uint64[F*h*w, K, ceil(N/64)] light samples seeing each layer
                                    # (sample s: bit s % 64 of word s // 64)
    n_layers: np.ndarray            # int32[F*h*w]
    samples: int                    # N
    epsilon: float
    warp: str
    complexity_by_samples: Dict[str, float]
    points: np.ndarray = None       # float64[N,3] sample points (sun: unit directions to it)
    light: np.ndarray = None        # sampling.pack_light: kind and axes for the irradiance weights
    directional: bool = False       # sun: ``points`` are directions
    centre: np.ndarray = None       # light centre (sun: mean direction) for the horizon bound
    reach: float = 0.0              # samples' bounding radius (sun: sin of the cone half-angle)
    render_s: float = 0.0           # summed Embree render time (worker threads)
    warp_insert_s: float = 0.0      # summed warp + insert time (main thread)

    @property
    def count(self) -> np.ndarray:
        """int64[F*h*w, K] light samples seeing each layer (the paper's count)."""
        return np.bitwise_count(self.seen).sum(axis=-1, dtype=np.int64)

    def nbytes(self) -> int:
        """Bytes of the layer arrays (capacity, not only the filled layers)."""
        return self.depth.nbytes + self.span.nbytes + self.seen.nbytes + self.n_layers.nbytes

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
        if layer < self.seen.shape[1]:
            out[has] = np.bitwise_count(self.seen[has, layer]).sum(axis=-1) / self.samples
        return out.reshape(F, h, w)


def seen_words(samples: int) -> int:
    """uint64 words per layer of a bitmask over ``samples`` light samples."""
    return max(1, -(-int(samples) // 64))


@inner(forceinline=True)
def popcount64(x):
    """Set bits of uint64 ``x`` (SWAR)."""
    x = x - ((x >> np.uint64(1)) & np.uint64(0x5555555555555555))
    x = (x & np.uint64(0x3333333333333333)) + ((x >> np.uint64(2)) & np.uint64(0x3333333333333333))
    x = (x + (x >> np.uint64(4))) & np.uint64(0x0F0F0F0F0F0F0F0F)
    return np.int64((x * np.uint64(0x0101010101010101)) >> np.uint64(56))


@inner(forceinline=True)
def seen_count(ldi_seen, pix, L):
    """Light samples that saw layer ``L`` of LDI pixel ``pix``."""
    c = 0
    for q in range(ldi_seen.shape[2]):
        c += popcount64(ldi_seen[pix, L, q])
    return c


def complexity(n_layers) -> float:
    """Average of ``n_layers`` over the pixels holding a layer (0 if none)."""
    nz = n_layers[n_layers > 0]
    return float(nz.mean()) if nz.size else 0.0


@kernel(opt=HOT, nogil=True)
def ldi_insert(ldi_depth, ldi_span, ldi_seen, ldi_n, wf, wx, wy, wz, gx, gy, span,
               foot, footprint, h, w, sample, eps, slope_t, foot_slope):
    """Insert one warped sample map: splat each point to the (up to four)
    neighbouring pixels with a non-zero bilinear weight (with ``footprint``:
    to the pixel centres in its footprint, unless its ``slope_t`` exceeds
    ``foot_slope``); join the nearest layer
    within tolerance (``eps`` + half the larger depth span across a texel of
    the point's and the layer's surface), setting ``sample``'s bit of its
    set (its count grows at most once per sample), or open a new layer
    (layers kept sorted by depth). Returns the arrays, reallocated when a
    pixel needs more layers than they hold."""
    sw = sample // 64
    sbit = np.uint64(1) << np.uint64(sample % 64)
    nw = ldi_seen.shape[2]
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
                    ldi_seen[pix, best, sw] |= sbit
                    continue
                K = ldi_depth.shape[1]
                if n == K:
                    nd = np.empty((ldi_depth.shape[0], 2 * K), ldi_depth.dtype)
                    ns = np.zeros((ldi_depth.shape[0], 2 * K), ldi_span.dtype)
                    nm = np.zeros((ldi_depth.shape[0], 2 * K, nw), ldi_seen.dtype)
                    for q in range(ldi_depth.shape[0]):   # element loops: a slice copy compiles
                        for L in range(K):                # Numba's shape-error formatting
                            nd[q, L] = ldi_depth[q, L]
                            ns[q, L] = ldi_span[q, L]
                            for c in range(nw):
                                nm[q, L, c] = ldi_seen[q, L, c]
                    ldi_depth, ldi_span, ldi_seen = nd, ns, nm
                pos = 0
                while pos < n and ldi_depth[pix, pos] < zc:
                    pos += 1
                for L in range(n, pos, -1):
                    ldi_depth[pix, L] = ldi_depth[pix, L - 1]
                    ldi_span[pix, L] = ldi_span[pix, L - 1]
                    for c in range(nw):
                        ldi_seen[pix, L, c] = ldi_seen[pix, L - 1, c]
                ldi_depth[pix, pos] = zc
                ldi_span[pix, pos] = sp
                for c in range(nw):
                    ldi_seen[pix, pos, c] = np.uint64(0)
                ldi_seen[pix, pos, sw] = sbit
                ldi_n[pix] = n + 1
    return ldi_depth, ldi_span, ldi_seen
