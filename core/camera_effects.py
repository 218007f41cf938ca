"""What the camera's effects are in a frame and how its passes take them:
the frame JSON's ``camera_effects`` (``describe_effects``) and the line
``penumbra plan`` prints (``effects_line``). The sampling itself is
``camera_samples``'; which methods follow each receiver's time is
``Method.shutter_time``; the others take ``motion.TIME_SLICES`` slices.
"""
from __future__ import annotations

from typing import Optional

from . import methods as registry
from .motion import TIME_SLICES


def describe_effects(scene, sampled: bool) -> Optional[dict]:
    """The camera's effects as the frame's JSON records them (None: a still
    frame through a pinhole): the thin lens' parameters, the shutter's
    motion (``ShutterMotion.to_json``), and whether the passes sample them
    (a filtered frame: every method's sub-pixel receivers lie on their own
    lens rays at their own times; pixel centres: a pinhole at the frame)."""
    cam, motion = scene.camera, scene.motion
    moves = motion is not None and motion.moves
    if not cam.has_depth_of_field and not moves:
        return None
    out = {}
    if cam.has_depth_of_field:
        out["depth_of_field"] = {"aperture_radius": float(cam.aperture_radius),
                                 "focus_distance": float(cam.focus_distance),
                                 "blades": int(cam.aperture_blades), "rotation": float(cam.aperture_rotation),
                                 "ratio": float(cam.aperture_ratio)}
    if moves:
        out["motion_blur"] = motion.to_json()
    out["sampled"] = "per sub-pixel receiver" if sampled else "no: pixel centres (a pinhole at the frame)"
    return out


def effects_line(scene, sampled: bool) -> Optional[str]:
    """One line for ``penumbra plan``: the camera's effects and how the
    passes take them (None: a still frame through a pinhole)."""
    cam, motion = scene.camera, scene.motion
    parts = []
    if cam.has_depth_of_field:
        parts.append(f"depth of field, lens radius {cam.aperture_radius:.4g}, focus {cam.focus_distance:.4g}")
    if motion is not None and motion.moves:
        what = [f"{len(motion.objects)} moving object(s)"] + (["the camera"] if motion.camera is not None else [])
        parts.append(f"motion blur over {motion.shutter:g} frame(s) ({' and '.join(what)}, {motion.steps} steps)")
    if not parts:
        return None
    timed = ", ".join(sorted(p for p in registry.pass_ids(external=False)
                             if getattr(registry.producer_of(p), "shutter_time", False)))
    how = "each sub-pixel receiver on its own lens ray and shutter time"
    if motion is not None and len(motion.objects):
        how += (f"; moving occluders at the receiver's time for {timed}, at {TIME_SLICES} time slices "
                f"for the other methods")
    if not sampled:
        how = "ignored: pixel centres through a pinhole at the frame (--pixel-filter none)"
    return f"camera: {'; '.join(parts)}: {how}"
