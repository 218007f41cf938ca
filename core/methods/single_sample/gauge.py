"""The search gauge: the light's shape in the map's texel coordinates and the
penumbra scale s(z_b) of a blocker depth.
"""
import math
from collections import namedtuple

import numpy as np

from ...jit import inner
from .packed import NORM_L1, NORM_MAX, P_GSCALE, P_KIND, P_NORM, P_RADIUS, P_SUNTAN


Gauge = namedtuple("Gauge", "G00 G01 G10 G11 norm emax")
"""The search gauge: texel offset -> rho by the matrix G and the norm
(NORM_*), ``emax`` its largest stretch."""


@inner
def _light_axes(prm, finfo, fp, pvx, pvy, pvz):
    """The light's two half axes in the face's view coordinates:
    area: per face; sphere: the disk facing P; sun: tan(angle/2) along x, y."""
    kind = prm[P_KIND]
    if kind == 0.0:
        return finfo[0], finfo[1], finfo[2], finfo[3], finfo[4], finfo[5]
    if kind == 1.0:
        r = prm[P_RADIUS]
        n = math.sqrt(pvx * pvx + pvy * pvy + pvz * pvz)
        if n == 0.0:
            return r, 0.0, 0.0, 0.0, r, 0.0
        dx, dy, dz = pvx / n, pvy / n, pvz / n
        # any unit vector perpendicular to d, then d x b1
        if abs(dx) < 0.9:
            ax, ay, az = 0.0, -dz, dy          # e_x x d
        else:
            ax, ay, az = dz, 0.0, -dx          # e_y x d
        an = math.sqrt(ax * ax + ay * ay + az * az)
        ax, ay, az = ax / an, ay / an, az / an
        bx = dy * az - dz * ay
        by = dz * ax - dx * az
        bz = dx * ay - dy * ax
        return r * ax, r * ay, r * az, r * bx, r * by, r * bz
    t = prm[P_SUNTAN]
    return t, 0.0, 0.0, 0.0, t, 0.0


@inner
def _shape(prm, finfo_f, fp, pvx, pvy, pvz, zr):
    """The light's shape in the map (auto_radius): G maps texel offsets to
    the light's shape coordinates per unit of s(z_b) (gauge ``prm[P_NORM]``),
    ``emax`` the largest texel half extent of its unit ball."""
    ortho = fp[16] == 1.0
    ku = fp[21] / (fp[18] - fp[17])
    kv = fp[22] / (fp[20] - fp[19])
    a1x, a1y, a1z, a2x, a2y, a2z = _light_axes(prm, finfo_f, fp, pvx, pvy, pvz)
    if ortho:
        tx, ty = 0.0, 0.0
    else:
        tx, ty = pvx / zr, pvy / zr
    # o -> o_xy - o_d t_P with o_d = -o_z (first order in the light's size),
    # then to texel offsets: du = ku dx, dv = -kv dy
    n00 = ku * (a1x + a1z * tx)
    n01 = ku * (a2x + a2z * tx)
    n10 = -kv * (a1y + a1z * ty)
    n11 = -kv * (a2y + a2z * ty)
    fro = math.sqrt(n00 * n00 + n01 * n01 + n10 * n10 + n11 * n11)
    if not (fro > 0.0) or not np.isfinite(fro):
        return 1.0, 0.0, 0.0, 1.0, 1.0
    det = n00 * n11 - n01 * n10
    if abs(det) < 1e-6 * fro * fro:    # seen edge-on: keep a sliver of width
        n00 += 1e-3 * fro
        n11 += 1e-3 * fro
        det = n00 * n11 - n01 * n10
    gs = prm[P_GSCALE]
    norm = prm[P_NORM]
    if norm == NORM_MAX:
        eu = abs(n00) + abs(n01)
        ev = abs(n10) + abs(n11)
    elif norm == NORM_L1:
        eu = max(abs(n00), abs(n01))
        ev = max(abs(n10), abs(n11))
    else:
        eu = math.sqrt(n00 * n00 + n01 * n01)
        ev = math.sqrt(n10 * n10 + n11 * n11)
    return gs * n11 / det, -gs * n01 / det, -gs * n10 / det, gs * n00 / det, max(eu, ev) / gs


@inner
def _s_of(zb, zr, ortho):
    """Penumbra scale of a blocker at depth zb over a receiver at zr:
    1/zb - 1/zr (perspective), zr - zb (orthographic)."""
    if ortho:
        return zr - zb
    if zb <= 0.0:
        return np.inf
    return 1.0 / zb - 1.0 / zr
