"""What every part of ``penumbra bench`` shares: the repository root, the
sample scenes (captured through ``tests/scenes.py``), the machine the numbers
were measured on, and the median of warm runs.
"""
from __future__ import annotations

import os
import platform
import statistics
import sys
import time

import numba
import numpy

#: the repository (and package) root: bench/ sits directly under it
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TESTS = os.path.join(ROOT, "tests")


def cache_dir(*parts: str) -> str:
    """``<cache>/penumbra/<parts...>``: ``$XDG_CACHE_HOME`` or ``~/.cache``
    (what the benchmark builds or renders once and keeps between runs)."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "penumbra", *parts)


def load_sample(name: str, resolution):
    """``sample_blends/<name>.blend`` captured at ``resolution`` (W, H), as the
    tests capture it (cached per name and resolution)."""
    if TESTS not in sys.path:
        sys.path.insert(0, TESTS)
    from scenes import load_sample as capture    # tests/scenes.py: not a package
    return capture(name, tuple(resolution))


def open_sample(name: str):
    """``sample_blends/<name>.blend`` opened in bpy (its scene), as the tests open it."""
    if TESTS not in sys.path:
        sys.path.insert(0, TESTS)
    from scenes import open_sample as open_blend    # tests/scenes.py: not a package
    return open_blend(name)


def machine() -> dict:
    """CPU, core count, library versions and Numba threads, with the date."""
    cpu = platform.processor() or ""
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    return {"cpu": cpu, "cores": os.cpu_count(), "python": platform.python_version(),
            "numpy": numpy.__version__, "numba": numba.__version__,
            "numba_threads": numba.get_num_threads(), "date": time.strftime("%Y-%m-%d")}


def median_run(fn, repeats: int):
    """``(median seconds, output)`` of ``repeats`` calls of ``fn`` after one
    warm call (JIT, caches); the output is the last call's."""
    fn()
    times = []
    out = None
    for _ in range(repeats):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times), out


def median_runs(fns, repeats: int):
    """Median seconds of each of ``fns``, measured interleaved (round i calls
    every fn once, in turn) after one warm call each, so a change of the
    machine's load hits all of them alike."""
    for fn in fns:
        fn()
    times = [[] for _ in fns]
    for _ in range(repeats):
        for k, fn in enumerate(fns):
            t = time.perf_counter()
            fn()
            times[k].append(time.perf_counter() - t)
    return [statistics.median(ts) for ts in times]
