"""The warm-up (``core/warmup.py``): compilation reported apart from the
methods' times (``compile_s``) with a notice first, the warm-up compiling
every kernel a run calls, nothing compiled outside it on a matte scene, and
the add-on's warm-up thread."""
import json
import os
import subprocess
import sys

import numpy as np
import pytest

from penumbra.core import methods as registry
from penumbra.core import warmup
from penumbra.core.buffers import FrameBuffers
from helpers import COMPILES_OUTSIDE_WARM_UP, PENUMBRA
from scenes import sample_path
from synthetic import area_light, half_plane_scene, sphere_light, sun_light


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


@pytest.mark.parametrize("pixel_filter", ["none", "blackman-harris:1.5"])
def test_a_matte_scene_compiles_nothing_outside_the_warm_up(tmp_path, pixel_filter):
    """On a fresh Numba cache, every kernel a frame with
    alpha mattes compiles (camera G-buffer pass-through, dithered light map,
    matte transmittance, the planner's reach; filtered: the refine masks,
    sub-pixel G-buffer, resolve) compiles inside the warm-up, never inside a
    buffer's or a method's time."""
    env = dict(os.environ, PENUMBRA_NUMBA_CACHE_ROOT=str(tmp_path / "cache"))
    env.pop("NUMBA_CACHE_DIR", None)
    code = COMPILES_OUTSIDE_WARM_UP.format(tests=os.path.dirname(os.path.abspath(__file__)),
                                            methods=["pcf", "embree"], pixel_filter=pixel_filter)
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert p.returncode == 0, p.stderr
    seen = json.loads(p.stdout.strip().splitlines()[-1])
    assert any("transmittance" in n or "cross" in n or "clear" in n for n in seen["inside"]), seen["inside"]
    assert seen["outside"] == [], seen["outside"]


def test_warm_up_thread_compiles_the_default_methods():
    from penumbra.bridge import pipeline
    from penumbra.core.scene import Light
    th = pipeline.start_warm_up(["pcf"])
    assert th.daemon                                   # never keeps Blender from exiting
    th.join(600)
    assert not th.is_alive()
    m = registry.producer_of("pcf")
    light = Light("any", "area", np.eye(4), blender_type="AREA", size=1.0)
    assert warmup.ensure_compiled(m, light, m.make_params({"seed": 0, "samples": 64})) == 0.0
    assert set(pipeline.default_methods()) >= {"pcf"}
