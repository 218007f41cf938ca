"""bridge/compat.py and the bpy API Penumbra relies on, on whichever Blender
runs the suite (``make test`` runs this file on 5.0.1, 5.2.3 and 5.3.0)."""
import os
import warnings

import bpy
import numpy as np
import OpenEXR
import pytest

from penumbra.bridge import compat
from penumbra.bridge import compositor
from scenes import open_sample, tiny_cycles_scene

EFFECTS = bpy.app.version >= (5, 3, 0)


def _user_multiply_tree(scale: float):
    """A user's compositor: Render Layers x ``scale`` -> Group Output."""
    tree = bpy.data.node_groups.new("My Compositor", "CompositorNodeTree")
    tree.interface.new_socket("Image", in_out="OUTPUT", socket_type="NodeSocketColor")
    rl = tree.nodes.new("CompositorNodeRLayers")
    mix = tree.nodes.new("ShaderNodeMix")
    mix.name = "My Mix"
    mix.data_type, mix.blend_type = "RGBA", "MULTIPLY"
    mix.inputs["Factor"].default_value = 1.0
    mix.inputs[7].default_value = (scale, scale, scale, 1.0)
    out = tree.nodes.new("NodeGroupOutput")
    tree.links.new(rl.outputs["Image"], mix.inputs[6])
    tree.links.new(mix.outputs[2], out.inputs["Image"])
    return tree


def _render(scene, path) -> np.ndarray:
    scene.render.image_settings.file_format = "OPEN_EXR"
    scene.render.filepath = str(path)
    bpy.ops.render.render(write_still=True)
    with OpenEXR.File(str(path), separate_channels=True) as f:
        return np.asarray(f.parts[0].channels["R"].pixels, np.float32)


def _tiny_scene():
    return tiny_cycles_scene(8, 8, world_color=(0.5, 0.5, 0.5))


def test_api_line_is_detected():
    assert compat.has_compositor_effects() == EFFECTS
    assert compat.RENDER_INPUT_NODES == (("NodeGroupInput",) if EFFECTS else ())


def test_compositor_tree_leaves_the_users_compositor_and_its_result_alone(tmp_path):
    scene = _tiny_scene()
    assert compat.compositor_tree(scene, create=False) is None
    user = _user_multiply_tree(0.5)
    compat.set_compositor_tree(scene, user)
    plain = _render(scene, tmp_path / "user.exr")
    assert 0.0 < plain.max() and np.ptp(plain) < 1e-6       # the world, halved
    user_nodes = sorted(n.name for n in user.nodes)
    ours = compat.compositor_tree(scene, create=True)
    assert compat.compositor_tree(scene, create=True) == ours      # made once
    if EFFECTS:
        # 5.3: Penumbra's own effect after the user's, the user's still active
        effects = scene.compositor_effects
        assert [e.name for e in effects] == ["Scene Effect", compat.EFFECT_NAME]
        assert effects.active.name == "Scene Effect" and effects[0].node_group == user
        assert ours != user and ours.get(compat.EFFECT_TREE_TAG)
        assert compat.render_trees(scene) == [user, ours]
    else:
        # 5.0 - 5.2: the scene's one group is the user's
        assert ours == user and compat.render_trees(scene) == [user]
    ours.nodes.new("CompositorNodeViewer").name = "Penumbra:Viewer"
    assert sorted(n.name for n in user.nodes if not n.name.startswith("Penumbra:")) == user_nodes
    # the render is the user's compositor's, bit for bit
    np.testing.assert_array_equal(_render(scene, tmp_path / "ours.exr"), plain)
    # clearing removes Penumbra's effect only once nothing of ours is left in it
    ours.nodes.remove(ours.nodes["Penumbra:Viewer"])
    assert compat.remove_penumbra_effect(scene) == EFFECTS
    assert compat.render_trees(scene) == [user]
    assert bpy.data.node_groups.get(compat.EFFECT_TREE_NAME) is None


def test_compositor_tree_on_a_scene_without_one(tmp_path):
    scene = _tiny_scene()
    plain = _render(scene, tmp_path / "plain.exr")
    tree = compat.compositor_tree(scene, create=True)
    kinds = sorted(n.bl_idname for n in tree.nodes)
    assert kinds == (["NodeGroupInput", "NodeGroupOutput"] if EFFECTS
                     else ["CompositorNodeRLayers", "NodeGroupOutput"])
    assert compat.render_trees(scene) == [tree]
    np.testing.assert_array_equal(_render(scene, tmp_path / "through.exr"), plain)


def test_render_layers_sockets_by_name():
    scene = _tiny_scene()
    tree = compat.compositor_tree(scene, create=True)
    rl = tree.nodes.new("CompositorNodeRLayers")
    assert compat.render_layers_socket(rl, "Image").name == "Image"
    assert not scene.view_layers[0].use_pass_z
    with pytest.raises(KeyError, match="Depth"):
        compat.render_layers_socket(rl, "Depth")       # the pass is off
    depth = compat.render_layers_socket(rl, "Depth", pass_flag="use_pass_z")
    assert depth.name == "Depth" and depth.enabled and scene.view_layers[0].use_pass_z
    link = tree.links.new(depth, tree.nodes.new("CompositorNodeViewer").inputs["Image"])
    assert link.is_valid


def test_no_deprecation_warning_from_penumbra(registered, tmp_path):
    """Compute Passes, Set Up Compositor, a render with passes and Clear with
    DeprecationWarning as an error (5.3 deprecates compositing_node_group)."""
    scene = open_sample("sphere_plane", (32, 24))
    scene.cycles.samples = 1
    scene.cycles.use_denoising = False
    for lt in bpy.data.lights:
        lt.penumbra.method = "pcf"
        lt.penumbra.light_samples = 4
    scene.penumbra.references = {"embree"}
    scene.render.filepath = str(tmp_path / "render" / "frame_")
    scene.render.image_settings.file_format = "OPEN_EXR"
    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)
        assert bpy.ops.penumbra.compute_passes(samples=4, methods="pcf,embree") == {"FINISHED"}
        assert bpy.ops.penumbra.setup_compositor() == {"FINISHED"}
        scene.penumbra.render_passes = True
        bpy.ops.render.render(write_still=True)
        assert bpy.ops.penumbra.clear() == {"FINISHED"}
    written = sorted(os.listdir(tmp_path / "render"))
    assert written == ["frame_.exr", "sphere_plane.0001.exr", "sphere_plane.0001.json"]
    if EFFECTS:     # Penumbra's effect held only Penumbra's nodes: gone with them
        assert compat.penumbra_effect(scene) is None
    assert not any(n.name.startswith(compositor.PREFIX) for t in compat.render_trees(scene) for n in t.nodes)


# --------------------------------------------------------------------------
# The bpy API Penumbra uses, the same on every line

def test_cli_command_registers_and_runs():
    seen = []
    handle = bpy.utils.register_cli_command("penumbra_compat_test", lambda argv: seen.append(list(argv)) or 0)
    assert handle is not None
    bpy.utils.unregister_cli_command(handle)
    assert seen == []                                 # registering runs nothing


def test_render_handlers_run_in_order(tmp_path):
    scene = _tiny_scene()
    calls = []
    names = ("render_init", "render_pre", "render_post", "render_write", "render_complete")
    fns = {n: (lambda n: lambda *_a: calls.append(n))(n) for n in names}
    for n, fn in fns.items():
        getattr(bpy.app.handlers, n).append(fn)
    try:
        _render(scene, tmp_path / "h.exr")
    finally:
        for n, fn in fns.items():
            getattr(bpy.app.handlers, n).remove(fn)
    assert calls == ["render_init", "render_pre", "render_post", "render_write", "render_complete"]


def test_light_properties():
    want = {"POINT": {"shadow_soft_size": 0.25}, "SPOT": {"shadow_soft_size": 0.1, "spot_size": 0.8,
                                                          "spot_blend": 0.3},
            "SUN": {"angle": 0.05}, "AREA": {"shape": "ELLIPSE", "size": 2.0, "size_y": 0.5}}
    for kind, props in want.items():
        lt = bpy.data.lights.new(f"compat {kind}", kind)
        assert lt.use_shadow is True
        lt.use_shadow = False
        for k, v in props.items():
            setattr(lt, k, v)
            got = getattr(lt, k)
            assert got == v if isinstance(v, str) else abs(got - v) < 1e-6, (kind, k, got)
        assert lt.use_shadow is False
        bpy.data.lights.remove(lt)


def test_loop_triangles_of_an_evaluated_cube():
    scene = _tiny_scene()
    bpy.ops.mesh.primitive_cube_add(size=2.0)
    ob = bpy.context.active_object
    ob.modifiers.new("tri", "TRIANGULATE")
    ev = ob.evaluated_get(bpy.context.evaluated_depsgraph_get())
    mesh = ev.to_mesh()
    try:
        mesh.calc_loop_triangles()
        n = len(mesh.loop_triangles)
        tris = np.empty(3 * n, np.int32)
        mesh.loop_triangles.foreach_get("vertices", tris)
        co = np.empty(3 * len(mesh.vertices), np.float32)
        mesh.vertices.foreach_get("co", co)
    finally:
        ev.to_mesh_clear()
    assert n == 12 and sorted(set(tris.tolist())) == list(range(8))
    v = co.reshape(-1, 3)[tris.reshape(-1, 3)]
    area = 0.5 * np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1)
    assert abs(area.sum() - 24.0) < 1e-5                   # 6 faces of 2 x 2
    assert scene.objects[ob.name] == ob


def test_image_pixels_round_trip_bit_for_bit():
    img = bpy.data.images.new("compat pixels", 5, 3, alpha=True, float_buffer=True)
    rgba = np.random.default_rng(7).random((3, 5, 4), dtype=np.float32)
    rgba[0, 0] = (0.0, 1e-30, 3.0e38, -2.5)                 # float32 extremes stay as they are
    img.pixels.foreach_set(rgba.ravel())
    back = np.empty(rgba.size, np.float32)
    img.pixels.foreach_get(back)
    np.testing.assert_array_equal(back, rgba.ravel())
    bpy.data.images.remove(img)


def test_the_scenes_pixel_filter_is_read_from_its_engine_settings():
    """``settings.render_pixel_filter`` on a real scene: Cycles' type and
    width, EEVEE's ``render.filter_size``, and none for EEVEE at one render
    sample (``eevee.taa_render_samples``; eevee_film.cc sets the radius to 0)."""
    from penumbra.bridge.settings import render_pixel_filter
    from penumbra.core.pixel_filter import PixelFilter
    scene = _tiny_scene()
    scene.cycles.pixel_filter_type, scene.cycles.filter_width = "GAUSSIAN", 2.5
    assert render_pixel_filter(scene) == PixelFilter("gaussian", 2.5)
    scene.render.engine = "BLENDER_EEVEE"
    scene.render.filter_size = 2.0
    scene.eevee.taa_render_samples = 16
    assert render_pixel_filter(scene) == PixelFilter("eevee", 2.0)
    scene.eevee.taa_render_samples = 1
    assert render_pixel_filter(scene).is_none
