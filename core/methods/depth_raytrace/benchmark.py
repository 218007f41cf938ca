"""The paper's figure 10 (middle) for ``depth_raytrace`` as a table: the
tracing time without the accelerations of 5.1.1-5.1.2, with them, and with
them plus the coherent sampling of 5.2, against the ``embree`` reference.
"""
from __future__ import annotations

import time
from dataclasses import replace
from typing import List, Sequence

import numpy as np

from ..embree_ref import EmbreeReference
from . import DepthRaytrace, DepthRaytraceParams

NO_ACCEL = dict(hierarchical_connectedness=False, minmax_clipping=False, rank_images=False,
                clear_miss=False, occlusion_intervals=False, coherence=False)
ACCEL = dict(coherence=False)
ACCEL_COHERENCE = dict()


def benchmark_table(buffers, light, sample_counts: Sequence[int] = (64, 256, 1024), seed: int = 0,
                    configs=None, embree: bool = True, embree_coherent: bool = False,
                    repeats: int = 1) -> List[dict]:
    """Figure 10 (middle): per sample count, the tracing time without the
    accelerations, with them, and with them plus coherence; rays per pixel;
    speed-ups; and the ``embree`` reference's time at the same count.
    Reference maps are built once (they do not depend on the sample count)
    and their time reported separately. Times are wall seconds, the best of
    ``repeats`` (warm JIT: call once at a small size first); ``*_cpu_s`` is
    the process CPU time of the last repeat (all threads), a figure that a
    machine shared with other work disturbs less."""
    m = DepthRaytrace()
    configs = configs or {"no_accel": NO_ACCEL, "accel": ACCEL, "accel_coherence": ACCEL_COHERENCE}
    base = DepthRaytraceParams(seed=seed)
    buffers.gbuffer
    buffers.shadow_scene
    t0 = time.perf_counter()
    maps = m.build_maps(buffers, light, base)
    t_maps = time.perf_counter() - t0
    rows = []
    ref = EmbreeReference()
    for n in sample_counts:
        row = {"samples": int(n), "precompute_s": t_maps, "pixels": int(buffers.gbuffer.hit.sum())}
        outs = {}
        for name, over in configs.items():
            p = replace(base, samples=int(n), **over)
            best = None
            for _ in range(max(1, repeats)):
                c0 = time.process_time()
                r = m.run(buffers, light, p, maps=maps)
                cpu = time.process_time() - c0
                tt = r.time_s["trace"] + r.time_s.get("order", 0.0)
                best = tt if best is None else min(best, tt)
            row[f"{name}_s"] = best
            row[f"{name}_cpu_s"] = cpu
            row[f"{name}_rays_per_pixel"] = r.stats["rays_per_pixel"]
            outs[name] = r.passes["depth_raytrace"]
        if embree:
            rp = ref.make_params({"samples": int(n), "seed": seed})
            best = None
            for _ in range(max(1, repeats)):
                c0 = time.process_time()
                rr = ref.run(buffers, light, rp)
                cpu = time.process_time() - c0
                best = rr.time_s["total"] if best is None else min(best, rr.time_s["total"])
            row["embree_s"] = best
            row["embree_cpu_s"] = cpu
            refimg = rr.passes["embree"]
            for name in outs:
                d = (outs[name].astype(np.float64) - refimg)[buffers.gbuffer.hit]
                row[f"{name}_rmse"] = float(np.sqrt(np.mean(d * d))) if d.size else 0.0
        if embree_coherent:
            p = replace(base, samples=int(n), tracer="embree")
            r = m.run(buffers, light, p)
            row["embree_coherent_s"] = r.time_s["trace"] + r.time_s.get("order", 0.0)
            row["embree_coherent_rays_per_pixel"] = r.stats["rays_per_pixel"]
        if "no_accel_s" in row and "accel_s" in row:
            row["speedup_accel"] = row["no_accel_s"] / max(row["accel_s"], 1e-12)
        if "no_accel_s" in row and "accel_coherence_s" in row:
            row["speedup_accel_coherence"] = row["no_accel_s"] / max(row["accel_coherence_s"], 1e-12)
        if "embree_s" in row:
            for name in configs:
                row[f"{name}_vs_embree"] = row["embree_s"] / max(row[f"{name}_s"], 1e-12)
                row[f"{name}_vs_embree_incl_maps"] = row["embree_s"] / max(row[f"{name}_s"] + t_maps, 1e-12)
        rows.append(row)
    return rows


def format_table(rows: List[dict]) -> str:
    """Markdown version of ``benchmark_table``'s rows."""
    head = ("| samples | no accel (s) | accel (s) | accel+coherence (s) | rays/pixel | "
            "speed-up accel | speed-up accel+coh | embree (s) | vs embree (incl. maps) |")
    lines = [head, "|" + "---|" * 9]
    for r in rows:
        lines.append("| {samples} | {a:.3f} | {b:.3f} | {c:.3f} | {rp:.1f} | {s1:.2f}x | {s2:.2f}x | {e} | {v} |".format(
            samples=r["samples"], a=r.get("no_accel_s", float("nan")), b=r.get("accel_s", float("nan")),
            c=r.get("accel_coherence_s", float("nan")), rp=r.get("accel_coherence_rays_per_pixel", float("nan")),
            s1=r.get("speedup_accel", float("nan")), s2=r.get("speedup_accel_coherence", float("nan")),
            e=f"{r['embree_s']:.3f}" if "embree_s" in r else "-",
            v=(f"{r['accel_coherence_vs_embree']:.2f}x ({r['accel_coherence_vs_embree_incl_maps']:.2f}x)"
               if "accel_coherence_vs_embree" in r else "-")))
    return "\n".join(lines)
