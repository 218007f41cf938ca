"""The shading region of a camera pixel mapped into the depth map (Reeves
et al. 3.2): the camera's rays as affine functions of the pixel position
(``pixel_ray_terms``) and the half extents, in texels, of the pixel's
corners carried onto the receiver's tangent plane and into the map
(``pixel_footprint``: figure 4's ``sres``, ``tres`` before ResFactor)."""
from __future__ import annotations

import numpy as np

from ...jit import inner


def pixel_ray_terms(cp) -> np.ndarray:
    """The camera's rays through float pixel (c, r) as affine functions:
    origin = o0 + c oc + r orr, direction = d0 + c dc + r dr (unnormalised),
    rows (o0, oc, orr, d0, dc, dr) of a float64[6, 3], from ``pack_camera``'s
    layout."""
    R = np.array([cp[0], cp[3], cp[6]])
    U = np.array([cp[1], cp[4], cp[7]])
    B = np.array([cp[2], cp[5], cp[8]])
    eye = np.array([cp[9], cp[10], cp[11]])
    per_c = R * (cp[13] - cp[12]) / cp[17]
    per_r = -U * (cp[15] - cp[14]) / cp[18]
    corner = R * cp[12] + U * cp[15]
    zero = np.zeros(3)
    if cp[16] == 1.0:
        rows = (eye + corner, per_c, per_r, -B, zero, zero)
    else:
        rows = (eye, zero, zero, corner - B, per_c, per_r)
    return np.ascontiguousarray(np.array(rows, np.float64))


@inner
def pixel_footprint(rt, fp, col, row, px, py, pz, nx, ny, nz, u0, v0, max_half):
    """Half extents (in face texels) of the bounding box of camera pixel
    (col, row)'s four corners, carried along their camera rays onto the
    tangent plane through P (normal n) and projected into face ``fp``: the
    shading region of Reeves et al. 3.2 in the map. Corners whose ray misses the plane (grazing) or that
    fall behind the light give ``max_half``. The rays' affine terms ``rt``
    (``pixel_ray_terms``) leave two divisions per corner."""
    su = fp[21] / (fp[18] - fp[17])
    sv = fp[22] / (fp[20] - fp[19])
    hu = 0.0
    hv = 0.0
    for k in range(4):
        c = col + (1.0 if k & 1 else 0.0)
        r = row + (1.0 if k & 2 else 0.0)
        ox = rt[0, 0] + c * rt[1, 0] + r * rt[2, 0]
        oy = rt[0, 1] + c * rt[1, 1] + r * rt[2, 1]
        oz = rt[0, 2] + c * rt[1, 2] + r * rt[2, 2]
        dx = rt[3, 0] + c * rt[4, 0] + r * rt[5, 0]
        dy = rt[3, 1] + c * rt[4, 1] + r * rt[5, 1]
        dz = rt[3, 2] + c * rt[4, 2] + r * rt[5, 2]
        den = dx * nx + dy * ny + dz * nz
        if abs(den) < 1e-12 * (abs(dx) + abs(dy) + abs(dz)):
            return max_half, max_half
        t = ((px - ox) * nx + (py - oy) * ny + (pz - oz) * nz) / den
        if not (t > 0.0):
            return max_half, max_half
        x = ox + t * dx
        y = oy + t * dy
        z = oz + t * dz
        vx = fp[0] * x + fp[1] * y + fp[2] * z + fp[3]
        vy = fp[4] * x + fp[5] * y + fp[6] * z + fp[7]
        if fp[16] == 0.0:
            depth = -(fp[8] * x + fp[9] * y + fp[10] * z + fp[11])
            if not (depth > 0.0):
                return max_half, max_half
            inv = 1.0 / depth
            vx *= inv
            vy *= inv
        u = (vx - fp[17]) * su
        v = (fp[20] - vy) * sv
        if not (np.isfinite(u) and np.isfinite(v)):
            return max_half, max_half
        hu = max(hu, abs(u - u0))
        hv = max(hv, abs(v - v0))
    return min(hu, max_half), min(hv, max_half)
