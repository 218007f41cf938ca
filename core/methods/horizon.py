"""The horizon: the share of a light (DESIGN.md "Light domains") above a
receiver's tangent plane, i.e. the part of the light its own surface does
not hide. For the methods whose occluder tests cannot see a receiver shadow
itself (``single_sample``'s id test, ``irregular``'s silhouettes from the
light's centre).

Closed forms (``_share_at``), h the light centre's signed height above the
plane (along its normal n):

  * area rectangle / square (half sizes hx, hy along X, Y): the share of
    (u, v) in [-1, 1]^2 with h + A u + B v > 0, A = hx n.X, B = hy n.Y:
    1 - G(-h), G the trapezoidal CDF of A U + B V (U, V uniform);
  * area disk / ellipse: the share of the unit disk with h + s w > 0,
    s = |(A, B)|: the segment beyond the chord at x = -h / s,
    (acos x - x sqrt(1 - x^2)) / pi;
  * sphere of radius r: the same for the disk facing the point, s = r x
    the normal's part across the direction to the centre;
  * sun: the cone of directions in ``SUN_RINGS`` rings of equal solid
    angle, each cut exactly by the plane.

One Numba kernel over ranges of points (``_horizon_range``) on Numba's
thread count.
"""
from __future__ import annotations

import math

import numpy as np

from ..jit import inner, kernel
from ..kernels import each_range

SUN_RINGS = 16   # under a sun: rings of the cone of directions (equal solid angle)
SHAPE_RECT, SHAPE_ROUND, SHAPE_SPHERE, SHAPE_SUN = 0, 1, 2, 3   # lp[0]
N_LP = 18


def pack_light(light) -> np.ndarray:
    """float64[N_LP]: what ``_share_at`` needs of the light: shape code,
    position, unit axes X and Y, half sizes, radius, the direction to a sun,
    cos / sin of its half-angle."""
    lp = np.zeros(N_LP, np.float64)
    if light.kind == "sun":
        lp[0] = SHAPE_SUN
        lp[13:16] = -np.asarray(light.direction, np.float64)
        lp[16], lp[17] = math.cos(light.sun_half_angle), math.sin(light.sun_half_angle)
        return lp
    lp[0] = SHAPE_SPHERE if light.kind == "sphere" else (SHAPE_ROUND if light.is_round else SHAPE_RECT)
    lp[1:4] = np.asarray(light.position, np.float64)
    if light.kind == "area":
        ax, ay, _ = light.axes
        lp[4:7], lp[7:10] = ax, ay
        lp[10], lp[11] = light.half_size
    else:
        lp[12] = float(light.radius)
    return lp


@inner(error_model="numpy")
def _disk_share_at(x):
    """Share of the unit disk where its coordinate along some axis exceeds x
    (the segment beyond the chord at x)."""
    x = min(max(x, -1.0), 1.0)
    return (math.acos(x) - x * math.sqrt(1.0 - x * x)) / math.pi


@inner(error_model="numpy")
def _share_at(lp, px, py, pz, nx, ny, nz):
    """The share of the light ``lp`` (``pack_light``) above the plane
    through (px, py, pz) with normal (nx, ny, nz) (module docstring); 1 / 0
    where the plane does not cut the light."""
    shape = lp[0]
    nn = nx * nx + ny * ny + nz * nz
    if shape == SHAPE_SUN:
        h = nx * lp[13] + ny * lp[14] + nz * lp[15]
        m = math.sqrt(max(nn - h * h, 0.0))
        ca, sa = lp[16], lp[17]
        if h * ca - m * sa > 0.0:
            return 1.0
        if not (h * ca + m * sa > 0.0):
            return 0.0
        acc = 0.0
        for k in range(SUN_RINGS):      # rings of equal solid angle, each cut exactly
            cos_t = 1.0 - (k + 0.5) / SUN_RINGS * (1.0 - ca)
            sin_t = math.sqrt(max(1.0 - cos_t * cos_t, 0.0))
            x = -(cos_t * h) / (sin_t * m)
            if math.isnan(x):
                x = -1.0 if h > 0.0 else 1.0
            acc += math.acos(min(max(x, -1.0), 1.0)) / math.pi
        return acc / SUN_RINGS
    dx, dy, dz = lp[1] - px, lp[2] - py, lp[3] - pz
    h = nx * dx + ny * dy + nz * dz
    if shape == SHAPE_SPHERE:
        dist2 = dx * dx + dy * dy + dz * dz
        along2 = h * h / dist2 if dist2 > 0.0 else 0.0
        spread = lp[12] * math.sqrt(max(nn - along2, 0.0))
    else:
        A = lp[10] * (nx * lp[4] + ny * lp[5] + nz * lp[6])
        B = lp[11] * (nx * lp[7] + ny * lp[8] + nz * lp[9])
        spread = math.hypot(A, B) if shape == SHAPE_ROUND else abs(A) + abs(B)
    if h > spread:
        return 1.0
    if not (abs(h) <= spread):
        return 0.0
    if shape != SHAPE_RECT:                  # the disk facing the point / the ellipse
        if spread > 0.0:
            return _disk_share_at(-h / spread)
        return _disk_share_at(-np.inf if h > 0.0 else np.inf)
    # the rectangle: 1 - G(-h), G the trapezoidal CDF of a U + b V
    a = max(abs(A), abs(B))
    b = min(abs(A), abs(B))
    t = -h
    if not (a > 0.0):                        # a plane parallel to the light
        return 0.0 if t >= 0.0 else 1.0
    if t <= -(a + b):
        return 1.0
    if t >= a + b:
        return 0.0
    if t <= -(a - b):
        q = t + a + b
        G = q * q / (8.0 * a * b)
    elif t <= a - b:
        G = (t + a) / (2.0 * a)
    else:
        q = a + b - t
        G = 1.0 - q * q / (8.0 * a * b)
    return 1.0 if math.isnan(G) else 1.0 - G


@kernel(nogil=True, error_model="numpy")
def _horizon_range(i0, i1, P, Nrm, lp, only, out, scale):
    """Points i0..i1-1: ``out[i] = share`` or, with ``scale``, ``out[i] *=
    share`` where ``only[i]`` and out[i] > 0 (the share cannot lift a 0)."""
    for i in range(i0, i1):
        if scale and not (only[i] and out[i] > 0.0):
            continue
        s = _share_at(lp, P[i, 0], P[i, 1], P[i, 2],
                      np.float64(Nrm[i, 0]), np.float64(Nrm[i, 1]), np.float64(Nrm[i, 2]))
        out[i] = out[i] * s if scale else s


def horizon_share(light, P: np.ndarray, Nrm: np.ndarray, threads=None) -> np.ndarray:
    """float64[n]: the share of the light (DESIGN.md's light domains) above
    each point's tangent plane (normal Nrm, any length), ranges of points
    on Numba's thread count."""
    P = np.ascontiguousarray(P, np.float64)
    Nrm = np.ascontiguousarray(Nrm)
    if Nrm.dtype != np.float32:
        Nrm = np.ascontiguousarray(Nrm, np.float64)
    out = np.empty(P.shape[0], np.float64)
    lp = pack_light(light)
    only = np.zeros(1, np.bool_)
    each_range(lambda i0, i1: _horizon_range(i0, i1, P, Nrm, lp, only, out, False), P.shape[0], threads)
    return out


def scale_by_horizon(light, P: np.ndarray, Nrm: np.ndarray, only: np.ndarray, out: np.ndarray, threads=None) -> None:
    """``out[i] *= horizon_share`` in place where ``only[i]`` and out[i] > 0
    (P float64[n,3], Nrm float32 or float64[n,3], only bool[n], out
    float64[n], all contiguous): no gather of the points, nothing computed
    where V is already 0."""
    lp = pack_light(light)
    each_range(lambda i0, i1: _horizon_range(i0, i1, P, Nrm, lp, only, out, True), P.shape[0], threads)
