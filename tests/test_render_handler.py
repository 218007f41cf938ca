"""Passes in every render: the render handlers (bpy, background mode)."""
import json
import os

import bpy
import numpy as np
import OpenEXR

from penumbra.bridge import compat
from penumbra.addon import handlers
from penumbra.bridge import compositor, pipeline, settings
from penumbra.cli import main
from penumbra.core import exr
from scenes import open_sample

SIZE = 32
SEED = 3
SAMPLES = 4


def _animated_scene(tmp_path, enable=True):
    """sphere_plane at 32x32, Cycles at 1 sample, the sphere moving over
    frames 1-3, every light on pcf with the embree reference; saved as
    tmp_path/anim.blend (bpy's current file is then that copy)."""
    scene = open_sample("sphere_plane", (SIZE, SIZE))
    r = scene.render
    r.engine = "CYCLES"
    scene.cycles.samples = 1
    scene.cycles.use_denoising = False
    scene.frame_start, scene.frame_end = 1, 3
    sphere = bpy.data.objects["Sphere"]
    z0 = sphere.location.z
    for f, dx in ((1, -0.6), (3, 0.6)):
        sphere.location.x = dx
        sphere.location.z = z0
        sphere.keyframe_insert("location", frame=f)
    scene.frame_set(1)
    for lt in bpy.data.lights:
        lt.penumbra.method = "pcf"
        lt.penumbra.light_samples = SAMPLES
    scene.penumbra.references = {"embree"}
    scene.penumbra.seed = SEED
    scene.penumbra.render_passes = enable
    r.filepath = str(tmp_path / "render" / "frame_")
    r.image_settings.file_format = "OPEN_EXR"
    blend = str(tmp_path / "anim.blend")
    bpy.ops.wm.save_as_mainfile(filepath=blend)
    return scene, blend


def _compositor_showing(scene, image_name):
    """Composite = the given image; Render Layers feeds a Viewer so Blender
    still renders (and the render depsgraph reaches frame_change_post)."""
    img = bpy.data.images.get(image_name) or bpy.data.images.new(image_name, SIZE, SIZE, alpha=False,
                                                                  float_buffer=True)
    tree = bpy.data.node_groups.new("Test Compositor", "CompositorNodeTree")
    tree.interface.new_socket("Image", in_out="OUTPUT", socket_type="NodeSocketColor")
    node = tree.nodes.new("CompositorNodeImage")
    node.image = img
    out = tree.nodes.new("NodeGroupOutput")
    tree.links.new(node.outputs["Image"], out.inputs["Image"])
    rl = tree.nodes.new("CompositorNodeRLayers")
    viewer = tree.nodes.new("CompositorNodeViewer")
    tree.links.new(rl.outputs["Image"], viewer.inputs[0])
    compat.set_compositor_tree(scene, tree)
    return tree


def _read_rgba_r(path):
    f = OpenEXR.File(path, separate_channels=True)
    for part in f.parts:
        for name, ch in part.channels.items():
            if name.endswith("R"):
                return np.asarray(ch.pixels, np.float32)
    raise AssertionError(f"no R channel in {path}")


def test_animation_render_writes_passes_matching_cli(registered, tmp_path):
    scene, blend = _animated_scene(tmp_path)
    layer = "Key_Light"
    _compositor_showing(scene, compositor.pass_image_name(layer, "pcf"))
    bpy.ops.wm.save_mainfile()
    scene.render.use_lock_interface = False
    scene.penumbra.render_passes = True            # the update sets the lock again
    assert scene.render.use_lock_interface is True
    bpy.ops.render.render(animation=True)
    assert handlers.state["errors"] == []
    assert handlers.state["active"] is False      # render_complete ended it
    out = tmp_path / "render"
    written = sorted(p for p in os.listdir(out) if p.startswith("anim."))
    assert written == ["anim.0001.exr", "anim.0001.json", "anim.0002.exr", "anim.0002.json",
                       "anim.0003.exr", "anim.0003.json"]
    ours = {f: exr.read_multilayer(str(out / f"anim.{f:04d}.exr")) for f in (1, 2, 3)}
    # the compositor saw the current frame's pass (not the previous frame's)
    for f in (1, 2, 3):
        composite = _read_rgba_r(str(out / f"frame_{f:04d}.exr")).reshape(SIZE, SIZE)
        np.testing.assert_allclose(composite, ours[f][layer]["pcf"], atol=1e-6)
    # the sphere moved: the shadow did too
    assert np.abs(ours[1][layer]["pcf"] - ours[3][layer]["pcf"]).max() > 0.5
    recs = {f: json.loads((out / f"anim.{f:04d}.json").read_text()) for f in (1, 2, 3)}
    assert [recs[f]["frame"] for f in (1, 2, 3)] == [1, 2, 3]
    # per-frame CLI output with the same methods / seed / samples: the same bits
    for f in (1, 2, 3):
        cli_out = tmp_path / "cli"
        assert main(["render", blend, "--frame", str(f), "--resolution", f"{SIZE}x{SIZE}",
                     "--methods", "pcf,embree", "--samples", str(SAMPLES), "--seed", str(SEED),
                     "--out", str(cli_out), "--no-previews"]) == 0
        cli = exr.read_multilayer(str(cli_out / f"anim.{f:04d}.exr"))
        assert set(cli) == set(ours[f]) == {layer}
        # filtered like the render by default: the coverage as an Alpha pass
        assert set(cli[layer]) == set(ours[f][layer]) == {"pcf", "embree", "Alpha"}
        for pid in ("pcf", "embree", "Alpha"):
            np.testing.assert_array_equal(ours[f][layer][pid], cli[layer][pid])
        cli_rec = json.loads((cli_out / f"anim.{f:04d}.json").read_text())
        for pid in ("pcf", "embree"):
            assert recs[f]["lights"][0]["methods"][pid]["params"] == \
                cli_rec["lights"][0]["methods"][pid]["params"]
    # the CLI opened the saved file (render_passes on): its capture renders ran
    # the handlers, which stayed out of the way (still the animation's 3 frames)
    assert handlers.state["errors"] == [] and len(handlers.state["written"]) == 3


def test_still_render_writes_its_frame(registered, tmp_path):
    scene, _ = _animated_scene(tmp_path)
    scene.frame_set(2)
    scene.render.filepath = str(tmp_path / "still" / "img")
    scene.penumbra.references = {"embree", "cycles"}     # cycles cannot run inside a render
    bpy.ops.render.render(write_still=True)
    assert handlers.state["errors"] == []
    assert any("cycles reference skipped" in n for n in handlers.state["notes"])
    layers = exr.read_multilayer(str(tmp_path / "still" / "anim.0002.exr"))
    assert set(layers["Key_Light"]) == {"pcf", "embree", "Alpha"}
    rec = json.loads((tmp_path / "still" / "anim.0002.json").read_text())
    assert rec["frame"] == 2 and rec["resolution"] == [SIZE, SIZE]
    assert rec["pixel_filter"]["type"] == settings.render_pixel_filter(scene).kind     # the render's own


def test_render_without_render_layers_node(registered, tmp_path):
    """A compositor without Render Layers: Blender renders nothing and
    frame_change_post never sees a render depsgraph; render_pre computes."""
    scene, _ = _animated_scene(tmp_path)
    img_name = compositor.pass_image_name("Key_Light", "pcf")
    tree = _compositor_showing(scene, img_name)
    for n in [n for n in tree.nodes if n.bl_idname in ("CompositorNodeRLayers", "CompositorNodeViewer")]:
        tree.nodes.remove(n)
    scene.frame_end = 2
    bpy.ops.render.render(animation=True)
    assert handlers.state["errors"] == []
    out = tmp_path / "render"
    for f in (1, 2):
        ours = exr.read_multilayer(str(out / f"anim.{f:04d}.exr"))
        composite = _read_rgba_r(str(out / f"frame_{f:04d}.exr")).reshape(SIZE, SIZE)
        np.testing.assert_allclose(composite, ours["Key_Light"]["pcf"], atol=1e-6)


def test_render_passes_off_by_default(registered, tmp_path):
    scene, _ = _animated_scene(tmp_path, enable=False)
    scene.frame_end = 1
    bpy.ops.render.render(animation=True)
    assert not any(p.startswith("anim.") for p in os.listdir(tmp_path / "render"))
    assert not any(i.name.startswith("Penumbra ") for i in bpy.data.images)


def test_output_folder_under_a_file_is_one_line_not_a_traceback(registered, tmp_path, capfd):
    scene, _ = _animated_scene(tmp_path)
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    scene.penumbra.output_folder = str(blocker / "penumbra")
    scene.frame_end = 2
    capfd.readouterr()
    bpy.ops.render.render(animation=True)           # the render itself goes on
    err = capfd.readouterr().err
    assert "Traceback" not in err
    lines = [ln for ln in err.splitlines() if ln.startswith("Penumbra:")]
    assert len(lines) == 2 and all("cannot create output folder" in ln for ln in lines)
    assert len(handlers.state["errors"]) == 2
    assert os.path.exists(tmp_path / "render" / "frame_0002.exr")


def test_handler_failure_does_not_stop_the_render(registered, tmp_path, capfd, monkeypatch):
    scene, _ = _animated_scene(tmp_path)
    scene.frame_end = 1

    def boom(*a, **k):
        raise ValueError("kernel exploded\nsecond line")
    monkeypatch.setattr(pipeline, "run_step", boom)
    capfd.readouterr()
    bpy.ops.render.render(animation=True)
    err = capfd.readouterr().err
    assert "Traceback" not in err
    assert handlers.state["errors"] == ["frame 1: ValueError: second line"]
    assert os.path.exists(tmp_path / "render" / "frame_0001.exr")


def test_no_enabled_light_writes_nothing(registered, tmp_path):
    scene, _ = _animated_scene(tmp_path)
    scene.frame_end = 1
    for lt in bpy.data.lights:
        lt.penumbra.enabled = False
    bpy.ops.render.render(animation=True)
    assert handlers.state["errors"] == []
    assert any("nothing written" in n for n in handlers.state["notes"])
    assert not any(p.startswith("anim.") for p in os.listdir(tmp_path / "render"))


def test_output_name_clash_goes_to_a_subfolder(registered, tmp_path):
    scene, _ = _animated_scene(tmp_path)
    scene.render.filepath = str(tmp_path / "render" / "anim.")   # frame_path = .../anim.0001.exr
    assert pipeline.render_output_folder(scene, 1) == str(tmp_path / "render" / "penumbra")
    scene.render.filepath = str(tmp_path / "render" / "x_")
    assert pipeline.render_output_folder(scene, 1) == str(tmp_path / "render")
