"""``penumbra bench --part filter``: what a filtered pass costs (issue 14).

Per method (pcf, penumbra_casting) on a sample scene at 1920x1080 (``--quick``:
480x270): the wall time of the pixel-centre pass (``--pixel-filter none``)
and of the adaptive filtered pass (Cycles' default Blackman-Harris 1.5 px,
4 x 4 sub-pixel samples where a footprint holds an edge), their ratio (wall
and CPU time: the machine is shared, CPU time is the steadier), and
the filtered pass's RMSE against the fully supersampled one (16 sub-pixel
samples in every pixel: every pixel refined), over the pixels that see a
surface. Medians of warm runs; the machine is recorded beside them.
"""
from __future__ import annotations

import dataclasses
import json
import os
import resource
import statistics

import numpy as np

from .harness import load_sample, machine, median_run

SCENE = "torus_plane"
METHODS = ("pcf", "penumbra_casting")
RESOLUTION = (1920, 1080)
QUICK_RESOLUTION = (480, 270)
TARGET_RATIO = 1.6
TARGET_RMSE = 0.005


def bench_pixel_filter(out_dir: str, repeats: int, quick: bool) -> str:
    """Time and measure; write ``pixel_filter.md`` / ``.json``; return the table."""
    from ..core.filtered_frame import render_filtered
    from ..core.frame import render_frame
    from ..core.pixel_filter import PixelFilter
    res = QUICK_RESOLUTION if quick else RESOLUTION
    scene = load_sample(SCENE, res)
    flt = PixelFilter("blackman-harris", 1.5)
    full = dataclasses.replace(flt, threshold=-1.0)        # every pixel refined: 16 samples each
    rows = []
    for m in METHODS:
        cpu_centre, cpu_filt = [], []
        t_centre, _ = median_run(_cpu_timed(lambda: render_frame(scene, [m]), cpu_centre), repeats)
        t_filt, r = median_run(_cpu_timed(lambda: render_filtered(scene, [m], pixel_filter=flt), cpu_filt), repeats)
        c_centre, c_filt = statistics.median(cpu_centre[1:]), statistics.median(cpu_filt[1:])   # warm runs
        ref = render_filtered(scene, [m], pixel_filter=full)
        hit = ref.coverage > 0
        errs = [float(np.sqrt(np.mean((a.passes[m].astype(np.float64) - b.passes[m])[hit] ** 2)))
                for a, b in zip(r.lights, ref.lights)]
        st = r.lights[0].record[m]["pixel_filter"]
        rows.append({"method": m, "resolution": f"{res[0]}x{res[1]}", "centre_s": round(t_centre, 3),
                     "filtered_s": round(t_filt, 3), "ratio": round(t_filt / t_centre, 3),
                     "centre_cpu_s": round(c_centre, 3), "filtered_cpu_s": round(c_filt, 3),
                     "cpu_ratio": round(c_filt / c_centre, 3),
                     "refined_pixels": st["refined_pixels"], "subpixel_samples": st["subpixel_samples"],
                     "rmse_vs_16": round(max(errs), 5)})
    head = ("method", "resolution", "centre_s", "filtered_s", "ratio", "centre_cpu_s", "filtered_cpu_s",
            "cpu_ratio", "refined_pixels", "subpixel_samples", "rmse_vs_16")
    md = "\n".join(["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
                   + ["| " + " | ".join(str(r[k]) for k in head) + " |" for r in rows])
    load = os.getloadavg()
    md += (f"\n\nscene {SCENE}, filter {flt.spec()}, threshold {flt.threshold:g} ({flt.v_test}), reach "
           f"{flt.reach} px, medians of {repeats} warm runs (wall; cpu: user + sys of the process, all "
           f"threads), {machine()['numba_threads']} Numba threads, load average at the end "
           f"{load[0]:.1f} / {load[1]:.1f} / {load[2]:.1f}; targets: ratio <= {TARGET_RATIO}, rmse_vs_16 <= "
           f"{TARGET_RMSE} (issue 14)\n")
    os.makedirs(out_dir, exist_ok=True)
    stem = os.path.join(out_dir, "pixel_filter" + ("_quick" if quick else ""))
    with open(stem + ".md", "w") as f:
        f.write(md)
    with open(stem + ".json", "w") as f:
        json.dump({"machine": machine(), "load_average": list(load), "rows": rows}, f, indent=2)
    return md


def _cpu_timed(fn, seconds: list):
    """``fn`` that appends its CPU time (user + sys, every thread) to ``seconds``."""
    def run():
        t = _cpu()
        out = fn()
        seconds.append(_cpu() - t)
        return out
    return run


def _cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime
