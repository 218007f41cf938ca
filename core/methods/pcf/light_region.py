"""region="light"'s sizes: the light's half extents per face in texels
(``light_reach``), its extent as the rays from a receiver cross a depth
(``light_halfwidth``), and the blocker search region narrowed by the tiles'
nearest depths (``search_region``)."""
from __future__ import annotations

import numpy as np

from ...jit import inner
from .tiles import TILE, _texel_box, tile_range

SEARCH_STEPS = 2     # narrowing steps of the blocker search region (``search_region``)


def light_reach(light, faces) -> np.ndarray:
    """float64[F, 3] per face: (ku, kv, ortho), the light's half extents along
    the face's u and v over the texel size (a perspective face: view-plane
    units at unit depth; a sun's orthographic face: tan(half angle) per unit
    of depth), for ``light_halfwidth``. An area light's rectangle (a disk's
    or ellipse's bounding one) is turned into the view's axes; a sphere
    light's facing disk has its radius on both; zero for a light of size zero."""
    out = np.zeros((len(faces), 3), np.float64)
    for k, face in enumerate(faces):
        rot = np.asarray(face.view_from_world, np.float64)[:3, :3]
        l, r, b, t = face.bounds
        tu, tv = (r - l) / face.width, (t - b) / face.height
        if light.kind == "area":
            ax, ay, _ = light.axes
            hx, hy = light.half_size
            ex, ey = rot @ (ax * hx), rot @ (ay * hy)
            half = (abs(ex[0]) + abs(ey[0]), abs(ex[1]) + abs(ey[1]))
        elif light.kind == "sphere":
            half = (light.radius, light.radius)
        else:
            half = (light.sun_spread, light.sun_spread)
        out[k] = (half[0] / tu, half[1] / tv, 1.0 if face.ortho else 0.0)
    return out


@inner(forceinline=True)
def light_halfwidth(lsize, z, zb):
    """Half extents (texels) of the light as the rays from a receiver at
    depth ``z`` cross depth ``zb``: lsize = (ku, kv, ortho) from
    ``light_reach``; ku (z - zb) / (z zb) for a perspective face, ku (z - zb)
    for an orthographic one (region="light", module doc)."""
    dz = max(z - zb, 0.0)
    if lsize[2] == 1.0:
        return lsize[0] * dz, lsize[1] * dz
    q = dz / (z * max(zb, 1e-30 * z))
    return lsize[0] * q, lsize[1] * q


@inner
def search_region(tt, w, h, s, t, z, lsize, zmin, sres, tres, MaxSize, steps):
    """region="light"'s blocker search region (half sizes, texels): the
    light's reach (``light_halfwidth``) at the nearest depth ``zmin`` of the
    face, at least the figure-4 region (``sres``, ``tres``), at most
    ``MaxSize``; then ``steps`` times (the filter's: SEARCH_STEPS) the reach
    at the nearest depth the tiles hold inside the region so far. Exact: a texel of
    depth d blocks a ray from the receiver to the light only within the
    reach at d, which shrinks as d grows, so every such texel stays inside."""
    zs = zmin
    ws, wt = light_halfwidth(lsize, z, zs)
    ws = min(max(ws, sres), MaxSize)
    wt = min(max(wt, tres), MaxSize)
    for _ in range(steps):
        u0, u1, v0, v1 = _texel_box(w, h, s, t, ws, wt)
        dmin, _ = tile_range(tt, int(v0) // TILE, (int(v1) - 1) // TILE,
                             int(u0) // TILE, (int(u1) - 1) // TILE)
        if not (dmin > zs):
            break
        zs = dmin
        ws2, wt2 = light_halfwidth(lsize, z, min(zs, z))
        ws = min(max(ws2, sres), ws)
        wt = min(max(wt2, tres), wt)
    return ws, wt
