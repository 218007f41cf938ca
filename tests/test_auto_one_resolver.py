"""``auto`` is resolved one way for every caller: Compute Passes in the add-on
and ``penumbra render`` write the same method for the same scene and light,
on a small scene and on one of a million triangles, where the scene's shape
(``auto_choice`` rule 5) changes the pick."""
import json

import bpy
import pytest

from penumbra import cli
from penumbra.core import auto_choice as ac
from scenes import sample_path

RES = (32, 24)


def _cli_pick(name, tmp_path):
    out = tmp_path / "cli"
    assert cli.main(["render", sample_path(name), "--out", str(out), "--resolution", f"{RES[0]}x{RES[1]}",
                     "--frame", "1", "--samples", "4", "--pixel-filter", "none", "--no-previews",
                     "--quiet"]) == 0
    rec = json.loads((out / f"{name}.0001.json").read_text())
    return {lr["name"]: list(lr["methods"]) for lr in rec["lights"]}, rec["plan"]["lights"]


def _addon_pick(name, tmp_path):
    bpy.ops.wm.open_mainfile(filepath=sample_path(name), load_ui=False)
    scene = bpy.context.scene
    scene.frame_set(1)
    scene.render.resolution_x, scene.render.resolution_y = RES
    scene.render.resolution_percentage = 100
    scene.penumbra.references = set()
    scene.penumbra.pixel_filter = "NONE"
    scene.penumbra.output_folder = str(tmp_path / "addon")
    for ob in scene.objects:
        if ob.type == "LIGHT":
            assert ob.data.penumbra.method == "auto"
    assert bpy.ops.penumbra.compute_passes(samples=4) == {"FINISHED"}
    rec = json.loads((tmp_path / "addon" / f"{name}.0001.json").read_text())
    return {lr["name"]: list(lr["methods"]) for lr in rec["lights"]}, rec["plan"]["lights"]


@pytest.mark.parametrize("name", ["sphere_plane", "dense_sphere"])
def test_compute_passes_and_render_pick_the_same_method(registered, tmp_path, name):
    cli_methods, cli_plan = _cli_pick(name, tmp_path)
    addon_methods, addon_plan = _addon_pick(name, tmp_path)
    assert cli_methods and addon_methods == cli_methods
    for a, c in zip(addon_plan, cli_plan):
        assert a["auto"]["method"] == c["auto"]["method"] and a["auto"]["rule"] == c["auto"]["rule"]
    if name == "dense_sphere":
        # the scene's shape decides here: the measured scenes' own shape would pick another method
        (light,) = cli_plan
        assert "1,032,194 triangles" in light["auto"]["reason"]
        assert light["auto"]["method"] != ac.choose("area", 1.0).method
