"""``penumbra bench``: per-phase wall times of the pipeline (issue 2's
benchmark). Medians of ``--repeats`` warm runs; thread counts stated.
Results go to ``bench/results/`` as CSV and Markdown, with the machine.
"""
from __future__ import annotations

import csv
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.abspath(__file__))


def machine() -> dict:
    import numba
    import numpy
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


def _median_time(fn, repeats):
    fn()  # warm (JIT, caches)
    times = []
    out = None
    for _ in range(repeats):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times), out


def _load(name, resolution):
    sys.path.insert(0, os.path.join(ROOT, "tests"))
    from scenes import load_sample
    return load_sample(name, resolution)


def bench_skeleton(repeats: int, quick: bool):
    """G-buffer, light depth map, pcf and embree on grids; pcf at 1920x1080."""
    import numba
    from .core.buffers import FrameBuffers
    from .core.methods import producer_of
    rows = []
    res = (128, 128) if quick else (512, 512)
    scene = _load("grids", res)
    light = scene.lights[0]
    threads_all = numba.get_num_threads()

    def fresh():
        return FrameBuffers(scene, *res)

    t, _ = _median_time(lambda: fresh().gbuffer, repeats)
    rows.append(dict(scene="grids", size=f"{res[0]}x{res[1]}", phase="gbuffer", method="", threads=threads_all,
                     samples="", seconds=t, rays_per_s=""))
    fb = fresh()
    _ = fb.gbuffer, fb.shadow_scene
    t, _ = _median_time(lambda: fb.light_view(light, key=str(time.perf_counter())), repeats)
    rows.append(dict(scene="grids", size=f"{res[0]}x{res[1]}", phase="light_view", method="", threads=threads_all,
                     samples="", seconds=t, rays_per_s=""))
    pcf = producer_of("pcf")
    t, _ = _median_time(lambda: pcf.run(fb, light, pcf.make_params({})), repeats)
    rows.append(dict(scene="grids", size=f"{res[0]}x{res[1]}", phase="pcf filter", method="pcf",
                     threads=threads_all, samples=16, seconds=t, rays_per_s=""))
    emb = producer_of("embree")
    for threads in sorted({1, threads_all}):
        numba.set_num_threads(threads)
        for ns in ((16, 64) if quick else (16, 64, 256)):
            t, r = _median_time(lambda: emb.run(fb, light, emb.make_params({"samples": ns})), repeats)
            rows.append(dict(scene="grids", size=f"{res[0]}x{res[1]}", phase="embree trace", method="embree",
                             threads=threads, samples=ns, seconds=t, rays_per_s=r.stats["rays"] / t))
    numba.set_num_threads(threads_all)
    hd = (480, 270) if quick else (1920, 1080)
    scene_hd = _load("grids", hd)
    fbh = FrameBuffers(scene_hd, *hd)
    _ = fbh.light_view(scene_hd.lights[0])
    t, _ = _median_time(lambda: pcf.run(fbh, scene_hd.lights[0], pcf.make_params({"NumSamples": 16})), repeats)
    rows.append(dict(scene="grids", size=f"{hd[0]}x{hd[1]}", phase="pcf filter", method="pcf",
                     threads=threads_all, samples=16, seconds=t, rays_per_s=""))
    return rows


_STARTUP = r"""
import time, sys
t0 = time.perf_counter()
sys.path.insert(0, {tests!r})
from synthetic import half_plane_scene, area_light
from penumbra.core.frame import render_frame
render_frame(half_plane_scene(area_light(1.0), res=32), ["pcf", "embree"], overrides={{"samples": 4}})
print(time.perf_counter() - t0)
"""


def bench_startup():
    """Cold (empty Numba cache) and warm (second process) start-up of a tiny render."""
    code = _STARTUP.format(tests=os.path.join(ROOT, "tests"))
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, PENUMBRA_NUMBA_CACHE_ROOT=cache)
        out = []
        for label in ("cold", "warm"):
            p = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
            out.append(dict(scene="synthetic 32x32", size="32x32", phase=f"start-up {label}", method="pcf+embree",
                            threads="", samples=4, seconds=float(p.stdout.strip().splitlines()[-1]), rays_per_s=""))
    return out


def write_results(rows, out_dir, name):
    os.makedirs(out_dir, exist_ok=True)
    keys = ["scene", "size", "phase", "method", "threads", "samples", "seconds", "rays_per_s"]
    with open(os.path.join(out_dir, f"{name}.csv"), "w", newline="") as f:
        w = csv.DictWriter(f, keys)
        w.writeheader()
        w.writerows(rows)
    lines = ["| " + " | ".join(keys) + " |", "|" + "---|" * len(keys)]
    for r in rows:
        cells = []
        for k in keys:
            v = r[k]
            if k == "seconds":
                v = f"{v:.4f}"
            elif k == "rays_per_s" and v != "":
                v = f"{v / 1e6:.2f} M/s"
            cells.append(str(v))
        lines.append("| " + " | ".join(cells) + " |")
    md = "\n".join(lines) + "\n"
    with open(os.path.join(out_dir, f"{name}.md"), "w") as f:
        f.write(md)
    with open(os.path.join(out_dir, "machine.json"), "w") as f:
        json.dump(machine(), f, indent=2)
    return md


def run_bench(args) -> int:
    repeats = max(1, args.repeats)
    print(f"machine: {json.dumps(machine())}")
    if args.part in ("all", "skeleton"):
        rows = bench_skeleton(repeats, args.quick) + bench_startup()
        md = write_results(rows, args.out, "skeleton")
        print(f"pipeline phases, medians of {repeats} warm runs")
        print(md)
    if args.part in ("all", "methods"):
        from .bench_methods import run_method_benchmarks
        run_method_benchmarks(args.out, repeats, args.quick)
    if args.part in ("all", "study"):
        from .study import run_study
        run_study(args.out, repeats=repeats, quick=args.quick)
    return 0
