"""The pipeline's phases and its start-up (``--part skeleton``, ``--part startup``).

- ``bench_skeleton``: G-buffer, light depth map, the ``pcf`` filter and the
  ``embree`` trace on ``grids``, ``pcf`` at 1920x1080: ``skeleton.csv`` /
  ``skeleton.md`` beside ``machine.json``;
- ``bench_buffers``: at 1920x1080 each buffer beside raw embreex for its
  rays, and ``bench_preview``: the Preview end to end: ``buffers.csv`` /
  ``buffers.md``;
- ``bench_startup``: ``penumbra render`` per core method and all seven in
  one run from a fresh Numba cache, cold and warm: ``startup.csv`` /
  ``startup.md``.

The targets are data (the buffer rows' ``target``, ``PREVIEW_TARGET_S``,
``STARTUP_TARGETS``); each row says what it was measured against.
"""
from __future__ import annotations

import csv
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time

import numba

import numpy as np

from ..core import pixel_rays, raycast
from ..core.buffers import FrameBuffers
from ..core.methods import producer_of
from .harness import TESTS, load_sample, machine, median_run, open_sample

#: the columns of skeleton.csv / skeleton.md
COLUMNS = ["scene", "size", "phase", "method", "threads", "samples", "seconds", "rays_per_s"]
#: the columns of buffers.csv / buffers.md (each buffer beside raw Embree for its rays): wall seconds
#: and their ratio, and the same in CPU seconds (user + sys of the process: robust on a loaded machine)
BUFFER_COLUMNS = ["scene", "size", "buffer", "rays", "threads", "embree_1t_s", "seconds", "ratio", "target",
                  "embree_1t_cpu_s", "cpu_s", "cpu_ratio", "load"]
#: the scenes of the 1080p buffer table
BUFFER_SCENES = ("grids", "sphere_plane")


def bench_skeleton(repeats: int, quick: bool):
    """G-buffer, light depth map, pcf and embree on grids; pcf at 1920x1080."""
    rows = []
    res = (128, 128) if quick else (512, 512)
    scene = load_sample("grids", res)
    light = scene.lights[0]
    threads_all = numba.get_num_threads()

    def fresh():
        return FrameBuffers(scene, *res)

    t, _ = median_run(lambda: fresh().gbuffer, repeats)
    rows.append(dict(scene="grids", size=f"{res[0]}x{res[1]}", phase="gbuffer", method="", threads=threads_all,
                     samples="", seconds=t, rays_per_s=""))
    fb = fresh()
    _ = fb.gbuffer, fb.shadow_scene
    t, _ = median_run(lambda: fb.light_view(light, key=str(time.perf_counter())), repeats)
    rows.append(dict(scene="grids", size=f"{res[0]}x{res[1]}", phase="light_view", method="", threads=threads_all,
                     samples="", seconds=t, rays_per_s=""))
    pcf = producer_of("pcf")
    t, _ = median_run(lambda: pcf.run(fb, light, pcf.make_params({})), repeats)
    rows.append(dict(scene="grids", size=f"{res[0]}x{res[1]}", phase="pcf filter", method="pcf",
                     threads=threads_all, samples=16, seconds=t, rays_per_s=""))
    emb = producer_of("embree")
    for threads in sorted({1, threads_all}):
        numba.set_num_threads(threads)
        for ns in ((16, 64) if quick else (16, 64, 256)):
            t, r = median_run(lambda: emb.run(fb, light, emb.make_params({"samples": ns})), repeats)
            rows.append(dict(scene="grids", size=f"{res[0]}x{res[1]}", phase="embree trace", method="embree",
                             threads=threads, samples=ns, seconds=t, rays_per_s=r.stats["rays"] / t))
    numba.set_num_threads(threads_all)
    hd = (480, 270) if quick else (1920, 1080)
    scene_hd = load_sample("grids", hd)
    fbh = FrameBuffers(scene_hd, *hd)
    _ = fbh.light_view(scene_hd.lights[0])
    t, _ = median_run(lambda: pcf.run(fbh, scene_hd.lights[0], pcf.make_params({"NumSamples": 16})), repeats)
    rows.append(dict(scene="grids", size=f"{hd[0]}x{hd[1]}", phase="pcf filter", method="pcf",
                     threads=threads_all, samples=16, seconds=t, rays_per_s=""))
    return rows


def raw_embree_call(tri_scene, params, width: int, height: int, bounded: bool):
    """ONE embreex call on one thread intersecting the rays through every
    pixel centre of ``params`` with hit output (the same float32 rays the
    buffer traces, generated here, before it is timed): a function to time."""
    n = width * height
    org = np.empty((n, 3), np.float32)
    dirs = np.empty((n, 3), np.float32)
    tfar = np.empty(n, np.float32)
    pixel_rays.make_rays(params, width, height, 0, height, org, dirs, tfar)
    kw = {"dists": tfar} if bounded else {}
    return lambda: tri_scene._scene.run(org, dirs, output=1, **kw)


def raw_embree_seconds(tri_scene, params, width: int, height: int, bounded: bool, repeats: int):
    """(median wall, median CPU seconds) of ``raw_embree_call``."""
    (t, c), = wall_cpu_runs([raw_embree_call(tri_scene, params, width, height, bounded)], repeats)
    return t, c


def _cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def wall_cpu_runs(fns, repeats: int):
    """[(median wall, median CPU seconds)] of each of ``fns``, measured
    interleaved after one warm call each (``harness.median_runs``), CPU as
    the process's user + sys time."""
    for fn in fns:
        fn()
    wall = [[] for _ in fns]
    cpu = [[] for _ in fns]
    for _ in range(repeats):
        for k, fn in enumerate(fns):
            c, t = _cpu(), time.perf_counter()
            fn()
            wall[k].append(time.perf_counter() - t)
            cpu[k].append(_cpu() - c)
    return [(statistics.median(w), statistics.median(c)) for w, c in zip(wall, cpu)]


def _ratios(raw, own):
    """The row fields of a figure ``own`` (wall, CPU) beside raw embreex's ``raw``."""
    return dict(embree_1t_s=raw[0], seconds=own[0], ratio=own[0] / raw[0], embree_1t_cpu_s=raw[1], cpu_s=own[1],
                cpu_ratio=own[1] / raw[1], load=f"{os.getloadavg()[0]:.1f}")


def bench_buffers(repeats: int, quick: bool):
    """The 1080p buffer table: per scene, the camera G-buffer and each
    light's view beside raw embreex on one thread for the same rays (the
    ratio's target: 1.5), and ``pcf``'s whole time from a fresh frame
    (buffers, BVHs and filter) against the raw primary-ray time (target 4);
    each figure measured interleaved with its raw one (``wall_cpu_runs``),
    in wall and CPU seconds."""
    rows = []
    res = (480, 270) if quick else (1920, 1080)
    size = f"{res[0]}x{res[1]}"
    threads = numba.get_num_threads()
    pcf = producer_of("pcf")
    for name in BUFFER_SCENES:
        scene = load_sample(name, res)
        fb = FrameBuffers(scene, *res)
        cs = fb.camera_scene
        cam_params = raycast.camera_params(scene.camera, *res)
        raw, t = wall_cpu_runs([raw_embree_call(cs, cam_params, *res, True),
                                lambda: raycast.camera_gbuffer(scene, *res, cs)], repeats)
        rows.append(dict(scene=name, size=size, buffer="camera G-buffer", rays=res[0] * res[1], threads=threads,
                         target="<= 1.5", **_ratios(raw, t)))
        for light in scene.lights:
            if not light.casts_shadow:
                continue
            lv = fb.light_view(light)
            occ = fb.shadow_scene_for(light)
            if occ._scene is None or not lv.faces:
                continue
            calls = [raw_embree_call(occ, raycast.face_params(f), f.width, f.height, False) for f in lv.faces]
            lraw, t = wall_cpu_runs([lambda: [c() for c in calls],
                                     lambda: fb.light_view(light, key=str(time.perf_counter()))], repeats)
            rays = sum(f.width * f.height for f in lv.faces)
            rows.append(dict(scene=name, size=size, buffer=f"light view {light.name} ({len(lv.faces)} face(s))",
                             rays=rays, threads=threads, target="<= 1.5", **_ratios(lraw, t)))
        light = scene.lights[0]

        def whole_pcf():
            return pcf.run(FrameBuffers(scene, *res), light, pcf.make_params({"NumSamples": 16}))

        raw_call = raw_embree_call(cs, cam_params, *res, True)
        raw, t = wall_cpu_runs([raw_call, whole_pcf], repeats)
        rows.append(dict(scene=name, size=size, buffer=f"pcf whole ({light.name}: BVHs, buffers, filter)",
                         rays=res[0] * res[1], threads=threads, target="<= 4", **_ratios(raw, t)))
    return rows


#: the Preview's target in seconds, end to end, capture included
PREVIEW_TARGET_S = 0.25


def bench_preview(repeats: int, quick: bool, name: str = "sphere_plane"):
    """The Preview's figure: Preview (``prepare_frame`` with
    ``preview=True`` -> run -> the "Penumbra Preview" image, capture included)
    of ``name`` at 1920x1080 on an unchanged camera, warm (kernels compiled,
    the camera G-buffer kept from the Preview before), for pcf and
    single_sample, with nothing changed and with the light moved before each
    run (its view is rebuilt); beside raw embreex for the camera's rays and
    with the phases of the median run in the row's name."""
    from ..bridge import buffer_cache
    from ..bridge.images import combine, show_preview
    from ..bridge.pipeline import FrameRequest, prepare_frame
    res = (480, 270) if quick else (1920, 1080)
    rows = []
    threads = numba.get_num_threads()
    captured = load_sample(name, res)
    raw = raw_embree_seconds(raycast.TriangleScene.from_scene(captured, captured.tri_visible_camera),
                             raycast.camera_params(captured.camera, *res), *res, True, repeats)
    scene = open_sample(name)             # after load_sample, which opens the file too
    light = next(o for o in scene.objects if o.type == "LIGHT")
    for method in ("pcf", "single_sample"):
        buffer_cache.invalidate()
        for moved in (False, True):
            runs = []
            sign = [1.0]

            def preview():
                if moved:
                    light.location.x += 0.05 * sign[0]
                    sign[0] = -sign[0]
                c0, t0 = _cpu(), time.perf_counter()
                request = FrameRequest.from_scene_settings(resolution=res, preview=True, methods=[method],
                                                           references=())
                request.threads = threads
                job = prepare_frame(scene, request)
                t1 = time.perf_counter()
                job.run()
                result = job.result()
                t2 = time.perf_counter()
                show_preview(combine(result, job.captured))
                t3 = time.perf_counter()
                phases = dict(result.lights[0].record[method]["time_s"])
                runs.append((t3 - t0, t1 - t0, phases, t3 - t2, job.reused, _cpu() - c0))

            median_run(preview, repeats)
            runs = sorted(runs[1:], key=lambda r: r[0])
            total, capture, phases, write, reused, cpu = runs[len(runs) // 2]
            parts = [f"capture {capture:.3f}"] + [f"{k} {v:.3f}" for k, v in phases.items() if k != "total"]
            parts.append(f"image {write:.3f}")
            what = "light moved" if moved else "nothing changed"
            rows.append(dict(scene=name, size=f"{res[0]}x{res[1]}",
                             buffer=f"Preview {method}, {what}{'' if reused else ' (buffers NOT reused)'}: "
                                    f"{', '.join(parts)} s",
                             rays=res[0] * res[1], threads=threads, target=f"<= {PREVIEW_TARGET_S} s",
                             **_ratios(raw, (total, cpu))))
    buffer_cache.unwatch()                # prepare_frame installed the depsgraph handler
    return rows


#: the columns of startup.csv / startup.md
STARTUP_COLUMNS = ["scene", "size", "methods", "runs", "cold_s", "warm_s", "cold_minus_warm_s", "cold_minus_warm_range",
                   "one_process_cold_minus_warm_s",
                   "cold_cpu_s", "warm_cpu_s",
                   "compile_s", "target_s", "met", "load"]
#: the core methods of the start-up table and their targets (cold minus warm wall seconds; None: no target)
STARTUP_TARGETS = {"pcf": 10.0, "single_sample": 10.0, "layered": 10.0, "penumbra_casting": 15.0,
                   "irregular": 15.0, "depth_raytrace": 30.0, "embree": None}
#: all seven in one run: at most this much more than warm
STARTUP_ALL_TARGET = 60.0


def _cli_run(args, env):
    """(wall s, CPU s of the child: user + sys) of one ``penumbra`` command in a new process."""
    import resource
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    subprocess.run([sys.executable, "-c", "import sys; from penumbra.cli import main; sys.exit(main())", *args],
                   env=env, capture_output=True, text=True, check=True)
    wall = time.perf_counter() - t
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)


def bench_startup(quick: bool = False, scene: str = "sphere_plane", size: str = "128x128", repeats: int = 1,
                  methods=None):
    """The start-up table: per core method, and all seven in one run,
    ``penumbra render`` at ``size`` from a fresh Numba cache folder (cold)
    and again on the cache it left (warm), each in a new process; wall and
    CPU (user + sys, robust on a loaded machine; the helper processes'
    included) with the load average, the JSON's ``compile_s`` of the cold
    run, and the same run's baseline: cold with one compiling process
    (``PENUMBRA_COMPILE_PROCESSES=1``: no helper, ``core/compile_ahead.py``).
    ``repeats`` cold / warm / baseline runs per row, interleaved, each cold
    one on its own empty cache: the row gives their medians. ``methods``:
    the rows to run (method ids, "all" for the seven together; default every row)."""
    if methods is None:
        methods = ["pcf", "embree"] if quick else list(STARTUP_TARGETS) + ["all"]
    runs = [list(STARTUP_TARGETS) if m == "all" else [m] for m in methods]
    rows = []
    blend = os.path.join(os.path.dirname(TESTS), "sample_blends", f"{scene}.blend")
    for ms in runs:
        load = os.getloadavg()[0]
        cold, cold_cpu, warm, warm_cpu, compile_s, cold1 = ([] for _ in range(6))
        for _ in range(max(1, repeats)):
            with tempfile.TemporaryDirectory() as tmp:
                env = dict(os.environ, PENUMBRA_NUMBA_CACHE_ROOT=os.path.join(tmp, "cache"))
                env.pop("NUMBA_CACHE_DIR", None)
                env.pop("PENUMBRA_COMPILE_PROCESSES", None)
                args = ["render", blend, "--out", os.path.join(tmp, "out"), "--methods", ",".join(ms),
                        "--resolution", size, "--samples", "64", "--seed", "0", "--no-previews", "--quiet", "--force"]
                w, c = _cli_run(args, env)
                cold.append(w)
                cold_cpu.append(c)
                sidecar = next(f for f in os.listdir(os.path.join(tmp, "out")) if f.endswith(".json"))
                with open(os.path.join(tmp, "out", sidecar)) as f:
                    compile_s.append(json.load(f).get("compile_s", 0.0))
                w, c = _cli_run(args, env)
                warm.append(w)
                warm_cpu.append(c)
            with tempfile.TemporaryDirectory() as tmp:    # the same run's baseline: no helper process
                env1 = dict(env, PENUMBRA_NUMBA_CACHE_ROOT=os.path.join(tmp, "cache"),
                            PENUMBRA_COMPILE_PROCESSES="1")
                args1 = args[:args.index("--out") + 1] + [os.path.join(tmp, "out")] + args[args.index("--out") + 2:]
                cold1.append(_cli_run(args1, env1)[0])
        med = statistics.median
        target = STARTUP_TARGETS[ms[0]] if len(ms) == 1 else STARTUP_ALL_TARGET
        gap = med(cold) - med(warm)
        rows.append(dict(scene=scene, size=size, methods="all seven" if len(ms) > 1 else ms[0], runs=len(cold),
                         cold_s=med(cold), warm_s=med(warm), cold_minus_warm_s=gap,
                         cold_minus_warm_range=f"{min(cold) - med(warm):.1f}-{max(cold) - med(warm):.1f}",
                         one_process_cold_minus_warm_s=med(cold1) - med(warm), cold_cpu_s=med(cold_cpu),
                         warm_cpu_s=med(warm_cpu), compile_s=med(compile_s),
                         target_s="" if target is None else f"<= {target:g}",
                         met="" if target is None else ("yes" if gap <= target else "no"),
                         load=f"{load:.1f}-{os.getloadavg()[0]:.1f}"))
    return rows


def write_results(rows, out_dir, name, columns=COLUMNS):
    """``<name>.csv``, ``<name>.md`` and ``machine.json`` under ``out_dir``;
    returns the Markdown table."""
    os.makedirs(out_dir, exist_ok=True)
    with open(os.path.join(out_dir, f"{name}.csv"), "w", newline="") as f:
        w = csv.DictWriter(f, columns)
        w.writeheader()
        w.writerows(rows)
    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    for r in rows:
        cells = []
        for k in columns:
            v = r[k]
            if k in ("seconds", "embree_1t_s") or k.endswith("_s") and isinstance(v, float):
                v = f"{v:.4f}"
            elif k in ("ratio", "cpu_ratio"):
                v = f"{v:.2f}x"
            elif k == "rays_per_s" and v != "":
                v = f"{v / 1e6:.2f} M/s"
            elif isinstance(v, float):
                v = f"{v:.4g}"
            cells.append(str(v))
        lines.append("| " + " | ".join(cells) + " |")
    md = "\n".join(lines) + "\n"
    with open(os.path.join(out_dir, f"{name}.md"), "w") as f:
        f.write(md)
    with open(os.path.join(out_dir, "machine.json"), "w") as f:
        json.dump(machine(), f, indent=2)
    return md
