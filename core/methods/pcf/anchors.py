"""``pixel_step``: V filtered at anchor pixels and shared with or blended
into the pixels between them on the same surface: the step for a view's
size (``auto_pixel_step``), the levels of the lattice (``step_levels``) and
the per-pixel tests and blend (``_same_surface``, ``_on_anchor_surface``,
``_interpolated``)."""
from __future__ import annotations

import math

import numpy as np

from ...jit import inner

AUTO_STEP4_SIDE = 1280  # ``auto_pixel_step``: views at least this wide (or tall) take anchors 4 pixels apart
PIXEL_STEP_COS = 0.95   # ``pixel_step``: normals at most ~18 degrees apart share a V
PIXEL_STEP_SLOPE = 0.2  # ``step_fill="interpolate"``: a pixel lies on an anchor's surface when its offset from
                        # the anchor leaves the anchor's tangent plane by at most this fraction of its length


def auto_pixel_step(width: int, height: int) -> int:
    """``pixel_step=0``'s step for a ``width`` x ``height`` view: 4 from
    AUTO_STEP4_SIDE pixels on its larger side (a light-sized penumbra spans
    twice the pixels of a view half the size), else 2."""
    return 4 if max(width, height) >= AUTO_STEP4_SIDE else 2


def step_levels(pixel_step: int, interpolate: bool):
    """``pcf_kernel``'s stages, in order: step_fill="interpolate" with
    ``pixel_step`` 2^k > 1: the anchor lattice's spacing 2^k, then each
    finer spacing down to 1 (2^k, ..., 2, 1); otherwise one stage, 0 (every
    pixel; "copy": the block's first pixel before the others)."""
    if pixel_step > 1 and interpolate:
        return [pixel_step >> k for k in range(int(pixel_step).bit_length())]
    return [0]


@inner(forceinline=True)
def _same_surface(cam, i, j):
    """``pixel_step``: pixel j's V stands for pixel i's (both hit the same
    object, normals within PIXEL_STEP_COS)."""
    if not cam.hit[j] or cam.obj[i] != cam.obj[j]:
        return False
    dot = cam.Nrm[i, 0] * cam.Nrm[j, 0] + cam.Nrm[i, 1] * cam.Nrm[j, 1] + cam.Nrm[i, 2] * cam.Nrm[j, 2]
    return dot >= PIXEL_STEP_COS


@inner(forceinline=True)
def _on_anchor_surface(cam, i, j):
    """``step_fill="interpolate"``: anchor j's V stands for pixel i's surface
    (``_same_surface``, and i's offset from j within PIXEL_STEP_SLOPE of j's
    tangent plane: not the same object seen again behind a fold)."""
    if not _same_surface(cam, i, j):
        return False
    dx, dy, dz = cam.P[i, 0] - cam.P[j, 0], cam.P[i, 1] - cam.P[j, 1], cam.P[i, 2] - cam.P[j, 2]
    off = abs(dx * cam.Nrm[j, 0] + dy * cam.Nrm[j, 1] + dz * cam.Nrm[j, 2])
    return off <= PIXEL_STEP_SLOPE * math.sqrt(dx * dx + dy * dy + dz * dz)


@inner(forceinline=True)
def _entry(cam, p):
    """The entry of view pixel ``p``: itself in a dense G-buffer; in a packed
    one (``cam.pixel``, ascending) its index, or -1 when it is not listed."""
    n = cam.pixel.shape[0]
    if n == 0:
        return p
    lo, hi = 0, n                 # a binary search: np.searchsorted's overload is slow to compile
    while lo < hi:
        mid = (lo + hi) >> 1
        if cam.pixel[mid] < p:
            lo = mid + 1
        else:
            hi = mid
    if lo < n and cam.pixel[lo] == p:
        return lo
    return -1


@inner(forceinline=True)
def _interpolated(cam, out, i, r, c, step, height, tol):
    """``step_fill="interpolate"``: out[i] = the bilinear blend of the
    anchors around view pixel (r, c) (those of non-zero weight: 2 on an
    anchor row or column, else 4) that are entries (a packed G-buffer's
    sub-pixel receivers: listed) on its surface (``_on_anchor_surface``),
    their weights renormalised, when there are at least 2 of them holding
    at least half the weight (a pixel beside a silhouette blends the
    anchors on its own side) and their V spans at most ``tol`` without
    mixing a decided V (0: umbra, 1: lit, exact) with another: True. False
    (out[i] untouched) otherwise, or past the view's last anchor row or
    column."""
    W = cam.width
    r0, c0 = r - r % step, c - c % step
    fr, fc = (r - r0) / step, (c - c0) / step
    r1 = r0 + step if r > r0 else r0
    c1 = c0 + step if c > c0 else c0
    if r1 >= height or c1 >= W:
        return False
    lo, hi, acc, wsum, used = np.inf, -np.inf, 0.0, 0.0, 0
    for q in range(4):
        wr = fr if q & 2 else 1.0 - fr
        wc = fc if q & 1 else 1.0 - fc
        if wr * wc == 0.0:
            continue
        j = _entry(cam, (r1 if q & 2 else r0) * W + (c1 if q & 1 else c0))
        if j < 0 or not _on_anchor_surface(cam, i, j):
            continue
        v = np.float64(out[j])
        lo, hi = min(lo, v), max(hi, v)
        acc += wr * wc * v
        wsum += wr * wc
        used += 1
    if used < 2 or wsum < 0.5:
        return False
    if hi - lo > tol or (hi > lo and (lo == 0.0 or hi == 1.0)):
        return False            # a sharp edge, or the border of a decided umbra or lit region
    out[i] = acc / wsum
    return True
