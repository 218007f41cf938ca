"""The ``penumbra`` command line with the bpy module: contract and bad input."""
import json
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest

from penumbra.cli import main
from penumbra.core import exr
from scenes import sample_path

PENUMBRA = os.path.join(os.path.dirname(sys.executable), "penumbra")


def test_render_sphere_plane_contract(tmp_path):
    blend = sample_path("sphere_plane")
    before = open(blend, "rb").read()
    rc = main(["render", blend, "--out", str(tmp_path), "--resolution", "64x48", "--samples", "16",
               "--methods", "pcf,embree,embree_irr"])
    assert rc == 0
    assert open(blend, "rb").read() == before            # the .blend is never written
    exr_path = tmp_path / "sphere_plane.0001.exr"
    rec = json.loads((tmp_path / "sphere_plane.0001.json").read_text())
    layers = exr.read_multilayer(str(exr_path))
    assert rec["scene"] == "sphere_plane" and rec["frame"] == 1 and rec["resolution"] == [64, 48]
    # the default pixel filter is the scene's render filter (issue 14): Cycles' Blackman-Harris 1.5
    assert rec["pixel_filter"]["type"] == "blackman-harris" and rec["pixel_filter"]["width_px"] == 1.5
    for light in rec["lights"]:
        assert light["layer"] == light["name"].replace(".", "_")
        passes = layers[light["layer"]]
        assert set(passes) == {"pcf", "embree", "embree_irr", "Alpha"}     # Alpha: the coverage
        for pid, img in passes.items():
            assert img.shape == (48, 64) and np.isfinite(img).all()
            assert img.min() >= 0 and img.max() <= 1
            if pid == "Alpha":
                continue
            m = light["methods"][pid]
            assert m["visibility"] in ("average", "irradiance")
            assert m["time_s"]["total"] >= 0
        assert light["methods"]["pcf"]["error"]["reference"] == "embree"
        # pcf is not physical, but on this scene it must be close to the reference
        assert light["methods"]["pcf"]["error"]["rmse"] < 0.1
    assert any(l["name"] == "Key.Light" for l in rec["lights"])


def test_render_filtered_contract(tmp_path):
    """--pixel-filter: the filter and sub-pixel counts in the JSON, an Alpha pass
    (the coverage) in every layer; with none, no Alpha and no filter record."""
    blend = sample_path("torus_plane")
    args = ["--resolution", "40x32", "--samples", "8", "--methods", "pcf,embree,embree_irr", "--no-previews"]
    assert main(["render", blend, "--out", str(tmp_path / "f"), "--pixel-filter", "gaussian:1"] + args) == 0
    assert main(["render", blend, "--out", str(tmp_path / "n"), "--pixel-filter", "none"] + args) == 0
    rec = json.loads((tmp_path / "f" / "torus_plane.0001.json").read_text())
    assert rec["pixel_filter"]["type"] == "gaussian" and rec["pixel_filter"]["width_px"] == 1.0
    layers = exr.read_multilayer(str(tmp_path / "f" / "torus_plane.0001.exr"))
    plain = exr.read_multilayer(str(tmp_path / "n" / "torus_plane.0001.exr"))
    for light in rec["lights"]:
        for pid in ("pcf", "embree_irr", "embree"):
            pf = light["methods"][pid]["pixel_filter"]
            assert pf["type"] == "gaussian" and pf["subpixel_receivers"] > 0
            assert 0 < pf["refined_pixels"] < 40 * 32
        a = layers[light["layer"]]["Alpha"]
        assert a.shape == (32, 40) and a.min() >= 0 and a.max() <= 1
        assert set(plain[light["layer"]]) == {"pcf", "embree", "embree_irr"}
    assert "pixel_filter" not in json.loads((tmp_path / "n" / "torus_plane.0001.json").read_text())


def test_render_is_deterministic(tmp_path):
    blend = sample_path("torus_plane")
    args = ["--resolution", "48x48", "--samples", "8", "--seed", "7", "--methods", "pcf,embree", "--no-previews"]
    assert main(["render", blend, "--out", str(tmp_path / "a")] + args) == 0
    assert main(["render", blend, "--out", str(tmp_path / "b")] + args) == 0
    a = exr.read_multilayer(str(tmp_path / "a" / "torus_plane.0001.exr"))
    b = exr.read_multilayer(str(tmp_path / "b" / "torus_plane.0001.exr"))
    for layer in a:
        for p in a[layer]:
            np.testing.assert_array_equal(a[layer][p], b[layer][p])


def _make_blend(path, with_camera=True):
    import bpy
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.mesh.primitive_plane_add(size=4)
    bpy.ops.object.light_add(type="AREA", location=(0, 0, 3))
    if with_camera:
        bpy.ops.object.camera_add(location=(0, 0, 5))
        bpy.context.scene.camera = bpy.context.object
    bpy.ops.wm.save_as_mainfile(filepath=str(path))


@pytest.mark.parametrize("argv, message", [
    (["render", "/nonexistent/x.blend"], "no such file"),
    (["render", "{blend}", "--methods", "pcf,nope"], "unknown method"),
    (["render", "{blend}", "--lights", "Nope"], "unknown light"),
    (["render", "{blend}", "--resolution", "0x10"], "bad --resolution"),
    (["render", "{blend}", "--resolution", "big"], "bad --resolution"),
    (["render", "{blend}", "--resolution", "100000x100000"], "bad --resolution"),
    (["render", "{blend}", "--samples", "-3"], "bad --samples"),
    (["render", "{blend}", "--pixel-filter", "lanczos:2"], "bad pixel filter"),
    (["render", "{blend}", "--pixel-filter", "gaussian:0"], "bad pixel filter width"),
    (["render", "{text}"], "not a .blend"),
    (["render", "{trunc}"], "cannot open"),
    (["render", "{nocam}"], "no camera"),
    (["render", "{blend}", "--out", "{text}/sub"], "cannot create output folder"),
    (["frobnicate"], "invalid choice"),
    ([], "expected a command"),
])
def test_bad_input_exits_2_with_one_line(tmp_path, capsys, argv, message):
    text = tmp_path / "notes.txt"
    text.write_text("hello")
    trunc = tmp_path / "trunc.blend"
    trunc.write_bytes(open(sample_path("sphere_plane"), "rb").read()[:3000])
    nocam = tmp_path / "nocam.blend"
    if "{nocam}" in argv:
        _make_blend(nocam, with_camera=False)
    out = tmp_path / "out"
    argv = [a.format(blend=sample_path("sphere_plane"), text=text, trunc=trunc, nocam=nocam) for a in argv]
    if argv and argv[0] == "render" and "--out" not in argv:
        argv += ["--out", str(out)]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0] and err[0].startswith("penumbra: error:")
    assert not out.exists() or not [f for f in os.listdir(out) if f.endswith((".exr", ".json"))]


def test_console_script_exit_code_and_stderr(tmp_path):
    p = subprocess.run([PENUMBRA, "render", str(tmp_path / "missing.blend")], capture_output=True, text=True)
    assert p.returncode == 2
    assert p.stderr.strip().splitlines() == [f"penumbra: error: no such file: {tmp_path / 'missing.blend'}"]


def test_scene_with_no_shadow_casting_light_writes_ones(tmp_path):
    import bpy
    blend = tmp_path / "noshadow.blend"
    _make_blend(blend)
    for lt in bpy.data.lights:
        lt.use_shadow = False
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    assert main(["render", str(blend), "--out", str(tmp_path / "o"), "--resolution", "16x16"]) == 0
    layers = exr.read_multilayer(str(tmp_path / "o" / "noshadow.0001.exr"))
    assert layers and all((img == 1).all() for passes in layers.values() for img in passes.values())


def test_frame_ranges_resume_and_force(tmp_path, capsys):
    blend = sample_path("torus_plane")
    args = ["render", blend, "--out", str(tmp_path), "--resolution", "24x24", "--samples", "4",
            "--methods", "pcf,embree", "--no-previews"]
    assert main(args + ["--frames", "1-3:2"]) == 0
    names = sorted(f for f in os.listdir(tmp_path) if f.endswith((".exr", ".json")))
    assert names == ["torus_plane.0001.exr", "torus_plane.0001.json", "torus_plane.0003.exr", "torus_plane.0003.json"]
    stamp = os.stat(tmp_path / "torus_plane.0001.exr").st_mtime_ns
    capsys.readouterr()
    assert main(args + ["--frames", "1,2,3"]) == 0
    out = capsys.readouterr().out
    assert out.count("skipped") == 2 and "torus_plane.0002.exr" in out
    assert os.stat(tmp_path / "torus_plane.0001.exr").st_mtime_ns == stamp
    assert main(args + ["--frames", "1", "--force"]) == 0
    assert os.stat(tmp_path / "torus_plane.0001.exr").st_mtime_ns != stamp
    assert not [f for f in os.listdir(tmp_path) if f.startswith(".penumbra-")]


@pytest.mark.parametrize("frames", ["5-1", "a-b", "1-3:0", ""])
def test_bad_frame_ranges(tmp_path, capsys, frames):
    assert main(["render", sample_path("torus_plane"), "--out", str(tmp_path), "--frames", frames]) == 2
    assert "bad --frames" in capsys.readouterr().err


def test_an_error_after_sigterm_is_an_interrupt(monkeypatch, capsys):
    """A farm's SIGTERM raises KeyboardInterrupt wherever Python is; inside a
    Blender callback (the capture render's) Blender catches and prints it,
    and the capture then fails ("did not run"). That failure is the
    interrupt's echo: exit 130 with "penumbra: interrupted", as for any
    interrupt, no traceback. Without a SIGTERM the same error is not hidden."""
    import signal
    import threading
    from penumbra import cli

    def render_swallowing_the_interrupt(args):
        try:
            cli._interrupt(signal.SIGTERM, None)
        except KeyboardInterrupt:
            pass                                   # as Blender does around its callbacks
        raise RuntimeError("capture_scene: the capture render of scene 'x' did not run")

    monkeypatch.setattr(cli, "_TERMINATED", threading.Event())
    monkeypatch.setattr(cli, "cmd_render", render_swallowing_the_interrupt)
    assert main(["render", "x.blend"]) == 130
    assert capsys.readouterr().err.strip() == "penumbra: interrupted"

    def render_failing(args):
        raise RuntimeError("a real bug")
    monkeypatch.setattr(cli, "_TERMINATED", threading.Event())
    monkeypatch.setattr(cli, "cmd_render", render_failing)
    with pytest.raises(RuntimeError, match="a real bug"):
        main(["render", "x.blend"])
