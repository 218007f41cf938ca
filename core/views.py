"""Camera and light-view projections: perspective, orthographic, cube faces.

The camera follows Blender's ``BKE_camera_params_compute_viewplane`` (sensor
fit, shift, pixel aspect); light views are fitted to the receivers the camera
sees (DESIGN.md, "Where the buffers come from"), so no texel is spent where
nothing is shaded.
"""
from __future__ import annotations

import math
from typing import List, Tuple

import numpy as np

from .scene import Camera, Light, ViewFace

# A single perspective light view is used while the receivers fit in this
# half-angle around the light's axis; wider spreads switch to cube faces.
MAX_SINGLE_VIEW_HALF_ANGLE = math.radians(60.0)
# Fraction of the fitted window added on each side (PCF footprints and
# penumbra searches reach a little past the receivers).
FIT_MARGIN = 0.03


def _rows(m: np.ndarray) -> np.ndarray:
    """``m[:3, :3].T`` as a contiguous array: ``points @`` it is NumPy's
    BLAS product (a transposed view of a 4x4's corner is not: NumPy falls
    back to its generic loop); the product's bits are the same."""
    return np.ascontiguousarray(np.asarray(m, np.float64)[:3, :3].T)


# --------------------------------------------------------------------------
# camera
def camera_viewplane(cam: Camera, width: int, height: int) -> Tuple[float, float, float, float]:
    """(xmin, xmax, ymin, ymax) of the view plane: at distance 1 for a
    perspective camera, in scene units for an orthographic one."""
    aspx, aspy = float(cam.pixel_aspect_x), float(cam.pixel_aspect_y)
    ycor = aspy / aspx
    if cam.kind == "ORTHO":
        pixsize = float(cam.ortho_scale)
    else:
        sensor = cam.sensor_height if cam.sensor_fit == "VERTICAL" else cam.sensor_width
        pixsize = float(sensor) / float(cam.lens)
    fit = cam.sensor_fit
    if fit == "AUTO":
        fit = "HORIZONTAL" if aspx * width >= aspy * height else "VERTICAL"
    viewfac = float(width) if fit == "HORIZONTAL" else ycor * float(height)
    pixsize /= viewfac
    dx = cam.shift_x * viewfac
    dy = cam.shift_y * viewfac
    xmin, xmax = -0.5 * width + dx, 0.5 * width + dx
    ymin, ymax = -0.5 * ycor * height + dy, 0.5 * ycor * height + dy
    return xmin * pixsize, xmax * pixsize, ymin * pixsize, ymax * pixsize


def camera_rays(cam: Camera, width: int, height: int):
    """Rays through pixel centres, starting on the near clip plane.

    Returns origins float64[H,W,3], unit directions float64[H,W,3], tfar
    float64[H,W] (to the far clip plane) and ``axis_scale`` float64[H,W]:
    view-axis depth per unit of ray length, so depth = t * axis_scale + clip_start.
    """
    xmin, xmax, ymin, ymax = camera_viewplane(cam, width, height)
    m = np.asarray(cam.world_from_camera, np.float64)
    rot = m[:3, :3] / np.linalg.norm(m[:3, :3], axis=0)
    eye = m[:3, 3]
    xs = xmin + (np.arange(width) + 0.5) / width * (xmax - xmin)
    ys = ymax - (np.arange(height) + 0.5) / height * (ymax - ymin)
    X, Y = np.meshgrid(xs, ys)
    if cam.kind == "ORTHO":
        local_o = np.stack([X, Y, np.full_like(X, -cam.clip_start)], -1)
        org = local_o @ rot.T + eye
        d = np.broadcast_to(-rot[:, 2], org.shape).copy()
        axis_scale = np.ones_like(X)
    else:
        local_d = np.stack([X, Y, -np.ones_like(X)], -1)
        norm = np.linalg.norm(local_d, axis=-1)
        d = (local_d / norm[..., None]) @ rot.T
        axis_scale = 1.0 / norm                   # cos of angle to the axis
        org = eye + d * (cam.clip_start / axis_scale)[..., None]
    tfar = (cam.clip_end - cam.clip_start) / axis_scale
    return org, d, tfar, axis_scale


def world_to_camera_pixels(cam: Camera, width: int, height: int, points: np.ndarray):
    """Project world points to (column, row) float pixel coordinates and view depth."""
    xmin, xmax, ymin, ymax = camera_viewplane(cam, width, height)
    m = np.asarray(cam.world_from_camera, np.float64)
    inv = np.linalg.inv(m)
    p = np.asarray(points, np.float64) @ _rows(inv) + inv[:3, 3]
    depth = -p[..., 2]
    if cam.kind == "ORTHO":
        x, y = p[..., 0], p[..., 1]
    else:
        with np.errstate(divide="ignore", invalid="ignore"):
            x, y = p[..., 0] / depth, p[..., 1] / depth
    col = (x - xmin) / (xmax - xmin) * width
    row = (ymax - y) / (ymax - ymin) * height
    return col, row, depth


# --------------------------------------------------------------------------
# generic view faces
def look_rotation(forward: np.ndarray, up_hint: np.ndarray | None = None) -> np.ndarray:
    """3x3 world-from-view rotation whose -Z is ``forward``."""
    f = np.asarray(forward, np.float64)
    f = f / np.linalg.norm(f)
    if up_hint is None or abs(np.dot(up_hint, f)) > 0.999:
        up_hint = np.array([0.0, 0.0, 1.0]) if abs(f[2]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(f, up_hint)
    x /= np.linalg.norm(x)
    y = np.cross(x, f)
    return np.stack([x, y, -f], axis=1)


def view_from_world(rotation: np.ndarray, eye: np.ndarray) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = rotation.T
    m[:3, 3] = -rotation.T @ np.asarray(eye, np.float64)
    return m


def project_to_face(face: ViewFace, points: np.ndarray):
    """World points -> (u, v, depth): u, v in map pixels (float, centre at +0.5),
    depth = -z in view space. Points behind a perspective eye get depth <= 0."""
    m = np.asarray(face.view_from_world, np.float64)
    p = np.asarray(points, np.float64) @ _rows(m) + m[:3, 3]
    depth = -p[..., 2]
    l, r, b, t = face.bounds
    if face.ortho:
        x, y = p[..., 0], p[..., 1]
    else:
        with np.errstate(divide="ignore", invalid="ignore"):
            safe = np.where(depth > 0, depth, np.nan)
            x, y = p[..., 0] / safe, p[..., 1] / safe
    u = (x - l) / (r - l) * face.width
    v = (t - y) / (t - b) * face.height
    return u, v, depth


def face_rays(face: ViewFace):
    """Rays through the face's pixel centres: origins, unit dirs, axis_scale (H,W)."""
    l, r, b, t = face.bounds
    xs = l + (np.arange(face.width) + 0.5) / face.width * (r - l)
    ys = t - (np.arange(face.height) + 0.5) / face.height * (t - b)
    X, Y = np.meshgrid(xs, ys)
    inv = np.linalg.inv(np.asarray(face.view_from_world, np.float64))
    rot, eye = inv[:3, :3], inv[:3, 3]
    if face.ortho:
        org = np.stack([X, Y, np.zeros_like(X)], -1) @ rot.T + eye
        d = np.broadcast_to(-rot[:, 2], org.shape).copy()
        scale = np.ones_like(X)
    else:
        ld = np.stack([X, Y, -np.ones_like(X)], -1)
        n = np.linalg.norm(ld, axis=-1)
        d = (ld / n[..., None]) @ rot.T
        org = np.broadcast_to(eye, d.shape).copy()
        scale = 1.0 / n
    return org, d, scale


def default_map_size(width: int, height: int, kind: str = "area") -> int:
    """A light map's larger side when none is set, for a light of ``kind``:
    sqrt(width x height), rounded, so a map fitted to the receivers holds at
    most as many texels as the output has pixels (the output's larger side
    for a square one): a map that is a wide frame's larger side squared
    costs more rays than the camera's for an error the methods' own
    sampling hides. A sun's: the output's larger side, as its orthographic
    view spreads its texels over the whole receiver box."""
    if kind == "sun":
        return max(1, int(width), int(height))
    return max(1, int(round(math.sqrt(float(width) * float(height)))))


def _padded(lo: float, hi: float, margin: float) -> Tuple[float, float]:
    span = max(hi - lo, 1e-12)
    return lo - margin * span, hi + margin * span


def _window_resolution(bounds, map_size: int) -> Tuple[int, int]:
    """Largest side = map_size, square texels."""
    l, r, b, t = bounds
    w, h = r - l, t - b
    if w >= h:
        return map_size, max(1, int(round(map_size * h / w)))
    return max(1, int(round(map_size * w / h))), map_size


def fit_perspective_face(eye, forward, receivers, map_size, margin=FIT_MARGIN,
                         pad_tan=0.0, label="persp") -> ViewFace | None:
    """A perspective face from ``eye`` along ``forward`` fitted to ``receivers``
    in front of it; None if no receiver is in front."""
    rot = look_rotation(forward)
    vfw = view_from_world(rot, eye)
    p = receivers @ _rows(vfw) + vfw[:3, 3]
    depth = -p[:, 2]
    ok = depth > 1e-12 * max(1.0, float(np.abs(receivers).max(initial=1.0)))
    if not ok.any():
        return None
    x = p[ok, 0] / depth[ok]
    y = p[ok, 1] / depth[ok]
    l, r = _padded(float(x.min()) - pad_tan, float(x.max()) + pad_tan, margin)
    b, t = _padded(float(y.min()) - pad_tan, float(y.max()) + pad_tan, margin)
    # keep a minimum window so a single receiver point still has a map
    eps = 1e-4
    if r - l < eps:
        l, r = l - eps, r + eps
    if t - b < eps:
        b, t = b - eps, t + eps
    w, h = _window_resolution((l, r, b, t), map_size)
    return ViewFace(vfw, False, (l, r, b, t), w, h, label)


CUBE_AXES = {
    "+X": np.array([1.0, 0, 0]), "-X": np.array([-1.0, 0, 0]),
    "+Y": np.array([0, 1.0, 0]), "-Y": np.array([0, -1.0, 0]),
    "+Z": np.array([0, 0, 1.0]), "-Z": np.array([0, 0, -1.0]),
}


def cube_faces(eye, receivers, map_size, allowed=None) -> List[ViewFace]:
    """Cube faces (90 degree frusta, square, map_size^2) around ``eye`` that
    see at least one receiver; each face's window is the full face so faces
    tile the sphere of directions without gaps."""
    d = np.asarray(receivers, np.float64) - eye
    faces = []
    if len(d) == 0:
        return faces
    major = np.argmax(np.abs(d), axis=1)
    sign = np.sign(d[np.arange(len(d)), major])
    for label, axis in CUBE_AXES.items():
        if allowed is not None and not allowed(axis):
            continue
        k = int(np.argmax(np.abs(axis)))
        if not np.any((major == k) & (sign == axis[k])):
            continue
        rot = look_rotation(axis)
        faces.append(ViewFace(view_from_world(rot, eye), False, (-1.0, 1.0, -1.0, 1.0),
                              map_size, map_size, "cube" + label))
    return faces


def light_view_faces(light: Light, receivers: np.ndarray, scene_bounds, map_size: int,
                     eye: np.ndarray | None = None, sun_pad: float | None = None) -> List[ViewFace]:
    """The faces of one light's view, fitted to the visible ``receivers``.

    * sun: one orthographic face along the sun direction, window fitted to the
      receivers (padded by the penumbra the sun's angle can throw across the
      scene's depth; ``sun_pad`` scene units instead), view origin beyond the
      scene so every caster is in front;
    * spot and area lights: one perspective face along the light's axis while
      the receivers fit within 60 degrees of it, otherwise cube faces;
    * point lights: the cube faces that see receivers.
    """
    receivers = np.asarray(receivers, np.float64).reshape(-1, 3)
    if len(receivers) == 0:
        return []
    lo, hi = scene_bounds
    lo = np.minimum(lo, receivers.min(0))
    hi = np.maximum(hi, receivers.max(0))
    diag = float(np.linalg.norm(hi - lo)) or 1.0
    eye = light.position if eye is None else np.asarray(eye, np.float64)
    if light.kind == "sun":
        fwd = light.direction
        rot = look_rotation(fwd)
        center = 0.5 * (lo + hi)
        origin = center - fwd * (diag + 1e-6 * diag)   # every caster lies in front
        vfw = view_from_world(rot, origin)
        p = receivers @ _rows(vfw) + vfw[:3, 3]
        pad = light.sun_spread * diag if sun_pad is None else float(sun_pad)
        l, r = _padded(p[:, 0].min() - pad, p[:, 0].max() + pad, FIT_MARGIN)
        b, t = _padded(p[:, 1].min() - pad, p[:, 1].max() + pad, FIT_MARGIN)
        eps = 1e-6 * diag
        if r - l < eps:
            l, r = l - eps, r + eps
        if t - b < eps:
            b, t = b - eps, t + eps
        w, h = _window_resolution((l, r, b, t), map_size)
        return [ViewFace(vfw, True, (l, r, b, t), w, h, "ortho")]

    fwd = light.direction
    d = receivers - eye
    dist = np.linalg.norm(d, axis=1)
    dist = np.where(dist > 0, dist, 1.0)
    cosang = (d @ fwd) / dist
    if light.kind == "area":
        front = cosang > 0
        use_single = front.any() and (cosang[front].min() >= math.cos(MAX_SINGLE_VIEW_HALF_ANGLE))
        rec = receivers[front] if front.any() else receivers
    elif light.is_spot:
        inside = cosang >= math.cos(min(light.spot_half_angle, math.pi / 2 - 1e-3) + 1e-3)
        rec = receivers[inside] if inside.any() else receivers[:0]
        use_single = light.spot_half_angle <= MAX_SINGLE_VIEW_HALF_ANGLE or (
            len(rec) > 0 and (rec - eye) @ fwd / np.maximum(np.linalg.norm(rec - eye, axis=1), 1e-300)
            >= math.cos(MAX_SINGLE_VIEW_HALF_ANGLE)).all()
    else:
        rec = receivers
        use_single = False
    if len(rec) == 0:
        return []
    if use_single:
        face = fit_perspective_face(eye, fwd, rec, map_size)
        return [face] if face is not None else []
    allowed = None
    if light.kind == "area" or light.is_spot:
        allowed = lambda axis: np.dot(axis, fwd) > -0.7072
    return cube_faces(eye, rec, map_size, allowed)


def pack_camera(cam: Camera, width: int, height: int) -> np.ndarray:
    """float64[20] for kernels: world-from-camera rotation (9, row-major),
    eye (3), view plane xmin, xmax, ymin, ymax, ortho flag, width, height, clip_start."""
    xmin, xmax, ymin, ymax = camera_viewplane(cam, width, height)
    m = np.asarray(cam.world_from_camera, np.float64)
    rot = m[:3, :3] / np.linalg.norm(m[:3, :3], axis=0)
    out = np.zeros(20, np.float64)
    out[:9] = rot.reshape(9)
    out[9:12] = m[:3, 3]
    out[12:16] = (xmin, xmax, ymin, ymax)
    out[16] = 1.0 if cam.kind == "ORTHO" else 0.0
    out[17] = width
    out[18] = height
    out[19] = cam.clip_start
    return out
