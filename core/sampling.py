"""Light-shape sampling, per-pixel decorrelation, seeds, and the ray offset.

All randomness is a counter-based hash of (seed, pixel, sample, dimension)
(PCG's output permutation over a 32-bit state), so results do not depend on
how work is split across threads or batches: same seed -> same bits.

Light domains follow DESIGN.md: area lights uniform over their shape in the
local XY plane, sphere lights uniform over the disk of radius r through the
centre facing the shaded point, sun directions uniform in the cone of
half-angle angle/2 around the direction to the sun.
"""
from __future__ import annotations

import math

import numpy as np

from .jit import inner, kernel
from .kernels import each_range
from .scene import KIND_AREA, KIND_SPHERE, KIND_SUN, Light  # noqa: F401 (kernels' kind codes)

# packed light layout (float64[24]) for kernels
L_KIND, L_CX, L_AX, L_AY, L_AZ, L_HX, L_HY, L_SHAPE, L_RADIUS, L_COSMAX, L_SPOTCOS = \
    0, 1, 4, 7, 10, 13, 14, 15, 16, 17, 18


def pack_light(light: Light) -> np.ndarray:
    """float64[24]: kind, centre(3), local X, Y, Z axes (unit), half sizes,
    shape (0 rectangle, 1 ellipse), radius, cos of the sun cone half-angle,
    cos of the spot cone half-angle."""
    out = np.zeros(24, np.float64)
    out[L_KIND] = light.kind_code
    out[L_CX:L_CX + 3] = light.position
    for a, off in zip(light.axes, (L_AX, L_AY, L_AZ)):
        out[off:off + 3] = a
    out[L_HX], out[L_HY] = light.half_size
    out[L_SHAPE] = 1.0 if light.is_round else 0.0
    out[L_RADIUS] = light.radius
    out[L_COSMAX] = light.sun_cos_max
    out[L_SPOTCOS] = light.spot_cos
    return out


@kernel
def strata(n):
    """(nx, ny) with nx * ny == n and nx the largest divisor of n not above
    sqrt(n): the stratification of n light samples (every method's)."""
    n = max(1, n)
    nx = int(math.sqrt(n))
    while nx * nx > n:
        nx -= 1
    while (nx + 1) * (nx + 1) <= n:
        nx += 1
    while n % nx:
        nx -= 1
    return nx, n // nx


@inner(forceinline=True)
def stratum_uv(seed, key, s, nx, ny):
    """A jittered point of stratum s (row-major, nx x ny) of the unit
    square, the jitter from rand01(seed, key, s, 0 / 1) (np.int64: a
    literal argument would compile rand01 once per value)."""
    return ((s % nx) + rand01(seed, key, s, np.int64(0))) / nx, ((s // nx) + rand01(seed, key, s, np.int64(1))) / ny


# --------------------------------------------------------------------------
# counter-based random numbers
@inner(forceinline=True)
def _pcg(v):
    """PCG's output permutation of one LCG step of a uint32 (callers pass
    uint32 only: one compiled signature)."""
    v = (v * np.uint32(747796405) + np.uint32(2891336453)) & np.uint32(0xFFFFFFFF)
    word = (((v >> ((v >> np.uint32(28)) + np.uint32(4))) ^ v) * np.uint32(277803737)) & np.uint32(0xFFFFFFFF)
    return ((word >> np.uint32(22)) ^ word) & np.uint32(0xFFFFFFFF)


@inner(forceinline=True)
def rand01(seed, pixel, sample, dim):
    """Uniform in [0, 1) from four counters."""
    h = _pcg(np.uint32(dim))
    h = _pcg(np.uint32(np.uint32(sample) ^ h))
    h = _pcg(np.uint32(np.uint32(pixel >> 32) ^ h))
    h = _pcg(np.uint32(np.uint32(pixel & 0xFFFFFFFF) ^ h))
    h = _pcg(np.uint32(np.uint32(seed & 0xFFFFFFFF) ^ h))
    return np.float64(h >> np.uint32(8)) * (1.0 / 16777216.0)


@inner(forceinline=True)
def stream_start(seed, pixel):
    """A 32-bit state for one pixel's stream of cheap random numbers
    (``stream_next``): one hash per pixel instead of one per number."""
    h = _pcg(np.uint32(pixel >> 32))
    h = _pcg(np.uint32(np.uint32(pixel & 0xFFFFFFFF) ^ h))
    return _pcg(np.uint32(np.uint32(seed & 0xFFFFFFFF) ^ h))


@inner(forceinline=True)
def stream_next(state):
    """(next state, uniform in [0, 1)): PCG's output permutation of an LCG step."""
    state = (state * np.uint32(747796405) + np.uint32(2891336453)) & np.uint32(0xFFFFFFFF)
    word = (((state >> ((state >> np.uint32(28)) + np.uint32(4))) ^ state) * np.uint32(277803737)) & np.uint32(0xFFFFFFFF)
    word = ((word >> np.uint32(22)) ^ word) & np.uint32(0xFFFFFFFF)
    return state, np.float64(word >> np.uint32(8)) * (1.0 / 16777216.0)


@inner(forceinline=True)
def stream_word(state):
    """(next state, a uniform 32-bit word): ``stream_next``'s step with all
    of its output's bits, for a caller that splits one word into several
    coarser uniforms (pcf's sampler: three per sample)."""
    state = (state * np.uint32(747796405) + np.uint32(2891336453)) & np.uint32(0xFFFFFFFF)
    word = (((state >> ((state >> np.uint32(28)) + np.uint32(4))) ^ state) * np.uint32(277803737)) & np.uint32(0xFFFFFFFF)
    return state, ((word >> np.uint32(22)) ^ word) & np.uint32(0xFFFFFFFF)


@inner(forceinline=True)
def concentric_disk(u, v):
    """Shirley-Chiu concentric map of [0,1)^2 to the unit disk (area-preserving,
    keeps strata compact)."""
    a = 2.0 * u - 1.0
    b = 2.0 * v - 1.0
    if a == 0.0 and b == 0.0:
        return 0.0, 0.0
    if abs(a) > abs(b):
        r = a
        phi = (math.pi / 4.0) * (b / a)
    else:
        r = b
        phi = (math.pi / 2.0) - (math.pi / 4.0) * (a / b)
    return r * math.cos(phi), r * math.sin(phi)


@kernel(forceinline=True)
def orthonormal_basis(nx, ny, nz):
    """Duff et al. 2017 branchless ONB around a unit vector."""
    s = 1.0 if nz >= 0.0 else -1.0
    a = -1.0 / (s + nz)
    b = nx * ny * a
    return (1.0 + s * nx * nx * a, s * b, -s * nx), (b, s + ny * ny * a, -ny)


@inner
def light_sample(lp, px, py, pz, u, v):
    """A point on (or direction to) the light for unit-square coordinates (u, v).

    Returns (x, y, z, is_direction, cos_light): a world point on the light, or
    for a sun a unit direction towards it; ``cos_light`` is the cosine at the
    light used by the irradiance weight (1 for a sun).
    """
    kind = lp[0]
    cx, cy, cz = lp[1], lp[2], lp[3]
    if kind == 0.0:  # area
        if lp[15] == 1.0:
            dx, dy = concentric_disk(u, v)
        else:
            dx, dy = 2.0 * u - 1.0, 2.0 * v - 1.0
        dx *= lp[13]
        dy *= lp[14]
        x = cx + lp[4] * dx + lp[7] * dy
        y = cy + lp[5] * dx + lp[8] * dy
        z = cz + lp[6] * dx + lp[9] * dy
        return x, y, z, False, 0.0
    if kind == 1.0:  # sphere: disk through the centre facing the point
        wx, wy, wz = cx - px, cy - py, cz - pz
        d = math.sqrt(wx * wx + wy * wy + wz * wz)
        if d == 0.0 or lp[16] == 0.0:
            return cx, cy, cz, False, 1.0
        wx /= d
        wy /= d
        wz /= d
        b1, b2 = orthonormal_basis(wx, wy, wz)
        dx, dy = concentric_disk(u, v)
        r = lp[16]
        return (cx + (b1[0] * dx + b2[0] * dy) * r, cy + (b1[1] * dx + b2[1] * dy) * r,
                cz + (b1[2] * dx + b2[2] * dy) * r, False, 1.0)
    # sun: uniform over the spherical cap of half-angle a/2 around +Z (towards the sun)
    dx, dy = concentric_disk(u, v)
    r2 = dx * dx + dy * dy
    one_minus_cos = r2 * (1.0 - lp[17])
    cos_t = 1.0 - one_minus_cos
    sin_t = math.sqrt(max(0.0, one_minus_cos * (2.0 - one_minus_cos)))
    if r2 > 0.0:
        rr = math.sqrt(r2)
        sx, sy = dx / rr * sin_t, dy / rr * sin_t
    else:
        sx, sy = 0.0, 0.0
    x = lp[4] * sx + lp[7] * sy + lp[10] * cos_t
    y = lp[5] * sx + lp[8] * sy + lp[11] * cos_t
    z = lp[6] * sx + lp[9] * sy + lp[12] * cos_t
    return x, y, z, True, 1.0


@inner(forceinline=True)
def reference_sample(lp, seed, pixel, s, nx, ny, px, py, pz, ox, oy, oz, n0, n1, n2):
    """The ``embree`` reference's sample ``s`` of ``pixel`` (stratum s of an
    nx x ny grid, jittered by the counter hash), seen from origin (ox, oy, oz).

    Returns (u, v, x, y, z, is_dir, dx, dy, dz, dist, w_light): the unit-square
    point, the light point (or, for a sun, the direction), the unit direction
    from the origin, the distance (1e30 for a sun), and the light's share of
    the irradiance weight (cos at the light / d^2; 1 for a sun). Every method
    that traces "the reference's own samples" goes through here, so they
    cannot drift apart."""
    u, v = stratum_uv(seed, pixel, s, nx, ny)
    x, y, z, is_dir, cos_l = light_sample(lp, px, py, pz, u, v)
    if is_dir:
        return u, v, x, y, z, True, x, y, z, 1e30, 1.0
    dx, dy, dz = x - ox, y - oy, z - oz
    dist = math.sqrt(dx * dx + dy * dy + dz * dz)
    if dist > 0.0:
        dx /= dist
        dy /= dist
        dz /= dist
    else:
        dx, dy, dz = n0, n1, n2
    if lp[0] == 0.0:  # area light: one-sided, emits along its -Z
        cos_l = dx * lp[10] + dy * lp[11] + dz * lp[12]
        if cos_l < 0.0:
            cos_l = 0.0
    return u, v, x, y, z, False, dx, dy, dz, dist, cos_l / max(dist * dist, 1e-300)


# --------------------------------------------------------------------------
# self-intersection offset
OFFSET_ULPS = 32.0
@inner(forceinline=True)
def _nudge(p, of_i):
    """Move float32 ``p`` by ``of_i`` units in the last place, away from zero
    when ``of_i`` has p's sign."""
    b = np.float32(p).view(np.int32)
    if p < 0:
        b = b - of_i
    else:
        b = b + of_i
    return np.float64(np.int32(b).view(np.float32))


@inner(forceinline=True)
def offset_origin(px, py, pz, nx, ny, nz, scale):
    """Wächter & Binder, "A Fast and Robust Method for Avoiding Self-Intersection"
    (Ray Tracing Gems, ch. 6): move the hit point off its surface along the
    normal by ``OFFSET_ULPS`` float32 ULPs per component (scaled by the normal's
    component), or near the origin (where ULPs vanish) by ``scale / 65536``.

    Two departures, both documented: the paper's absolute constants (1/32,
    1/65536) assume scenes of unit size, so here they are multiplied by the
    scene's extent ``scale`` (the same scheme for a 1e-3 and a 1e4 scene); and
    the paper's 256 ULPs cover hit points computed as o + t d, whose error
    grows with t, while Penumbra's come from barycentrics on the float32
    triangle (error about one ULP of the vertices), so 32 ULPs keep a wide
    margin and shift a surface 8x less (0.03 units at 1e4 from the origin)."""
    origin = scale / 32.0
    fs = scale / 65536.0
    ix = np.int32(OFFSET_ULPS * nx)
    iy = np.int32(OFFSET_ULPS * ny)
    iz = np.int32(OFFSET_ULPS * nz)
    ox = px + fs * nx if abs(px) < origin else _nudge(px, ix)
    oy = py + fs * ny if abs(py) < origin else _nudge(py, iy)
    oz = pz + fs * nz if abs(pz) < origin else _nudge(pz, iz)
    return ox, oy, oz


def offset_points(P, Nrm, scale, to_float32, threads=None):
    """``offset_origin`` for every point P[i] with normal Nrm[i] (float64[n,3]);
    ``to_float32``: rounded to float32, as the Embree reference's own ray
    origins are (methods that must meet its rays exactly). Ranges of points
    on Numba's thread count (``kernels.each_range``)."""
    P = np.ascontiguousarray(P, np.float64)
    Nrm = np.ascontiguousarray(Nrm, np.float64)
    out = np.empty((P.shape[0], 3), np.float64)
    each_range(lambda i0, i1: _offset_points(i0, i1, P, Nrm, float(scale), bool(to_float32), out), P.shape[0], threads)
    return out


@kernel(nogil=True)
def _offset_points(i0, i1, P, Nrm, scale, to_float32, out):
    """``offset_points`` for points i0..i1-1 into ``out``."""
    for i in range(i0, i1):
        ox, oy, oz = offset_origin(P[i, 0], P[i, 1], P[i, 2], Nrm[i, 0], Nrm[i, 1], Nrm[i, 2], scale)
        if to_float32:
            ox, oy, oz = np.float64(np.float32(ox)), np.float64(np.float32(oy)), np.float64(np.float32(oz))
        out[i, 0] = ox
        out[i, 1] = oy
        out[i, 2] = oz


def scene_scale(lo, hi) -> float:
    """The extent used by ``offset_origin``: the bounding-box diagonal."""
    d = float(np.linalg.norm(np.asarray(hi, np.float64) - np.asarray(lo, np.float64)))
    return d if d > 0 and np.isfinite(d) else 1.0


@kernel
def light_sample_set(lp, n, seed):
    """The same ``n`` stratified jittered unit-square points for every pixel
    (the layered method's sampling, Agrawala et al. section 3), float64[n, 2]."""
    nx, ny = strata(n)
    out = np.empty((n, 2))
    for s in range(n):
        out[s, 0], out[s, 1] = stratum_uv(seed, np.int64(0), s, nx, ny)
    return out
