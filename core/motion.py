"""Motion over the shutter: where the moving objects and the camera are at a
sample's time, as Cycles' object and camera motion blur defines it.

``ShutterMotion`` holds K >= 2 time steps spread evenly over the shutter
(shutter time t in [0, 1]: step k at t = k / (K - 1)); per moving object its
rigid motion as ``delta[k]``, the 4x4 that takes its world placement at the
frame to its placement at step k (world(t_k) = delta[k] @ world(frame)); the
camera's the same way (``camera``: its world_from_camera's delta). Between steps a placement is the linear blend of the
two steps' matrices (``blend``): what Embree does with an instance's time
steps, so a hit found by a ray at time t and the point moved here agree.

Parameters (``bridge/capture.py`` reads them as Cycles syncs them):

    steps      3       Cycles' (2 << (motion_steps - 1)) + 1 over the moving objects
    shutter    0.5     the shutter's length in frames (``render.motion_blur_shutter``)
    position   CENTER  START | CENTER | END: where the shutter opens relative to the frame

A step k is captured at frame + offset(t_k): CENTER (t - 1/2) shutter, START
t shutter, END (t - 1) shutter (``frame_offsets``).

Time slices (``TIME_SLICES``, 3): a method that does not trace each
receiver's own time (``Method.shutter_time`` False: every method but the
ray-traced references) shades a sub-pixel receiver whose time falls in the
k-th of K equal spans of the shutter with the occluders where they are at
the span's middle, t = (k + 1/2) / K: its own light views, BVHs traced at
that time and triangles moved there (``move_triangles``,
``FrameBuffers.supersampled``'s ``at_time``).

Departures from Cycles: Cycles interpolates an object's decomposed
transform (translation, rotation quaternion, scale); the linear blend of
matrices is the same for translation and scale and shrinks a rotating
object slightly between steps. Deformation (vertices moving within a mesh),
moving lights and the shutter curve are not taken: the mesh is the frame's,
lights stand still, times are uniform over the shutter.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np

POSITIONS = ("START", "CENTER", "END")
#: shutter spans whose occluders a method that does not trace each receiver's time sees (module docstring)
TIME_SLICES = 3


def frame_offsets(steps: int, shutter: float, position: str = "CENTER") -> np.ndarray:
    """float64[steps]: each step's offset from the frame, in frames."""
    t = np.linspace(0.0, 1.0, int(steps))
    start = {"START": 0.0, "CENTER": -0.5, "END": -1.0}[position]
    return (t + start) * float(shutter)


@dataclass
class ShutterMotion:
    """What moves over the shutter (module docstring); ``objects[i]``'s
    motion is ``delta[:, i]``; ``camera`` None: the camera stands still."""

    objects: np.ndarray                      # int32[m]: moving object ids
    delta: np.ndarray                        # float64[K, m, 4, 4]
    camera: Optional[np.ndarray] = None      # float64[K, 4, 4]: the camera's delta
    shutter: float = 0.5
    position: str = "CENTER"
    _slot: Optional[np.ndarray] = field(default=None, repr=False, compare=False)

    def __post_init__(self):
        self.objects = np.asarray(self.objects, np.int32).reshape(-1)
        self.delta = np.asarray(self.delta, np.float64)
        if self.delta.ndim != 4 or self.delta.shape[1:] != (len(self.objects), 4, 4):
            raise ValueError("ShutterMotion.delta must be float64[K, moving objects, 4, 4]")
        if self.camera is not None:
            self.camera = np.asarray(self.camera, np.float64).reshape(-1, 4, 4)

    @property
    def steps(self) -> int:
        return int(self.delta.shape[0])

    @property
    def moves(self) -> bool:
        """Something moves over the shutter (objects or the camera)."""
        return bool(len(self.objects)) or self.camera is not None

    @property
    def frame_time(self) -> float:
        """The frame's own time in the shutter's [0, 1]: where a ray without
        a time finds the moving geometry (START 0, CENTER 1/2, END 1)."""
        return {"START": 0.0, "CENTER": 0.5, "END": 1.0}[self.position]

    def slot_of(self, object_ids: np.ndarray) -> np.ndarray:
        """int32 per object id: its index in ``objects`` (-1: it stands still)."""
        object_ids = np.asarray(object_ids, np.int64)
        top = int(max(object_ids.max(initial=-1), self.objects.max(initial=-1))) + 2
        if self._slot is None or len(self._slot) < top:
            self._slot = np.full(top, -1, np.int32)
            self._slot[self.objects] = np.arange(len(self.objects), dtype=np.int32)
        out = np.full(len(object_ids), -1, np.int32)
        ok = object_ids >= 0
        out[ok] = self._slot[object_ids[ok]]
        return out

    def to_json(self) -> dict:
        return {"steps": self.steps, "shutter": float(self.shutter), "position": self.position,
                "moving_objects": int(len(self.objects)), "camera_moves": self.camera is not None}


def blend(steps: np.ndarray, t: np.ndarray) -> np.ndarray:
    """float64[n, 4, 4]: the matrices ``steps`` (float64[K, n, 4, 4], or
    [K, 4, 4] for one shared by all) blended linearly at times ``t``
    (float[n] in [0, 1]) between their two neighbouring steps."""
    t = np.clip(np.asarray(t, np.float64), 0.0, 1.0)
    K = steps.shape[0]
    x = t * (K - 1)
    k = np.minimum(np.floor(x).astype(np.int64), K - 2)
    f = (x - k)[:, None, None]
    if steps.ndim == 3:
        return (1.0 - f) * steps[k] + f * steps[k + 1]
    n = np.arange(len(t))
    return (1.0 - f) * steps[k, n] + f * steps[k + 1, n]


def move_points(motion: ShutterMotion, position: np.ndarray, normal: np.ndarray, object_id: np.ndarray,
                time: np.ndarray) -> np.ndarray:
    """Move receivers found at the frame's placement to their time: for each
    entry on a moving object, position <- D(t) position and normal <- the
    unit D(t)^-T normal (D: the object's ``blend``ed delta). In place
    (position float64[n,3], normal float[n,3]); returns the moved entries'
    indices."""
    slot = motion.slot_of(object_id)
    idx = np.flatnonzero(slot >= 0)
    if not len(idx):
        return idx
    D = blend(motion.delta[:, slot[idx]], time[idx])
    P = position[idx]
    position[idx] = np.einsum("nij,nj->ni", D[:, :3, :3], P) + D[:, :3, 3]
    N = np.einsum("nji,nj->ni", np.linalg.inv(D[:, :3, :3]), normal[idx].astype(np.float64))
    N /= np.maximum(np.linalg.norm(N, axis=1), 1e-300)[:, None]
    normal[idx] = N
    return idx


def retime_points(motion: ShutterMotion, position: np.ndarray, normal: np.ndarray, object_id: np.ndarray,
                  time: np.ndarray, to: float) -> None:
    """Move receivers found at their ``time`` (float[n]) to where their
    objects put them at shutter time ``to``: for each entry on a moving
    object, position <- D(to) D(time)^-1 position, the normal by that
    matrix's inverse transpose, unit (D: the object's ``blend``ed delta).
    In place (position float64[n,3], normal float[n,3])."""
    slot = motion.slot_of(object_id)
    idx = np.flatnonzero(slot >= 0)
    if not len(idx):
        return
    M = blend(motion.delta[:, slot[idx]], np.full(len(idx), to)) @ np.linalg.inv(
        blend(motion.delta[:, slot[idx]], time[idx]))
    position[idx] = np.einsum("nij,nj->ni", M[:, :3, :3], position[idx]) + M[:, :3, 3]
    N = np.einsum("nji,nj->ni", np.linalg.inv(M[:, :3, :3]), normal[idx].astype(np.float64))
    normal[idx] = N / np.maximum(np.linalg.norm(N, axis=1), 1e-300)[:, None]


def move_triangles(motion: ShutterMotion, triangles: np.ndarray, object_id: np.ndarray, t: float) -> np.ndarray:
    """float32[T, 3, 3]: ``triangles`` (at the frame's placement, their
    objects ``object_id``) with those of moving objects where they are at
    shutter time ``t`` (``blend``); ``triangles`` itself when none moves."""
    slot = motion.slot_of(object_id)
    idx = np.flatnonzero(slot >= 0)
    if not len(idx):
        return triangles
    out = np.array(triangles, np.float32, copy=True)
    for j in np.unique(slot[idx]):
        sel = idx[slot[idx] == j]
        D = blend(motion.delta[:, j], np.array([t]))[0]
        v = triangles[sel].reshape(-1, 3).astype(np.float64)
        out[sel] = (v @ D[:3, :3].T + D[:3, 3]).reshape(-1, 3, 3).astype(np.float32)
    return out


def box_corners(boxes: np.ndarray) -> np.ndarray:
    """float64[m, 8, 3]: the corners of the boxes (lo, hi) ``boxes``
    (float[m, 2, 3]); corner b takes hi on axis a where bit a of b is set."""
    boxes = np.asarray(boxes, np.float64)
    return np.stack([np.stack([boxes[:, (b >> a) & 1, a] for a in range(3)], 1) for b in range(8)], 1)


def step_corners(delta: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """float64[K, m, 8, 3]: the corners of the boxes ``boxes`` (float[m, 2, 3],
    at the frame) placed by each step's ``delta`` (float64[K, m, 4, 4])."""
    return np.einsum("kmij,mcj->kmci", delta[:, :, :3, :3], box_corners(boxes)) + delta[:, :, None, :3, 3]
