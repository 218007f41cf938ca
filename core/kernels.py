"""Small Numba helpers shared by the image-space methods: projecting a world
point into a packed ``ViewFace`` and picking the face that holds it, and the
camera pixel footprint on a surface's tangent plane."""
from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, inline="always")
def face_project(fp, x, y, z):
    """World point -> (u, v, depth) in face pixels; depth = -z_view.
    For perspective faces points at depth <= 0 get u = v = nan."""
    vx = fp[0] * x + fp[1] * y + fp[2] * z + fp[3]
    vy = fp[4] * x + fp[5] * y + fp[6] * z + fp[7]
    vz = fp[8] * x + fp[9] * y + fp[10] * z + fp[11]
    depth = -vz
    if fp[16] == 0.0:
        if depth <= 0.0:
            return np.nan, np.nan, depth
        vx /= depth
        vy /= depth
    u = (vx - fp[17]) / (fp[18] - fp[17]) * fp[21]
    v = (fp[20] - vy) / (fp[20] - fp[19]) * fp[22]
    return u, v, depth


@njit(cache=True)
def pick_face(faces, x, y, z):
    """Index of the first face whose window holds the point, or -1."""
    for f in range(faces.shape[0]):
        u, v, d = face_project(faces[f], x, y, z)
        if d > 0.0 and u >= 0.0 and v >= 0.0 and u < faces[f, 21] and v < faces[f, 22]:
            return f
        if faces[f, 16] == 1.0 and u >= 0.0 and v >= 0.0 and u < faces[f, 21] and v < faces[f, 22]:
            return f
    return -1


@njit(cache=True, inline="always")
def pixel_ray(cp, col, row):
    """Camera ray through float pixel (col, row): origin and unit direction."""
    x = cp[12] + col / cp[17] * (cp[13] - cp[12])
    y = cp[15] - row / cp[18] * (cp[15] - cp[14])
    if cp[16] == 1.0:
        ox = cp[9] + cp[0] * x + cp[1] * y
        oy = cp[10] + cp[3] * x + cp[4] * y
        oz = cp[11] + cp[6] * x + cp[7] * y
        return ox, oy, oz, -cp[2], -cp[5], -cp[8]
    dx = cp[0] * x + cp[1] * y - cp[2]
    dy = cp[3] * x + cp[4] * y - cp[5]
    dz = cp[6] * x + cp[7] * y - cp[8]
    n = math.sqrt(dx * dx + dy * dy + dz * dz)
    return cp[9], cp[10], cp[11], dx / n, dy / n, dz / n


@njit(cache=True)
def footprint_on_face(cp, fp, col, row, px, py, pz, nx, ny, nz, u0, v0, max_half):
    """Half extents (in face pixels) of the bounding box of camera pixel
    (col, row)'s four corners, intersected with the tangent plane through P
    with normal n and projected into face ``fp``. Corners whose ray misses the
    plane (grazing) give ``max_half``."""
    hu = 0.0
    hv = 0.0
    for k in range(4):
        c = col + (0.5 if k & 1 else -0.5) + 0.5
        r = row + (0.5 if k & 2 else -0.5) + 0.5
        ox, oy, oz, dx, dy, dz = pixel_ray(cp, c, r)
        den = dx * nx + dy * ny + dz * nz
        if abs(den) < 1e-12:
            return max_half, max_half
        t = ((px - ox) * nx + (py - oy) * ny + (pz - oz) * nz) / den
        if t <= 0.0:
            return max_half, max_half
        u, v, d = face_project(fp, ox + t * dx, oy + t * dy, oz + t * dz)
        if not (d > 0.0) or not np.isfinite(u) or not np.isfinite(v):
            return max_half, max_half
        hu = max(hu, abs(u - u0))
        hv = max(hv, abs(v - v0))
    return min(hu, max_half), min(hv, max_half)


@njit(cache=True)
def finite_bbox(depth):
    """Per face: (umin, umax, vmin, vmax) of finite depths (Reeves et al. 3.3),
    (1, 0, 1, 0) for an empty face."""
    F, h, w = depth.shape
    out = np.empty((F, 4), np.int64)
    for f in range(F):
        umin, umax, vmin, vmax = w, -1, h, -1
        for r in range(h):
            for c in range(w):
                if depth[f, r, c] < np.inf:
                    if c < umin:
                        umin = c
                    if c > umax:
                        umax = c
                    if r < vmin:
                        vmin = r
                    if r > vmax:
                        vmax = r
        out[f, 0], out[f, 1], out[f, 2], out[f, 3] = umin, umax, vmin, vmax
    return out
