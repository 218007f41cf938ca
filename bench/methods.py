"""Per-method benchmark tables, run by ``penumbra bench --part methods``.

Each table sets a method's switches (the paper's accelerations, its
departures) side by side on the sample scenes, most against ``embree``;
all times are medians of ``repeats`` warm runs (JIT compiled, shared
buffers built) in seconds, with the per-phase split each method reports.
Written to ``bench/results/methods.md``.
"""
from __future__ import annotations

import copy
import os
import statistics
import time
from typing import Callable, Dict, List

import numba

from ..core.buffers import FrameBuffers
from ..core.methods import producers
from .harness import load_sample, median_run


def _phases(res):
    return ", ".join(f"{k} {v:.3f}" for k, v in res.time_s.items() if k != "total")


def _scaled(light, scale: float):
    """A copy of an area ``light`` with each side ``scale`` times as long."""
    lt = copy.copy(light)
    lt.size *= scale
    lt.size_y *= scale
    return lt


class Tables:
    """What the tables share: the registry, the run sizes, and the ``embree``
    time of each case (measured once, compared against by several tables)."""

    def __init__(self, repeats: int, quick: bool):
        self.repeats = repeats
        self.quick = quick
        self.big = 128 if quick else 512          # the side of the "512x512" tables
        self.reg = producers()
        self._embree: Dict[tuple, float] = {}

    def buffers(self, name: str, res: int, map_size=None):
        """Sample scene ``name`` at res x res and its buffers, G-buffer built."""
        sc = load_sample(name, (res, res))
        fb = FrameBuffers(sc, res, res, map_size)
        fb.gbuffer
        return sc, fb

    def embree_time(self, key, fb, light, ns: int) -> float:
        if key not in self._embree:
            emb = self.reg["embree"]
            self._embree[key] = median_run(lambda: emb.run(fb, light, emb.make_params({"samples": ns})),
                                           self.repeats)[0]
        return self._embree[key]


def single_sample_table(tb: Tables) -> List[str]:
    m = tb.reg["single_sample"]
    lines = ["## single_sample (Brabec & Seidel): 512x512, 256x256 light map", "",
             "| scene | adaptive | search off | speed-up | pixels searched |", "|---|---|---|---|---|"]
    for name in ("grids", "torus_plane", "foliage"):
        sc, fb = tb.buffers(name, tb.big, tb.big // 2)
        lt = sc.lights[0]
        ta, ra = median_run(lambda: m.run(fb, lt, m.make_params({"adaptive": True})), tb.repeats)
        tf, _ = median_run(lambda: m.run(fb, lt, m.make_params({"adaptive": False})), tb.repeats)
        lines.append(f"| {name} | {ta:.4f} | {tf:.4f} | {tf / ta:.2f}x | "
                     f"{100 * ra.stats.get('searched_fraction', 0):.1f}% |")
    return lines


def layered_table(tb: Tables) -> List[str]:
    m = tb.reg["layered"]
    lines = ["## layered (Agrawala et al. 4): 512x512 output, 256x256 maps", "",
             "| scene | samples | precompute | display | depth complexity |", "|---|---|---|---|---|"]
    for name in ("grids", "torus_plane", "foliage"):
        sc, fb = tb.buffers(name, tb.big, tb.big // 2)
        lt = sc.lights[0]
        for ns in ((16, 64) if tb.quick else (64, 256)):
            t, r = median_run(lambda: m.run(fb, lt, m.make_params({"samples": ns})), tb.repeats)
            ph = r.time_s
            pre = sum(v for k, v in ph.items() if k not in ("total", "display"))
            lines.append(f"| {name} | {ns} | {pre:.3f} | {ph.get('display', float('nan')):.4f} | "
                         f"{r.stats.get('depth_complexity', float('nan')):.3f} |")
    return lines


def depth_raytrace_table(tb: Tables) -> List[str]:
    m = tb.reg["depth_raytrace"]
    lines = ["## depth_raytrace (Agrawala et al. 5, figure 10 middle): 512x512, grids and sun_pillars "
             "(thin pillars under a 4-degree sun)", "",
             "| scene | samples | no accel | accel | accel + coherence | rays/pixel | embree | speed-up vs embree |",
             "|---|---|---|---|---|---|---|---|"]
    cases = [("grids", (16, 64) if tb.quick else (64, 256, 1024)), ("sun_pillars", (16,) if tb.quick else (64, 256))]
    for name, counts in cases:
        sc, fb = tb.buffers(name, tb.big)
        lt = sc.lights[0]
        for ns in counts:
            none = {"samples": ns, "coherence": False, "hierarchical_connectedness": False, "minmax_clipping": False,
                    "rank_images": False, "clear_miss": False, "occlusion_intervals": False}
            acc = {"samples": ns, "coherence": False}
            coh = {"samples": ns, "coherence": True}
            t0, _ = median_run(lambda: m.run(fb, lt, m.make_params(none)), 1 if ns > 256 else tb.repeats)
            t1, _ = median_run(lambda: m.run(fb, lt, m.make_params(acc)), tb.repeats)
            t2, r2 = median_run(lambda: m.run(fb, lt, m.make_params(coh)), tb.repeats)
            te = tb.embree_time((name, tb.big, ns), fb, lt, ns)
            lines.append(f"| {name} | {ns} | {t0:.3f} | {t1:.3f} | {t2:.3f} | "
                         f"{r2.stats.get('rays_per_pixel', float('nan')):.1f} | {te:.3f} | {te / t2:.2f}x |")
    return lines


def penumbra_casting_table(tb: Tables) -> List[str]:
    m = tb.reg["penumbra_casting"]
    lines = ["## penumbra_casting (Laine & Aila, table 2 shape): grids", "",
             "Blockers: `polygons` = coplanar triangles cast as one convex polygon (the default, paper "
             "section 5); `triangles` = the paper's per-triangle algorithm (`coplanar_blockers` off).", "",
             "| case | blockers | time | phases | peak mask MB | embree | embree / casting |",
             "|---|---|---|---|---|---|---|"]
    cases = [(64, 64, 1.0), (128, 64, 1.0)] if tb.quick else [(256, 256, 1.0), (512, 256, 1.0), (1024, 256, 1.0),
                                                               (512, 1024, 1.0), (512, 256, 2.0)]
    for res, ns, scale in cases:
        sc, fb = tb.buffers("grids", res)
        lt = sc.lights[0] if scale == 1.0 else _scaled(sc.lights[0], scale)
        te = tb.embree_time(("grids", res, ns, scale), fb, lt, ns)
        for merged in (True, False):
            prm = m.make_params({"samples": ns, "coplanar_blockers": merged})
            t, r = median_run(lambda: m.run(fb, lt, prm), 1 if res >= 1024 or ns > 256 else tb.repeats)
            kind = f"{r.stats['blockers']} {'polygons' if merged else 'triangles'}"
            lines.append(f"| {res}^2, {ns} spp{', light x4 area' if scale != 1 else ''} | {kind} | {t:.3f} | "
                         f"{_phases(r)} | {r.stats.get('peak_mask_bytes', 0) / 2**20:.1f} | {te:.3f} | "
                         f"{te / t:.2f}x |")
    return lines + alpha_cards_rows(tb, m)


def _interleaved(fns: Dict[str, Callable], repeats: int):
    """{name: (median wall s, median CPU s (user + sys, all threads), last
    output)} of ``repeats`` warm calls of each of ``fns``, interleaved (one
    of each per round, so a change in the machine's load hits all alike)."""
    for fn in fns.values():
        fn()
    wall: Dict[str, List[float]] = {k: [] for k in fns}
    cpu: Dict[str, List[float]] = {k: [] for k in fns}
    out = {}
    for _ in range(repeats):
        for k, fn in fns.items():
            c, t = time.process_time(), time.perf_counter()
            out[k] = fn()
            wall[k].append(time.perf_counter() - t)
            cpu[k].append(time.process_time() - c)
    return {k: (statistics.median(wall[k]), statistics.median(cpu[k]), out[k]) for k in fns}


def alpha_cards_rows(tb: Tables, m) -> List[str]:
    """penumbra_casting with alpha-matte blockers against embree on
    leaf_cards at 960x540 and 1920x1080 (quick: 480x270), 64 spp: the
    paper's texture fetch (default) and Embree rays through the mattes
    (``alpha_fetch`` off), interleaved runs, wall and CPU time, and the load
    average the row ran under."""
    ns = 64
    lines = ["", "leaf_cards (alpha mattes on {} shadow-casting triangles; matte blockers after the opaque "
             "ones, `alpha_blockers`; `texture fetch` = section 4's fetch at the relation-blocker intersection, "
             "the default; `Embree rays` = `alpha_fetch` off). Interleaved runs; CPU = user + sys of all threads:",
             "", "| case | matte blockers | time | CPU | phases | embree | embree CPU | embree / casting | "
             "CPU ratio |", "|---|---|---|---|---|---|---|---|---|"]
    mattes = 0
    for W, H in [(480, 270)] if tb.quick else [(960, 540), (1920, 1080)]:
        sc = load_sample("leaf_cards", (W, H))
        fb = FrameBuffers(sc, W, H)
        fb.gbuffer
        lt = sc.lights[0]
        mattes = 0 if sc.alpha is None else int((sc.alpha.tri_matte[sc.tri_casts_shadow] >= 0).sum())
        emb = tb.reg["embree"]
        pe, pf, pr = (emb.make_params({"samples": ns}), m.make_params({"samples": ns}),
                      m.make_params({"samples": ns, "alpha_fetch": False}))
        res = _interleaved({"embree": lambda: emb.run(fb, lt, pe), "texture fetch": lambda: m.run(fb, lt, pf),
                            "Embree rays": lambda: m.run(fb, lt, pr)}, tb.repeats)
        te, tce, _ = res["embree"]
        for kind in ("texture fetch", "Embree rays"):
            t, tc, r = res[kind]
            lines.append(f"| leaf_cards {W}x{H}, {ns} spp | {kind} | {t:.3f} | {tc:.3f} | {_phases(r)} | {te:.3f} | "
                         f"{tce:.3f} | {te / t:.2f}x | {tce / tc:.2f}x |")
    lines[1] = lines[1].format(mattes)
    load = ", ".join(f"{x:.1f}" for x in os.getloadavg())
    return lines + ["", f"Load average when the leaf_cards rows finished (1, 5, 15 min): {load}."]


def irregular_table(tb: Tables) -> List[str]:
    m = tb.reg["irregular"]
    lines = ["## irregular (Johnson et al.): 512x512, grids at four light sizes and foliage ("
             "overlapping occluders, the overlap C sampled or the paper's C = 0)", "",
             "| scene | light size x | silhouettes from | overlap C | time | phases |", "|---|---|---|---|---|---|"]
    cases = [("grids", scale, mode, "sampled") for scale in (0.5, 1.0, 2.0, 4.0) for mode in ("centre", "light")]
    cases += [("foliage", 1.0, "centre", "sampled"), ("foliage", 1.0, "centre", "zero")]
    scenes = {}
    for name, scale, mode, overlap in cases:
        if name not in scenes:
            scenes[name] = tb.buffers(name, tb.big)
        sc, fb = scenes[name]
        lt = _scaled(sc.lights[0], scale)
        prm = m.make_params({"silhouette_from": mode, "overlap": overlap})
        t, r = median_run(lambda: m.run(fb, lt, prm), tb.repeats)
        lines.append(f"| {name} | {scale} | {mode} | {overlap} | {t:.3f} | {_phases(r)} |")
    return lines


#: method id -> its table, in the order methods.md lists them
TABLES = {"single_sample": single_sample_table, "layered": layered_table, "depth_raytrace": depth_raytrace_table,
          "penumbra_casting": penumbra_casting_table, "irregular": irregular_table}


def run_method_benchmarks(out_dir: str, repeats: int = 3, quick: bool = False):
    """Every registered method's table into ``out_dir/methods.md`` (and stdout)."""
    tb = Tables(repeats, quick)
    lines = [f"# Per-method benchmarks (medians of {repeats} warm runs, {numba.get_num_threads()} threads)", ""]
    for mid, table in TABLES.items():
        if mid in tb.reg:
            lines += table(tb) + [""]
    text = "\n".join(lines) + "\n"
    os.makedirs(out_dir, exist_ok=True)
    with open(os.path.join(out_dir, "methods.md"), "w") as f:
        f.write(text)
    print(text)
