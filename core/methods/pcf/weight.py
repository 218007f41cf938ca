"""``visibility="irradiance"``: each sample of the filter region stands for
a point of the light (region="light": the region is the light's extent at
the blocker depth z_b) and weighs the light's emission towards the
receiver there: cos_l / d^2 on an area light (cos_l at its emitting side),
1 / d^2 on a sphere light's facing disk, a sun's cos^3 of the angle from
its axis (its directions are uniform in solid angle, the region in their
gnomonic plane), nothing past the light's shape (a disk's or a turned
rectangle's box corners). The receiver's cos_r is left out (the package's
doc says why).

A region corner's point: its offset from the region's centre scaled by the
light's extent at z_b over the region's (a region widened to figure 4's or
narrowed to MaxSize still spans the whole light), the ray from the receiver
through that texel position at depth z_b, met with the light (an area
light's plane, the disk facing the receiver, a sun's direction)
(``_corner``). Between the corners, the point's coordinates in the light's
shape and its weight are bilinear (exact for the point where the light's
plane is parallel to the map's, an area light seen from its own face)
(``sample_weight``). Per face the light in view coordinates
(``light_frames``), per pixel the corners (``weight_frame``).
"""
from __future__ import annotations

import math

import numpy as np

from ...jit import inner

N_LF = 13         # ``light_frames``' columns
N_WF = 18         # ``weight_frame``'s entries
#: ``weight_frame``'s value where samples are not weighted (its first entry 0)
NO_WEIGHTS = (0.0,) * N_WF


def light_frames(light, faces) -> np.ndarray:
    """float64[F, N_LF] per face, the light in its view coordinates (the
    light's centre at the origin): kind (0 area, 1 sphere, 2 sun), round
    (a disk or ellipse), half sizes (area) | radius | tan of the sun's
    half angle, and the light's unit X, Y, Z axes (an area light emits
    along -Z)."""
    out = np.zeros((len(faces), N_LF), np.float64)
    ax, ay, az = light.axes
    for k, face in enumerate(faces):
        rot = np.asarray(face.view_from_world, np.float64)[:3, :3]
        out[k, 0] = float(light.kind_code)
        out[k, 1] = 1.0 if light.is_round else 0.0
        if light.kind == "area":
            out[k, 2], out[k, 3] = light.half_size
        elif light.kind == "sphere":
            out[k, 2] = out[k, 3] = float(light.radius)
        else:
            out[k, 2] = out[k, 3] = light.sun_spread
        out[k, 4:7], out[k, 7:10], out[k, 10:13] = rot @ ax, rot @ ay, rot @ az
    return out


@inner(forceinline=True)
def _corner(fp, lf, zb, pvx, pvy, pvz, xs, ys, ux, uy, uz, vx, vy, vz):
    """(a, b, w): the light's point for texel position (xs, ys) at depth
    ``zb`` seen from the receiver at view (pvx, pvy, pvz), in the light's
    shape coordinates (the unit square, or the unit disk where ``lf[1]``,
    a sphere's, a sun's), and its weight (module doc); ``u``, ``v``: a
    sphere light's disk axes. w = 0 (and a, b far outside) where the ray
    misses the light's plane."""
    X = fp[17] + xs * (fp[18] - fp[17]) / fp[21]
    Y = fp[20] - ys * (fp[20] - fp[19]) / fp[22]
    if fp[16] == 1.0:                 # orthographic (a sun): the direction through (X, Y) at depth zb
        ex, ey, ez = X - pvx, Y - pvy, -zb - pvz
    else:
        ex, ey, ez = X * zb - pvx, Y * zb - pvy, -zb - pvz
    kind = lf[0]
    if kind == 2.0:
        if not (ez > 0.0):
            return 2.0, 2.0, 0.0
        c = ez / math.sqrt(ex * ex + ey * ey + ez * ez)
        return ex / (ez * lf[2]), ey / (ez * lf[2]), c * c * c
    if kind == 0.0:                   # the light's plane
        mx, my, mz = lf[10], lf[11], lf[12]
    else:                             # the disk through the centre facing the receiver
        mx, my, mz = pvx, pvy, pvz
    den = ex * mx + ey * my + ez * mz
    tt = -(pvx * mx + pvy * my + pvz * mz) / den if den != 0.0 else -1.0
    if not (tt > 0.0) or not np.isfinite(tt):
        return 2.0, 2.0, 0.0
    dx, dy, dz = tt * ex, tt * ey, tt * ez          # from the receiver to the light's point
    lx, ly, lz = pvx + dx, pvy + dy, pvz + dz
    d2 = dx * dx + dy * dy + dz * dz
    if kind == 0.0:
        a = (lx * lf[4] + ly * lf[5] + lz * lf[6]) / lf[2]
        b = (lx * lf[7] + ly * lf[8] + lz * lf[9]) / lf[3]
        cos_l = (dx * mx + dy * my + dz * mz) / math.sqrt(d2)
        return a, b, (cos_l / d2 if cos_l > 0.0 else 0.0)
    return (lx * ux + ly * uy + lz * uz) / lf[2], (lx * vx + ly * vy + lz * vz) / lf[2], 1.0 / d2


@inner
def weight_frame(fp, lf, zb, px, py, pz, s, t, sres, tres, ku, kv):
    """The tuple ``sample_weight`` reads for a receiver at world (px, py, pz)
    seen in face ``fp`` (``lf``: the face's ``light_frames`` row), the
    region of half sizes (sres, tres) around texel position (s, t), the
    blocker depth ``zb`` and the light's extent at zb over the region's per
    axis (ku, kv): (1, the region's corner (s - sres, t - tres), 1 / its
    size per axis, the shape (0 square, 1 disk), then (a, b, w) at its four
    corners (``_corner``))."""
    pvx = fp[0] * px + fp[1] * py + fp[2] * pz + fp[3]
    pvy = fp[4] * px + fp[5] * py + fp[6] * pz + fp[7]
    pvz = fp[8] * px + fp[9] * py + fp[10] * pz + fp[11]
    ux, uy, uz, vx, vy, vz = 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    if lf[0] == 1.0:                  # a sphere: axes of the disk facing the receiver
        n = math.sqrt(pvx * pvx + pvy * pvy + pvz * pvz)
        wx, wy, wz = pvx / n, pvy / n, pvz / n
        if abs(wx) < 0.9:
            ux, uy, uz = 0.0, -wz, wy
        else:
            ux, uy, uz = wz, 0.0, -wx
        un = math.sqrt(ux * ux + uy * uy + uz * uz)
        ux, uy, uz = ux / un, uy / un, uz / un
        vx, vy, vz = wy * uz - wz * uy, wz * ux - wx * uz, wx * uy - wy * ux
    a0, b0, w0 = _corner(fp, lf, zb, pvx, pvy, pvz, s - sres * ku, t - tres * kv, ux, uy, uz, vx, vy, vz)
    a1, b1, w1 = _corner(fp, lf, zb, pvx, pvy, pvz, s + sres * ku, t - tres * kv, ux, uy, uz, vx, vy, vz)
    a2, b2, w2 = _corner(fp, lf, zb, pvx, pvy, pvz, s - sres * ku, t + tres * kv, ux, uy, uz, vx, vy, vz)
    a3, b3, w3 = _corner(fp, lf, zb, pvx, pvy, pvz, s + sres * ku, t + tres * kv, ux, uy, uz, vx, vy, vz)
    square = 1.0 if (lf[0] == 0.0 and lf[1] == 0.0) else 0.0
    return (1.0, s - sres, t - tres, 0.5 / sres, 0.5 / tres, 1.0 - square,
            a0, b0, w0, a1, b1, w1, a2, b2, w2, a3, b3, w3)


@inner(forceinline=True)
def sample_weight(wf, xs, ys):
    """The weight of the light's point a sample at texel position (xs, ys)
    stands for, at the receiver of ``wf`` (``weight_frame``): bilinear
    between the region's corners, 0 past the light's shape."""
    fa = (xs - wf[1]) * wf[3]
    fb = (ys - wf[2]) * wf[4]
    ga, gb = 1.0 - fa, 1.0 - fb
    c0, c1, c2, c3 = ga * gb, fa * gb, ga * fb, fa * fb
    a = c0 * wf[6] + c1 * wf[9] + c2 * wf[12] + c3 * wf[15]
    b = c0 * wf[7] + c1 * wf[10] + c2 * wf[13] + c3 * wf[16]
    if wf[5] == 1.0:
        if a * a + b * b > 1.0:
            return 0.0
    elif abs(a) > 1.0 or abs(b) > 1.0:
        return 0.0
    return c0 * wf[8] + c1 * wf[11] + c2 * wf[14] + c3 * wf[17]
