"""The add-on's registration, settings, knob groups, panels and
preferences (bpy, background mode); its operators: test_addon_operators.py."""
import dataclasses
from types import SimpleNamespace

import bpy
import pytest

import penumbra
from penumbra.addon import properties as props
from penumbra.bridge import settings
from penumbra.core import methods as registry
from scenes import draw_panel


# --------------------------------------------------------------------------
# registration
def test_register_unregister_twice():
    for _ in range(2):
        penumbra.register()
        for op in ("compute_passes", "preview", "clear"):
            assert hasattr(bpy.ops.penumbra, op)
        assert bpy.ops.penumbra.compute_passes.poll() in (True, False)
        assert hasattr(bpy.types.Light, "penumbra") and hasattr(bpy.types.Scene, "penumbra")
        assert "PENUMBRA_PT_light" in dir(bpy.types) and "PENUMBRA_PT_render" in dir(bpy.types)
        names = [h.__name__ for h in bpy.app.handlers.frame_change_post]
        assert names.count("penumbra_frame_change_post") == 1
        penumbra.unregister()
        assert not hasattr(bpy.types.Light, "penumbra")
        assert not hasattr(bpy.types.Scene, "penumbra")
        for cls in ("PENUMBRA_OT_compute_passes", "PENUMBRA_OT_preview", "PENUMBRA_OT_clear", "PENUMBRA_PT_light",
                    "PENUMBRA_PG_light", "PENUMBRA_PG_knobs_pcf", "PENUMBRA_AP_preferences"):
            assert cls not in dir(bpy.types)
        assert "penumbra_frame_change_post" not in [h.__name__ for h in bpy.app.handlers.frame_change_post]
        assert "penumbra_render_init" not in [h.__name__ for h in bpy.app.handlers.render_init]


def test_cli_command_is_registered(registered):
    # Blender keeps the handle; registering twice must not raise
    assert penumbra._cli_handle is not None


# --------------------------------------------------------------------------
# settings, knobs, panels, preferences
def test_light_and_scene_properties(registered):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    light = bpy.data.lights.new("L", "AREA")
    s = light.penumbra
    assert s.enabled is True and s.method == "auto"
    assert s.light_samples == 256 and s.map_size == 0
    items = {e.identifier for e in s.bl_rna.properties["method"].enum_items}
    assert items == {"auto", *registry.pass_ids(external=False)}
    s.method = "embree_irr"
    assert s.method == "embree_irr"
    sc = bpy.context.scene.penumbra
    assert sc.output_folder == "" and sc.seed == 0 and sc.cycles_samples == 64
    assert sc.render_passes is False
    # the pixel filter: the scene's own by default, pixel centres, or one of Cycles' with a width
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
    from penumbra.addon import panels
    bpy.ops.wm.read_factory_settings(use_empty=True)
    shown = []

    def draw(cls, ctx):
        layout = draw_panel(cls, ctx)
        for data, name in layout.props:
            assert name in data.bl_rna.properties, name
            shown.append(name)
        for idname in layout.operators:
            mod, op = idname.split(".")
            assert hasattr(getattr(bpy.ops, mod), op), idname
            shown.append(idname)

    light = bpy.data.lights.new("L", "AREA")
    ctx = SimpleNamespace(light=light, scene=bpy.context.scene)
    for method in ["auto", *registry.pass_ids(external=False)]:
        light.penumbra.method = method
        for cls in (panels.PENUMBRA_PT_light, panels.PENUMBRA_PT_light_quality):
            assert cls.poll(ctx)
            draw(cls, ctx)
    light.penumbra.method = "pcf"
    assert {"NumSamples", "Bias0", "Bias0_auto", "method", "light_samples", "map_size"} <= set(shown)
    draw(panels.PENUMBRA_PT_render, ctx)
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
