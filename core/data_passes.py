"""The Z and vector passes beside the shadow passes, in Blender's (Cycles')
conventions, for a compositor that blurs in comp (Defocus, Vector Blur).

Both come from the camera's first hit at each pixel centre (Cycles writes
them from a pixel's first sample only):

    Depth   Z        distance of the hit from the camera plane along the view
                     axis (``GBuffer.depth``); 1e10 where nothing is hit, as
                     Cycles' film writes an empty depth
    Vector  X Y Z W  the hit's motion in raster pixels (x right, y up, from
                     the frame's bottom-left corner): X, Y = its position at
                     the previous frame - at this one, Z, W = at this one -
                     at the next (Cycles' ``camera_motion_vector``), each
                     frame's position projected by that frame's camera;
                     where nothing is hit, the view direction's motion under
                     the camera's (``camera_motion_vector_direction``)

The previous and next frames' placements are ``Scene.frame_motion`` (a
``ShutterMotion`` over frames -1, 0, +1: the objects and the camera, read
by the capture when the view layer's Vector pass is on). Departures from
Cycles: deformation within a mesh and a changing lens (zoom) are not
followed; the vector of a hit is its object's rigid motion.
"""
from __future__ import annotations

from typing import Dict, Optional, Tuple

import numpy as np

from . import views
from .exr import DEPTH_PASS, VECTOR_PASS
from .motion import ShutterMotion
from .scene import Camera, GBuffer

EMPTY_DEPTH = 1e10          # Cycles' depth where a pixel sees nothing


def frame_data_passes(scene, g: GBuffer) -> Dict[str, np.ndarray]:
    """The passes ``scene.data_passes`` asks for, from its pixel-centre
    G-buffer ``g`` ({} when none): Depth float32[H, W], Vector [H, W, 4]."""
    out = {}
    if DEPTH_PASS in scene.data_passes:
        out[DEPTH_PASS] = depth_pass(g)
    if VECTOR_PASS in scene.data_passes:
        out[VECTOR_PASS] = vector_pass(scene.camera, g, scene.frame_motion)
    return out


def depth_pass(g: GBuffer) -> np.ndarray:
    """float32[H, W]: the Depth pass of the pixel-centre G-buffer ``g``."""
    return np.where(g.hit, g.depth, np.float32(EMPTY_DEPTH)).astype(np.float32)


def raster(cam: Camera, world_from_camera: np.ndarray, points: np.ndarray, width: int,
           height: int) -> np.ndarray:
    """float64[n, 2]: ``points`` (world, float64[n, 3]) in raster pixels of
    ``cam`` placed at ``world_from_camera``: x from the left edge, y up from
    the bottom edge."""
    xmin, xmax, ymin, ymax = views.camera_viewplane(cam, width, height)
    m = np.asarray(world_from_camera, np.float64)
    rot = m[:3, :3] / np.linalg.norm(m[:3, :3], axis=0)
    local = (np.asarray(points, np.float64) - m[:3, 3]) @ rot
    if cam.kind == "ORTHO":
        x, y = local[:, 0], local[:, 1]
    else:
        with np.errstate(divide="ignore", invalid="ignore"):
            x, y = local[:, 0] / -local[:, 2], local[:, 1] / -local[:, 2]
    return np.stack([(x - xmin) / (xmax - xmin) * width, (y - ymin) / (ymax - ymin) * height], 1)


def _frame_cameras(cam: Camera, motion: ShutterMotion) -> Tuple[np.ndarray, np.ndarray]:
    """(world_from_camera at the previous frame, at the next)."""
    m = np.asarray(cam.world_from_camera, np.float64)
    if motion.camera is None:
        return m, m
    return motion.camera[0] @ m, motion.camera[-1] @ m


def vector_pass(cam: Camera, g: GBuffer, motion: Optional[ShutterMotion]) -> np.ndarray:
    """float32[H, W, 4]: the Vector pass of the pixel-centre G-buffer ``g``
    under ``motion`` (``Scene.frame_motion``; None: nothing moves, all 0)."""
    H, W = g.shape
    out = np.zeros((H, W, 4), np.float32)
    if motion is None or not motion.moves:
        return out
    pre_cam, post_cam = _frame_cameras(cam, motion)
    now = np.asarray(cam.world_from_camera, np.float64)
    hit = g.hit.reshape(-1)
    P = g.position.reshape(-1, 3).astype(np.float64)
    if not hit.all():                     # the world: a point far along the pixel's view direction
        rows, cols = np.divmod(np.flatnonzero(~hit), W)
        far = _far_points(cam, now, rows, cols, W, H)
        P = P.copy()
        P[~hit] = far
    pre, post = P.copy(), P.copy()
    slot = motion.slot_of(np.where(hit, g.object_id.reshape(-1), -1))
    idx = np.flatnonzero(slot >= 0)
    if len(idx):
        for D, into in ((motion.delta[0], pre), (motion.delta[-1], post)):
            M = D[slot[idx]]
            into[idx] = np.einsum("nij,nj->ni", M[:, :3, :3], P[idx]) + M[:, :3, 3]
    centre = raster(cam, now, P, W, H)
    before = raster(cam, pre_cam, pre, W, H)
    after = raster(cam, post_cam, post, W, H)
    v = np.concatenate([before - centre, centre - after], 1)
    v[~np.isfinite(v)] = 0.0
    return v.reshape(H, W, 4).astype(np.float32)


def _far_points(cam: Camera, world_from_camera: np.ndarray, rows, cols, width: int, height: int) -> np.ndarray:
    """World points far along the pixel-centre rays of (rows, cols): the
    view directions whose motion the world's pixels carry."""
    xmin, xmax, ymin, ymax = views.camera_viewplane(cam, width, height)
    x = xmin + (cols + 0.5) / width * (xmax - xmin)
    y = ymax - (rows + 0.5) / height * (ymax - ymin)
    m = np.asarray(world_from_camera, np.float64)
    rot = m[:3, :3] / np.linalg.norm(m[:3, :3], axis=0)
    far = 1e4 * max(float(cam.clip_end), 1.0)
    if cam.kind == "ORTHO":
        local = np.stack([x, y, np.full_like(x, -far)], 1)
    else:
        local = np.stack([x, y, -np.ones_like(x)], 1) * far
    return local @ rot.T + m[:3, 3]
