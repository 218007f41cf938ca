"""Error measures against a reference of the same V definition (DESIGN.md).

Only pixels where the light can reach the visible surface count
(``reach_mask``): outside a spot cone, behind an area light or facing away V
carries no meaning.
"""
from __future__ import annotations

import math
from typing import Dict, Optional

import numpy as np

from .jit import kernel
from .scene import GBuffer, Light

PENUMBRA_LO, PENUMBRA_HI = 0.02, 0.98


REACH_SUN, REACH_SPHERE, REACH_SPOT, REACH_AREA = 0, 1, 2, 3


def _area_boundary(light: Light, c, ax, ay) -> list:
    """An area light's boundary points around centre ``c`` along ``ax``,
    ``ay`` (its corners; 16 points of a disk / ellipse)."""
    hx, hy = light.half_size
    if light.is_round:
        ang = np.linspace(0, 2 * np.pi, 16, endpoint=False)
        return [c + ax * hx * math.cos(a) + ay * hy * math.sin(a) for a in ang]
    return [c + ax * sx * hx + ay * sy * hy for sx in (-1, 1) for sy in (-1, 1)]


def reach_mask(g: GBuffer, light: Light) -> np.ndarray:
    """bool[H,W]: visible pixels some part of the light can illuminate,
    ignoring occlusion (tests on the light's boundary points / cone), in
    one Numba pass over the G-buffer (``_reach_kernel``)."""
    c = np.asarray(light.position, np.float64)
    pts = np.zeros((0, 3), np.float64)
    axis = np.zeros(3, np.float64)
    limit = 0.0
    if light.kind == "sun":
        mode, axis, limit = REACH_SUN, np.asarray(-light.direction, np.float64), math.sin(light.sun_half_angle)
    elif light.kind == "sphere":
        mode = REACH_SPOT if light.is_spot else REACH_SPHERE
        if light.is_spot:
            axis, limit = np.asarray(light.direction, np.float64), float(light.spot_cos)
    else:
        # area: in front of the emitting side and some boundary point above the tangent plane
        mode = REACH_AREA
        m = light.world_from_light
        ax, ay, axis = m[:3, 0], m[:3, 1], -np.asarray(m[:3, 2], np.float64)
        pts = np.array(_area_boundary(light, c, ax, ay) + [c], np.float64)
    H, W = g.hit.shape
    out = np.empty(H * W, np.bool_)
    _reach_kernel(np.ascontiguousarray(g.position, np.float64).reshape(-1, 3),
                  np.ascontiguousarray(g.normal, np.float32).reshape(-1, 3), np.ascontiguousarray(g.hit).reshape(-1),
                  mode, c, np.ascontiguousarray(axis, np.float64), float(limit), float(light.radius),
                  np.ascontiguousarray(pts, np.float64), out)
    return out.reshape(H, W)


def whole_light_mask(g: GBuffer, light: Light, margin: float = 0.02) -> np.ndarray:
    """bool[H,W]: visible pixels that see the whole light above their tangent
    plane, by ``margin`` in cosine (the study's measure: "the pixels where
    the whole light is in front of the receiver"; the rule of
    tests/helpers.py's ``fully_facing``, with round area lights
    by 16 boundary points and suns by the cone's edge). Vectorised NumPy:
    within ``reach_mask``, it leaves out the receivers turned partly away
    from the light, where a method must also know what its own surface
    hides."""
    P = np.asarray(g.position, np.float64)
    n = np.asarray(g.normal, np.float64)
    ok = np.asarray(g.hit, bool).copy()
    if light.kind == "sun":
        axis = -np.asarray(light.direction, np.float64)
        cos_n = np.clip(n @ axis, -1.0, 1.0)
        # the angle between n and the axis plus the half-angle stays below 90 degrees
        return ok & (np.cos(np.arccos(cos_n) + light.sun_half_angle) > margin)
    c = np.asarray(light.position, np.float64)
    if light.kind == "sphere":
        d = c - P
        dist = np.maximum(np.linalg.norm(d, axis=-1), 1e-300)
        return ok & (np.einsum("...i,...i->...", n, d) / dist > np.minimum(light.radius / dist, 1.0) + margin)
    ax, ay, _ = light.axes
    for q in _area_boundary(light, c, ax, ay):
        dq = q - P
        ok &= np.einsum("...i,...i->...", n, dq) / np.maximum(np.linalg.norm(dq, axis=-1), 1e-300) > margin
    return ok


@kernel(nogil=True)
def _reach_kernel(P, N, hit, mode, c, axis, limit, radius, pts, out):
    """``reach_mask`` per pixel: sun: n . to_sun > -sin(half angle); sphere:
    n . d / |d| > -min(r / |d|, 1) (d: to the centre) and, for a spot, the
    cone; area: in front of the emitting side and n . (q - P) > 0 for some
    boundary point or the centre q."""
    for i in range(P.shape[0]):
        if not hit[i]:
            out[i] = False
            continue
        n0, n1, n2 = np.float64(N[i, 0]), np.float64(N[i, 1]), np.float64(N[i, 2])
        if mode == REACH_SUN:
            out[i] = n0 * axis[0] + n1 * axis[1] + n2 * axis[2] > -limit
            continue
        d0, d1, d2 = c[0] - P[i, 0], c[1] - P[i, 1], c[2] - P[i, 2]
        if mode != REACH_AREA:
            dist = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
            dist = dist if dist > 0 else 1e-300
            ok = (n0 * d0 + n1 * d1 + n2 * d2) / dist > -min(radius / dist, 1.0)
            if ok and mode == REACH_SPOT:
                ok = -(d0 * axis[0] + d1 * axis[1] + d2 * axis[2]) / dist >= limit
            out[i] = ok
            continue
        ok = (-d0) * axis[0] + (-d1) * axis[1] + (-d2) * axis[2] > 0
        above = False
        for k in range(pts.shape[0]):
            if n0 * (pts[k, 0] - P[i, 0]) + n1 * (pts[k, 1] - P[i, 1]) + n2 * (pts[k, 2] - P[i, 2]) > 0:
                above = True
                break
        out[i] = ok and above


def errors(v: np.ndarray, ref: np.ndarray, mask: Optional[np.ndarray] = None) -> Dict[str, float]:
    """rmse, max_abs, mean_signed (v - ref: positive = too bright), and the
    RMSE inside the reference's penumbra (0.02 < ref < 0.98)."""
    v = np.asarray(v, np.float64)
    ref = np.asarray(ref, np.float64)
    m = np.ones(v.shape, bool) if mask is None else np.asarray(mask, bool)
    d = (v - ref)[m]
    out = {"pixels": int(m.sum())}
    if d.size == 0:
        out.update(rmse=0.0, max_abs=0.0, mean_signed=0.0, rmse_penumbra=0.0, penumbra_pixels=0)
        return out
    pen = m & (ref > PENUMBRA_LO) & (ref < PENUMBRA_HI)
    dp = (v - ref)[pen]
    out.update(rmse=float(np.sqrt(np.mean(d * d))), max_abs=float(np.max(np.abs(d))),
               mean_signed=float(np.mean(d)),
               rmse_penumbra=float(np.sqrt(np.mean(dp * dp))) if dp.size else 0.0,
               penumbra_pixels=int(pen.sum()))
    return out
