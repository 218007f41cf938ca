"""``auto`` with bpy (background mode): Compute Passes, the panel, Set up
compositor and the command line's ``plan`` and ``render`` all resolve a
light's ``auto`` with core/auto_choice.py under the scene's error budget,
and the frame's JSON carries the decision (the rules themselves:
test_core_auto.py)."""
import json
from types import SimpleNamespace

import bpy
import pytest

from penumbra.bridge import compositor
from penumbra.core import auto_choice as ac
from scenes import draw_panel, open_sample, sample_path


def _sphere_plane(w=32, h=24):
    return open_sample("sphere_plane", (w, h)), bpy.data.objects["Key.Light"]


def _scene_aware_pick(scene, budget):
    """auto's decision for the sphere_plane light as the add-on captures it."""
    from penumbra.bridge.capture import capture_scene
    from penumbra.core.planner import auto_choice_for
    sc = capture_scene(scene, resolution=(scene.render.resolution_x, scene.render.resolution_y))
    return auto_choice_for(sc, sc.lights[0], budget)


def test_compute_writes_autos_pick_and_reason(registered, tmp_path):
    scene, light = _sphere_plane()
    assert light.data.penumbra.method == "auto"
    assert scene.penumbra.error_budget == pytest.approx(ac.DEFAULT_BUDGET)
    scene.penumbra.references = set()
    scene.penumbra.output_folder = str(tmp_path)
    picked = []
    for budget in (0.02, 0.3):
        scene.penumbra.error_budget = budget
        want = _scene_aware_pick(scene, scene.penumbra.error_budget)
        assert bpy.ops.penumbra.compute_passes(samples=4) == {"FINISHED"}
        rec = json.loads((tmp_path / "sphere_plane.0001.json").read_text())
        (lp,) = rec["plan"]["lights"]
        assert lp["auto"]["method"] == want.method and lp["decisions"][0] == want.reason
        assert lp["auto"]["budget"] == pytest.approx(budget)
        # the pass is written under the method id auto resolved to, never "auto"
        assert list(rec["lights"][0]["methods"]) == [want.method]
        assert bpy.data.images.get(compositor.pass_image_name("Key_Light", want.method)) is not None
        picked.append(want)
        # Set up compositor shows the same pick as the light's method
        from penumbra.operators.compositor_ops import light_method
        assert light_method("Key.Light", scene=scene) == want.method
    # a looser budget picks a cheaper, less accurate method
    assert picked[0].method != picked[1].method
    assert picked[1].seconds < picked[0].seconds and picked[1].rmse > picked[0].rmse


def test_zero_size_light_resolves_to_the_hard_shadow_method(registered):
    from penumbra.bridge import jobs as bj
    from penumbra.bridge.capture import capture_scene
    scene, light = _sphere_plane(16, 12)
    light.data.size = 0.0
    jobs, _ = bj.light_jobs(scene, capture_scene(scene, resolution=(16, 12)), references=())
    (job,) = jobs
    assert job.passes == ["pcf"] and job.auto.rule == "hard"
    assert bj.asks_for_auto(light.data.penumbra)
    assert bj.last_auto(scene.name, "Key.Light").method == "pcf"


def test_panel_says_what_auto_picked_for_the_scene(registered):
    """Before a frame was computed the light's panel says the pick is made
    per scene; afterwards it shows the pick (its short reason) and the
    picked method's knobs."""
    from penumbra.addon import panels
    from penumbra.bridge import jobs as bj
    scene, light = _sphere_plane()
    scene.penumbra.references = set()
    scene.penumbra.error_budget = 0.3
    prefix = "PENUMBRA_PG_knobs_"
    ctx = SimpleNamespace(scene=scene, light=light.data, object=light)

    def draw():
        drawn = [draw_panel(cls, ctx) for cls in (panels.PENUMBRA_PT_light, panels.PENUMBRA_PT_light_quality)]
        labels = [text for layout in drawn for text in layout.labels]
        knobs = [data.bl_rna.identifier[len(prefix):] for layout in drawn for data, _ in layout.props
                 if hasattr(data, "bl_rna") and data.bl_rna.identifier.startswith(prefix)]
        return labels, knobs
    bj._last_auto.clear()
    labels, knobs = draw()
    assert labels[0] == "Auto: picked for the scene when computed" and not knobs
    assert bpy.ops.penumbra.compute_passes(samples=4) == {"FINISHED"}
    want = _scene_aware_pick(scene, 0.3)
    labels, knobs = draw()
    assert labels == [f"Auto: {want.short}"]
    assert want.method.split("_irr")[0] in knobs           # the picked method's knobs


def _torus_shape(resolution):
    """auto's SceneShape of torus_plane's spot light as the CLI captures it
    (``resolution`` None: the scene's own)."""
    from penumbra.bridge.capture import capture_scene
    sc = capture_scene(open_sample("torus_plane"), resolution=resolution)
    return ac.scene_shape(sc, sc.lights[0])


def test_cli_plan_prints_autos_pick_under_the_budget(capsys, tmp_path):
    """``penumbra plan --methods auto`` resolves per light; a bad budget
    exits 2 with one line and writes nothing."""
    from penumbra.cli import main
    blend = sample_path("torus_plane")                      # a spot light: sphere kind
    picks = []
    for budget in ("0.005", "0.3"):
        assert main(["plan", blend, "--methods", "auto,embree", "--error-budget", budget]) == 0
        out = capsys.readouterr().out
        want = ac.choose("sphere", 0.8, budget=float(budget), shape=_torus_shape(None))
        assert want.reason in out and f"methods: {want.method}, embree" in out
        picks.append(want.method)
    assert picks[0] != picks[1]                     # the budget changes the pick
    for argv, msg in ((["plan", blend, "--methods", "auto", "--error-budget", "0"], "bad --error-budget"),
                      (["plan", blend, "--methods", "auto", "--error-budget", "nan"], "bad --error-budget"),
                      (["render", blend, "--methods", "auto", "--out", str(tmp_path), "--error-budget", "2"],
                       "bad --error-budget")):
        assert main(argv) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and msg in err[0]
    assert not list(tmp_path.iterdir())


def test_cli_render_auto_writes_the_picked_method_under_its_id(tmp_path):
    """``penumbra render --methods auto,embree_irr``: the light's pass is the
    method auto picked for the budget, under that id (never ``auto``), with
    its error against the reference of its definition and the decision in
    the plan."""
    import OpenEXR
    from penumbra.cli import main
    blend = sample_path("torus_plane")
    want = ac.choose("sphere", 0.8, budget=0.3, shape=_torus_shape((48, 48)))
    assert main(["render", blend, "--methods", "auto,embree_irr", "--out", str(tmp_path), "--resolution", "48x48",
                 "--samples", "16", "--error-budget", "0.3", "--no-previews"]) == 0
    rec = json.load(open(next(tmp_path.glob("*.json"))))
    (light,) = rec["lights"]
    assert set(light["methods"]) == {want.method, "embree_irr"}
    assert light["methods"][want.method]["visibility"] == "irradiance"
    assert light["methods"][want.method]["error"]["reference"] == "embree_irr"
    plan = rec["plan"]["lights"][0]
    assert plan["auto"]["method"] == want.method and plan["decisions"][0] == want.reason
    exr = OpenEXR.File(str(next(tmp_path.glob("*.exr"))), separate_channels=True)
    names = {c for part in exr.parts for c in part.channels}
    assert f"Spot.{want.method}.V" in names and not any(".auto." in c for c in names)
