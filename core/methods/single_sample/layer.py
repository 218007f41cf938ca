"""The virtual layer (section 3.2) a search compares map texels against.
"""
from collections import namedtuple

import numpy as np

from ...jit import inner


Layer = namedtuple("Layer", "A B C ortho tol")
"""The virtual layer P'_z per texel (s, t): A s + B t + C is its depth
(orthographic face) or 1 / depth (perspective), with the depth tolerance."""


@inner
def _layer_range(A, B, C, iu, iv, c, ortho):
    """Least and largest depth of the layer over the texel centres of that
    box (1/z, or z, is affine in texel coordinates: extremes at the corners)."""
    lo = np.inf
    hi = -np.inf
    for k in range(4):
        sc = iu + 0.5 + (c if k & 1 else -c)
        tc = iv + 0.5 + (c if k & 2 else -c)
        lv = A * sc + B * tc + C
        lo = min(lo, lv)
        hi = max(hi, lv)
    if ortho:
        return lo, hi
    zlo = 1.0 / hi if hi > 0.0 else np.inf
    zhi = 1.0 / lo if lo > 0.0 else np.inf
    return zlo, zhi


@inner
def _nearer(d, lv, ortho, tol):
    """Is map depth ``d`` in front of the layer, whose value at the texel is
    ``lv``: z_l = lv (orthographic) or 1 / lv (perspective, +inf where
    lv <= 0); "d < z_l - tol" is "(d + tol) lv < 1" there."""
    if ortho:
        return d < lv - tol
    if lv > 0.0:
        return (d + tol) * lv < 1.0
    return d < np.inf
