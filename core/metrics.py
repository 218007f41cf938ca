"""Error measures against a reference of the same V definition (DESIGN.md).

Only pixels where the light can reach the visible surface count
(``reach_mask``): outside a spot cone, behind an area light or facing away V
carries no meaning.
"""
from __future__ import annotations

import math
from typing import Dict, Optional

import numpy as np

from .scene import GBuffer, Light

PENUMBRA_LO, PENUMBRA_HI = 0.02, 0.98


def reach_mask(g: GBuffer, light: Light) -> np.ndarray:
    """bool[H,W]: visible pixels some part of the light can illuminate,
    ignoring occlusion (tests on the light's boundary points / cone)."""
    P = g.position
    n = g.normal.astype(np.float64)
    ok = g.hit.copy()
    c = light.position
    if light.kind == "sun":
        to_sun = -light.direction
        sin_half = math.sin(light.sun_half_angle)
        return ok & ((n @ to_sun) > -sin_half)
    d = c - P
    dist = np.linalg.norm(d, axis=-1)
    dist = np.where(dist > 0, dist, 1e-300)
    if light.kind == "sphere":
        sin_half = np.minimum(light.radius / dist, 1.0)
        ok &= np.einsum("...i,...i->...", n, d) / dist > -sin_half
        if light.is_spot:
            cosang = -(np.einsum("...i,...i->...", d, light.direction)) / dist
            ok &= cosang >= light.spot_cos
        return ok
    # area: in front of the emitting side and some boundary point above the tangent plane
    m = light.world_from_light
    ax, ay, az = m[:3, 0], m[:3, 1], m[:3, 2]
    ok &= ((P - c) @ (-az)) > 0
    hx, hy = light.half_size
    if light.is_round:
        ang = np.linspace(0, 2 * np.pi, 16, endpoint=False)
        pts = [c + ax * hx * math.cos(a) + ay * hy * math.sin(a) for a in ang]
    else:
        pts = [c + ax * sx * hx + ay * sy * hy for sx in (-1, 1) for sy in (-1, 1)]
    pts.append(c)
    above = np.zeros(ok.shape, bool)
    for q in pts:
        above |= np.einsum("...i,...i->...", n, q - P) > 0
    return ok & above


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
