"""The pipeline's phases (issue 2's benchmark, ``--part skeleton``): G-buffer,
light depth map, the ``pcf`` filter and the ``embree`` trace on ``grids``,
``pcf`` at 1920x1080, and the start-up of a tiny render with a cold and a warm
Numba cache. Written as ``skeleton.csv`` / ``skeleton.md`` beside
``machine.json``; the 1080p buffer table (issue 15: each buffer beside raw
embreex for its rays, ``bench_buffers``, and the Preview end to end,
``bench_preview``) as ``buffers.csv`` / ``buffers.md``.
"""
from __future__ import annotations

import csv
import json
import os
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
#: the columns of buffers.csv / buffers.md (issue 15: buffers at Embree's cost)
BUFFER_COLUMNS = ["scene", "size", "buffer", "rays", "threads", "embree_1t_s", "seconds", "ratio", "target"]
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


def raw_embree_seconds(tri_scene, params, width: int, height: int, bounded: bool, repeats: int) -> float:
    """Median seconds of ONE embreex call on one thread intersecting the
    rays through every pixel centre of ``params`` with hit output (the same
    float32 rays the buffer traces, generated beforehand and not timed)."""
    n = width * height
    org = np.empty((n, 3), np.float32)
    dirs = np.empty((n, 3), np.float32)
    tfar = np.empty(n, np.float32)
    pixel_rays.make_rays(params, width, height, 0, height, org, dirs, tfar)
    kw = {"dists": tfar} if bounded else {}
    t, _ = median_run(lambda: tri_scene._scene.run(org, dirs, output=1, **kw), repeats)
    return t


def bench_buffers(repeats: int, quick: bool):
    """Issue 15's 1080p buffer table: per scene, the camera G-buffer and each
    light's view beside raw embreex on one thread for the same rays (the
    ratio's target: 1.5), and ``pcf``'s whole time from a fresh frame
    (buffers, BVHs and filter) against the raw primary-ray time (target 4)."""
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
        raw = raw_embree_seconds(cs, cam_params, *res, True, repeats)
        t, _ = median_run(lambda: raycast.camera_gbuffer(scene, *res, cs), repeats)
        rows.append(dict(scene=name, size=size, buffer="camera G-buffer", rays=res[0] * res[1], threads=threads,
                         embree_1t_s=raw, seconds=t, ratio=t / raw, target="<= 1.5"))
        for light in scene.lights:
            if not light.casts_shadow:
                continue
            lv = fb.light_view(light)
            occ = fb.shadow_scene_for(light)
            if occ._scene is None or not lv.faces:
                continue
            lraw = sum(raw_embree_seconds(occ, raycast.face_params(f), f.width, f.height, False, repeats)
                       for f in lv.faces)
            t, _ = median_run(lambda: fb.light_view(light, key=str(time.perf_counter())), repeats)
            rays = sum(f.width * f.height for f in lv.faces)
            rows.append(dict(scene=name, size=size, buffer=f"light view {light.name} ({len(lv.faces)} face(s))",
                             rays=rays, threads=threads, embree_1t_s=lraw, seconds=t, ratio=t / lraw,
                             target="<= 1.5"))
        light = scene.lights[0]

        def whole_pcf():
            return pcf.run(FrameBuffers(scene, *res), light, pcf.make_params({"NumSamples": 16}))

        t, _ = median_run(whole_pcf, repeats)
        rows.append(dict(scene=name, size=size, buffer=f"pcf whole ({light.name}: BVHs, buffers, filter)",
                         rays=res[0] * res[1], threads=threads, embree_1t_s=raw, seconds=t, ratio=t / raw,
                         target="<= 4"))
    return rows


#: the Preview's target, end to end (issue 15: "at most 0.25 s ... capture included")
PREVIEW_TARGET_S = 0.25


def bench_preview(repeats: int, quick: bool, name: str = "sphere_plane"):
    """Issue 15's Preview figure: Preview (``prepare_frame`` with
    ``fast=True`` -> run -> the "Penumbra Preview" image, capture included)
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
                t0 = time.perf_counter()
                job = prepare_frame(scene, FrameRequest(resolution=res, fast=True, methods=[method], references=(),
                                                        threads=threads))
                t1 = time.perf_counter()
                job.run()
                result = job.result()
                t2 = time.perf_counter()
                show_preview(combine(result, job.captured))
                t3 = time.perf_counter()
                phases = dict(result.lights[0].record[method]["time_s"])
                runs.append((t3 - t0, t1 - t0, phases, t3 - t2, job.reused))

            median_run(preview, repeats)
            runs = sorted(runs[1:], key=lambda r: r[0])
            total, capture, phases, write, reused = runs[len(runs) // 2]
            parts = [f"capture {capture:.3f}"] + [f"{k} {v:.3f}" for k, v in phases.items() if k != "total"]
            parts.append(f"image {write:.3f}")
            what = "light moved" if moved else "nothing changed"
            rows.append(dict(scene=name, size=f"{res[0]}x{res[1]}",
                             buffer=f"Preview {method}, {what}{'' if reused else ' (buffers NOT reused)'}: "
                                    f"{', '.join(parts)} s",
                             rays=res[0] * res[1], threads=threads, embree_1t_s=raw, seconds=total,
                             ratio=total / raw, target=f"<= {PREVIEW_TARGET_S} s"))
    buffer_cache.unwatch()                # prepare_frame installed the depsgraph handler
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
    code = _STARTUP.format(tests=TESTS)
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, PENUMBRA_NUMBA_CACHE_ROOT=cache)
        out = []
        for label in ("cold", "warm"):
            p = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
            out.append(dict(scene="synthetic 32x32", size="32x32", phase=f"start-up {label}", method="pcf+embree",
                            threads="", samples=4, seconds=float(p.stdout.strip().splitlines()[-1]), rays_per_s=""))
    return out


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
            if k in ("seconds", "embree_1t_s"):
                v = f"{v:.4f}"
            elif k == "ratio":
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
