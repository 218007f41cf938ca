"""The Z and vector passes (``core/data_passes.py``) against their closed
forms on an orthographic top view, and in the EXR as Blender names them."""
from __future__ import annotations

import numpy as np

from penumbra.core import exr
from penumbra.core.data_passes import EMPTY_DEPTH
from penumbra.core.filtered_frame import render_filtered
from penumbra.core.frame import render_frame
from penumbra.core.motion import ShutterMotion
from penumbra.core.output import write_frame
from penumbra.core.pixel_filter import PixelFilter
from synthetic import half_plane_scene, sun_light

PX = 64 / 4.0          # half_plane_scene's top orthographic camera: 64 px over 4 scene units


def _frames(dx: float = 0.0, dy: float = 0.0) -> np.ndarray:
    """Deltas at frames -1, 0, +1 of a motion of (dx, dy) per frame."""
    d = np.tile(np.eye(4), (3, 1, 1))
    d[:, 0, 3] = (-dx, 0.0, dx)
    d[:, 1, 3] = (-dy, 0.0, dy)
    return d


def test_a_moving_surfaces_vector_is_its_raster_motion_per_frame():
    scene = half_plane_scene(sun_light(0.0), res=64)
    scene.data_passes = ("Depth", "Vector")
    scene.frame_motion = ShutterMotion([0], _frames(0.25, -0.125)[:, None], shutter=2.0)
    res = render_frame(scene, ["embree_irr"])
    V, Z = res.data_passes["Vector"], res.data_passes["Depth"]
    # the ground moves +0.25 x, -0.125 y per frame: at the previous frame it was 4 px left and
    # 2 px up (raster y points up): X, Y = previous - now = (-4, +2); Z, W = now - next, the same
    assert np.allclose(V, np.array([-0.25, 0.125, -0.25, 0.125]) * PX, atol=1e-4)
    assert np.allclose(Z, 1.0)                     # the camera 1 unit above the ground
    assert res.to_json()["data_passes"] == ["Depth", "Vector"]


def test_a_moving_cameras_vector_moves_the_still_scene_the_other_way():
    scene = half_plane_scene(sun_light(0.0), res=64)
    scene.data_passes = ("Vector",)
    cam = _frames(0.5)
    scene.frame_motion = ShutterMotion(np.zeros(0, np.int32), np.zeros((3, 0, 4, 4)), camera=cam, shutter=2.0)
    V = render_frame(scene, ["embree_irr"]).data_passes["Vector"]
    assert np.allclose(V, np.array([0.5, 0.0, 0.5, 0.0]) * PX, atol=1e-4)


def test_empty_pixels_and_still_frames():
    scene = half_plane_scene(sun_light(0.0), res=32, ground=1.0)     # the ground covers the middle only
    scene.data_passes = ("Depth", "Vector")
    res = render_frame(scene, ["embree_irr"])
    Z = res.data_passes["Depth"]
    assert (Z == np.float32(EMPTY_DEPTH)).any() and (Z == 1.0).any()
    assert not res.data_passes["Vector"].any()                      # nothing moves: all 0
    scene.data_passes = ()
    assert render_frame(scene, ["embree_irr"]).data_passes == {}


def test_the_exr_holds_them_in_every_layer_by_blenders_names(tmp_path):
    scene = half_plane_scene(sun_light(0.0), res=32)
    scene.data_passes = ("Depth", "Vector")
    scene.frame_motion = ShutterMotion([0], _frames(0.25)[:, None], shutter=2.0)
    res = render_filtered(scene, ["embree_irr"], pixel_filter=PixelFilter("blackman-harris", 1.5, 4))
    assert res.data_passes["Vector"].shape == (32, 32, 4)          # the frame's, not the sub-pixel stage's
    path = write_frame(res, str(tmp_path), previews=False)["exr"]
    import OpenEXR
    with OpenEXR.File(path) as f:
        names = set(f.parts[0].channels)
    assert {"Sun.Depth.Z", "Sun.Vector.X", "Sun.Vector.Y", "Sun.Vector.Z", "Sun.Vector.W"} <= names
    back = exr.read_multilayer(path)["Sun"]
    assert np.array_equal(back["Vector"], res.data_passes["Vector"])
    assert np.array_equal(back["Depth"], res.data_passes["Depth"])
