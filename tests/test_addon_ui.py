"""Settings, panels and operators of the add-on (bpy, background mode)."""
import dataclasses
import json

import bpy
import numpy as np
import pytest

import penumbra
from penumbra.bridge import compat
from penumbra.bridge import compositor
from penumbra.addon import properties as props
from penumbra.bridge import settings
from penumbra.core import exr
from penumbra.core import methods as registry
from scenes import sample_path

W, H = 40, 30


@pytest.fixture
def registered():
    penumbra.register()
    yield
    penumbra.unregister()


def _open_sphere_plane(w=W, h=H):
    bpy.ops.wm.open_mainfile(filepath=sample_path("sphere_plane"), load_ui=False)
    scene = bpy.context.scene
    scene.render.resolution_x = w
    scene.render.resolution_y = h
    scene.render.resolution_percentage = 100
    return scene


def _pixels(img):
    w, h = img.size
    px = np.empty(w * h * 4, np.float32)
    img.pixels.foreach_get(px)
    return px.reshape(h, w, 4)[::-1, :, 0]          # row 0 at the top


# --------------------------------------------------------------------------
# registration and settings
def test_register_unregister_twice_full_addon():
    for _ in range(2):
        penumbra.register()
        for op in ("compute_passes", "preview", "clear"):
            assert hasattr(bpy.ops.penumbra, op)
        assert hasattr(bpy.types.Light, "penumbra") and hasattr(bpy.types.Scene, "penumbra")
        assert "PENUMBRA_PT_light" in dir(bpy.types) and "PENUMBRA_PT_render" in dir(bpy.types)
        names = [h.__name__ for h in bpy.app.handlers.frame_change_post]
        assert names.count("penumbra_frame_change_post") == 1
        penumbra.unregister()
        assert not hasattr(bpy.types.Light, "penumbra")
        assert not hasattr(bpy.types.Scene, "penumbra")
        for cls in ("PENUMBRA_OT_preview", "PENUMBRA_OT_clear", "PENUMBRA_PT_light",
                    "PENUMBRA_PG_light", "PENUMBRA_PG_knobs_pcf", "PENUMBRA_AP_preferences"):
            assert cls not in dir(bpy.types)
        assert "penumbra_frame_change_post" not in [h.__name__ for h in bpy.app.handlers.frame_change_post]
        assert "penumbra_render_init" not in [h.__name__ for h in bpy.app.handlers.render_init]


def test_light_and_scene_properties(registered):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    light = bpy.data.lights.new("L", "AREA")
    s = light.penumbra
    assert s.enabled is True and s.method == "auto"
    assert s.light_samples == 64 and s.map_size == 0
    items = {e.identifier for e in s.bl_rna.properties["method"].enum_items}
    assert items == {"auto", *registry.pass_ids(external=False)}
    s.method = "embree_irr"
    assert s.method == "embree_irr"
    sc = bpy.context.scene.penumbra
    assert sc.output_folder == "" and sc.seed == 0 and sc.cycles_samples == 64
    assert sc.render_passes is False
    # the pixel filter: the scene's own by default (issue 14), pixel centres, or one of Cycles' with a width
    assert settings.pixel_filter_spec(bpy.context.scene) == "scene"
    sc.pixel_filter = "NONE"
    assert settings.pixel_filter_spec(bpy.context.scene) == "none"
    sc.pixel_filter, sc.pixel_filter_width = "GAUSSIAN", 0.7
    assert settings.pixel_filter_spec(bpy.context.scene) == "gaussian:0.7"
    bpy.context.scene.render.engine = "CYCLES"
    bpy.context.scene.cycles.pixel_filter_type, bpy.context.scene.cycles.filter_width = "BLACKMAN_HARRIS", 2.0
    sc.pixel_filter = "SCENE"
    f = settings.pixel_filter(bpy.context.scene)
    assert (f.kind, f.width) == ("blackman-harris", 2.0)
    sc.pixel_filter = "NONE"
    assert set(sc.references) == {"embree", "embree_irr"}
    sc.references = {"embree", "cycles"}
    assert settings.references(bpy.context.scene) == ["embree", "cycles"]
    # enabling render passes locks the interface (handlers change data)
    bpy.context.scene.render.use_lock_interface = False
    sc.render_passes = True
    assert bpy.context.scene.render.use_lock_interface is True


def test_every_method_has_its_knob_group(registered):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    knobs = bpy.data.lights.new("L", "SPOT").penumbra.knobs
    producers = registry.producers()
    assert producers
    for mid, m in producers.items():
        group = getattr(knobs, mid)
        rna = group.bl_rna.properties
        for f in dataclasses.fields(m.Params):
            if f.name in settings.COMMON_FIELDS:
                assert f.name not in rna
                continue
            assert f.name in rna, (mid, f.name)
            p = rna[f.name]
            assert p.name and p.description, (mid, f.name)
            default = f.default
            if default is None:
                assert getattr(group, f.name + settings.AUTO_SUFFIX) is True
            elif isinstance(default, bool):
                assert getattr(group, f.name) is default
            elif isinstance(default, (int, float)):
                assert getattr(group, f.name) == pytest.approx(default, rel=1e-6)
            elif isinstance(default, str):
                assert getattr(group, f.name) == default
        # untouched knobs override nothing: the same params as the command line
        assert settings.knob_overrides(group, m) == {}
    pcf = knobs.pcf
    assert pcf.bl_rna.properties["NumSamples"].name == "Num Samples"
    assert "acne" in pcf.bl_rna.properties["Bias0"].description
    pcf.NumSamples = 9
    pcf.Bias0_auto = False
    pcf.Bias0 = 0.25
    ov = settings.knob_overrides(pcf, producers["pcf"])
    assert ov == {"NumSamples": 9, "Bias0": 0.25}
    params = producers["pcf"].make_params(ov)
    assert params.NumSamples == 9 and params.Bias0 == 0.25 and params.Bias1 is None


def test_friendly_labels_and_tooltip_fallback():
    assert props.friendly_label("NumSamples") == "Num Samples"
    assert props.friendly_label("Bias0") == "Bias 0"
    assert props.friendly_label("r_scale") == "r Scale"
    assert props.friendly_label("id_test") == "ID Test"
    text, lo, hi = props.knob_tooltip("newmethod", "Frobnication", 3)
    assert "Frobnication" in text and "3" in text and lo is None and hi is None
    text, lo, hi = props.knob_tooltip("pcf", "NumSamples", 16)
    assert text.startswith("NumSamples:") and "cost" in text and lo == 1


def test_method_enum_numbers_are_stable(registered):
    items = props.method_items()
    numbers = [it[4] for it in items]
    assert len(set(numbers)) == len(numbers)
    assert dict((it[0], it[4]) for it in items)["pcf"] == props._enum_number("pcf", set())


def test_panels_draw_existing_properties(registered):
    """Draw the panels into a recording layout: every property they show exists."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    shown = []

    class Layout:
        use_property_split = use_property_decorate = active = enabled = True

        def prop(self, data, name, **kw):
            assert name in data.bl_rna.properties, name
            shown.append(name)

        def operator(self, idname, **kw):
            mod, op = idname.split(".")
            assert hasattr(getattr(bpy.ops, mod), op), idname
            shown.append(idname)
            return type("Props", (), {})()

        def label(self, **kw):
            pass

        def row(self, **kw):
            return self

        column = row

    class Ctx:
        pass

    from penumbra.addon import panels
    light = bpy.data.lights.new("L", "AREA")
    ctx = Ctx()
    ctx.light = light
    ctx.scene = bpy.context.scene
    for method in ["auto", *registry.pass_ids(external=False)]:
        light.penumbra.method = method
        for cls in (panels.PENUMBRA_PT_light, panels.PENUMBRA_PT_light_quality):
            assert cls.poll(ctx)
            self = type("P", (), {"layout": Layout()})()
            cls.draw(self, ctx)
    light.penumbra.method = "pcf"
    assert {"NumSamples", "Bias0", "Bias0_auto", "method", "light_samples", "map_size"} <= set(shown)
    self = type("P", (), {"layout": Layout()})()
    panels.PENUMBRA_PT_render.draw(self, ctx)
    for name in ("render_passes", "output_folder", "seed", "references", "cycles_samples", "pixel_filter",
                 "pixel_filter_width", "penumbra.preview", "penumbra.compute_passes", "penumbra.clear"):
        assert name in shown
    ctx.light = None
    assert not panels.PENUMBRA_PT_light.poll(ctx)


def test_preferences_defaults(registered):
    from penumbra.addon import preferences
    prefs = preferences.get_prefs()
    assert prefs.threads == 0 and prefs.numba_cache
    assert "penumbra" in prefs.numba_cache
    import numba
    assert preferences.apply_threads() == numba.config.NUMBA_NUM_THREADS
    assert numba.get_num_threads() == numba.config.NUMBA_NUM_THREADS


# --------------------------------------------------------------------------
# operators
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
    from penumbra.bridge.jobs import PREVIEW_MAP_SCALE, PREVIEW_PARAMS
    from penumbra.core.views import default_map_size
    assert light.data.type == "AREA"
    side = round(default_map_size(24, 16, "area") * PREVIEW_MAP_SCALE)
    ref = render_frame(capture_scene(scene, resolution=(24, 16)), ["pcf"], overrides={"seed": 0, "samples": 64},
                       method_overrides={"pcf": PREVIEW_PARAMS["pcf"]}, map_size=side)
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
    from penumbra.operators.compute import finish
    result, _written = finish(job, scene, None, build_nodes=True)
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
