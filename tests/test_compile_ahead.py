"""Cold-start compilation shared with helper processes (``core/compile_ahead.py``):
the recorded plan names the current kernels and matches what a cold
frame compiles; helpers take kernels off the caller's hands without changing
a pixel; the claim protocol (the caller claims what nobody has, waits for
what a helper claimed, a helper skips every claimed kernel)."""
import base64
import importlib
import json
import os
import pickle
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
from numba.core.dispatcher import Dispatcher
from numba.core.types import Type

from penumbra.core import compile_ahead
from penumbra.core import methods as registry
from helpers import ROOT

RECORD = os.path.join(ROOT, "scripts", "record_kernel_plan.py")
KINDS = ("area", "sphere", "sun")


def _env(tmp_path, processes):
    env = dict(os.environ, PENUMBRA_NUMBA_CACHE_ROOT=str(tmp_path / "cache"),
               PENUMBRA_COMPILE_PROCESSES=str(processes))
    env.pop("NUMBA_CACHE_DIR", None)
    return env


def test_the_plan_names_the_current_kernels_for_every_pass_and_kind():
    plan = compile_ahead.load_plan()
    assert plan, compile_ahead.PLAN_FILE
    for p in registry.pass_ids(external=False):
        for k in KINDS:
            for f in (True, False):
                assert compile_ahead.plan_key(p, k, f) in plan["lists"]
    for name, sig in plan["items"]:
        modname, qualname = name.split(":")
        disp = getattr(importlib.import_module(modname), qualname)
        assert isinstance(disp, Dispatcher), name
        args = pickle.loads(base64.b64decode(sig))
        assert isinstance(args, tuple) and all(isinstance(a, Type) for a in args), name


@pytest.mark.parametrize("key", ["pcf|area|filtered", "penumbra_casting|area|centres"])
def test_the_plan_is_what_a_cold_frame_compiles(tmp_path, key):
    """Recorded again from an empty cache, the list is the plan's: the plan
    is not stale (else: ``python scripts/record_kernel_plan.py``)."""
    pass_id, kind, model = key.split("|")
    p = subprocess.run([sys.executable, RECORD, "--one", pass_id, kind, "1" if model == "filtered" else "0"],
                       capture_output=True, text=True, env=_env(tmp_path, 1))
    assert p.returncode == 0, p.stderr[-2000:]
    fresh = json.loads(p.stdout.strip().splitlines()[-1])
    plan = compile_ahead.load_plan()
    recorded = [plan["items"][i] for i in plan["lists"][key]]
    assert [n for n, _ in fresh] == [n for n, _ in recorded]
    assert [pickle.loads(base64.b64decode(s)) for _, s in fresh] == \
        [pickle.loads(base64.b64decode(s)) for _, s in recorded]


_FRAME = r"""
import json, sys, threading
import numpy as np
from numba.core import event
from penumbra.core import compile_ahead
from penumbra.core.filtered_frame import render_filtered
from penumbra.core.pixel_filter import PixelFilter
from penumbra.core.scene import Light
from penumbra.core.warmup import warmup_scene
local = threading.local(); top = []
class L(event.Listener):
    def on_start(self, ev):
        if getattr(local, "d", 0) == 0:
            top.append(ev.data["dispatcher"].py_func.__qualname__)
        local.d = getattr(local, "d", 0) + 1
    def on_end(self, ev):
        local.d -= 1
event.register("numba:compile", L())
light = Light("Key", "area", np.eye(4), blender_type="AREA", size=1.0, size_y=1.0)
res = render_filtered(warmup_scene(light), ["pcf"], None, PixelFilter("blackman-harris", 1.5),
                      overrides={"samples": 16, "seed": 0})
np.save(sys.argv[1], res.lights[0].passes["pcf"])
print(json.dumps({"main": top, "done": compile_ahead.helper_done(), "compile_s": res.compile_s}))
"""


def test_helpers_take_kernels_off_the_frame_without_changing_a_pixel(tmp_path):
    """A cold filtered pcf frame with one helper: the helper finished
    kernels, the caller compiled fewer kernels itself than alone, and the
    pass is bit-identical to the frame compiled in one process."""
    runs = {}
    for n in (1, 2):
        out = tmp_path / f"v{n}.npy"
        p = subprocess.run([sys.executable, "-c", _FRAME, str(out)], capture_output=True, text=True,
                           env=_env(tmp_path / f"p{n}", n))
        assert p.returncode == 0, p.stderr[-2000:]
        runs[n] = json.loads(p.stdout.strip().splitlines()[-1]), np.load(out)
    (alone, v1), (shared, v2) = runs[1], runs[2]
    assert alone["done"] == 0 and shared["done"] > 0
    assert len(shared["main"]) < len(alone["main"])
    assert set(shared["main"]) < set(alone["main"])
    assert shared["compile_s"] > 0
    np.testing.assert_array_equal(v1, v2)


class _Proc:
    """A stand-in for a helper's Popen."""

    def __init__(self):
        self.alive = True

    def poll(self):
        return None if self.alive else 0


def test_the_caller_claims_what_nobody_has_and_waits_for_a_helpers_claim(tmp_path):
    helper = _Proc()
    alive = compile_ahead._any_alive([helper])                   # the caller's alive(): a helper still runs
    t0 = time.perf_counter()
    assert compile_ahead._claim_or_wait(str(tmp_path), 0, alive)
    assert (tmp_path / "0.claim").read_text() == f"main {os.getpid()}" and time.perf_counter() - t0 < 0.5
    (tmp_path / "1.claim").write_text("helper")
    threading.Timer(0.3, (tmp_path / "1.done").touch).start()
    t0 = time.perf_counter()
    assert not compile_ahead._claim_or_wait(str(tmp_path), 1, alive)
    assert 0.25 < time.perf_counter() - t0 < 5 and (tmp_path / "1.done").exists()
    (tmp_path / "2.claim").write_text("helper")                  # its helper died: no wait for ever
    threading.Timer(0.2, lambda: setattr(helper, "alive", False)).start()
    t0 = time.perf_counter()
    assert not compile_ahead._claim_or_wait(str(tmp_path), 2, alive)
    assert time.perf_counter() - t0 < 5 and not (tmp_path / "2.done").exists()
    gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    (tmp_path / "3.claim").write_text(f"helper {int(gone.stdout)}")    # its claimant exited: no wait
    t0 = time.perf_counter()
    assert not compile_ahead._claim_or_wait(str(tmp_path), 3, lambda: True)
    assert time.perf_counter() - t0 < 1


def test_a_callee_is_claimed_on_lookup_and_marked_done_after_its_compile(tmp_path):
    """The hook on ``disp.compile``: a process claims a listed signature when
    it compiles it (a caller's typing included) and marks it done after;
    another signature of the same kernel is not claimed."""
    from numba import njit, types
    from numba.core import sigutils

    @njit
    def twice(x):
        return 2 * x
    sig = base64.b64encode(pickle.dumps((types.int64,))).decode()
    compile_ahead._hook(twice, "test:twice", str(tmp_path), 0, sig, lambda: True)
    assert twice(3) == 6                                            # compiled for int64 through the hook
    assert (tmp_path / "0.claim").read_text() == f"main {os.getpid()}" and (tmp_path / "0.done").exists()
    assert twice(1.5) == 3.0 and not (tmp_path / "1.claim").exists()
    assert sigutils.normalize_signature((types.int64,))[0] in [tuple(s) for s in twice.signatures]


def test_a_helper_works_from_the_end_and_skips_what_is_claimed(tmp_path):
    plan = compile_ahead.load_plan()
    item = plan["items"][plan["lists"]["pcf|area|centres"][0]]
    items = [item, item, ["penumbra.core.pixel_rays:no_such_kernel", item[1]], item]
    (tmp_path / "items.json").write_text(json.dumps(items))
    (tmp_path / "3.claim").write_text("helper")                  # another helper's
    (tmp_path / "1.claim").write_text("main")                    # the caller's
    pkg_dir = os.path.dirname(os.path.dirname(os.path.abspath(compile_ahead.__file__)))
    assert compile_ahead._helper(pkg_dir, compile_ahead._PKG, str(tmp_path)) == 0
    for i in (0, 2):                                             # a stale entry is marked done too
        assert (tmp_path / f"{i}.claim").read_text().startswith("helper") and (tmp_path / f"{i}.done").exists()
    assert not (tmp_path / "1.done").exists() and not (tmp_path / "3.done").exists()
