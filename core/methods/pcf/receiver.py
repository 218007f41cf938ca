"""The receiver's depth in the light's view: its tangent plane along each
texel's light ray (``receiver_plane``, ``plane_depth``), the same as a
form compared without a division (``_receiver_form``), and the relative
margin of every depth comparison (``DEPTH_REL_EPS``)."""
from __future__ import annotations

import numpy as np

from ...jit import inner

# The map holds float32 depths from Embree (relative hit error near float32's
# epsilon): a receiver counts as behind a texel only beyond this relative
# margin, so a receiver-plane comparison of a surface with itself is not a
# coin toss.
DEPTH_REL_EPS = 1.0 + 1e-5

NO_PLANE = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)   # figure 4's constant receiver depth


@inner
def receiver_plane(fp, px, py, pz, nx, ny, nz):
    """The receiver's tangent plane in face ``fp``'s view space, as a function
    of the texel position (u, v), packed for ``plane_depth``:
    (1, ortho, A, B, C, K) with depth = K / (A u + B v + C) for a perspective
    face and depth = A u + B v + C for an orthographic one (the view-space
    plane n.x = n.p along the ray through the texel, solved once per pixel, so
    each sample costs one division). ``NO_PLANE`` (the point's own depth
    everywhere) when the plane holds the orthographic view direction."""
    vx = fp[0] * px + fp[1] * py + fp[2] * pz + fp[3]
    vy = fp[4] * px + fp[5] * py + fp[6] * pz + fp[7]
    vz = fp[8] * px + fp[9] * py + fp[10] * pz + fp[11]
    mx = fp[0] * nx + fp[1] * ny + fp[2] * nz
    my = fp[4] * nx + fp[5] * ny + fp[6] * nz
    mz = fp[8] * nx + fp[9] * ny + fp[10] * nz
    npv = mx * vx + my * vy + mz * vz
    # view-space x = l + u (r - l) / w, y = t - v (t - b) / h
    A = mx * (fp[18] - fp[17]) / fp[21]
    B = -my * (fp[20] - fp[19]) / fp[22]
    C = mx * fp[17] + my * fp[20]
    if fp[16] == 1.0:
        if abs(mz) < 1e-12:        # the view direction lies in the plane
            return NO_PLANE
        return (1.0, 1.0, A / mz, B / mz, (C - npv) / mz, 0.0)
    return (1.0, 0.0, A, B, C - mz, npv)


@inner(forceinline=True)
def plane_depth(pl, uc, vc, z):
    """Depth of the receiver's tangent plane along the ray through texel
    centre (uc, vc); ``z`` (the point's own depth) where the ray runs along
    the plane (grazing) or meets it behind the light."""
    if pl[1] == 1.0:
        d = pl[2] * uc + pl[3] * vc + pl[4]
    else:
        den = pl[2] * uc + pl[3] * vc + pl[4]
        if abs(den) < 1e-12:
            return z
        d = pl[5] / den
    if not (d > 0.0) or not np.isfinite(d):
        return z
    return d


@inner(forceinline=True)
def _receiver_form(plane, z, u0, u1, v0, v1):
    """The receiver's depth over the texel centres [u0, u1] x [v0, v1] as
    a form ``samples._region_samples`` compares without a division: (mode, a, b, c, k)
    with mode 0: the constant ``z`` (no plane); 1: a u + b v + c (an
    orthographic face); 2: k / (a u + b v + c) with k > 0 and a u + b v + c
    > 0 (a perspective face; ``plane_depth``'s own value, the sign folded
    into k); 3: ``plane_depth`` per sample (its fallbacks reached somewhere
    in the box). The form holds over the box when it holds at its corners:
    the denominator is affine, so it keeps one sign between them."""
    if plane[0] == 0.0:
        return 0, 0.0, 0.0, 0.0, z
    a, b, c = plane[2], plane[3], plane[4]
    k = plane[5]
    sg = 1.0 if k > 0.0 else -1.0
    for uc in (u0, u1):
        for vc in (v0, v1):
            den = a * uc + b * vc + c
            if plane[1] == 1.0:
                if not (den > 0.0) or not np.isfinite(den):
                    return 3, 0.0, 0.0, 0.0, z
            else:
                d = k / den
                if abs(den) < 1e-12 or not (d > 0.0) or not np.isfinite(d):
                    return 3, 0.0, 0.0, 0.0, z
    if plane[1] == 1.0:
        return 1, a, b, c, 0.0
    return 2, sg * a, sg * b, sg * c, sg * k
