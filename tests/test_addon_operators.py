"""The add-on's operators (bpy, background mode): Compute Passes, Preview
and Clear, what they write and leave alone, and bad input as a one-line
error report (never a traceback, nothing half-written). Their modal runs
off the UI thread: test_modal_jobs.py; Set up compositor:
test_compositor.py; the Cycles reference: test_cycles_reference.py."""
import json

import bpy
import numpy as np
import pytest

from penumbra.bridge import compat
from penumbra.bridge import compositor
from penumbra.core import exr
from scenes import BAD_MESHES, image_rgba, open_sample, save_plane_blend

W, H = 40, 30


def _open_sphere_plane(w=W, h=H):
    return open_sample("sphere_plane", (w, h))


def _pixels(img):
    """The image's first channel, row 0 at the top."""
    return image_rgba(img)[::-1, :, 0]


# --------------------------------------------------------------------------
# Compute Passes
def test_compute_operator_makes_images_and_nodes(registered):
    scene = _open_sphere_plane(48, 32)
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
    v = image_rgba(img)[..., 0]
    assert np.isfinite(v).all() and v.min() >= 0 and v.max() <= 1 and v.min() < 0.5
    # rebuild: same node count, the user's node untouched
    assert bpy.ops.penumbra.compute_passes(samples=8) == {"FINISHED"}
    assert len(tree.nodes) == n_user + len(ours) + 1      # + the frame
    assert tree.nodes["My Blur"].location[:] == (123.0, 45.0)
    assert len([n for n in tree.nodes if n.name.startswith(compositor.PREFIX)]) == len(ours)


def test_compute_uses_per_light_settings(registered, tmp_path):
    scene = _open_sphere_plane()
    light = next(ob for ob in bpy.data.objects if ob.type == "LIGHT")
    layer = light.name.replace(".", "_")
    s = light.data.penumbra
    s.method = "embree_irr"
    s.light_samples = 4
    s.knobs.pcf.NumSamples = 4           # not the chosen method: no effect
    scene.penumbra.references = {"embree"}
    scene.penumbra.seed = 5
    scene.penumbra.output_folder = str(tmp_path / "out")
    assert bpy.ops.penumbra.compute_passes() == {"FINISHED"}
    ours = {n.name for n in compat.compositor_tree(scene, create=False).nodes
            if n.name.startswith(compositor.PREFIX)}
    assert ours == {f"{compositor.PREFIX}{layer}:embree_irr", f"{compositor.PREFIX}{layer}:embree"}
    for pid in ("embree_irr", "embree"):
        assert tuple(bpy.data.images[compositor.pass_image_name(layer, pid)].size) == (W, H)
    rec = json.loads((tmp_path / "out" / "sphere_plane.0001.json").read_text())
    m = rec["lights"][0]["methods"]
    assert set(m) == {"embree_irr", "embree"}
    assert m["embree"]["params"] == {"samples": 4, "seed": 5}
    layers = exr.read_multilayer(str(tmp_path / "out" / "sphere_plane.0001.exr"))
    np.testing.assert_array_equal(layers[layer]["embree"],
                                  _pixels(bpy.data.images[compositor.pass_image_name(layer, "embree")]))
    # a knob of the chosen method reaches its params
    s.method = "pcf"
    s.knobs.pcf.NumSamples = 9
    scene.penumbra.references = set()
    assert bpy.ops.penumbra.compute_passes() == {"FINISHED"}
    rec = json.loads((tmp_path / "out" / "sphere_plane.0001.json").read_text())
    assert set(rec["lights"][0]["methods"]) == {"pcf"}
    assert rec["lights"][0]["methods"]["pcf"]["params"]["NumSamples"] == 9
    # the nodes show this run's passes; the earlier reference image is kept
    ours = {n.name for n in compat.compositor_tree(scene, create=False).nodes
            if n.name.startswith(compositor.PREFIX)}
    assert ours == {f"{compositor.PREFIX}{layer}:pcf"}
    assert bpy.data.images.get(compositor.pass_image_name(layer, "embree")) is not None


def test_compute_with_cycles_reference(registered):
    """The scene's references may include Cycles: it comes through the
    external producer of bridge/cycles_reference.py."""
    scene = _open_sphere_plane(24, 16)
    bpy.data.objects["Key.Light"].data.penumbra.method = "pcf"     # not auto: a fixed pass name
    scene.penumbra.references = {"embree_irr", "cycles"}
    scene.penumbra.cycles_samples = 2
    assert bpy.ops.penumbra.compute_passes(samples=4) == {"FINISHED"}
    img = bpy.data.images[compositor.pass_image_name("Key_Light", "cycles")]
    v = _pixels(img)
    assert tuple(img.size) == (24, 16) and np.isfinite(v).all() and v.min() < 0.5 < v.max()
    nodes = {n.name for n in compat.compositor_tree(scene, create=False).nodes}
    assert {f"{compositor.PREFIX}Key_Light:{p}" for p in ("pcf", "embree_irr", "cycles")} <= nodes


# --------------------------------------------------------------------------
# Preview and Clear
def test_disabled_light_is_skipped(registered):
    _open_sphere_plane()
    light = next(ob for ob in bpy.data.objects if ob.type == "LIGHT")
    light.data.penumbra.enabled = False
    with pytest.raises(RuntimeError, match="no light has Penumbra enabled"):
        bpy.ops.penumbra.compute_passes()
    with pytest.raises(RuntimeError, match="no light has Penumbra enabled"):
        bpy.ops.penumbra.preview()


def test_preview_updates_one_image_in_place(registered):
    scene = _open_sphere_plane(96, 64)
    light = next(ob for ob in bpy.data.objects if ob.type == "LIGHT")
    light.data.penumbra.method = "embree"            # not fast: the preview uses pcf
    scene.penumbra.preview_size = 48
    assert bpy.ops.penumbra.preview() == {"FINISHED"}
    img = bpy.data.images["Penumbra Preview"]
    assert tuple(img.size) == (48, 32)
    v = _pixels(img)
    assert np.isfinite(v).all() and 0 <= v.min() < 0.5 and v.max() <= 1.0
    ptr = img.as_pointer()
    n_images = len(bpy.data.images)
    assert bpy.ops.penumbra.preview(max_size=24) == {"FINISHED"}
    img = bpy.data.images["Penumbra Preview"]
    assert img.as_pointer() == ptr and tuple(img.size) == (24, 16)
    assert len(bpy.data.images) == n_images
    # the preview is the pcf pass at that size, its light view and samples at preview quality
    from penumbra.core.frame import render_frame
    from penumbra.bridge.capture import capture_scene
    from penumbra.bridge.jobs import PREVIEW_MAP_SCALE
    from penumbra.core.methods import producer_of
    from penumbra.core.views import default_map_size
    assert light.data.type == "AREA"
    side = round(default_map_size(24, 16, "area") * PREVIEW_MAP_SCALE)
    ref = render_frame(capture_scene(scene, resolution=(24, 16)), ["pcf"], overrides={"seed": 0, "samples": 64},
                       method_overrides={"pcf": producer_of("pcf").preview_params}, map_size=side)
    np.testing.assert_allclose(_pixels(img), ref.lights[0].passes["pcf"], atol=1e-6)
    # no image nodes, no pass images: a preview changes nothing else
    assert not any(i.name.startswith("Penumbra ") and i.name != "Penumbra Preview" for i in bpy.data.images)


def test_preview_active_light_only(registered, capfd):
    _open_sphere_plane()
    bpy.ops.object.light_add(type="POINT", location=(2, 2, 4))
    point = bpy.context.object
    point.data.shadow_soft_size = 0.3
    capfd.readouterr()
    assert bpy.ops.penumbra.preview(only_active=True) == {"FINISHED"}
    assert "1 light(s)" in capfd.readouterr().out        # reports print headless
    assert bpy.ops.penumbra.preview() == {"FINISHED"}
    assert "2 light(s)" in capfd.readouterr().out
    bpy.context.view_layer.objects.active = next(o for o in bpy.data.objects if o.type == "MESH")
    with pytest.raises(RuntimeError, match="not a light"):
        bpy.ops.penumbra.preview(only_active=True)


def test_clear_removes_only_penumbra_data(registered):
    scene = _open_sphere_plane()
    user_img = bpy.data.images.new("My Image", 4, 4)
    tree = compositor.compositor_tree(scene)
    user_node = tree.nodes.new("CompositorNodeBlur")
    user_node.name = "My Blur"
    group = bpy.data.node_groups.new("Penumbra", "CompositorNodeTree")
    gnode = tree.nodes.new("CompositorNodeGroup")
    gnode.node_tree = group
    gnode.name = "Penumbra:group"
    bpy.data.node_groups.new("My Group", "CompositorNodeTree")
    assert bpy.ops.penumbra.compute_passes(samples=4) == {"FINISHED"}
    assert bpy.ops.penumbra.preview() == {"FINISHED"}
    assert any(n.name.startswith(compositor.PREFIX) for n in tree.nodes)
    assert bpy.ops.penumbra.clear() == {"FINISHED"}
    assert not any(i.name.startswith("Penumbra ") for i in bpy.data.images)
    assert not any(n.name.startswith(compositor.PREFIX) or n.name == compositor.FRAME_NAME
                   for n in tree.nodes)
    assert "Penumbra" not in bpy.data.node_groups
    assert bpy.data.images.get("My Image") == user_img
    assert "My Blur" in tree.nodes and "My Group" in bpy.data.node_groups
    assert compat.compositor_tree(scene, create=False) == tree
    assert bpy.ops.penumbra.clear() == {"FINISHED"}       # nothing left: still fine


# --------------------------------------------------------------------------
# bad input
def test_operator_reports_missing_camera(registered):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.mesh.primitive_plane_add()
    with pytest.raises(RuntimeError, match="no camera"):
        bpy.ops.penumbra.compute_passes()


def test_no_camera_is_a_report(registered):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.mesh.primitive_plane_add()
    bpy.ops.object.light_add(type="AREA", location=(0, 0, 3))
    for op in (bpy.ops.penumbra.compute_passes, bpy.ops.penumbra.preview):
        with pytest.raises(RuntimeError, match="Penumbra: the scene has no camera"):
            op()


def test_output_folder_under_a_file_is_a_report(registered, tmp_path):
    scene = _open_sphere_plane()
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    scene.penumbra.output_folder = str(blocker / "sub")
    with pytest.raises(RuntimeError, match="cannot create output folder"):
        bpy.ops.penumbra.compute_passes(samples=4)
    assert not any(i.name.startswith("Penumbra ") for i in bpy.data.images)   # nothing changed


def test_unknown_method_is_a_report(registered):
    _open_sphere_plane()
    with pytest.raises(RuntimeError, match="unknown method 'nope'"):
        bpy.ops.penumbra.compute_passes(methods="pcf,nope")


def _operator_error(**kw):
    """Run compute_passes; bpy turns an ERROR report + CANCELLED into a
    RuntimeError carrying the report. Returns its text."""
    with pytest.raises(RuntimeError) as ei:
        bpy.ops.penumbra.compute_passes(**kw)
    text = str(ei.value)
    assert "Traceback" not in text and "Penumbra:" in text
    return text


@pytest.mark.parametrize("methods, message", [
    ("nope", "unknown method"), ("pcf,nope", "unknown method"), ("all,nope", "unknown method"),
    (",", "no methods given"),
])
def test_operator_unknown_ids(registered, tmp_path, methods, message):
    bpy.ops.wm.open_mainfile(filepath=save_plane_blend(tmp_path / "s.blend"), load_ui=False)
    bpy.context.scene.render.resolution_x = bpy.context.scene.render.resolution_y = 16
    text = _operator_error(methods=methods)
    assert message in text


def test_operator_absurd_resolution_is_an_error_report(registered, tmp_path):
    """65536 x 65536 at 100 %: refused before any buffer is allocated."""
    bpy.ops.wm.open_mainfile(filepath=save_plane_blend(tmp_path / "s.blend", resolution=(65536, 65536)),
                             load_ui=False)
    text = _operator_error(methods="pcf")
    assert "resolution" in text
    assert not [im for im in bpy.data.images if im.name.startswith("Penumbra")]


@pytest.mark.parametrize("kind", ["nan_vertices", "inf_vertices", "empty_mesh", "degenerate_faces"])
def test_operator_bad_mesh_data_finishes_with_finite_images(registered, tmp_path, kind):
    bpy.ops.wm.open_mainfile(filepath=save_plane_blend(tmp_path / f"{kind}.blend", mesh_data=BAD_MESHES[kind]),
                             load_ui=False)
    r = bpy.context.scene.render
    r.resolution_x, r.resolution_y = 24, 16
    assert bpy.ops.penumbra.compute_passes(methods="pcf,embree,penumbra_casting", samples=4) == {"FINISHED"}
    for pid in ("pcf", "embree", "penumbra_casting"):
        v = image_rgba(bpy.data.images[compositor.pass_image_name("Area", pid)])[..., 0]
        assert np.isfinite(v).all() and v.min() >= 0 and v.max() <= 1, pid


# --------------------------------------------------------------------------
# steps: one light at a time or all at once
def test_light_deleted_mid_way(registered):
    """The modal operator runs one light per step; a light deleted between
    steps is skipped with a warning, the others are written back."""
    from penumbra.bridge import jobs as bj, pipeline
    from penumbra.bridge.capture import capture_scene
    scene = _open_sphere_plane()
    bpy.ops.object.light_add(type="SPOT", location=(1, -1, 4))
    spot = bpy.context.object
    spot.name = "Second"
    spot.data.shadow_soft_size = 0.2
    for lt in bpy.data.lights:
        lt.penumbra.method = "pcf"                # not auto: a fixed pass name
    captured = capture_scene(scene, resolution=(W, H))
    jobs, _ = bj.light_jobs(scene, captured, samples=4)
    steps = bj.make_steps(jobs, per_light=True)
    assert [st.names for st in steps] == [["Key.Light"], ["Second"]]
    job = pipeline.FrameJob(scene, captured, steps)
    assert job.step()
    bpy.data.objects.remove(spot)
    while not job.done:
        job.step()
    result, _written = pipeline.finish_frame(scene, job, None, build_nodes=True)
    assert job.error is None
    assert job.warnings == ["light 'Second' was deleted during the run: skipped"]
    assert [lr.name for lr in result.lights] == ["Key.Light"]
    assert bpy.data.images.get(compositor.pass_image_name("Key_Light", "pcf")) is not None
    assert bpy.data.images.get(compositor.pass_image_name("Second", "pcf")) is None


def test_grouped_and_per_light_steps_agree(registered):
    """One render_frame for all lights or one per light: the same passes."""
    from penumbra.bridge import jobs as bj, pipeline
    from penumbra.bridge.capture import capture_scene
    scene = _open_sphere_plane()
    bpy.ops.object.light_add(type="AREA", location=(-1, 1, 3))
    bpy.context.object.name = "Key_Light"             # same EXR layer as Key.Light
    captured = capture_scene(scene, resolution=(W, H))
    jobs, _ = bj.light_jobs(scene, captured, samples=4)
    grouped = pipeline.merge_results(captured, [pipeline.run_step(captured, st)
                                               for st in bj.make_steps(jobs, False)])
    split = pipeline.merge_results(captured, [pipeline.run_step(captured, st)
                                             for st in bj.make_steps(jobs, True)])
    assert [lr.layer for lr in grouped.lights] == [lr.layer for lr in split.lights]
    assert len({lr.layer for lr in split.lights}) == 2
    for a, b in zip(grouped.lights, split.lights):
        for pid in a.passes:
            np.testing.assert_array_equal(a.passes[pid], b.passes[pid])
