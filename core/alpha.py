"""Alpha mattes: the texture-driven transparency of leaf cards, fences and
hair cards (issue 18), as Cycles sees it.

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
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import List

import numpy as np

CLOSEST, LINEAR = 0, 1
REPEAT, EXTEND, CLIP = 0, 1, 2


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

    def subset(self, keep: np.ndarray) -> "AlphaMattes":
        """The same mattes for the triangles ``keep`` (bool[T] or indices)
        selects, e.g. after ``scene.finite_triangles`` drops some."""
        return AlphaMattes(self.tri_matte[keep], self.tri_uv[keep], self.texels, self.offset,
                           self.width, self.height, self.interpolation, self.extension,
                           list(self.names))
