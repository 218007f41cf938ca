"""The light as the soft irregular shadow mapping kernels see it (Johnson
et al. 2009, section 2.3; DESIGN.md "Light domains"), and each receiver's
frame on it.

Every light becomes a unit shape (``geom.SHAPE_DISK`` or ``SHAPE_SQUARE``)
on a plane, on which an edge projected from a receiver is clipped and
measured:

  * sphere (point / spot, radius r): the disk of radius r through the centre
    facing each receiver, as the reference samples it (the paper's
    "disk-projected spherical light"); a frame per receiver;
  * area disk / ellipse: the light's own plane scaled to the unit disk (an
    affine map keeps area ratios, so equation 3 stays exact);
  * area square / rectangle: the light's plane scaled to [-1, 1]^2 with the
    rectangle kernel, or (``rect_kernel`` off) the ellipse of equal area and
    aspect with the disk kernel;
  * sun (angle a): the gnomonic projection of directions around the sun's
    direction, where the cone of half-angle a/2 is the disk of radius
    tan(a/2), treated as uniform (the reference is uniform in solid angle:
    relative weight cos^3 of the angle from the axis).
"""
from __future__ import annotations

import math
from collections import namedtuple
from dataclasses import dataclass

import numpy as np

from .geom import SHAPE_DISK, SHAPE_SQUARE

KernelLight = namedtuple("KernelLight", "cx cy cz is_sun shape rL tan_a")
"""The light's centre (sun: unit direction towards it), kind, shape
(SHAPE_*), bounding radius r_L and, for the sun, tan of the half angle."""


# --------------------------------------------------------------------------
def _basis(n: np.ndarray):
    """Duff et al. orthonormal basis around unit vectors n[..., 3]."""
    nx, ny, nz = n[..., 0], n[..., 1], n[..., 2]
    s = np.where(nz >= 0.0, 1.0, -1.0)
    a = -1.0 / (s + nz)
    b = nx * ny * a
    e1 = np.stack([1.0 + s * nx * nx * a, s * b, -s * nx], -1)
    e2 = np.stack([b, s + ny * ny * a, -ny], -1)
    return e1, e2


@dataclass
class LightModel:
    """The light as the kernels see it."""
    is_sun: bool
    shape: int              # SHAPE_DISK | SHAPE_SQUARE
    centre: np.ndarray      # local: light centre; sun: unit direction towards the sun
    rL: float               # bounding radius of the light (sun: tan of the half angle)
    s1: float = 0.0         # half extents of the normalized shape (area lights)
    s2: float = 0.0
    approx: str = ""        # which approximation applies, if any

    @property
    def zero(self) -> bool:
        return not (self.rL > 0.0)


LINE_ASPECT = 1e-6


def light_model(light, rect_kernel: bool = True) -> LightModel:
    if light.kind == "sun":
        return LightModel(True, SHAPE_DISK, -light.direction, light.sun_spread,
                          approx="gnomonic disk treated as uniform")
    c = light.position
    if light.kind == "sphere":
        return LightModel(False, SHAPE_DISK, c, float(light.radius))
    hx, hy = light.half_size
    # a line light (one side 0): a rectangle / ellipse of relative width
    # LINE_ASPECT, so the kernels' divisions by the half sizes stay finite
    hx, hy = max(hx, LINE_ASPECT * hy), max(hy, LINE_ASPECT * hx)
    if light.is_round:
        return LightModel(False, SHAPE_DISK, c, max(hx, hy), hx, hy)
    if rect_kernel:
        return LightModel(False, SHAPE_SQUARE, c, math.hypot(hx, hy), hx, hy)
    k = 2.0 / math.sqrt(math.pi)      # ellipse of the rectangle's area and aspect
    return LightModel(False, SHAPE_DISK, c, max(hx, hy) * k, hx * k, hy * k,
                      approx="rectangle as equal-area ellipse")


def receiver_frames(light, lm: LightModel, Ps: np.ndarray, emission: bool = False) -> np.ndarray:
    """float64[n, 14]: e1/s1, e2/s2, n, h_p, p2x, p2y per receiver (see
    ``geom.penumbra_term``); h_p <= 0 marks receivers without penumbra; then
    (``emission``, an area light) g, the light's emission towards the
    receiver (cos_l / d^2) as 1 + g . (x, y) over the unit shape, relative
    to its mean (``emission_gradient``); zero otherwise (a sphere's facing
    disk and a sun's cone are symmetric about their axis)."""
    n = len(Ps)
    RF = np.zeros((n, 14))
    if n == 0 or lm.zero:
        return RF
    if lm.is_sun:
        w = np.asarray(lm.centre, np.float64)
        e1, e2 = _basis(w[None])
        RF[:, 0:3] = e1[0] / lm.rL
        RF[:, 3:6] = e2[0] / lm.rL
        RF[:, 6:9] = w
        RF[:, 9] = 1.0
        return RF
    c = np.asarray(lm.centre, np.float64)
    d = Ps - c
    if light.kind == "sphere":
        h = np.linalg.norm(d, axis=1)
        nrm = d / np.where(h > 0, h, 1.0)[:, None]
        e1, e2 = _basis(nrm)
        RF[:, 0:3] = e1 / lm.rL
        RF[:, 3:6] = e2 / lm.rL
        RF[:, 6:9] = nrm
        RF[:, 9] = np.where(h > lm.rL * 1e-9, h, 0.0)
        return RF
    ax, ay, az = light.axes
    side = np.where(d @ az >= 0.0, 1.0, -1.0)
    nrm = side[:, None] * az[None]
    h = np.einsum("ij,ij->i", d, nrm)
    RF[:, 0:3] = ax / lm.s1
    RF[:, 3:6] = ay / lm.s2
    RF[:, 6:9] = nrm
    RF[:, 9] = np.where(h > 1e-12 * max(lm.rL, 1e-300), h, 0.0)
    RF[:, 10] = d @ (ax / lm.s1)
    RF[:, 11] = d @ (ay / lm.s2)
    if emission:
        RF[:, 12:14] = emission_gradient(RF[:, 10], RF[:, 11], h, lm.s1, lm.s2)
    return RF


def emission_gradient(px, py, h, s1, s2) -> np.ndarray:
    """float64[n, 2]: g such that 1 + g . (x, y) is an area light's emission
    towards receivers at height ``h`` over its unit-shape point (px, py)
    (half sizes s1, s2), cos_l / d^2 = h / d^3, over its mean: central
    differences between the shape's side midpoints, over their mean; |g_x| +
    |g_y| at most 1, so no part of the light weighs less than nothing."""
    def e(x, y):
        dx, dy = (x - px) * s1, (y - py) * s2
        d2 = dx * dx + dy * dy + h * h
        return h / (d2 * np.sqrt(d2))
    ex0, ex1, ey0, ey1 = e(-1.0, 0.0), e(1.0, 0.0), e(0.0, -1.0), e(0.0, 1.0)
    mean = 0.25 * (ex0 + ex1 + ey0 + ey1)
    ok = mean > 0.0
    g = np.zeros((len(h), 2))
    g[ok, 0] = 0.5 * (ex1 - ex0)[ok] / mean[ok]
    g[ok, 1] = 0.5 * (ey1 - ey0)[ok] / mean[ok]
    norm = np.abs(g).sum(axis=1)
    g[norm > 1.0] /= norm[norm > 1.0, None]
    return g
