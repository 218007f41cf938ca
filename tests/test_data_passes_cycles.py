"""The Z and vector passes against Cycles' own Depth and Vector passes, and
in Blender's compositor: a box sliding between frames 1 and 3 seen by a
camera that slides too, the render's motion blur off (Cycles writes a
Vector pass only then), the view layer's Z and Vector passes on. Cycles
renders one sample a pixel with a Gaussian of width 0.01 px (its pixel
centres, BLENDER_NOTES.md), so its passes are the first hits', as
Penumbra's are. Then Blender's Vector Blur node, fed the EXR Penumbra
wrote, blurs a pass along that motion."""
import os

import bpy
import numpy as np
import OpenEXR

from penumbra.bridge.capture import capture_scene
from penumbra.core import exr
from penumbra.core.frame import render_frame
from penumbra.core.output import write_frame
from scenes import linear_keys, sliding_box_scene

RES = (48, 48)


def _scene(factory_scene):
    sc = sliding_box_scene(factory_scene, RES)
    sc.render.use_motion_blur = False
    linear_keys(sc.camera, "location", [(0.0, -1.0, 6.0), (0.6, -1.0, 6.2)], [1, 3])
    sc.frame_set(2)
    vl = sc.view_layers[0]
    vl.use_pass_z = vl.use_pass_vector = True
    return sc


def _cycles_passes(sc, folder):
    sc.cycles.samples = 1
    sc.cycles.pixel_filter_type, sc.cycles.filter_width = "GAUSSIAN", 0.01
    sc.cycles.use_denoising = sc.cycles.use_adaptive_sampling = False
    sc.render.filepath = os.path.join(folder, "cycles")
    sc.render.image_settings.media_type = "MULTI_LAYER_IMAGE"
    bpy.ops.render.render(write_still=True)
    ch = {}
    with OpenEXR.File(sc.render.filepath + ".exr", separate_channels=True) as f:
        for part in f.parts:
            ch.update({k: np.asarray(v.pixels) for k, v in part.channels.items()})
    return ch["ViewLayer.Depth.Z"], np.stack([ch[f"ViewLayer.Vector.{a}"] for a in "XYZW"], -1)


def test_depth_and_vector_are_cycles_own(factory_scene, tmp_path):
    sc = _scene(factory_scene)
    captured = capture_scene(sc, resolution=RES)
    assert captured.data_passes == ("Depth", "Vector")
    assert (sc.frame_current, sc.frame_subframe) == (2, 0.0)
    assert [captured.objects[i].name for i in captured.frame_motion.objects] == ["Box"]
    res = render_frame(captured, ["embree_irr"], overrides={"samples": 1})
    depth, vector = _cycles_passes(sc, str(tmp_path))
    ours_z, ours_v = res.data_passes["Depth"], res.data_passes["Vector"]
    assert np.abs(vector).max() > 5                        # the box and the camera move several pixels
    assert np.allclose(ours_z, depth, rtol=1e-5)           # 1e10 where nothing is hit, as Cycles
    off = np.abs(ours_v - vector).max(-1) > 0.01
    assert off.sum() <= 3, off.sum()                       # float32 rounding at the box's very edge at most


def test_blenders_vector_blur_blurs_a_pass_along_that_motion(factory_scene, tmp_path):
    sc = _scene(factory_scene)
    captured = capture_scene(sc, resolution=RES)
    res = render_frame(captured, ["embree_irr"], overrides={"samples": 16})
    path = write_frame(res, str(tmp_path), previews=False)["exr"]
    layer = res.lights[0].layer
    blurred = _vector_blur(sc, path, layer, str(tmp_path / "blurred.exr"))
    sharp = exr.read_multilayer(path)[layer]["embree_irr"]
    changed = np.abs(blurred - sharp) > 0.02
    assert changed.any() and (~changed).any()
    # the blur runs along x, the way everything moves: it changes pixels beside a change of the pass
    # along x, never where the row is flat around them
    flat_x = np.zeros_like(changed)
    flat_x[:, 8:-8] = np.all([np.abs(sharp[:, 8 + d:sharp.shape[1] - 8 + d] - sharp[:, 8:-8]) < 1e-6
                              for d in range(-8, 9)], axis=0)
    assert not (changed & flat_x).any()


def _vector_blur(sc, exr_path: str, layer: str, out: str) -> np.ndarray:
    """Blender's compositor on Penumbra's EXR: Image (the layer) -> Vector
    Blur (Speed: the Vector pass, Depth: the Depth pass) -> the output;
    the blurred ``embree_irr`` pass."""
    img = bpy.data.images.load(exr_path)
    tree = bpy.data.node_groups.new("Penumbra test", "CompositorNodeTree")
    tree.interface.new_socket("Image", in_out="OUTPUT", socket_type="NodeSocketColor")
    sc.compositing_node_group = tree
    src = tree.nodes.new("CompositorNodeImage")
    src.image = img
    src.layer = layer
    blur = tree.nodes.new("CompositorNodeVecBlur")
    out_node = tree.nodes.new("NodeGroupOutput")
    tree.links.new(src.outputs["embree_irr"], blur.inputs["Image"])
    tree.links.new(src.outputs["Vector"], blur.inputs["Speed"])
    tree.links.new(src.outputs["Depth"], blur.inputs.get("Depth") or blur.inputs["Z"])   # 5.0 names it Z
    tree.links.new(blur.outputs["Image"], out_node.inputs[0])
    sc.render.engine = "BLENDER_WORKBENCH"
    sc.render.use_compositing = True
    sc.render.filepath = out
    sc.render.image_settings.media_type = "IMAGE"
    sc.render.image_settings.file_format = "OPEN_EXR"
    bpy.ops.render.render(write_still=True)
    with OpenEXR.File(out, separate_channels=True) as f:
        return np.asarray(f.parts[0].channels["R"].pixels)
