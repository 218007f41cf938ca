"""``visibility="irradiance"``: the light's emission towards the receiver
at a point of the light's shape, which weighs the part of the light a
blocker texel hides (``coverage``): cos_l / d^2 on an area light (cos_l at
its emitting side), 1 / d^2 on a sphere light's facing disk, a sun's cos^3
of the angle from its axis (directions uniform in solid angle, the shape
in their gnomonic plane). Exact at the shape's box corners
(``corner_weights``), bilinear between them (``part_weight``): the
emission is smooth over a light.
"""
import math

from ...jit import inner
from .packed import P_KIND

NO_WEIGHTS = (0.0, 0.0, 0.0, 0.0, 0.0)   # ``corner_weights``' value where parts are not weighted


@inner(forceinline=True)
def _emission(kind, lx, ly, lz, pvx, pvy, pvz, zx, zy, zz):
    """The emission towards the receiver at view (pvx, pvy, pvz) from the
    light's point (lx, ly, lz) (a sun: the direction, its axis the view's
    +Z); (zx, zy, zz): an area light's Z axis."""
    if kind == 2.0:
        return 1.0 / (lx * lx + ly * ly + 1.0) ** 1.5
    dx, dy, dz = lx - pvx, ly - pvy, lz - pvz
    d2 = dx * dx + dy * dy + dz * dz
    if not (d2 > 0.0):
        return 0.0
    if kind == 1.0:
        return 1.0 / d2
    cos_l = (dx * zx + dy * zy + dz * zz) / math.sqrt(d2)
    return cos_l / d2 if cos_l > 0.0 else 0.0


@inner
def corner_weights(prm, finfo_f, pvx, pvy, pvz, a1x, a1y, a1z, a2x, a2y, a2z):
    """(1, the emission at the shape's box corners y = (-1, -1), (1, -1),
    (-1, 1), (1, 1)): the light's point y1 a1 + y2 a2 (a sun: the
    direction y1 a1 + y2 a2 + the view's +Z), seen from the receiver at view
    (pvx, pvy, pvz); ``finfo_f[8:11]``: the light's Z axis in the view."""
    kind = prm[P_KIND]
    zx, zy, zz = finfo_f[8], finfo_f[9], finfo_f[10]
    e0 = _emission(kind, -a1x - a2x, -a1y - a2y, -a1z - a2z, pvx, pvy, pvz, zx, zy, zz)
    e1 = _emission(kind, a1x - a2x, a1y - a2y, a1z - a2z, pvx, pvy, pvz, zx, zy, zz)
    e2 = _emission(kind, -a1x + a2x, -a1y + a2y, -a1z + a2z, pvx, pvy, pvz, zx, zy, zz)
    e3 = _emission(kind, a1x + a2x, a1y + a2y, a1z + a2z, pvx, pvy, pvz, zx, zy, zz)
    return 1.0, e0, e1, e2, e3


@inner(forceinline=True)
def part_weight(ew, y1, y2):
    """The emission at (y1, y2) of the shape's box, bilinear between
    ``corner_weights``' ``ew``."""
    f1 = 0.5 * (y1 + 1.0)
    f2 = 0.5 * (y2 + 1.0)
    return (1.0 - f2) * ((1.0 - f1) * ew[1] + f1 * ew[2]) + f2 * ((1.0 - f1) * ew[3] + f1 * ew[4])


@inner(forceinline=True)
def bilinear_sum(ew, m0, mx, my, mxy):
    """Sum of ``part_weight`` over parts with weights w_k at (x_k, y_k),
    from their moments m0 = sum w_k, mx = sum w_k x_k, my = sum w_k y_k,
    mxy = sum w_k x_k y_k (the weight is bilinear)."""
    c = 0.25 * (ew[1] + ew[2] + ew[3] + ew[4])
    cx = 0.25 * (-ew[1] + ew[2] - ew[3] + ew[4])
    cy = 0.25 * (-ew[1] - ew[2] + ew[3] + ew[4])
    cxy = 0.25 * (ew[1] - ew[2] - ew[3] + ew[4])
    return c * m0 + cx * mx + cy * my + cxy * mxy
