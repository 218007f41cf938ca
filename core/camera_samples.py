"""A sub-pixel sample's camera dimensions beyond its place in the pixel:
where on the lens its ray starts (depth of field, Cycles' thin lens) and
when in the shutter it is taken (motion blur, ``core/motion.py``).

A camera with ``Camera.aperture_radius`` > 0 is a thin lens
(``intern/cycles/kernel/camera/camera.h``: ``camera_sample_aperture``,
``camera_sample_perspective``, ``camera_sample_orthographic``). A camera
sample with lens coordinates (u, v) in [0, 1)^2 starts at the lens point

    L = aperture_radius * bokeh(u, v)            (camera-local x, y; z = 0)

    bokeh   the unit disk (Shirley-Chiu concentric map), or with
            ``aperture_blades`` >= 3 the regular polygon of that many corners
            on the unit circle turned by ``aperture_rotation`` (Cycles'
            ``regular_polygon_sample``); x then divided by ``aperture_ratio``

and looks through the point where its pinhole ray meets the plane in focus,
``focus_distance`` along the view axis (``pixel_rays.lens_ray_batch``).
Blender's settings map as Cycles' sync does (``bridge/capture.py``):
aperture_radius = lens (mm) / 1000 / (2 f-stop), for an orthographic camera
1 / (2 f-stop); the focus object's distance along the view axis.

Sampling (``lens_points``). A filtered pass traces G x G sub-pixel samples
per pixel footprint (``pixel_filter``). The G x G samples of one pixel take
the G x G strata of the lens square, one each, in an order that a hashed
permutation (Kensler, "Correlated Multi-Jittered Sampling", 2013) draws per
pixel, jittered within the stratum: pixel position and lens position are
stratified jointly, and neither follows the other from pixel to pixel.

Shutter times (``shutter_times``): the G x G samples of a pixel take the
G^2 strata of the shutter [0, 1], one each, in a second per-pixel hashed
order (independent of the lens'), jittered: pixel position, lens point,
time and light sample are drawn jointly.

Parameters: ``seed`` (0) decorrelates frames; a sub-sample's lens point and
time depend only on the seed and its place in the supersampled view, not on
which list or batch holds it.

Departures from Cycles: Cycles draws (u, v) and the time from its
Sobol-Burley sequence per render sample; here one stratified lens sample
and time per sub-pixel sample.
"""
from __future__ import annotations

import math
import numpy as np

from .jit import inner, kernel
from .sampling import concentric_disk, rand01
from .scene import Camera

LENS_SALT = 0x6C656E73          # keeps the lens' hash streams apart from the light samples'
TIME_SALT = 0x74696D65          # ... and the shutter's apart from both
RAY_TIME_SALT = 0x72617974      # ... and a receiver's shadow rays' times apart from its own


@inner(forceinline=True)
def _permute(i, n, p):
    """Kensler's hashed permutation: the image of i under a permutation of
    0 .. n-1 chosen by the 32-bit key p (cycle walking over the next power
    of two)."""
    w = np.uint32(n - 1)
    w |= w >> np.uint32(1)
    w |= w >> np.uint32(2)
    w |= w >> np.uint32(4)
    w |= w >> np.uint32(8)
    w |= w >> np.uint32(16)
    x = np.uint32(i)
    p = np.uint32(p)
    m = np.uint32(0xFFFFFFFF)
    while True:
        x ^= p
        x = (x * np.uint32(0xE170893D)) & m
        x ^= p >> np.uint32(16)
        x ^= (x & w) >> np.uint32(4)
        x ^= p >> np.uint32(8)
        x = (x * np.uint32(0x0929EB3F)) & m
        x ^= p >> np.uint32(23)
        x ^= (x & w) >> np.uint32(1)
        x = (x * (np.uint32(1) | (p >> np.uint32(27)))) & m
        x = (x * np.uint32(0x6935FA69)) & m
        x ^= (x & w) >> np.uint32(11)
        x = (x * np.uint32(0x74DCB303)) & m
        x ^= (x & w) >> np.uint32(2)
        x = (x * np.uint32(0x9E501CC3)) & m
        x ^= (x & w) >> np.uint32(2)
        x = (x * np.uint32(0xC860A3DF)) & m
        x &= w
        x ^= x >> np.uint32(5)
        if x < np.uint32(n):
            break
    return (np.int64(x) + np.int64(p)) % n


@inner(forceinline=True)
def _pixel_and_index(f, sub_width, grid):
    """Sub-sample ``f`` (row-major in the ``grid``-times supersampled view,
    ``sub_width`` wide): its pixel's flat index and its index k < grid^2
    within the pixel."""
    row, col = f // sub_width, f % sub_width
    return (row // grid) * (sub_width // grid) + col // grid, (row % grid) * grid + col % grid


@inner(forceinline=True)
def _stratum_order(seed, pixel, k, n, salt):
    """Sample k's stratum of n in pixel ``pixel``'s own hashed order."""
    lo = np.uint32(rand01(seed, pixel, np.int64(salt), np.int64(2)) * 16777216.0)
    hi = np.uint32(rand01(seed, pixel, np.int64(salt), np.int64(3)) * 256.0)
    return _permute(k, n, lo | (hi << np.uint32(24)))


@inner(forceinline=True)
def aperture_point(u, v, blades, rotation, inv_ratio):
    """Cycles' ``camera_sample_aperture``: (u, v) in [0, 1)^2 -> a point of
    the unit disk (``blades`` < 3) or of the regular ``blades``-gon turned by
    ``rotation``, its x scaled by ``inv_ratio``."""
    if blades < 3:
        x, y = concentric_disk(u, v)
    else:
        corner = math.floor(u * blades)
        u = u * blades - corner
        u = math.sqrt(u)
        v = v * u
        u = 1.0 - u
        angle = math.pi / blades
        px, py = (u + v) * math.cos(angle), (u - v) * math.sin(angle)
        rot = rotation + corner * 2.0 * angle
        cr, sr = math.cos(rot), math.sin(rot)
        x, y = cr * px - sr * py, sr * px + cr * py
    return x * inv_ratio, y


@kernel(nogil=True)
def _lens_points(flat, sub_width, grid, seed, radius, blades, rotation, inv_ratio, out):
    """``lens_points``' kernel."""
    n = grid * grid
    for i in range(flat.shape[0]):
        pixel, k = _pixel_and_index(flat[i], sub_width, grid)
        s = _stratum_order(seed, pixel, k, n, LENS_SALT)
        u = ((s % grid) + rand01(seed, pixel, np.int64(LENS_SALT + 1 + k), np.int64(0))) / grid
        v = ((s // grid) + rand01(seed, pixel, np.int64(LENS_SALT + 1 + k), np.int64(1))) / grid
        x, y = aperture_point(u, v, blades, rotation, inv_ratio)
        out[i, 0] = radius * x
        out[i, 1] = radius * y


@kernel(nogil=True)
def _shutter_times(flat, sub_width, grid, seed, out):
    """``shutter_times``' kernel."""
    n = grid * grid
    for i in range(flat.shape[0]):
        pixel, k = _pixel_and_index(flat[i], sub_width, grid)
        s = _stratum_order(seed, pixel, k, n, TIME_SALT)
        out[i] = (s + rand01(seed, pixel, np.int64(TIME_SALT + 1 + k), np.int64(0))) / n


def shutter_times(flat: np.ndarray, sub_width: int, grid: int, seed: int = 0) -> np.ndarray:
    """float32[N]: the shutter time in [0, 1) of each sub-sample ``flat[i]``
    (as ``lens_points`` takes them): a pixel's G^2 samples on the G^2
    strata of the shutter, in a per-pixel hashed order, jittered."""
    flat = np.ascontiguousarray(flat, np.int64)
    out = np.zeros(len(flat), np.float64)
    if len(flat):
        _shutter_times(flat, int(sub_width), int(grid), int(seed), out)
    return out.astype(np.float32)


@kernel(nogil=True)
def _ray_times(pix, ns, seed, out):
    """``ray_times``' kernel."""
    for i in range(pix.shape[0]):
        lo = np.uint32(rand01(seed, pix[i], np.int64(RAY_TIME_SALT), np.int64(2)) * 16777216.0)
        hi = np.uint32(rand01(seed, pix[i], np.int64(RAY_TIME_SALT), np.int64(3)) * 256.0)
        key = lo | (hi << np.uint32(24))          # the pixel's order of the strata (``_stratum_order``)
        for s in range(ns):
            k = _permute(s, ns, key)
            out[i * ns + s] = (k + rand01(seed, pix[i], np.int64(RAY_TIME_SALT + 1), np.int64(s))) / ns


def ray_times(pix: np.ndarray, ns: int, seed: int = 0) -> np.ndarray:
    """float32[n * ns]: the shutter times of the ``ns`` shadow rays of each
    receiver ``pix[i]`` (its pixel id) that stands for the whole shutter
    (``GBuffer.over_shutter``): ray s on one of ns strata of the shutter,
    in a per-pixel hashed order, jittered, so light sample and time are
    stratified jointly."""
    pix = np.ascontiguousarray(pix, np.int64)
    out = np.zeros(len(pix) * int(ns), np.float64)
    if len(pix):
        _ray_times(pix, int(ns), int(seed), out)
    return out.astype(np.float32)


def lens_points(cam: Camera, flat: np.ndarray, sub_width: int, grid: int, seed: int = 0) -> np.ndarray:
    """float64[N, 2]: the camera-local lens point (x, y) of each sub-sample
    ``flat[i]`` (row-major index in the ``grid``-times supersampled view,
    ``sub_width`` wide): the thin lens' stratified, per-pixel permuted
    samples (module docstring). A pinhole camera: all zeros."""
    flat = np.ascontiguousarray(flat, np.int64)
    out = np.zeros((len(flat), 2), np.float64)
    if cam.has_depth_of_field and len(flat):
        _lens_points(flat, int(sub_width), int(grid), int(seed), float(cam.aperture_radius),
                     int(cam.aperture_blades), float(cam.aperture_rotation),
                     1.0 / max(float(cam.aperture_ratio), 1e-6), out)
    return out
