"""``penumbra bench --part filter``: what a filtered pass costs.

Per method (``METHODS``: pcf, penumbra_casting, embree_irr at their defaults)
on the sample scenes ``SCENES`` (or those ``--study-scenes`` names) at
1920x1080 (``--quick``: 480x270): the wall time of the pixel-centre pass
(``--pixel-filter none``) and of the adaptive filtered pass (Cycles' default
Blackman-Harris 1.5 px, 4 x 4 sub-pixel receivers where a footprint holds an
edge, sharing the pixel's light samples), their ratio (wall and CPU time: on a
shared machine CPU time is the steadier), the filtered pass's time over the
camera's raw primary rays (the pixel-centre frame's ``gbuffer`` phase: one
Embree ray per pixel), and the filtered pass's RMSE against the fully
supersampled one (16 sub-pixel receivers in every pixel), over the pixels that
see a surface (the two draw different light samples, so it holds both
passes' noise). The two passes are timed interleaved (medians of warm
rounds), so a change of the machine's load hits both alike; the machine and
the load are recorded beside them. A row meets its method's ``TARGETS``.
"""
from __future__ import annotations

import dataclasses
import json
import os
import resource
import statistics
import time

import numpy as np

from .harness import load_sample, machine

SCENES = ("torus_plane", "sphere_plane", "foliage", "leaf_cards")
METHODS = ("pcf", "penumbra_casting", "embree_irr")
#: scenes where penumbra_casting is not measured: its pass refined everywhere (16
#: sub-pixel receivers per pixel, 33 M at 1080p) is too slow a reference on their geometry
NO_PENUMBRA_CASTING = ("foliage", "leaf_cards")
RESOLUTION = (1920, 1080)
QUICK_RESOLUTION = (480, 270)
#: per method, the most a ratio may be (cpu_ratio: filtered / pixel-centre CPU
#: time; vs_primary: filtered wall time / the raw primary rays' wall time)
TARGETS = {"pcf": {"vs_primary": 4.0}, "penumbra_casting": {"cpu_ratio": 1.6}, "embree_irr": {"cpu_ratio": 1.5}}
HEAD = ("scene", "method", "resolution", "centre_s", "filtered_s", "ratio", "centre_cpu_s", "filtered_cpu_s",
        "cpu_ratio", "primary_s", "vs_primary", "refined_pixels", "subpixel_samples", "rmse_vs_16", "met")


def bench_pixel_filter(out_dir: str, repeats: int, quick: bool, scenes=SCENES) -> str:
    """Time and measure; write ``pixel_filter.md`` / ``.json``; return the table."""
    from ..core.filtered_frame import render_filtered
    from ..core.frame import render_frame
    from ..core.pixel_filter import PixelFilter
    res = QUICK_RESOLUTION if quick else RESOLUTION
    flt = PixelFilter("blackman-harris", 1.5)
    full = dataclasses.replace(flt, threshold=-1.0)        # every pixel refined: 16 samples each
    rows = []
    loads = [os.getloadavg()[0]]
    for name in scenes:
        scene = load_sample(name, res)
        for m in METHODS:
            if m == "penumbra_casting" and name in NO_PENUMBRA_CASTING:
                continue
            wall, cpu = _interleaved([lambda: render_frame(scene, [m]),
                                      lambda: render_filtered(scene, [m], pixel_filter=flt)], repeats)
            r = render_filtered(scene, [m], pixel_filter=flt)
            primary = render_frame(scene, [m]).lights[0].record[m]["time_s"]["gbuffer"]
            ref = render_filtered(scene, [m], pixel_filter=full)
            hit = ref.coverage > 0
            err = max(float(np.sqrt(np.mean((a.passes[m].astype(np.float64) - b.passes[m])[hit] ** 2)))
                      for a, b in zip(r.lights, ref.lights))
            st = r.lights[0].record[m]["pixel_filter"]
            row = {"scene": name, "method": m, "resolution": f"{res[0]}x{res[1]}",
                   "centre_s": round(wall[0], 3), "filtered_s": round(wall[1], 3),
                   "ratio": round(wall[1] / wall[0], 3), "centre_cpu_s": round(cpu[0], 3),
                   "filtered_cpu_s": round(cpu[1], 3), "cpu_ratio": round(cpu[1] / cpu[0], 3),
                   "primary_s": round(primary, 3), "vs_primary": round(wall[1] / max(primary, 1e-9), 2),
                   "refined_pixels": st["refined_pixels"], "subpixel_samples": st["subpixel_samples"],
                   "rmse_vs_16": round(err, 5)}
            row["met"] = "yes" if all(row[k] <= v for k, v in TARGETS[m].items()) else "no"
            rows.append(row)
            loads.append(os.getloadavg()[0])
    md = "\n".join(["| " + " | ".join(HEAD) + " |", "|" + "---|" * len(HEAD)]
                   + ["| " + " | ".join(str(r[k]) for k in HEAD) + " |" for r in rows])
    targets = "; ".join(f"{m}: " + " and ".join(f"{k} <= {v:g}" for k, v in t.items()) for m, t in TARGETS.items())
    md += (f"\n\nfilter {flt.spec()}, threshold {flt.threshold:g}, reach {flt.reach} px; each method at its "
           f"defaults; pixel-centre and filtered runs interleaved, medians of {repeats} warm rounds (wall; cpu: "
           f"user + sys of the process, all threads; primary_s: the pixel-centre frame's gbuffer phase; met: "
           f"{targets}), {machine()['numba_threads']} Numba threads, 1-minute load average "
           f"{min(loads):.1f}-{max(loads):.1f}\n")
    os.makedirs(out_dir, exist_ok=True)
    stem = os.path.join(out_dir, "pixel_filter" + ("_quick" if quick else ""))
    with open(stem + ".md", "w") as f:
        f.write(md)
    with open(stem + ".json", "w") as f:
        json.dump({"machine": machine(), "load_average": loads, "rows": rows}, f, indent=2)
    return md


def _interleaved(fns, repeats: int):
    """(median wall seconds, median CPU seconds) of each of ``fns``, measured
    interleaved after one warm call each (``harness.median_runs``'s rounds)."""
    for fn in fns:
        fn()
    wall = [[] for _ in fns]
    cpu = [[] for _ in fns]
    for _ in range(max(1, repeats)):
        for k, fn in enumerate(fns):
            t, c = time.perf_counter(), _cpu()
            fn()
            cpu[k].append(_cpu() - c)
            wall[k].append(time.perf_counter() - t)
    return [statistics.median(w) for w in wall], [statistics.median(c) for c in cpu]


def _cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime
