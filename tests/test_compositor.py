"""The "Penumbra" compositor node group (bridge/compositor.py) and the Set up
compositor operator (operators/compositor_ops.py).

The compositor evaluates headless: a render with ``write_still`` writes the
compositing node group's output (checked in bpy 5.0.1; the Viewer node's image
has no pixels in background mode), so the images the group makes are checked
on a tiny one-sample Cycles render of an empty scene.
"""
import os

import bpy
import numpy as np
import OpenEXR
import pytest

from penumbra.bridge import compat
from penumbra.bridge import compositor as C
from penumbra.bridge import images
from penumbra.core import exr
from scenes import tiny_cycles_scene

W, H = 16, 8


def _two_light_scene():
    """``tiny_cycles_scene`` with two area lights, "Key.Light" and "Fill"."""
    scene = tiny_cycles_scene(W, H)
    for name in ("Key.Light", "Fill"):
        ob = bpy.data.objects.new(name, bpy.data.lights.new(name, "AREA"))
        scene.collection.objects.link(ob)
    return scene


def _gradient():
    return np.tile(np.linspace(0.0, 1.0, W, dtype=np.float32), (H, 1))


def _user_blur_tree(scene):
    """The user's compositor: Render Layers -> their Blur -> Group Output
    (the scene's group on 5.0 - 5.2, their own effect on 5.3)."""
    tree = bpy.data.node_groups.new("My Compositor", "CompositorNodeTree")
    tree.interface.new_socket("Image", in_out="OUTPUT", socket_type="NodeSocketColor")
    rl = tree.nodes.new("CompositorNodeRLayers")
    out = tree.nodes.new("NodeGroupOutput")
    blur = tree.nodes.new("CompositorNodeBlur")
    blur.name = "My Blur"
    blur.location = (123.0, 45.0)
    tree.links.new(rl.outputs["Image"], blur.inputs["Image"])
    tree.links.new(blur.outputs["Image"], out.inputs["Image"])
    compat.set_compositor_tree(scene, tree)
    return tree, blur


def _ours(scene):
    """The tree Penumbra's nodes are in (the user's on 5.0 - 5.2, Penumbra's effect's on 5.3)."""
    return compat.compositor_tree(scene, create=False)


def _links(tree):
    return sorted((l.from_node.name, l.from_socket.identifier, l.to_node.name, l.to_socket.identifier)
                  for l in tree.links)


def _user_state(tree):
    ours = [n for n in tree.nodes if n.name.startswith(C.PREFIX) or n.name in (C.FRAME_NAME, C.SETUP_FRAME)]
    users = sorted((n.name, n.bl_idname, tuple(n.location), n.parent.name if n.parent else None)
                   for n in tree.nodes if n not in ours)
    links = [l for l in _links(tree) if not (l[0].startswith(C.PREFIX) or l[2].startswith(C.PREFIX))]
    return users, links


def _composite(scene, socket, path):
    """Render once with ``socket`` wired to the compositor's output; the
    written EXR's RGB (row 0 at the top)."""
    tree = compat.compositor_tree(scene, create=False)
    out = next(n for n in tree.nodes if n.bl_idname == "NodeGroupOutput")
    tree.links.new(socket, out.inputs["Image"])
    scene.render.image_settings.file_format = "OPEN_EXR"
    scene.render.image_settings.color_depth = "32"
    scene.render.filepath = str(path)
    bpy.ops.render.render(write_still=True)
    with OpenEXR.File(str(path), separate_channels=True) as f:
        ch = f.parts[0].channels
        return np.stack([np.asarray(ch[c].pixels, np.float32) for c in "RGB"], -1)


def _store(layer, method_v, embree_v, cycles_v):
    """pcf (the irradiance ratio, the default) beside its ray-traced reference
    of the same definition (embree_irr) and cycles."""
    images.store_pass_image(layer, "pcf", method_v)
    images.store_pass_image(layer, "embree_irr", embree_v)
    images.store_pass_image(layer, "cycles", cycles_v)


LIGHTS = [("Key.Light", "Key_Light", "pcf"), ("Fill", "Fill", "pcf")]


# --------------------------------------------------------------------------
def test_builds_twice_without_duplicates_and_leaves_user_nodes_alone():
    scene = _two_light_scene()
    tree, blur = _user_blur_tree(scene)
    before = _user_state(tree)
    g = _gradient()
    _store("Key_Light", g, g, 0.5 * g)
    _store("Fill", 1 - g, g, g)
    r1 = C.setup_compositor(scene, LIGHTS)
    ours_tree = _ours(scene)
    state1 = (len(ours_tree.nodes), sorted(n.name for n in ours_tree.nodes), len(r1.group.nodes),
              sorted(n.name for n in r1.group.nodes), len(r1.group.links), _links(r1.group))
    ids1 = {s.name: s.identifier for s in r1.node.outputs}
    r2 = C.setup_compositor(scene, LIGHTS)
    state2 = (len(ours_tree.nodes), sorted(n.name for n in ours_tree.nodes), len(r2.group.nodes),
              sorted(n.name for n in r2.group.nodes), len(r2.group.links), _links(r2.group))
    assert state1 == state2
    assert r1.group == r2.group
    assert [g_ for g_ in bpy.data.node_groups if g_.name.startswith(C.GROUP_NAME)] == [r2.group]
    # exactly one group node, one Render Layers, one Viewer and the frame of ours in the scene tree
    ours = sorted(n.name for n in ours_tree.nodes if n.name.startswith(C.SETUP_PREFIX))
    assert ours == [f"{C.SETUP_PREFIX}Penumbra", f"{C.SETUP_PREFIX}Render Layers", f"{C.SETUP_PREFIX}Viewer"]
    assert r2.node.bl_idname == "CompositorNodeGroup" and r2.node.node_tree == r2.group
    assert r2.node.parent.name == C.SETUP_FRAME
    # the user's node: same name, place, links; their output still fed by their blur
    assert _user_state(tree) == before
    assert tree.nodes["My Blur"].location[:] == (123.0, 45.0)
    # per light: the method, its references, error and side-by-side sockets
    for _name, layer, method in LIGHTS:
        for what in (method, "embree_irr", "cycles", "error", "shadowed", "side by side"):
            s = r2.node.outputs.get(C.socket_name(layer, what))
            assert s is not None, what
            assert r2.group.nodes[f"{C.PREFIX}Group Output"].inputs[C.socket_name(layer, what)].is_linked
    assert r2.missing == [] and r2.error_refs == {"Key_Light": "embree_irr", "Fill": "embree_irr"}
    # socket identifiers survive the rebuild (links from the user's own group nodes stay)
    assert {s.name: s.identifier for s in r2.node.outputs} == ids1
    # the viewer shows the first light's side by side
    viewer = ours_tree.nodes[f"{C.SETUP_PREFIX}Viewer"]
    assert viewer.inputs["Image"].links[0].from_socket.name == C.socket_name("Key_Light", "side by side")


def test_rebuild_keeps_links_of_a_users_group_node_and_drops_stale_lights():
    scene = _two_light_scene()
    tree, _blur = _user_blur_tree(scene)
    g = _gradient()
    _store("Key_Light", g, g, g)
    _store("Fill", g, g, g)
    res = C.setup_compositor(scene, LIGHTS)
    # the user adds their own instance of the group and uses one of its outputs
    mine = tree.nodes.new("CompositorNodeGroup")
    mine.name = "My Penumbra"
    mine.node_tree = res.group
    mix = tree.nodes.new("ShaderNodeMix")
    mix.name = "My Mix"
    tree.links.new(mine.outputs[C.socket_name("Key_Light", "cycles")], mix.inputs["Factor"])
    res = C.setup_compositor(scene, LIGHTS[:1])          # the Fill light is gone
    assert tree.nodes["My Penumbra"].outputs[C.socket_name("Key_Light", "cycles")].is_linked
    assert mix.inputs["Factor"].links[0].from_node.name == "My Penumbra"
    names = [s.name for s in res.node.outputs]
    assert not any(n.startswith("Fill:") for n in names)
    assert [i.name for i in res.group.interface.items_tree if i.item_type == "PANEL"] == ["Key_Light"]
    # a node the user put inside Penumbra's group stays too
    user_inner = res.group.nodes.new("CompositorNodeInvert")
    user_inner.name = "My Invert"
    C.setup_compositor(scene, LIGHTS[:1])
    assert "My Invert" in res.group.nodes


def test_error_of_identical_passes_is_black_and_side_by_side(tmp_path):
    scene = _two_light_scene()
    _user_blur_tree(scene)
    g = _gradient()
    _store("Key_Light", g, g, 0.5 * g)            # pcf == embree_irr: no error
    _store("Fill", np.zeros_like(g), np.ones_like(g), g)   # pcf off by 1 everywhere
    res = C.setup_compositor(scene, LIGHTS)
    node = res.node
    err = _composite(scene, node.outputs[C.socket_name("Key_Light", "error")], tmp_path / "err.exr")
    assert err.shape == (H, W, 3)
    assert np.abs(err).max() < 1e-6                          # black
    cyc = _composite(scene, node.outputs[C.socket_name("Key_Light", "cycles")], tmp_path / "cyc.exr")
    np.testing.assert_allclose(cyc[..., 0], 0.5 * g, atol=1e-5)
    # an error of 1 >= Error Scale saturates the ramp at its last colour
    err_fill = _composite(scene, node.outputs[C.socket_name("Fill", "error")], tmp_path / "err2.exr")
    np.testing.assert_allclose(err_fill.reshape(-1, 3).mean(0), C.ERROR_RAMP[-1][1][:3], atol=1e-4)
    # Error Scale on the group node: an error of 1 at scale 1 is the ramp's top too, 0.5 at scale 1
    # sits between the 0.3 and 0.65 stops: not black, not saturated
    _store("Fill", np.full_like(g, 0.5), np.ones_like(g), g)
    node.inputs["Error Scale"].default_value = 1.0
    half = _composite(scene, node.outputs[C.socket_name("Fill", "error")], tmp_path / "err3.exr")
    assert 0.05 < half.max() < 0.99
    # side by side: method top-left, embree_irr top-right, cycles bottom-left, error bottom-right
    sbs = _composite(scene, node.outputs[C.socket_name("Key_Light", "side by side")], tmp_path / "sbs.exr")
    top, bottom = sbs[: H // 2, :, 0], sbs[H // 2:, :, 0]
    half_g = 0.5 * (g[: H // 2, 0::2] + g[: H // 2, 1::2])    # bilinear at half size
    np.testing.assert_allclose(top[:, : W // 2], half_g, atol=2e-3)
    np.testing.assert_allclose(top[:, W // 2:], half_g, atol=2e-3)
    np.testing.assert_allclose(bottom[:, : W // 2], 0.5 * half_g, atol=2e-3)
    assert np.abs(sbs[H // 2:, W // 2:]).max() < 1e-6


def test_exr_source(tmp_path):
    scene = _two_light_scene()
    g = _gradient()
    path = str(tmp_path / "shot.0001.exr")
    exr.write_multilayer(path, {"Key_Light": {"pcf": g, "embree": g, "embree_irr": g, "cycles": 1 - g},
                                "Fill": {"single_sample": g, "embree": 0.25 * g}},
                         {"visibility": '{"Fill": {"single_sample": "average"}}'})   # Fill's pass: the average
    res = C.setup_compositor(scene, [("Key.Light", "Key_Light", "pcf"), ("Fill", "Fill", "single_sample")],
                             exr_path=path)
    src = res.group.nodes[f"{C.PREFIX}Key_Light:exr"]
    assert src.bl_idname == "CompositorNodeImage" and src.layer == "Key_Light"
    assert os.path.samefile(bpy.path.abspath(src.image.filepath), path)
    assert res.group.nodes[f"{C.PREFIX}Fill:exr"].layer == "Fill"
    assert res.missing == ["Fill: cycles"]                  # that EXR has no cycles pass for Fill
    # each pass against the reference of its definition: the header's for Fill, the default for Key_Light
    assert res.error_refs == {"Key_Light": "embree_irr", "Fill": "embree"}
    err = _composite(scene, res.node.outputs[C.socket_name("Key_Light", "error")], tmp_path / "e.exr")
    assert np.abs(err).max() < 1e-6
    cyc = _composite(scene, res.node.outputs[C.socket_name("Key_Light", "cycles")], tmp_path / "c.exr")
    np.testing.assert_allclose(cyc[..., 0], 1 - g, atol=1e-5)
    emb = _composite(scene, res.node.outputs[C.socket_name("Fill", "embree")], tmp_path / "f.exr")
    np.testing.assert_allclose(emb[..., 0], 0.25 * g, atol=1e-5)


def test_side_by_side_nodes_and_setup_coexist():
    scene = _two_light_scene()
    tree, _ = _user_blur_tree(scene)
    g = _gradient()
    _store("Key_Light", g, g, g)
    C.setup_compositor(scene, LIGHTS[:1])
    C.build_side_by_side(scene, {"Key.Light": "Key_Light"}, ["pcf", "embree_irr"])
    ours_tree = _ours(scene)
    assert f"{C.SETUP_PREFIX}Penumbra" in ours_tree.nodes          # Compute Passes keeps the setup
    assert f"{C.PREFIX}Key_Light:pcf" in ours_tree.nodes
    C.setup_compositor(scene, LIGHTS[:1])
    assert f"{C.PREFIX}Key_Light:pcf" in ours_tree.nodes          # and the setup keeps those
    assert C.clear_nodes(ours_tree) == 3 + 1 + 2 + 1              # setup (3 + frame), side by side (2 + frame)
    assert not any(n.name.startswith(C.PREFIX) for n in ours_tree.nodes)
    assert "My Blur" in tree.nodes and not any(n.name.startswith(C.PREFIX) for n in tree.nodes)


# --------------------------------------------------------------------------
# the operator
def test_setup_operator_from_images(registered):
    scene = _two_light_scene()
    tree, _ = _user_blur_tree(scene)
    before = _user_state(tree)
    g = _gradient()
    _store("Key_Light", g, g, g)
    scene.objects["Key.Light"].data.penumbra.method = "pcf"
    assert bpy.ops.penumbra.setup_compositor() == {"FINISHED"}
    assert bpy.ops.penumbra.setup_compositor() == {"FINISHED"}
    node = _ours(scene).nodes[f"{C.SETUP_PREFIX}Penumbra"]
    names = [s.name for s in node.outputs]
    # the Fill light has no stored passes: it is not shown
    assert "Key_Light: pcf" in names and not any(n.startswith("Fill") for n in names)
    assert _user_state(tree) == before
    assert len([n for n in _ours(scene).nodes if n.name.startswith(C.SETUP_PREFIX)]) == 3


def test_setup_operator_from_exr_and_bad_input(registered, tmp_path):
    scene = _two_light_scene()
    g = _gradient()
    path = str(tmp_path / "shot.0001.exr")
    exr.write_multilayer(path, {"Key_Light": {"pcf": g, "embree_irr": g, "cycles": g}})
    scene.objects["Key.Light"].data.penumbra.method = "pcf"        # not auto: a fixed pass name
    assert bpy.ops.penumbra.setup_compositor(source="EXR", filepath=path) == {"FINISHED"}
    node = compat.compositor_tree(scene, create=False).nodes[f"{C.SETUP_PREFIX}Penumbra"]
    assert [s.name for s in node.outputs][:4] == ["Image", "Key_Light: pcf", "Key_Light: embree_irr",
                                                   "Key_Light: cycles"]
    with pytest.raises(RuntimeError, match="no such EXR"):
        bpy.ops.penumbra.setup_compositor(source="EXR", filepath=str(tmp_path / "none.exr"))
    bad = tmp_path / "bad.exr"
    bad.write_bytes(b"not an exr")
    with pytest.raises(RuntimeError, match="cannot read"):
        bpy.ops.penumbra.setup_compositor(source="EXR", filepath=str(bad))
    with pytest.raises(RuntimeError, match="unknown method"):
        bpy.ops.penumbra.setup_compositor(method="nope")
    bpy.ops.wm.read_factory_settings(use_empty=True)
    with pytest.raises(RuntimeError, match="no passes to show"):
        bpy.ops.penumbra.setup_compositor()


def test_the_group_composites_the_unshadowed_render_times_the_pass(tmp_path):
    """The group's "<layer>: shadowed" output is its "<layer>: unshadowed"
    input times the method's pass (the irradiance ratio composites: the
    light's render with its shadow off x V = the shadowed render)."""
    scene = _two_light_scene()
    _user_blur_tree(scene)
    g = _gradient()
    _store("Key_Light", g, g, g)
    _store("Fill", np.ones_like(g), g, g)
    res = C.setup_compositor(scene, LIGHTS)
    assert res.unwired == [C.socket_name("Key_Light", "unshadowed"), C.socket_name("Fill", "unshadowed")]
    colour = np.stack([0.2 + 0.0 * g, 0.6 + 0.0 * g, g[::-1, ::-1]], -1)
    images.store_pass_image("Unshadowed", "render", colour[..., 2])
    src = bpy.data.images[images.pass_image_name("Unshadowed", "render")]
    tree = compat.compositor_tree(scene, create=False)
    img = tree.nodes.new("CompositorNodeImage")
    img.image = src
    tree.links.new(img.outputs["Image"], res.node.inputs[C.socket_name("Key_Light", "unshadowed")])
    out = _composite(scene, res.node.outputs[C.socket_name("Key_Light", "shadowed")], tmp_path / "shadowed.exr")
    np.testing.assert_allclose(out[..., 0], g[::-1, ::-1] * g, atol=1e-4)


def test_setup_wires_each_lights_light_group_to_its_unshadowed_input():
    """A light in a light group of the view layer gets that group's Combined
    pass; the user's render settings are left as they are."""
    scene = _two_light_scene()
    _user_blur_tree(scene)
    g = _gradient()
    _store("Key_Light", g, g, g)
    _store("Fill", g, g, g)
    vl = scene.view_layers[0]
    vl.lightgroups.add(name="KeyGroup")
    bpy.data.objects["Key.Light"].lightgroup = "KeyGroup"
    passes_before = (vl.use_pass_diffuse_direct, [lg.name for lg in vl.lightgroups])
    res = C.setup_compositor(scene, LIGHTS)
    assert res.unwired == [C.socket_name("Fill", "unshadowed")]
    sock = res.node.inputs[C.socket_name("Key_Light", "unshadowed")]
    (link,) = sock.links
    assert link.from_socket.name == "Combined_KeyGroup" and link.from_node.bl_idname == "CompositorNodeRLayers"
    assert (vl.use_pass_diffuse_direct, [lg.name for lg in vl.lightgroups]) == passes_before
