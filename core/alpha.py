"""Alpha mattes: the texture-driven transparency of leaf cards, fences and
hair cards, as Cycles sees it.

A surface point on triangle ``t`` with alpha ``a`` lets ``1 - a`` of a
shadow ray through (Cycles multiplies ``1 - a`` over every surface a shadow
ray crosses, counted against ``transparent_max_bounces``), and the camera
sees through it where ``a`` is 0 (a binary matte) or partly (a filtered
edge). Laine and Aila 2005, section 4, "Alpha matte textures", name the
texture fetch at the ray-blocker intersection as future work; Reeves et al.
1987 do not address transparent objects.

This module is the data model only: what the capture (``bridge/capture.py``)
fills in and every method reads. Mattes are flattened into plain arrays so
Numba kernels take them as they are.

Layout (``M`` mattes, ``T`` triangles):

- ``tri_matte`` int32[T]: the triangle's matte, -1 = opaque (no lookup).
- ``tri_uv`` float32[T,3,2]: UV at the triangle's three corners (the active
  UV map; zeros where the triangle is opaque). A hit with Embree's
  barycentrics (u, v) has UV ``(1-u-v) uv0 + u uv1 + v uv2``.
- ``texels`` float32[N]: every matte's alpha values, one matte after
  another, each row-major with row 0 at v = 0 (Blender's bottom-up pixel
  order); already the alpha Cycles uses (the Alpha output, or the Color
  output converted to a float, or 1 - the Transparent BSDF's share).
- ``offset`` int64[M], ``width`` int32[M], ``height`` int32[M]: where each
  matte's texels start and its size. A constant alpha is a 1x1 matte.
- ``interpolation`` int8[M]: ``CLOSEST`` or ``LINEAR`` (Cycles' Image Texture
  node; Cubic and Smart are captured as Linear).
- ``extension`` int8[M]: ``REPEAT``, ``EXTEND`` or ``CLIP`` (outside [0,1]:
  alpha 0).
- ``names`` list[str] of M: "material / image" per matte, for the plan and
  for warnings.

Kernels take the arrays as one ``MatteArrays`` namedtuple (``packed()``)
and look a hit's alpha up with ``alpha_at`` (Cycles' Image Texture node:
``intern/cycles/kernel/device/cpu/image.h``, ``interp_closest`` /
``interp_linear``).
"""
from __future__ import annotations

import math
from collections import namedtuple
from dataclasses import dataclass, field
from typing import List

import numpy as np

from .jit import kernel

CLOSEST, LINEAR = 0, 1
REPEAT, EXTEND, CLIP = 0, 1, 2

#: the arrays of ``AlphaMattes`` as one argument for Numba kernels
MatteArrays = namedtuple("MatteArrays", "tri_matte tri_uv texels offset width height interpolation extension")

#: UVs are clamped to +-UV_LIMIT before texel indices are taken (keeps the
#: float -> int conversion defined for absurd UVs; far past any real repeat)
UV_LIMIT = 1e9


@dataclass
class AlphaMattes:
    """The scene's alpha mattes (module docstring for the layout)."""

    tri_matte: np.ndarray
    tri_uv: np.ndarray
    texels: np.ndarray
    offset: np.ndarray
    width: np.ndarray
    height: np.ndarray
    interpolation: np.ndarray
    extension: np.ndarray
    names: List[str] = field(default_factory=list)

    def __post_init__(self):
        self.tri_matte = np.ascontiguousarray(self.tri_matte, np.int32).reshape(-1)
        self.tri_uv = np.ascontiguousarray(self.tri_uv, np.float32).reshape(-1, 3, 2)
        self.texels = np.ascontiguousarray(self.texels, np.float32).reshape(-1)
        self.offset = np.ascontiguousarray(self.offset, np.int64).reshape(-1)
        self.width = np.ascontiguousarray(self.width, np.int32).reshape(-1)
        self.height = np.ascontiguousarray(self.height, np.int32).reshape(-1)
        self.interpolation = np.ascontiguousarray(self.interpolation, np.int8).reshape(-1)
        self.extension = np.ascontiguousarray(self.extension, np.int8).reshape(-1)
        m = len(self.offset)
        if len(self.tri_uv) != len(self.tri_matte):
            raise ValueError("tri_uv must have one entry per triangle")
        if not (len(self.width) == len(self.height) == len(self.interpolation)
                == len(self.extension) == m):
            raise ValueError("every matte needs an offset, width, height, interpolation and extension")
        if len(self.tri_matte) and int(self.tri_matte.max(initial=-1)) >= m:
            raise ValueError("tri_matte names a matte that does not exist")
        if m and np.any(self.offset + self.width.astype(np.int64) * self.height > len(self.texels)):
            raise ValueError("a matte's texels run past the texel array")

    @property
    def count(self) -> int:
        return len(self.offset)

    def any_matte(self, tri_mask: np.ndarray) -> bool:
        """True when one of the triangles ``tri_mask`` selects has a matte."""
        return bool(np.any(self.tri_matte[np.asarray(tri_mask, bool)] >= 0))

    def packed(self) -> MatteArrays:
        """The arrays as kernels take them (``alpha_at``)."""
        return MatteArrays(self.tri_matte, self.tri_uv, self.texels, self.offset, self.width,
                           self.height, self.interpolation, self.extension)

    def subset(self, keep: np.ndarray) -> "AlphaMattes":
        """The same mattes for the triangles ``keep`` (bool[T] or indices)
        selects, e.g. after ``scene.finite_triangles`` drops some."""
        return AlphaMattes(self.tri_matte[keep], self.tri_uv[keep], self.texels, self.offset,
                           self.width, self.height, self.interpolation, self.extension,
                           list(self.names))


@kernel(nogil=True, inline="always")
def _wrap(i, n, extension):
    """Texel index ``i`` of a row of ``n`` folded in as Cycles' REPEAT
    (``wrap_periodic``) or EXTEND (``wrap_clamp``) does; CLIP: unchanged."""
    if extension == REPEAT:
        i %= n
        return i + n if i < 0 else i
    if extension == EXTEND:
        return min(max(i, 0), n - 1)
    return i


@kernel(nogil=True, inline="always")
def _texel(m, k, ix, iy):
    """Texel (ix, iy) of matte ``k`` (row iy from v = 0); 0 outside it (CLIP)."""
    w = m.width[k]
    if ix < 0 or iy < 0 or ix >= w or iy >= m.height[k]:
        return 0.0
    return np.float64(m.texels[m.offset[k] + np.int64(iy) * w + ix])


@kernel(nogil=True, inline="always")   # per hit: no call (tuple reference counts)
def matte_alpha(m, k, s, t):
    """Alpha of matte ``k`` at texture coordinates (s, t), as Cycles' Image
    Texture node samples it: CLOSEST takes texel (floor(s w), floor(t h));
    LINEAR blends the four texels around (s w - 0.5, t h - 0.5) (texel
    centres at (i + 0.5) / w); indices wrap (REPEAT), clamp (EXTEND) or read
    0 outside the image (CLIP, so a LINEAR matte fades to 0 over half a texel
    at its border). Non-finite coordinates give 1 (opaque); the result is
    clamped to [0, 1]."""
    if not (math.isfinite(s) and math.isfinite(t)):
        return 1.0
    s = min(max(s, -UV_LIMIT), UV_LIMIT)
    t = min(max(t, -UV_LIMIT), UV_LIMIT)
    w = m.width[k]
    h = m.height[k]
    ext = m.extension[k]
    if m.interpolation[k] == CLOSEST:
        ix = np.int64(math.floor(s * w))
        iy = np.int64(math.floor(t * h))
        a = _texel(m, k, _wrap(ix, w, ext), _wrap(iy, h, ext))
    else:
        x = s * w - 0.5
        y = t * h - 0.5
        fx = math.floor(x)
        fy = math.floor(y)
        tx = x - fx
        ty = y - fy
        ix = np.int64(fx)
        iy = np.int64(fy)
        x0, x1 = _wrap(ix, w, ext), _wrap(ix + 1, w, ext)
        y0, y1 = _wrap(iy, h, ext), _wrap(iy + 1, h, ext)
        a = ((1.0 - ty) * ((1.0 - tx) * _texel(m, k, x0, y0) + tx * _texel(m, k, x1, y0))
             + ty * ((1.0 - tx) * _texel(m, k, x0, y1) + tx * _texel(m, k, x1, y1)))
    return min(max(a, 0.0), 1.0)


@kernel(nogil=True, inline="always")   # per hit: no call (tuple reference counts)
def alpha_at(m, tri, u, v):
    """Alpha of triangle ``tri`` (an index into the scene's triangles) at the
    hit with Embree barycentrics (u, v): its matte at UV = (1-u-v) uv0 +
    u uv1 + v uv2; 1 where the triangle has no matte."""
    k = m.tri_matte[tri]
    if k < 0:
        return 1.0
    uv = m.tri_uv
    b = 1.0 - u - v
    s = b * uv[tri, 0, 0] + u * uv[tri, 1, 0] + v * uv[tri, 2, 0]
    t = b * uv[tri, 0, 1] + u * uv[tri, 1, 1] + v * uv[tri, 2, 1]
    return matte_alpha(m, k, s, t)
