"""Record ``core/kernel_plan.json`` (``core/compile_ahead.py``): for each core
pass, light kind and pixel model, the Numba dispatchers and signatures a
cold frame compiles, callees included, in the order their compiles start (a
caller before its callees: read backwards, callees before their callers,
the order a helper works in). Each list is recorded in
its own process on an empty cache, rendering the warm-up scene
(``core/warmup.py``) as a real frame does (its warm-ups first).

    python scripts/record_kernel_plan.py [--jobs 2]

Run it after a change to a kernel's signature or to what a method compiles
(``tests/test_compile_ahead.py`` says when the plan no longer matches).
"""
from __future__ import annotations

import argparse
import base64
import concurrent.futures
import json
import os
import pickle
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
KINDS = ("area", "sphere", "sun")


def _light(kind: str):
    import numpy as np
    from penumbra.core.scene import Light
    if kind == "area":
        return Light("warm-up", "area", np.eye(4), blender_type="AREA", shape="SQUARE", size=1.0, size_y=1.0)
    if kind == "sphere":
        return Light("warm-up", "sphere", np.eye(4), blender_type="POINT", radius=0.25)
    return Light("warm-up", "sun", np.eye(4), blender_type="SUN", angle=0.05)


def _named(disp) -> bool:
    """A helper can find ``disp`` by its function's module and name (not so
    for a second dispatcher made from one Python function, e.g.
    ``single_sample.warp._warp_inline``: the caller compiles it itself)."""
    mod = sys.modules.get(disp.py_func.__module__)
    return getattr(mod, disp.py_func.__qualname__, None) is disp


def record_one(pass_id: str, kind: str, filtered: bool) -> list:
    """[[dispatcher, sig_b64], ...]: the compiles of one cold frame, callees
    included, in the order they start (this process must start on an empty cache)."""
    from numba.core import event

    from penumbra.core.filtered_frame import render_filtered
    from penumbra.core.pixel_filter import PixelFilter
    from penumbra.core.warmup import warmup_scene
    out = []

    class Listener(event.Listener):
        def on_start(self, ev):
            d = ev.data["dispatcher"]
            name = f"{d.py_func.__module__}:{d.py_func.__qualname__}"
            if name.startswith("penumbra.") and _named(d):
                out.append([name, base64.b64encode(pickle.dumps(tuple(ev.data["args"]))).decode()])

        def on_end(self, ev):
            pass

    event.register("numba:compile", Listener())
    flt = PixelFilter("blackman-harris", 1.5) if filtered else PixelFilter()
    render_filtered(warmup_scene(_light(kind)), [pass_id], None, flt, overrides={"samples": 64, "seed": 0})
    return out


def _run_one(args):
    pass_id, kind, filtered = args
    with tempfile.TemporaryDirectory(prefix="penumbra-plan-") as root:
        env = dict(os.environ, PENUMBRA_NUMBA_CACHE_ROOT=root, PENUMBRA_COMPILE_PROCESSES="1")
        env.pop("NUMBA_CACHE_DIR", None)
        r = subprocess.run([sys.executable, __file__, "--one", pass_id, kind, "1" if filtered else "0"],
                           env=env, capture_output=True, text=True, cwd=HERE)
        if r.returncode != 0:
            raise RuntimeError(f"{pass_id} {kind} {filtered}: {r.stderr[-2000:]}")
        return args, json.loads(r.stdout.strip().splitlines()[-1])


def merged_signatures(items: list, lists: dict):
    """One item per dispatcher and signature: the same Numba types can pickle
    to other bytes in another process (pickle's memo follows object
    identity), which would list one kernel twice for the helpers."""
    from penumbra.core.compile_ahead import _unpickle
    first, remap, out = {}, {}, []
    for i, (name, sig) in enumerate(items):
        key = (name, repr(_unpickle(sig, "penumbra")))
        if key not in first:
            first[key] = len(out)
            out.append([name, sig])
        remap[i] = first[key]
    return out, {k: [remap[i] for i in ids] for k, ids in lists.items()}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--one", nargs=3, metavar=("PASS", "KIND", "FILTERED"))
    ap.add_argument("--passes", default="", help="comma list (default: every core pass)")
    a = ap.parse_args(argv)
    if a.one:
        print(json.dumps(record_one(a.one[0], a.one[1], a.one[2] == "1")))
        return 0
    from penumbra.core import methods as method_registry
    from penumbra.core.compile_ahead import PLAN_FILE, plan_key
    passes = a.passes.split(",") if a.passes else method_registry.pass_ids(external=False)
    jobs = [(p, k, f) for p in passes for k in KINDS for f in (True, False)]
    items, index, lists = [], {}, {}
    with concurrent.futures.ThreadPoolExecutor(a.jobs) as pool:
        for (p, k, f), rows in pool.map(_run_one, jobs):
            ids = []
            for name, sig in rows:
                if (name, sig) not in index:
                    index[(name, sig)] = len(items)
                    items.append([name, sig])
                ids.append(index[(name, sig)])
            lists[plan_key(p, k, f)] = ids
            print(f"{plan_key(p, k, f)}: {len(ids)} kernels", file=sys.stderr)
    items, lists = merged_signatures(items, lists)
    import numba
    with open(PLAN_FILE, "w") as f:
        json.dump({"numba": numba.__version__, "items": items, "lists": dict(sorted(lists.items()))}, f,
                  indent=0, separators=(",", ":"))
        f.write("\n")
    print(f"wrote {PLAN_FILE}: {len(items)} kernels, {len(lists)} lists", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
