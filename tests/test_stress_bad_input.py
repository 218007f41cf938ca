"""Issue 7's bad input through the CLI and the operators (bpy, background):
a clear one-line error and exit 2 (CLI) / an error report and CANCELLED
(operators), never a traceback, nothing half-written in the output folder.

test_cli.py already covers: a missing file, a text file, the first 3000 bytes
of a .blend, no camera, 0x10 / "big" / 100000x100000 resolutions, negative
samples, unknown method and light, an unwritable output folder. Here: the rest
of the hard inputs, and files that are bad inside (NaN vertices, empty meshes).
"""
import os
import subprocess
import sys

import numpy as np
import pytest

import penumbra
from penumbra.cli import main
from penumbra.core import exr
from scenes import sample_path

PENUMBRA = os.path.join(os.path.dirname(sys.executable), "penumbra")
SPHERE = sample_path("sphere_plane")


def leftovers(folder):
    """Every file in ``folder`` (none may be left by a failed run)."""
    return sorted(os.listdir(folder)) if os.path.isdir(folder) else []


def _one_line_error(err: str, message: str):
    lines = err.strip().splitlines()
    assert len(lines) == 1, lines
    assert lines[0].startswith("penumbra: error:") and message in lines[0], lines[0]
    assert "Traceback" not in err


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
# files that open but hold bad data
def _blend_with(path, mesh_data=None, resolution=None):
    """A plane, an area light, a camera, plus a mesh built from ``mesh_data``
    (vertices, faces); saved to ``path``."""
    import bpy
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.mesh.primitive_plane_add(size=4)
    bpy.ops.object.light_add(type="AREA", location=(0, 0, 3))
    bpy.ops.object.camera_add(location=(0, 0, 6))
    bpy.context.scene.camera = bpy.context.object
    if mesh_data is not None:
        verts, faces = mesh_data
        me = bpy.data.meshes.new("bad")
        me.from_pydata(verts, [], faces)
        ob = bpy.data.objects.new("bad", me)
        bpy.context.scene.collection.objects.link(ob)
    if resolution is not None:
        r = bpy.context.scene.render
        r.resolution_x, r.resolution_y = resolution
        r.resolution_percentage = 100
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    return str(path)


NAN = float("nan")
INF = float("inf")
BAD_MESHES = {
    "nan_vertices": ([(NAN, 0, 1), (1, 0, 1), (0, 1, 1), (0.5, 0.5, 1)], [(0, 1, 2), (1, 3, 2)]),
    "inf_vertices": ([(INF, 0, 1), (1, -INF, 1), (0, 1, 1)], [(0, 1, 2)]),
    "huge_vertices": ([(3e38, 0, 1), (-3e38, 0, 1), (0, 3e38, 1)], [(0, 1, 2)]),
    "empty_mesh": ([], []),
    "vertices_only": ([(0, 0, 1), (1, 0, 1)], []),
    "degenerate_faces": ([(0, 0, 1), (0, 0, 1), (0, 0, 1), (1, 1, 1), (2, 2, 1)], [(0, 1, 2), (0, 3, 4)]),
}


@pytest.mark.parametrize("kind", list(BAD_MESHES))
def test_bad_mesh_data_renders_finite_passes(tmp_path, capsys, kind):
    """NaN / inf / float32-overflowing vertices, empty meshes: not an error of
    the user's input file as a whole, so exit 0 with finite V in [0, 1] for
    every method (the bad triangles are dropped at capture)."""
    blend = _blend_with(tmp_path / f"{kind}.blend", BAD_MESHES[kind])
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
    blend = _blend_with(tmp_path / "huge.blend", resolution=(65536, 65536))
    out = tmp_path / "out"
    assert main(["render", blend, "--out", str(out)]) == 2
    _one_line_error(capsys.readouterr().err, "resolution")
    assert leftovers(out) == []


# --------------------------------------------------------------------------
# operators
@pytest.fixture
def registered():
    penumbra.register()
    yield
    penumbra.unregister()


def _operator_error(**kw):
    """Run compute_passes; bpy turns an ERROR report + CANCELLED into a
    RuntimeError carrying the report. Returns its text."""
    import bpy
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
    import bpy
    bpy.ops.wm.open_mainfile(filepath=_blend_with(tmp_path / "s.blend"), load_ui=False)
    bpy.context.scene.render.resolution_x = bpy.context.scene.render.resolution_y = 16
    text = _operator_error(methods=methods)
    assert message in text


def test_operator_absurd_resolution_is_an_error_report(registered, tmp_path):
    """65536 x 65536 at 100 %: refused before any buffer is allocated."""
    import bpy
    bpy.ops.wm.open_mainfile(filepath=_blend_with(tmp_path / "s.blend", resolution=(65536, 65536)),
                             load_ui=False)
    text = _operator_error(methods="pcf")
    assert "resolution" in text
    assert not [im for im in bpy.data.images if im.name.startswith("Penumbra")]


@pytest.mark.parametrize("kind", ["nan_vertices", "inf_vertices", "empty_mesh", "degenerate_faces"])
def test_operator_bad_mesh_data_finishes_with_finite_images(registered, tmp_path, kind):
    import bpy
    from penumbra.bridge import compositor
    bpy.ops.wm.open_mainfile(filepath=_blend_with(tmp_path / f"{kind}.blend", BAD_MESHES[kind]), load_ui=False)
    r = bpy.context.scene.render
    r.resolution_x, r.resolution_y = 24, 16
    assert bpy.ops.penumbra.compute_passes(methods="pcf,embree,penumbra_casting", samples=4) == {"FINISHED"}
    for pid in ("pcf", "embree", "penumbra_casting"):
        img = bpy.data.images[compositor.pass_image_name("Area", pid)]
        px = np.empty(24 * 16 * 4, np.float32)
        img.pixels.foreach_get(px)
        v = px.reshape(16, 24, 4)[..., 0]
        assert np.isfinite(v).all() and v.min() >= 0 and v.max() <= 1, pid
