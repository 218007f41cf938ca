"""Add-on registration, the compute operator and the compositor nodes (bpy)."""
import bpy
import numpy as np
import pytest

import penumbra
from penumbra.bridge import compat
from penumbra.bridge import compositor
from scenes import sample_path


@pytest.fixture
def registered():
    penumbra.register()
    yield
    penumbra.unregister()


def test_register_unregister_twice():
    for _ in range(2):
        penumbra.register()
        assert hasattr(bpy.ops.penumbra, "compute_passes")
        assert bpy.ops.penumbra.compute_passes.poll() in (True, False)
        penumbra.unregister()
        assert "PENUMBRA_OT_compute_passes" not in dir(bpy.types)


def _open_sphere_plane():
    bpy.ops.wm.open_mainfile(filepath=sample_path("sphere_plane"), load_ui=False)
    scene = bpy.context.scene
    scene.render.resolution_x = 48
    scene.render.resolution_y = 32
    scene.render.resolution_percentage = 100
    return scene


def test_compute_operator_makes_images_and_nodes(registered):
    scene = _open_sphere_plane()
    user_tree = compositor.compositor_tree(scene)
    user = user_tree.nodes.new("CompositorNodeBlur")
    user.name = "My Blur"
    user.location = (123.0, 45.0)
    n_user = len(user_tree.nodes)
    assert bpy.ops.penumbra.compute_passes(samples=8) == {"FINISHED"}
    tree = compat.compositor_tree(scene, create=False)
    ours = [n for n in tree.nodes if n.name.startswith(compositor.PREFIX)]
    light_layers = [lt.name.replace(".", "_") for lt in bpy.data.objects if lt.type == "LIGHT"]
    assert len(ours) == 3 * len(light_layers)
    for n in ours:
        assert n.bl_idname == "CompositorNodeImage" and n.image is not None
        assert n.parent is not None and n.parent.name == compositor.FRAME_NAME
        assert tuple(n.image.size) == (48, 32)
    img = bpy.data.images[compositor.pass_image_name(light_layers[0], "embree")]
    px = np.empty(48 * 32 * 4, np.float32)
    img.pixels.foreach_get(px)
    v = px.reshape(32, 48, 4)[..., 0]
    assert np.isfinite(v).all() and v.min() >= 0 and v.max() <= 1 and v.min() < 0.5
    # rebuild: same node count, the user's node untouched
    assert bpy.ops.penumbra.compute_passes(samples=8) == {"FINISHED"}
    assert len(tree.nodes) == n_user + len(ours) + 1      # + the frame
    assert tree.nodes["My Blur"].location[:] == (123.0, 45.0)
    assert len([n for n in tree.nodes if n.name.startswith(compositor.PREFIX)]) == len(ours)


def test_operator_reports_missing_camera(registered):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.mesh.primitive_plane_add()
    with pytest.raises(RuntimeError, match="no camera"):
        bpy.ops.penumbra.compute_passes()


def test_cli_command_is_registered(registered):
    # Blender keeps the handle; registering twice must not raise
    assert penumbra._cli_handle is not None
