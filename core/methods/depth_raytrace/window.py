"""Where a sun's orthographic reference views look (``depth_raytrace``).

The paper "places no restrictions on the position and orientation of the
reference views" and leaves choosing them open (section 5.1.2, footnote 4).
A window fitted to every visible receiver spends the map on ground nothing
shadows: under a low sun over a wide ground, thin pillars are a texel or two
wide, and their silhouettes, quantised to texel edges (floors and walls),
spread into their penumbrae.

A ray needs the depth images only where it can be blocked, so the window
only has to hold the *blockers*: the geometry some visible receiver's cone
of shadow rays can pass behind. Found on one orthographic view along the
sun's centre direction, fitted to the receivers: a ray from receiver p
(depth z_p) leaving at most alpha = the sun's half-angle from the view axis
lies, at lateral distance rho from p, at depth <= z_p - rho cot(alpha). It
can therefore be behind the floor Zp(q) of texel q only if

    Zp(q) < F(q) = max_p  z_p - cot(alpha) * rho(p, q),

the upper envelope of the receivers' cones, computed with the chessboard
distance (<= the Euclidean one, so F is over- rather than under-estimated)
by a two-pass distance transform (``cone_envelope``). The floors carry the
method's bias, which keeps a receiver in front of its own texel's floor, so
the receivers' own surfaces do not count. Thin caster triangles the render
can miss between texel centres are added by their vertices
(``thin_blockers``). Rays leaving the window are unresolved there, which the
tracer already treats as unblocked once no image knows more (section 5.1:
"until ... we pass through all the shadow maps").
"""
from __future__ import annotations

import math

import numpy as np

from ...jit import kernel


@kernel
def cone_envelope(R, step):
    """max over texels q of R(q) - step * chessboard distance (in texels), per
    texel (two raster passes); R = -inf where no receiver projects."""
    h, w = R.shape
    F = R.copy()
    for i in range(h):
        for j in range(w):
            b = F[i, j]
            if j > 0:
                b = max(b, F[i, j - 1] - step)
            if i > 0:
                for jj in range(max(j - 1, 0), min(j + 2, w)):
                    b = max(b, F[i - 1, jj] - step)
            F[i, j] = b
    for i in range(h - 1, -1, -1):
        for j in range(w - 1, -1, -1):
            b = F[i, j]
            if j + 1 < w:
                b = max(b, F[i, j + 1] - step)
            if i + 1 < h:
                for jj in range(max(j - 1, 0), min(j + 2, w)):
                    b = max(b, F[i + 1, jj] - step)
            F[i, j] = b
    return F


def to_view(face, pts: np.ndarray):
    """World points -> (texel column, texel row, depth) in orthographic ``face``."""
    m = np.asarray(face.view_from_world, np.float64)
    v = pts @ m[:3, :3].T + m[:3, 3]
    l, r, b, t = face.bounds
    return (v[:, 0] - l) / (r - l) * face.width, (t - v[:, 1]) / (t - b) * face.height, -v[:, 2]


def to_world(face, col: np.ndarray, row: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """Texel centres (column, row) at ``depth`` in orthographic ``face`` -> world points."""
    m = np.asarray(face.view_from_world, np.float64)
    l, r, b, t = face.bounds
    v = np.stack([l + (col + 0.5) / face.width * (r - l), t - (row + 0.5) / face.height * (t - b), -depth], -1)
    return (v - m[:3, 3]) @ m[:3, :3]


def _max_over_boxes(F: np.ndarray, c0, c1, r0, r1) -> np.ndarray:
    """Per box [c0, c1] x [r0, r1] (texel indices, inclusive) an upper bound of
    F's maximum over it: the max of the <= 2 x 2 nodes of the max pyramid at
    the first level where the box spans at most two nodes per axis."""
    levels = [F]
    while max(levels[-1].shape) > 1:
        a = levels[-1]
        h, w = a.shape
        a = np.pad(a, ((0, h % 2), (0, w % 2)), constant_values=-np.inf)
        levels.append(a.reshape(a.shape[0] // 2, 2, a.shape[1] // 2, 2).max(axis=(1, 3)))
    span = np.maximum(c1 - c0, r1 - r0)
    k = np.minimum(np.ceil(np.log2(span + 1.0)).astype(np.int64), len(levels) - 1)
    out = np.full(len(c0), -np.inf)
    for lv in np.unique(k):
        sel = np.flatnonzero(k == lv)
        a = levels[lv]
        for cc in (c0[sel] >> lv, c1[sel] >> lv):
            for rr in (r0[sel] >> lv, r1[sel] >> lv):
                out[sel] = np.maximum(out[sel], a[np.minimum(rr, a.shape[0] - 1), np.minimum(cc, a.shape[1] - 1)])
    return out


def thin_blockers(face, F: np.ndarray, casters: np.ndarray, thin_texels: float = 2.0) -> np.ndarray:
    """Vertices of the caster triangles thinner than ``thin_texels`` texels in
    ``face`` (the render can miss them between texel centres) that may be in
    front of the envelope ``F``: nearest vertex in front of F's maximum over
    the triangle's box (a conservative test)."""
    h, w = F.shape
    tri = np.asarray(casters, np.float64).reshape(-1, 3, 3)
    col, row, z = (a.reshape(-1, 3) for a in to_view(face, tri.reshape(-1, 3)))
    e = [(col[:, (k + 1) % 3] - col[:, k], row[:, (k + 1) % 3] - row[:, k]) for k in range(3)]
    area2 = np.abs(e[0][0] * e[1][1] - e[0][1] * e[1][0])
    longest = np.sqrt(np.max([du * du + dv * dv for du, dv in e], axis=0))
    ok = np.isfinite(z).all(1) & (area2 < thin_texels * np.maximum(longest, 1e-300))
    ok &= (col.max(1) >= 0) & (col.min(1) < w) & (row.max(1) >= 0) & (row.min(1) < h)
    sel = np.flatnonzero(ok)
    if not len(sel):
        return np.zeros((0, 3))
    cl = lambda a, n: np.clip(np.floor(a), 0, n - 1).astype(np.int64)
    fmax = _max_over_boxes(F, cl(col[sel].min(1), w), cl(col[sel].max(1), w),
                           cl(row[sel].min(1), h), cl(row[sel].max(1), h))
    hit = sel[z[sel].min(1) < fmax]
    return tri[hit].reshape(-1, 3)


def blocker_points(face, depth: np.ndarray, floors: np.ndarray, receivers: np.ndarray,
                   half_angle: float, casters: np.ndarray) -> np.ndarray:
    """World points of what some receiver's cone of half-angle ``half_angle``
    around ``face``'s axis can pass behind (see the module docstring): the
    texel centres (at their depth) whose floor is in front of the envelope,
    plus the vertices of ``thin_blockers`` among ``casters``. ``depth`` the
    rendered map, ``floors`` its biased floors."""
    h, w = depth.shape
    col, row, z = to_view(face, np.asarray(receivers, np.float64).reshape(-1, 3))
    j = np.clip(np.floor(col), 0, w - 1).astype(np.int64)
    i = np.clip(np.floor(row), 0, h - 1).astype(np.int64)
    R = np.full(h * w, -np.inf)
    np.maximum.at(R, i * w + j, z)
    foot = 0.5 * ((face.bounds[1] - face.bounds[0]) / w + (face.bounds[3] - face.bounds[2]) / h)
    step = foot / max(math.tan(half_angle), 1e-12)
    F = cone_envelope(R.reshape(h, w), step)
    ii, jj = np.nonzero(np.isfinite(floors) & (floors < F))
    pts = to_world(face, jj.astype(np.float64), ii.astype(np.float64), depth[ii, jj].astype(np.float64))
    return np.concatenate([pts, thin_blockers(face, F, casters)])
