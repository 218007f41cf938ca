"""Compilation reported apart (``compile_s``, issue 15), the compiling notice,
the warm-up covering every kernel a run calls, and ``penumbra plan``
making the decisions ``render`` makes."""
import json
import os
import re
import subprocess
import sys

import numpy as np
import pytest

from penumbra.cli import main
from penumbra.core import methods as registry
from penumbra.core import warmup
from penumbra.core.buffers import FrameBuffers
from scenes import sample_path
from synthetic import area_light, half_plane_scene, light_matrix, sphere_light, sun_light

PENUMBRA = os.path.join(os.path.dirname(sys.executable), "penumbra")


def _render(out, cache_root):
    env = dict(os.environ, PENUMBRA_NUMBA_CACHE_ROOT=str(cache_root))
    env.pop("NUMBA_CACHE_DIR", None)
    p = subprocess.run([PENUMBRA, "render", sample_path("sphere_plane"), "--out", str(out), "--methods", "pcf",
                        "--resolution", "32x32", "--no-previews"], capture_output=True, text=True, env=env)
    assert p.returncode == 0, p.stderr
    return p, json.loads((out / "sphere_plane.0001.json").read_text())


def test_compile_time_is_reported_apart_from_the_method(tmp_path):
    """A fresh Numba cache: the notice comes first, the compilation is the
    frame's compile_s and not inside pcf's time; the next process is warm."""
    cold, rec = _render(tmp_path / "a", tmp_path / "cache")
    assert "penumbra: compiling pcf kernels (first run only)..." in cold.stderr.splitlines()
    (light,) = rec["lights"]
    assert rec["compile_s"] > 0
    assert light["methods"]["pcf"]["time_s"]["total"] < rec["compile_s"]
    assert "kernel compilation:" in cold.stdout
    warm, rec2 = _render(tmp_path / "b", tmp_path / "cache")
    assert "compiling" not in warm.stderr
    assert rec2["compile_s"] == 0.0


def _lights():
    spot = sphere_light(0.3, name="Spot", spot_size=np.radians(60))
    return [area_light(1.0), sphere_light(0.3), spot, sun_light(0.1), area_light(0.0, name="Hard")]


@pytest.mark.parametrize("method", ["pcf", "single_sample", "embree", "penumbra_casting"])
def test_warm_up_compiles_every_kernel_the_run_calls(method):
    """After ensure_compiled, the real run adds no overload to any dispatcher
    (no compilation, no cache load inside the method's time)."""
    m = registry.producers()[method]
    for light in _lights() if method != "penumbra_casting" else [area_light(1.0)]:
        params = m.make_params({"samples": 16, "seed": 0})
        warmup.ensure_compiled(m, light, params)
        assert warmup.ensure_compiled(m, light, params) == 0.0       # once per process
        sc = half_plane_scene(light, res=24)
        before = warmup._overload_counts()
        m.run(FrameBuffers(sc, 24, 24), light, params)
        after = warmup._overload_counts()
        assert {k: n for k, n in after.items() if n != before.get(k)} == {}, (method, light.name)
    assert warmup.kernels_cached(method)


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


_COMPILES_OUTSIDE_WARM_UP = r"""
import json, sys
sys.path.insert(0, {tests!r})
from numba.core import event
from penumbra.core import warmup
from penumbra.core.alpha import CLOSEST, REPEAT
from penumbra.core.filtered_frame import render_filtered
from penumbra.core.pixel_filter import parse
from synthetic import area_light, matte_layers_scene

inside, outside = [], []

def in_warm_up():
    # the warm-up holds warmup._lock while it runs (its worker threads see it taken)
    owned = getattr(warmup._lock, "_is_owned", None)      # an RLock: its owner may re-acquire it
    if owned is not None and owned():
        return True
    if warmup._lock.acquire(blocking=False):
        warmup._lock.release()
        return False
    return True

class Compiles(event.Listener):
    def on_start(self, ev):
        (inside if in_warm_up() else outside).append(ev.data["dispatcher"].py_func.__qualname__)
    def on_end(self, ev):
        pass

event.register("numba:compile", Compiles())
sc = matte_layers_scene(area_light(1.0), [(2.0, [[0.0, 1.0], [1.0, 0.0]], CLOSEST, REPEAT)], res=16,
                        camera_sees=True)
render_filtered(sc, {methods!r}, overrides={{"samples": 4}}, pixel_filter=parse({pixel_filter!r}))
print(json.dumps({{"inside": inside, "outside": outside}}))
"""


@pytest.mark.parametrize("pixel_filter", ["none", "blackman-harris:1.5"])
def test_a_matte_scene_compiles_nothing_outside_the_warm_up(tmp_path, pixel_filter):
    """Issue 15 / 18 / 14: on a fresh Numba cache, every kernel a frame with
    alpha mattes compiles (camera G-buffer pass-through, dithered light map,
    matte transmittance, the planner's reach; filtered: the refine masks,
    sub-pixel G-buffer, resolve) compiles inside the warm-up, never inside a
    buffer's or a method's time."""
    env = dict(os.environ, PENUMBRA_NUMBA_CACHE_ROOT=str(tmp_path / "cache"))
    env.pop("NUMBA_CACHE_DIR", None)
    code = _COMPILES_OUTSIDE_WARM_UP.format(tests=os.path.dirname(os.path.abspath(__file__)),
                                            methods=["pcf", "embree"], pixel_filter=pixel_filter)
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert p.returncode == 0, p.stderr
    seen = json.loads(p.stdout.strip().splitlines()[-1])
    assert any("transmittance" in n or "cross" in n or "clear" in n for n in seen["inside"]), seen["inside"]
    assert seen["outside"] == [], seen["outside"]
