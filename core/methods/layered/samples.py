"""The light samples and the views they render: ``sample_points`` (the
samples' world points, or a sun's directions), ``centre_faces`` (the view
from the light's centre that holds the LDI) and ``sample_plans`` (per sample,
its faces and how its map warps into the centre view)."""
from __future__ import annotations

import dataclasses
import math
from typing import List

import numpy as np

from ... import views
from ...jit import kernel
from ...sampling import concentric_disk, light_sample, rand01
from ...scene import Light, ViewFace

PAD_TEXELS = 2               # texels of a sample map beyond the receivers it must see
PAD_CAP = 1.0                # at most this many map sizes of padding per side (else a fitted view)


@kernel
def sample_points(lp, uv, seed):
    """World points (area, sphere) or unit directions towards the light (sun)
    for the unit-square samples ``uv`` (float64[n, 2])."""
    n = uv.shape[0]
    out = np.empty((n, 3))
    for s in range(n):
        u, v = uv[s, 0], uv[s, 1]
        if lp[0] == 1.0:
            # sphere: density ~ 1/sqrt(1 - r^2) in the ball (a 3-sphere's
            # projection), whose projection along any axis is the uniform disk
            dx, dy = concentric_disk(u, v)
            hz = math.sqrt(max(0.0, 1.0 - dx * dx - dy * dy)) * \
                math.cos(2.0 * math.pi * rand01(seed, np.int64(0), s, np.int64(2)))
            r = lp[16]
            for k in range(3):
                out[s, k] = lp[1 + k] + r * (dx * lp[4 + k] + dy * lp[7 + k] + hz * lp[10 + k])
        else:
            x, y, z, _, _ = light_sample(lp, 0.0, 0.0, 0.0, u, v)
            out[s, 0], out[s, 1], out[s, 2] = x, y, z
    return out


def _inside_face(face: ViewFace, pts: np.ndarray) -> np.ndarray:
    u, v, d = views.project_to_face(face, pts)
    ok = np.isfinite(u) & np.isfinite(v) & (u >= 0) & (v >= 0) & (u < face.width) & (v < face.height)
    return ok & ((d > 0) | face.ortho)


def _padded_sample_face(cf: ViewFace, eye_c: np.ndarray, q: np.ndarray, rec: np.ndarray):
    """The centre face moved to sample point ``q`` (same rotation, same texel
    grid), its window grown by whole texels until it holds the receivers
    ``rec`` as seen from ``q``. Returns the face, the left / top pads in
    texels and the offset of ``q`` in the view's x, y, z over the texel size
    (z: in scene units), or None when that would take more than
    ``PAD_CAP`` map sizes of padding or a receiver lies behind ``q``'s image
    plane (a light large against its distance to the receivers)."""
    rot = np.asarray(cf.view_from_world, np.float64)[:3, :3].T
    vfw = views.view_from_world(rot, q)
    l, r, b, t = cf.bounds
    tx = (r - l) / cf.width
    ty = (t - b) / cf.height
    kl = kr = kb = kt = 0
    if len(rec):
        p = rec @ vfw[:3, :3].T + vfw[:3, 3]
        d = -p[:, 2]
        if not (d > 0).all():
            return None
        xs = p[:, 0] / d
        ys = p[:, 1] / d
        pads = np.array([(l - xs.min()) / tx, (xs.max() - r) / tx, (b - ys.min()) / ty,
                         (ys.max() - t) / ty])
        if not np.isfinite(pads).all() or pads.max() > PAD_CAP * max(cf.width, cf.height):
            return None
        kl, kr, kb, kt = (max(0, int(math.ceil(x)) + PAD_TEXELS) for x in pads)
    face = ViewFace(vfw, False, (l - kl * tx, r + kr * tx, b - kb * ty, t + kt * ty),
                    cf.width + kl + kr, cf.height + kb + kt, "ldi-sample")
    dv = np.asarray(cf.view_from_world, np.float64)[:3, :3] @ (np.asarray(q, np.float64) - eye_c)
    return face, kl, kt, dv[0] / tx, dv[1] / ty, dv[2]


def _sun_sample_light(light: Light, direction: np.ndarray) -> Light:
    """A copy of the sun shining along -direction, with no angle (its view is
    fitted to the receivers only)."""
    m = np.eye(4)
    m[:3, :3] = views.look_rotation(-np.asarray(direction, np.float64))
    m[:3, 3] = light.world_from_light[:3, 3]
    return dataclasses.replace(light, world_from_light=m, angle=0.0)


def centre_faces(light: Light, receivers, bounds, map_size) -> List[ViewFace]:
    """The view from the light's centre that holds the LDI, fitted to the
    visible receivers (only they are looked up): ``views.light_view_faces``,
    except that a sun's window is not padded by its angle (the padding is for
    filters reaching past the receivers) and a point light whose receivers fit
    in 60 degrees gets one fitted perspective face instead of 90-degree cube
    faces (four times the texels on them at the same map size)."""
    if light.kind == "sun":
        return views.light_view_faces(dataclasses.replace(light, angle=0.0), receivers, bounds, map_size)
    if light.kind == "sphere" and not light.is_spot and len(receivers):
        d = receivers - light.position
        n = np.linalg.norm(d, axis=1)
        ok = n > 0
        if ok.any():
            d = d[ok] / n[ok, None]
            m = d.mean(axis=0)
            if np.linalg.norm(m) > 0:
                m /= np.linalg.norm(m)
                if (d @ m).min() >= math.cos(views.MAX_SINGLE_VIEW_HALF_ANGLE):
                    face = views.fit_perspective_face(light.position, m, receivers[ok], map_size)
                    if face is not None:
                        return [face]
    return views.light_view_faces(light, receivers, bounds, map_size)


def sample_plans(light: Light, centre: List[ViewFace], receivers, bounds, map_size, pts, warp):
    """Per light sample (faces, eye, mode, shift), mode 0 = equation 3's shift
    (shift = left / top pads and the offset over the texel size, as
    ``warp_shift`` takes them), 1 = projective; and the warp's name for the
    stats."""
    plans = []
    eye_c = light.position
    if light.is_zero_size:
        return [(centre, eye_c, 0, (0, 0, 0.0, 0.0))], "identity"
    single_persp = len(centre) == 1 and not centre[0].ortho and light.kind != "sun"
    if single_persp:
        rec = receivers[_inside_face(centre[0], receivers)]
        shift_ok = light.kind == "area" and warp != "projective"
        fwd = -np.asarray(centre[0].view_from_world, np.float64)[2, :3]
        for q in pts:
            got = _padded_sample_face(centre[0], eye_c, q, rec)
            if got is None:
                face = views.fit_perspective_face(q, fwd, rec, map_size, label="ldi-sample")
                plans.append(([face] if face is not None else [], q, 1, None))
                continue
            face, kl, kt, ax, ay, az = got
            if shift_ok and abs(az) <= 1e-9 * max(1.0, float(np.linalg.norm(q - eye_c))):
                plans.append(([face], q, 0, (kl, kt, ax, ay)))
            else:
                plans.append(([face], q, 1, None))
        modes = {p[2] for p in plans}
        mode = {frozenset({0}): "planar shift (eq. 3)", frozenset({1}): "projective"}.get(
            frozenset(modes), "planar shift (eq. 3) + projective")
        return plans, mode
    for q in pts:
        if light.kind == "sun":
            faces = views.light_view_faces(_sun_sample_light(light, q), receivers, bounds, map_size)
            eye = light.position
        else:
            faces = views.light_view_faces(light, receivers, bounds, map_size, eye=q)
            eye = q
        plans.append((faces, eye, 1, None))
    return plans, "projective"
