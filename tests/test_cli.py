"""The ``penumbra`` command line with the bpy module: the render's contract
(EXR, JSON, the .blend never written, determinism, frame ranges), ``plan``
making the decisions ``render`` makes, the progress bar, and bad input of
every kind: a clear one-line error and exit 2, never a traceback, nothing
half-written in the output folder."""
import json
import os
import re
import subprocess
import sys

import numpy as np
import pytest

from penumbra.cli import main
from penumbra.core import exr
from helpers import PENUMBRA
from scenes import BAD_MESHES, sample_path, save_plane_blend

SPHERE = sample_path("sphere_plane")


def leftovers(folder):
    """Every file in ``folder`` (none may be left by a failed run)."""
    return sorted(os.listdir(folder)) if os.path.isdir(folder) else []


def _one_line_error(err: str, message: str):
    lines = err.strip().splitlines()
    assert len(lines) == 1, lines
    assert lines[0].startswith("penumbra: error:") and message in lines[0], lines[0]
    assert "Traceback" not in err


def test_render_sphere_plane_contract(tmp_path):
    blend = SPHERE
    before = open(blend, "rb").read()
    rc = main(["render", blend, "--out", str(tmp_path), "--resolution", "64x48", "--samples", "16",
               "--methods", "pcf,embree,embree_irr"])
    assert rc == 0
    assert open(blend, "rb").read() == before            # the .blend is never written
    exr_path = tmp_path / "sphere_plane.0001.exr"
    rec = json.loads((tmp_path / "sphere_plane.0001.json").read_text())
    layers = exr.read_multilayer(str(exr_path))
    assert rec["scene"] == "sphere_plane" and rec["frame"] == 1 and rec["resolution"] == [64, 48]
    # the default pixel filter is the scene's render filter: Cycles' Blackman-Harris 1.5
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
            assert m["visibility"] == ("average" if pid == "embree" else "irradiance")
            assert m["time_s"]["total"] >= 0
        assert light["methods"]["pcf"]["error"]["reference"] == "embree_irr"
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


def test_scene_with_no_shadow_casting_light_writes_ones(tmp_path):
    import bpy
    blend = tmp_path / "noshadow.blend"
    save_plane_blend(blend, camera_at=(0, 0, 5))
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


# --------------------------------------------------------------------------
# plan says what render does
def _plan_lights(text):
    """{light: (action, [methods])} from ``penumbra plan``'s output."""
    out, name = {}, None
    for line in text.splitlines():
        m = re.match(r"light '(.+)' -> layer '.+': (\w+) \(", line)
        if m:
            name = m.group(1)
            out[name] = (m.group(2), [])
        m = re.match(r"    methods: (.+); buffers:", line)
        if m and name:
            out[name] = (out[name][0], m.group(1).split(", "))
    return out


def _render_lights(rec):
    return {lp["name"]: (lp["action"], lp["producers"]) for lp in rec["plan"]["lights"]}


def _unreached_blend(path):
    """A plane, a camera above it, one area light over it and a spot light
    whose cone points away from everything the camera sees."""
    import bpy
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.mesh.primitive_plane_add(size=4)
    bpy.ops.mesh.primitive_cube_add(size=0.5, location=(0, 0, 1))
    bpy.ops.object.light_add(type="AREA", location=(0, 0, 3))
    bpy.ops.object.light_add(type="SPOT", location=(0, 0, 3), rotation=(np.pi, 0, 0))   # shines up
    bpy.context.object.name = "Away"
    bpy.context.object.data.spot_size = np.radians(30)
    bpy.ops.object.camera_add(location=(0, 0, 6))
    bpy.context.scene.camera = bpy.context.object
    bpy.context.scene.render.resolution_x = bpy.context.scene.render.resolution_y = 32
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    return str(path)


@pytest.mark.parametrize("scene", ["sphere_plane", "torus_plane", "grids", "unreached"])
def test_plan_and_render_agree(tmp_path, capsys, scene):
    blend = _unreached_blend(tmp_path / "unreached.blend") if scene == "unreached" else sample_path(scene)
    res = "48x40"
    capsys.readouterr()
    assert main(["plan", blend, "--resolution", res]) == 0             # default: auto
    said = capsys.readouterr().out
    planned = _plan_lights(said)
    counts = re.search(r"geometry: ([\d,]+) instance\(s\), ([\d,]+) unique / ([\d,]+) instanced triangles", said)
    instances, unique, placed = (int(g.replace(",", "")) for g in counts.groups())
    assert instances >= 1 and unique == placed > 0          # nothing instanced in these scenes
    assert main(["render", blend, "--out", str(tmp_path / "o"), "--resolution", res, "--samples", "4",
                 "--no-previews", "--quiet"]) == 0
    stem = os.path.splitext(os.path.basename(blend))[0]
    frame = next(f for f in os.listdir(tmp_path / "o") if f.endswith(".json"))
    rec = json.loads((tmp_path / "o" / frame).read_text())
    assert rec["plan"]["passes"] == ["auto"]
    assert planned == _render_lights(rec) and planned, stem
    flt = rec["pixel_filter"]                                           # default: the scene's filter
    assert f"pixel filter: {flt['type']} {flt['width_px']:g} px (" in said
    if scene == "unreached":
        assert planned["Away"] == ("skip", [])
        (lp,) = [lp for lp in rec["plan"]["lights"] if lp["name"] == "Away"]
        assert "reaches no visible receiver" in lp["reason"]
        assert planned["Area"][0] == "compute"


def test_progress_bar_only_on_a_terminal_and_not_quiet(monkeypatch, capsys):
    from penumbra import cli
    from penumbra.core.warmup import CompileNotice
    p = cli._Progress(2)                          # under capsys stderr is not a terminal
    assert p.bar is None
    p.frame(0, 1)(CompileNotice("pcf"), 0.0)
    p.frame(0, 1)("Key: pcf", 0.5)
    assert capsys.readouterr().err == "penumbra: compiling pcf kernels (first run only)...\n"
    cli._Progress(2, quiet=True).frame(0, 1)(CompileNotice("pcf"), 0.0)
    assert capsys.readouterr().err == ""
    monkeypatch.setattr(sys.stderr, "isatty", lambda: True)
    assert cli._Progress(2, quiet=True).bar is None
    bar = cli._Progress(2)
    bar.frame(1, 5)("Key: pcf", 0.5)
    assert bar.bar.n == pytest.approx(1.5)
    bar.close()
    assert "frame 5: Key: pcf" in capsys.readouterr().err


# --------------------------------------------------------------------------
# bad input: arguments and files that are no .blend
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
    trunc.write_bytes(open(SPHERE, "rb").read()[:3000])
    nocam = tmp_path / "nocam.blend"
    if "{nocam}" in argv:
        save_plane_blend(nocam, camera_at=None)
    out = tmp_path / "out"
    argv = [a.format(blend=SPHERE, text=text, trunc=trunc, nocam=nocam) for a in argv]
    if argv and argv[0] == "render" and "--out" not in argv:
        argv += ["--out", str(out)]
    assert main(argv) == 2
    _one_line_error(capsys.readouterr().err, message)
    assert not out.exists() or not [f for f in os.listdir(out) if f.endswith((".exr", ".json"))]


def test_console_script_exit_code_and_stderr(tmp_path):
    p = subprocess.run([PENUMBRA, "render", str(tmp_path / "missing.blend")], capture_output=True, text=True)
    assert p.returncode == 2
    assert p.stderr.strip().splitlines() == [f"penumbra: error: no such file: {tmp_path / 'missing.blend'}"]


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


def _bad_blends(tmp_path):
    rng = np.random.default_rng(3)
    data = open(SPHERE, "rb").read()
    files = {
        "random": rng.bytes(4096),                               # no .blend header at all
        "blender_header_random": b"BLENDER-v500" + rng.bytes(8192),   # header, then garbage
        "zstd_header_random": b"\x28\xb5\x2f\xfd" + rng.bytes(8192),  # compressed header, garbage
        "gzip_header_random": b"\x1f\x8b" + rng.bytes(8192),
        "truncated_half": data[: len(data) // 2],
        "empty": b"",
    }
    paths = {}
    for k, v in files.items():
        p = tmp_path / f"{k}.blend"
        p.write_bytes(v)
        paths[k] = str(p)
    return paths


@pytest.mark.parametrize("kind, message", [
    ("random", "not a .blend"), ("empty", "not a .blend"),
    ("blender_header_random", "cannot open"), ("zstd_header_random", "cannot open"),
    ("gzip_header_random", "cannot open"), ("truncated_half", "cannot open"),
])
def test_malformed_blend_exits_2(tmp_path, capsys, kind, message):
    path = _bad_blends(tmp_path)[kind]
    out = tmp_path / "out"
    assert main(["render", path, "--out", str(out), "--resolution", "16x16"]) == 2
    _one_line_error(capsys.readouterr().err, message)
    assert leftovers(out) == []


@pytest.mark.parametrize("argv, message", [
    (["--resolution", "0x0"], "bad --resolution"),
    (["--resolution=-5x10"], "bad --resolution"),
    (["--resolution", "-5x10"], "--resolution"),               # argparse: looks like an option
    (["--resolution", "16385x16"], "bad --resolution"),
    (["--resolution", "16x"], "bad --resolution"),
    (["--resolution", "nanxnan"], "bad --resolution"),
    (["--resolution", "1e3x10"], "bad --resolution"),
    (["--samples", "0"], "bad --samples"),
    (["--samples", "1e9"], "bad --samples"),
    (["--map-size", "0"], "bad --map-size"),
    (["--threads", "0"], "bad --threads"),
    (["--frame", "abc"], "bad --frame"),
    (["--methods", ","], "no methods given"),
    (["--methods", "all,nope"], "unknown method"),             # "all" must not hide an unknown id
    (["--methods", "PCF"], "unknown method"),                  # ids are case-sensitive
    (["--methods", "pcf", "--lights", "Key.Light,Nope"], "unknown light"),
    (["--methods", "cycles_ref"], "unknown method"),
])
def test_absurd_arguments_and_unknown_ids_exit_2(tmp_path, capsys, argv, message):
    out = tmp_path / "out"
    small = [] if any(a.startswith("--resolution") for a in argv) else ["--resolution", "16x16"]
    small += [] if "--samples" in argv else ["--samples", "2"]
    assert main(["render", SPHERE, "--out", str(out), "--no-previews"] + small + argv) == 2
    _one_line_error(capsys.readouterr().err, message)
    assert leftovers(out) == []


def test_plan_with_malformed_blend_and_unknown_ids(tmp_path, capsys):
    paths = _bad_blends(tmp_path)
    assert main(["plan", paths["truncated_half"]]) == 2
    _one_line_error(capsys.readouterr().err, "cannot open")
    assert main(["plan", SPHERE, "--methods", "nope"]) == 2
    _one_line_error(capsys.readouterr().err, "unknown method")


def test_console_script_malformed_blend_no_traceback(tmp_path):
    """The installed console script in a fresh process: exit 2, one line, no
    traceback (Blender's own messages on stdout are allowed)."""
    path = _bad_blends(tmp_path)["blender_header_random"]
    out = tmp_path / "out"
    p = subprocess.run([PENUMBRA, "render", path, "--out", str(out)], capture_output=True, text=True,
                       timeout=300)
    assert p.returncode == 2
    _one_line_error(p.stderr, "cannot open")
    assert "Traceback" not in p.stdout
    assert leftovers(out) == []


# --------------------------------------------------------------------------
# bad input: files that open but hold bad data
@pytest.mark.parametrize("kind", list(BAD_MESHES))
def test_bad_mesh_data_renders_finite_passes(tmp_path, capsys, kind):
    """NaN / inf / float32-overflowing vertices, empty meshes: not an error of
    the user's input file as a whole, so exit 0 with finite V in [0, 1] for
    every method (the bad triangles are dropped at capture)."""
    blend = save_plane_blend(tmp_path / f"{kind}.blend", mesh_data=BAD_MESHES[kind])
    out = tmp_path / "out"
    rc = main(["render", blend, "--out", str(out), "--resolution", "24x24", "--samples", "4",
               "--methods", "all", "--no-previews"])
    err = capsys.readouterr().err
    assert rc == 0, err
    assert "Traceback" not in err
    layers = exr.read_multilayer(str(out / f"{kind}.0001.exr"))
    assert layers
    for passes in layers.values():
        assert "embree" in passes and "pcf" in passes
        for pid, img in passes.items():
            assert img.shape == (24, 24) and np.isfinite(img).all(), pid
            assert img.min() >= 0 and img.max() <= 1, pid
    assert leftovers(out) == [f"{kind}.0001.exr", f"{kind}.0001.json"]


def test_absurd_scene_resolution_exits_2(tmp_path, capsys):
    """The .blend's own render size (no --resolution) is checked like the
    option: 65536 x 65536 would need hundreds of GB."""
    blend = save_plane_blend(tmp_path / "huge.blend", resolution=(65536, 65536))
    out = tmp_path / "out"
    assert main(["render", blend, "--out", str(out)]) == 2
    _one_line_error(capsys.readouterr().err, "resolution")
    assert leftovers(out) == []


def test_plan_and_render_carry_the_cameras_effects(tmp_path, capsys, factory_scene):
    import bpy
    from scenes import sliding_box_scene
    sc = sliding_box_scene(factory_scene)
    sc.camera.data.dof.use_dof = True
    sc.camera.data.dof.focus_distance, sc.camera.data.dof.aperture_fstop = 3.0, 1.0
    blend = str(tmp_path / "moving.blend")
    bpy.ops.wm.save_as_mainfile(filepath=blend, copy=True)
    mtime = os.path.getmtime(blend)
    capsys.readouterr()
    assert main(["plan", blend, "--resolution", "32x32"]) == 0
    said = capsys.readouterr().out
    assert "camera: depth of field, lens radius 0.0175, focus 3" in said
    assert "motion blur over 0.5 frame(s) (1 moving object(s), 3 steps)" in said
    assert "auto -> embree_irr: objects or the camera move over the shutter" in said
    assert main(["render", blend, "--out", str(tmp_path / "o"), "--resolution", "32x32", "--samples", "4",
                 "--no-previews", "--quiet"]) == 0
    rec = json.loads(next((tmp_path / "o").glob("*.json")).read_text())
    eff = rec["camera_effects"]
    assert eff["sampled"] == "per sub-pixel receiver" and eff["motion_blur"]["moving_objects"] == 1
    assert eff["depth_of_field"]["focus_distance"] == pytest.approx(3.0)
    (light,) = rec["lights"]
    assert light["methods"]["embree_irr"]["shutter"] == "occluders at the receiver's time"
    assert os.path.getmtime(blend) == mtime
