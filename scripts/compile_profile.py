"""Where a cold start's compile time goes: one ``penumbra render``
in this process on a fresh Numba cache folder, with a listener on Numba's
``numba:compile`` events; prints each dispatcher's compile CPU (the
compiling thread's CPU time: robust on a loaded machine), self (without the
callees it compiled) and total, the Numba-internal overloads by the
Penumbra kernel that pulled them in, and the dispatchers compiled for more
than one signature (a literal argument compiles a callee once per value).

    python scripts/compile_profile.py METHODS [--scene sphere_plane] [--size 128x128] [--top 40]

METHODS as ``render --methods`` (e.g. ``layered`` or ``pcf,embree``);
``--pixel-filter`` as ``render``'s (default ``scene``, render's own default).
"""
from __future__ import annotations

import argparse
import collections
import os
import resource
import shutil
import sys
import tempfile
import threading
import time

HERE = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _name(disp) -> str:
    return f"{disp.py_func.__module__.replace('penumbra.core.', '')}:{disp.py_func.__qualname__}"


class _Listener:
    """Self and total thread CPU per dispatcher (nested compiles: a stack per thread)."""

    def __init__(self):
        self.local = threading.local()
        self.rows = collections.defaultdict(lambda: [0.0, 0.0, 0])     # self, total, compiles
        self.pulled = collections.defaultdict(float)                     # (numba overload, kernel) -> self

    def stack(self):
        if not hasattr(self.local, "s"):
            self.local.s = []
        return self.local.s

    def on_start(self, event):
        self.stack().append([time.thread_time(), 0.0, event.data["dispatcher"]])

    def on_end(self, event):
        st = self.stack()
        t0, child, disp = st.pop()
        total = time.thread_time() - t0
        name = _name(disp)
        row = self.rows[name]
        row[0] += total - child
        row[1] += total
        row[2] += 1
        if st:
            st[-1][1] += total
        if not disp.py_func.__module__.startswith("penumbra"):
            owner = next((_name(x[2]) for x in reversed(st) if x[2].py_func.__module__.startswith("penumbra")), "?")
            self.pulled[(name, owner)] += total - child


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("methods")
    ap.add_argument("--scene", default="sphere_plane")
    ap.add_argument("--size", default="128x128")
    ap.add_argument("--top", type=int, default=40)
    ap.add_argument("--pixel-filter", default="scene", help="as render's (default scene)")
    a = ap.parse_args(argv)
    root = tempfile.mkdtemp(prefix="penumbra-cold-")
    os.environ["PENUMBRA_NUMBA_CACHE_ROOT"] = root
    os.environ.pop("NUMBA_CACHE_DIR", None)
    try:
        return _profile(a)
    finally:
        shutil.rmtree(root, ignore_errors=True)


def _profile(a) -> int:
    from numba.core import event

    lst = _Listener()
    listener = type("L", (event.Listener,), {"on_start": lambda s, e: lst.on_start(e),
                                              "on_end": lambda s, e: lst.on_end(e)})()
    event.register("numba:compile", listener)
    from penumbra.cli import main as cli_main
    from penumbra.core.warmup import _dispatchers
    r0, t0 = resource.getrusage(resource.RUSAGE_SELF), time.perf_counter()
    with tempfile.TemporaryDirectory() as out:
        rc = cli_main(["render", os.path.join(HERE, "sample_blends", f"{a.scene}.blend"), "--out", out,
                       "--methods", a.methods, "--resolution", a.size, "--samples", "64", "--seed", "0",
                       "--no-previews", "--quiet", "--force", "--pixel-filter", a.pixel_filter])
    r1 = resource.getrusage(resource.RUSAGE_SELF)
    cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
    total = sum(r[0] for r in lst.rows.values())
    print(f"exit {rc}; wall {time.perf_counter() - t0:.2f} s, CPU {cpu:.2f} s, compile CPU {total:.2f} s, "
          f"load {os.getloadavg()[0]:.1f}")
    print(" self s  total s  compiles  dispatcher")
    for name, (s, t, c) in sorted(lst.rows.items(), key=lambda kv: -kv[1][0])[:a.top]:
        print(f"{s:7.2f}  {t:7.2f}  {c:8d}  {name}")
    print("\nNumba-internal overloads, by the kernel that pulled them in (self s):")
    for (name, owner), s in sorted(lst.pulled.items(), key=lambda kv: -kv[1])[:a.top // 2]:
        print(f"{s:7.2f}  {name}  <- {owner}")
    print("\nDispatchers compiled for several signatures:")
    for k, d in sorted(_dispatchers().items()):
        if len(d.signatures) > 1:
            print(f"  {k.replace('penumbra.core.', '')}: {len(d.signatures)}")
            for sig in d.signatures:
                print(f"      {sig}")
    return rc


if __name__ == "__main__":
    sys.exit(main())
