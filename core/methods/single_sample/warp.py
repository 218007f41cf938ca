"""The warp of a camera pixel into the light view and the hard test
(section 3.2).
"""
import math

import numpy as np

from ...jit import kernel
from ...kernels import face_project
from .packed import P_BIAS, P_TOLABS, P_TOLREL


@kernel(inline="always")
def _face_of(faces, px, py, pz):
    """``kernels.pick_face`` and the point's projection into that face:
    (face, u, v, depth), face -1 (and zeros) outside every face."""
    for f in range(faces.shape[0]):
        u, v, d = face_project(faces[f], px, py, pz)
        if u >= 0.0 and v >= 0.0 and u < faces[f, 21] and v < faces[f, 22] and (d > 0.0 or faces[f, 16] == 1.0):
            return f, u, v, d
    return -1, 0.0, 0.0, 0.0


def _warp_py(P, Nrm, i, faces, depth, prm):
    """Warp pixel i into the light view (section 3.2) and run the hard test.

    Returns (face, u, v, zr, inner, z_map, planar, A, B, C, tol, pvx, pvy, pvz):
    the receiver's tangent plane over the map is 1/z (perspective) or z
    (orthographic) = A sc + B tc + C in texel coordinates (sc, tc); ``tol``
    is the hard test's tolerance; face < 0 means "not in the light view".
    Compiled twice from this one source: ``_warp`` (a function of its own,
    called per searched pixel) and ``_warp_inline`` (inlined into the hard
    test over every pixel, ``shade._hard_range``, where a call per pixel
    would weigh on a loop that does little else)."""
    px, py, pz = P[i, 0], P[i, 1], P[i, 2]
    f, u, v, zr = _face_of(faces, px, py, pz)
    if f < 0:
        return -1, 0.0, 0.0, 0.0, False, 0.0, False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    fp = faces[f]
    if not (zr > 0.0) or not np.isfinite(u) or not np.isfinite(v) or not np.isfinite(zr):
        return -1, 0.0, 0.0, 0.0, False, 0.0, False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    w = int(fp[21])
    h = int(fp[22])
    ortho = fp[16] == 1.0
    l, t = fp[17], fp[20]
    ku = fp[21] / (fp[18] - l)
    kv = fp[22] / (t - fp[19])
    pvx = fp[0] * px + fp[1] * py + fp[2] * pz + fp[3]
    pvy = fp[4] * px + fp[5] * py + fp[6] * pz + fp[7]
    pvz = fp[8] * px + fp[9] * py + fp[10] * pz + fp[11]
    nx0, ny0, nz0 = Nrm[i, 0], Nrm[i, 1], Nrm[i, 2]
    nvx = fp[0] * nx0 + fp[1] * ny0 + fp[2] * nz0
    nvy = fp[4] * nx0 + fp[5] * ny0 + fp[6] * nz0
    nvz = fp[8] * nx0 + fp[9] * ny0 + fp[10] * nz0
    d0 = nvx * pvx + nvy * pvy + nvz * pvz
    A = 0.0
    B = 0.0
    C = zr if ortho else 1.0 / zr
    planar = False
    if ortho:
        if abs(nvz) > 1e-9:
            A = nvx / (ku * nvz)
            B = -nvy / (kv * nvz)
            C = (nvx * l + nvy * t - d0) / nvz
            planar = True
    elif abs(d0) > 1e-12 * zr * math.sqrt(pvx * pvx + pvy * pvy + pvz * pvz):
        A = nvx / (ku * d0)
        B = -nvy / (kv * d0)
        C = (nvx * l + nvy * t - nvz) / d0
        planar = True
    if planar:   # re-anchor so the plane passes exactly through P'
        C += (zr if ortho else 1.0 / zr) - (A * u + B * v + C)
    # slope-scaled tolerance: the receiver's depth change across a texel
    # plus the texel's world size, in units of bias_texels
    if ortho:
        dzu, dzv = A, B
        texel_world = 1.0 / ku
    else:
        dzu, dzv = -A * zr * zr, -B * zr * zr
        texel_world = zr / ku
    tol = prm[P_TOLREL] * zr + prm[P_TOLABS] + prm[P_BIAS] * (math.sqrt(dzu * dzu + dzv * dzv) + texel_world)
    tol = min(tol, 0.1 * zr)
    # hard test at the texel under P', against the plane at its centre
    iu = min(max(int(math.floor(u)), 0), w - 1)
    iv = min(max(int(math.floor(v)), 0), h - 1)
    zt = zr
    if planar:
        lv = A * (iu + 0.5) + B * (iv + 0.5) + C
        if ortho:
            zt = lv
        elif lv > 0.0:
            zt = 1.0 / lv
    zmap = np.float64(depth[f, iv, iu])
    inner = zmap < zt - tol
    return f, u, v, zr, inner, zmap, planar, A, B, C, tol, pvx, pvy, pvz


_warp = kernel(_warp_py)
_warp_inline = kernel(cache=False, inline="always")(_warp_py)
