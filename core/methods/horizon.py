"""The horizon: the share of a light (DESIGN.md's light domains) above a
receiver's tangent plane, the light its own surface does not hide (issue
17). For the methods whose occluder tests cannot see a receiver shadow
itself (``single_sample``'s id test, ``irregular``'s silhouettes from the
light's centre). Closed forms in NumPy: no kernel to compile."""
from __future__ import annotations

import math

import numpy as np

SUN_RINGS = 16   # under a sun: rings of the cone of directions (equal solid angle)


def _disk_share(x):
    """Share of the unit disk where its coordinate along some axis exceeds x
    (the segment beyond the chord at x)."""
    x = np.clip(x, -1.0, 1.0)
    return (np.arccos(x) - x * np.sqrt(1.0 - x * x)) / np.pi


def _share_above(h, s):
    """Share of a unit disk mapped to h + s w (w its coordinate along one
    axis) where that is > 0: the light above a plane at signed height h whose
    tilt spreads it by s."""
    with np.errstate(divide="ignore", invalid="ignore"):
        x = np.where(s > 0.0, -h / np.where(s > 0.0, s, 1.0), np.where(h > 0.0, -np.inf, np.inf))
    return _disk_share(x)


def _square_share_above(h, A, B):
    """Share of (u, v) in [-1, 1]^2 with h + A u + B v > 0: 1 - G(-h), G the
    trapezoidal CDF of a U + b V (a >= b the larger / smaller of |A|, |B|)."""
    a = np.maximum(np.abs(A), np.abs(B))
    b = np.minimum(np.abs(A), np.abs(B))
    t = -h
    with np.errstate(divide="ignore", invalid="ignore"):
        lo = (t + a + b) ** 2 / (8.0 * a * b)
        mid = (t + a) / (2.0 * a)
        hi = 1.0 - (a + b - t) ** 2 / (8.0 * a * b)
    G = np.where(t <= -(a - b), lo, np.where(t <= a - b, mid, hi))
    G = np.where(t <= -(a + b), 0.0, np.where(t >= a + b, 1.0, G))
    G = np.where(a > 0.0, G, (t >= 0.0).astype(np.float64))        # a plane parallel to the light
    return 1.0 - np.nan_to_num(G, nan=0.0)


def horizon_share(light, P: np.ndarray, Nrm: np.ndarray) -> np.ndarray:
    """float64[n]: the share of the light (DESIGN.md's light domains) above
    each point's tangent plane (normal Nrm). Area lights: the rectangle's /
    ellipse's area (closed forms); sphere lights: the disk of radius r facing
    the point; suns: the cone's solid angle (``SUN_RINGS`` rings of equal
    solid angle, each cut exactly). Only points whose plane cuts the light
    are computed (1 / 0 for the others)."""
    P = np.asarray(P, np.float64)
    N = np.asarray(Nrm, np.float64)
    nn = np.einsum("ij,ij->i", N, N)
    if light.kind == "sun":
        h = N @ -np.asarray(light.direction, np.float64)
        m = np.sqrt(np.maximum(nn - h * h, 0.0))
        ca, sa = math.cos(light.sun_half_angle), math.sin(light.sun_half_angle)
        out = (h * ca - m * sa > 0.0).astype(np.float64)      # the whole cone above / not
        cut = np.flatnonzero((h * ca - m * sa <= 0.0) & (h * ca + m * sa > 0.0))
        cos_t = 1.0 - (np.arange(SUN_RINGS) + 0.5) / SUN_RINGS * (1.0 - ca)
        sin_t = np.sqrt(np.maximum(1.0 - cos_t * cos_t, 0.0))
        # per ring: the share of the circle's angle with cos_t h + sin_t m cos(phi) > 0
        with np.errstate(divide="ignore", invalid="ignore"):
            x = -(cos_t[None, :] * h[cut, None]) / (sin_t[None, :] * m[cut, None])
        x = np.where(np.isnan(x), np.where(h[cut, None] > 0.0, -1.0, 1.0), x)
        out[cut] = (np.arccos(np.clip(x, -1.0, 1.0)) / np.pi).mean(axis=1)
        return out
    d = np.asarray(light.position, np.float64) - P
    h = np.einsum("ij,ij->i", N, d)
    if light.kind == "sphere":
        dist2 = np.einsum("ij,ij->i", d, d)
        with np.errstate(divide="ignore", invalid="ignore"):
            along2 = np.where(dist2 > 0.0, h * h / dist2, 0.0)
        spread = light.radius * np.sqrt(np.maximum(nn - along2, 0.0))
    else:
        ax, ay, _ = light.axes
        hx, hy = light.half_size
        A = hx * (N @ ax)
        B = hy * (N @ ay)
        spread = np.hypot(A, B) if light.is_round else np.abs(A) + np.abs(B)
    out = (h > spread).astype(np.float64)
    cut = np.flatnonzero(np.abs(h) <= spread)
    if light.kind == "area" and not light.is_round:
        out[cut] = _square_share_above(h[cut], A[cut], B[cut])
    else:
        out[cut] = _share_above(h[cut], spread[cut])
    return out
