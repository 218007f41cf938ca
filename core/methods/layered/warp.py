"""Line 5 of procedure Precompute: a sample map's pixels warped into the view
from the light's centre, by equation 3's disparity shift (``warp_shift``) or
by unprojecting and projecting them (``warp_projective``). Each writes, per
sample pixel, the centre face (-1: none) and the fractional texel position
and depth there."""
from __future__ import annotations

import numpy as np

from ...jit import HOT, inner, kernel
from ...kernels import face_project, pick_face


@kernel(opt=HOT, nogil=True)
def warp_shift(sdepth, kx, ky, ax, ay, wf, wx, wy, wz):
    """Equation 3 for a sample map on the centre map's texel grid (same
    rotation, window padded by ``kx``, ``ky`` whole texels on the left / top):
    u_c = u_s - kx + ax / z, v_c = v_s - ky - ay / z, with (ax, ay) the
    sample's offset from the centre in the view's x, y over the texel size.
    Face f of the sample map warps into face f of the centre map."""
    F, h, w = sdepth.shape
    for k in range(F * h * w):
        f = k // (h * w)
        r = (k // w) % h
        c = k % w
        d = np.float64(sdepth[f, r, c])
        if not (d > 0.0 and d < np.inf):
            wf[k] = -1
            continue
        wf[k] = f
        wx[k] = c + 0.5 - kx + ax / d
        wy[k] = r + 0.5 - ky - ay / d
        wz[k] = d


@inner
def _unproject(fp, r, c, d):
    """World point seen at pixel (r, c) of packed face ``fp`` at depth ``d``."""
    x = fp[17] + (c + 0.5) / fp[21] * (fp[18] - fp[17])
    y = fp[20] - (r + 0.5) / fp[22] * (fp[20] - fp[19])
    if fp[16] == 0.0:
        vx, vy = x * d, y * d
    else:
        vx, vy = x, y
    vx -= fp[3]
    vy -= fp[7]
    vz = -d - fp[11]
    # world = R^T (v - T): the view rotation is orthonormal
    X = fp[0] * vx + fp[4] * vy + fp[8] * vz
    Y = fp[1] * vx + fp[5] * vy + fp[9] * vz
    Z = fp[2] * vx + fp[6] * vy + fp[10] * vz
    return X, Y, Z


@kernel(opt=HOT, nogil=True)
def warp_projective(sfaces, sdepth, cfaces, wf, wx, wy, wz):
    """General warp: unproject each sample pixel to world space and project it
    into the centre face that holds it (-1: outside the centre view)."""
    F, h, w = sdepth.shape
    for k in range(F * h * w):
        f = k // (h * w)
        r = (k // w) % h
        c = k % w
        d = np.float64(sdepth[f, r, c])
        wf[k] = -1
        if not (d < np.inf) or (sfaces[f, 16] == 0.0 and not (d > 0.0)):
            continue
        X, Y, Z = _unproject(sfaces[f], r, c, d)
        g = pick_face(cfaces, X, Y, Z)
        if g < 0:
            continue
        u, v, dd = face_project(cfaces[g], X, Y, Z)
        if not (np.isfinite(u) and np.isfinite(v) and np.isfinite(dd)):
            continue
        wf[k] = g
        wx[k] = u
        wy[k] = v
        wz[k] = dd
