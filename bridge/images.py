"""Write-back into Blender: each pass as a float image, and the preview.

Pass images are named ``Penumbra <layer> <pass>`` (the compositor nodes of
``compositor.py`` show them); the preview is the image "Penumbra Preview".
Both are updated in place, so an Image Editor showing them refreshes.
"""
from __future__ import annotations

from typing import List

import numpy as np

import bpy

IMAGE_PREFIX = "Penumbra "          # pass images and the preview
PREVIEW_IMAGE = "Penumbra Preview"


def pass_image_name(layer: str, pass_id: str) -> str:
    return f"{IMAGE_PREFIX}{layer} {pass_id}"


def fill_grey(img, v) -> None:
    """Write ``v`` (float[H,W], row 0 at the top) into ``img`` (H x W) as
    opaque grey, in one ``foreach_set`` (Blender rows go bottom-up)."""
    h, w = v.shape
    rgba = np.empty((h, w, 4), np.float32)
    rgba[..., :3] = np.asarray(v, np.float32)[::-1, :, None]
    rgba[..., 3] = 1.0
    img.pixels.foreach_set(rgba.ravel())
    img.update()


def store_pass_image(layer: str, pass_id: str, v) -> bpy.types.Image:
    """A float Blender image holding pass ``v`` (float32[H,W], row 0 at the
    top) as grey; updated in place when it already exists with that size."""
    h, w = v.shape
    name = pass_image_name(layer, pass_id)
    img = bpy.data.images.get(name)
    if img is not None and tuple(img.size) != (w, h):
        bpy.data.images.remove(img)
        img = None
    if img is None:
        img = bpy.data.images.new(name, w, h, alpha=False, float_buffer=True)
    fill_grey(img, v)
    return img


def store_images(result) -> List[str]:
    """Each light's passes of a ``FrameResult`` as ``Penumbra <layer> <pass>``
    images, updated in place. Images of other passes (an earlier run's
    reference, the Cycles reference operator's) are kept. Returns the names."""
    names = []
    for lr in result.lights:
        for pid, v in lr.passes.items():
            names.append(store_pass_image(lr.layer, pid, v).name)
    return names


def combine(result, captured) -> np.ndarray:
    """Energy-weighted mean of the lights' passes (float32[H,W]; 1 = every
    light fully visible)."""
    W, H = captured.resolution
    energy = {lt.name: max(float(lt.energy), 0.0) for lt in captured.lights}
    acc = np.zeros((H, W), np.float64)
    total = 0.0
    for lr in result.lights:
        v = next(iter(lr.passes.values()), None)
        if v is None:
            continue
        w = energy.get(lr.name, 0.0) or 1e-12
        acc += w * v
        total += w
    if total <= 0.0:
        return np.ones((H, W), np.float32)
    return (acc / total).astype(np.float32)


def show_preview(v: np.ndarray) -> bpy.types.Image:
    """Write ``v`` (row 0 at the top) into the "Penumbra Preview" image,
    resizing it in place rather than making a new one."""
    h, w = v.shape
    img = bpy.data.images.get(PREVIEW_IMAGE)
    if img is None:
        img = bpy.data.images.new(PREVIEW_IMAGE, w, h, alpha=False, float_buffer=True)
    elif tuple(img.size) != (w, h):
        img.scale(w, h)
    fill_grey(img, v)
    return img
