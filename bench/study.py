"""The accuracy-versus-time study (``--part study``): every method and quality knob on
the sample scenes at two resolutions, against the compositing truth.

The truth is Cycles' shadow ratio (the light's Diffuse Direct with its shadow
over the same without it) at ``truth.TRUTH_SAMPLES``, filtered like the
scene renders (``bench/truth.py``). Every method runs as ``penumbra render``
runs it by default: the irradiance ratio, filtered like the render
(``filtered_frame.render_filtered``). For each run: the median wall time of
the frame over ``repeats`` warm runs, and its error against the truth over
the pixels the light reaches (RMSE, max abs, mean signed, RMSE inside the
truth's penumbra 0.02 < V < 0.98) and over the silhouette pixels (those whose
filter footprint holds an edge of the geometry). Cycles' own pair at fewer
samples is measured beside them, in the same run (method ``cycles``).
Output under ``bench/results/``: ``study.csv`` (every run), ``study.md``,
``pareto_<scene>.png`` (error vs time, log axes, Pareto front),
``sheet_<scene>.png`` (passes and error images), ``auto_table.json`` (what
the planner's ``auto`` reads). A method that fails a scene is recorded as
failed, not dropped.
"""
from __future__ import annotations

import csv
import json
import os
import statistics
import sys
import time
import traceback
from typing import Dict, List

import numba
import numpy as np

from ..core import auto_choice
from ..core import methods as registry
from ..core.buffers import FrameBuffers
from ..core.methods.base import DEFAULT_LIGHT_SAMPLES
from ..core.filtered_frame import render_filtered
from ..core.metrics import errors, reach_mask
from .harness import ROOT, load_sample, open_sample
from .truth import TRUTH_SAMPLES, cycles_pair, cycles_truth

#: Cycles' own pair beside the methods: its samples (the truth's noise at each)
CYCLES_SAMPLES = (16, 64, 256)
QUICK_TRUTH_SAMPLES = 128
SCENES = ("grids", "sphere_plane", "torus_plane", "foliage", "sun_pillars", "leaf_cards")
#: per scene, the two sizes a full run measures (the larger one is the Pareto
#: plot's, the contact sheet's and the auto table's); small, so a full run of
#: every scene stays affordable on a 2-core machine (README "Accuracy versus time")
SIZES = {name: ((128, 128), (256, 256)) for name in SCENES}
QUICK_SIZES = ((48, 48), (64, 64))

# method id -> list of (label, params) or (label, params, light kinds it runs
# for). The knobs each paper names; "paper:" rows are the paper's version
# where a default departs from it, so the study shows both. The entry whose
# params are {} or {"samples": 256} is the method's default (``default_setting``);
# the first entry is the contact sheet's. Variants of a sampling method run at
# 64 samples, beside its samples=64 row.
SWEEPS: Dict[str, List] = {
    # the default: the filter region from the light's size at the mean blocker depth (PCSS-like);
    # the paper's figure-4 region behind region="figure4"
    "pcf": [("light region, PenumbraSamples=64", {}),
            ("light region, PenumbraSamples=16", {"PenumbraSamples": 16}),
            ("light region, map 2x", {"map_scale": 2.0}),
            ("light region, every pixel filtered (pixel_step=1)", {"pixel_step": 1}),
            ("paper: figure-4 region, NumSamples=16 ResFactor=3", {"region": "figure4"}),
            ("paper: figure-4 region, ResFactor=8", {"region": "figure4", "ResFactor": 8.0}),
            ("paper: figure-4 region, receiver_plane off", {"region": "figure4", "receiver_plane": False})],
    "embree": [(f"samples={n}", {"samples": n}) for n in (256, 4, 16, 64)],
    # the defaults: every blocker texel's light summed, ids = connected mesh pieces, no
    # adaptive sampling (section 4.3's interpolation is made for a ramp), V x the light above
    # the receiver's tangent plane (horizon)
    "single_sample": [("sum of blockers, mesh pieces", {}),
                      ("sum of blockers, mesh pieces, no horizon", {"horizon": False}),
                      ("sum of blockers, mesh pieces, adaptive", {"adaptive": True}),
                      ("map 2x", {"map_scale": 2.0}),
                      ("paper radius knobs", {"auto_radius": False}),
                      # the paper's one blocker per pixel on object ids (adaptive, section 4.3)
                      ("paper: nearest blocker, object ids, adaptive", {"blocker": "nearest", "surfaces": "object",
                                                                         "horizon": False})],
    # the default: the footprint splat and the bilinear display (the paper's 4-neighbour splat and
    # nearest pixel on surfaces steeper than steep_slope), ids = connected mesh pieces
    "layered": [("samples=256", {"samples": 256}), ("samples=16", {"samples": 16}), ("samples=64", {"samples": 64}),
                ("nearest LDI pixel", {"samples": 64, "bilinear": False}),
                ("footprint splat, bilinear everywhere", {"samples": 64, "steep_slope": float("inf")}),
                ("paper: 4-neighbour splat, nearest pixel, object ids",
                 {"samples": 64, "splat": "neighbours", "bilinear": False, "surfaces": "object"})],
    "depth_raytrace": [("samples=256", {"samples": 256}), ("samples=16", {"samples": 16}),
                       ("samples=64", {"samples": 64}), ("no coherence", {"samples": 64, "coherence": False})],
    "penumbra_casting": [("samples=256", {"samples": 256}), ("samples=16", {"samples": 16}),
                         ("samples=64", {"samples": 64}),
                         # the paper's per-triangle blockers (no coplanar polygons, no interior slices)
                         ("paper: triangles", {"samples": 64, "coplanar_blockers": False,
                                               "interior_blockers": False})],
    "irregular": [("silhouettes from centre", {}), ("overlap C=0 (paper)", {"overlap": "zero"}),
                  ("silhouettes from light", {"silhouette_from": "light"}),
                  # V at most the light above the receiver's tangent plane (not the default)
                  ("silhouettes from centre, horizon", {"horizon": True})],
}


def sweep(mid: str, light_kind: str = None) -> List[tuple]:
    """``(label, params)`` of ``mid``'s sweep for a light of ``light_kind``
    (None: every entry)."""
    return [(e[0], e[1]) for e in SWEEPS.get(mid, ())
            if light_kind is None or len(e) < 3 or light_kind in e[2]]


def _apply(method, params: dict, buffers):
    """Params for ``method`` from a sweep entry; ``map_scale`` multiplies the
    default map size (the output's larger side)."""
    p = dict(params)
    scale = p.pop("map_scale", None)
    fields = {f for f in method.Params.__dataclass_fields__}
    if scale is not None and "map_size" in fields:
        p["map_size"] = int(scale * max(buffers.width, buffers.height))
    unknown = [k for k in p if k not in fields]
    return method.make_params(p), unknown


def run_study(out_dir: str, repeats: int = 3, scenes=SCENES, resolutions=None, quick=False) -> List[dict]:
    """Every sweep of ``SWEEPS`` on ``scenes`` at their ``SIZES`` (or
    ``resolutions`` for all). A full run of a subset of ``SCENES`` keeps the
    other scenes' rows from ``out_dir/study.csv`` (so one scene is re-measured
    alone); when the rows then cover every scene, the table is installed."""
    unknown = [s for s in scenes if s not in SCENES]
    if unknown:
        raise ValueError(f"unknown study scene(s) {', '.join(unknown)}: expected some of {', '.join(SCENES)}")
    os.makedirs(out_dir, exist_ok=True)
    rows = [] if quick else kept_rows(os.path.join(out_dir, "study.csv"), scenes)
    sheets = {}
    producers = registry.producers()
    for name in scenes:
        for res in resolutions or (QUICK_SIZES if quick else SIZES[name]):
            rows += _measure_scene(name, res, repeats, quick, producers, sheets)
            write_outputs(rows, sheets, out_dir)      # after every scene: a cut-short run keeps its rows
    if not quick and resolutions is None and set(SCENES) <= {r["scene"] for r in rows}:
        # a full run is the planner's new measured table (core/auto_table.json)
        print(f"auto table installed: {install_table(os.path.join(out_dir, 'auto_table.json'))}")
    return rows


def silhouette_mask(g, radius: float) -> np.ndarray:
    """bool[H, W]: pixels with a pixel centre within ``radius`` (the pixel
    filter's) that sees another object, or the world where this one sees a
    surface or the other way round: the footprints that hold an edge."""
    H, W = g.hit.shape
    r = int(np.ceil(radius))
    key = np.where(g.hit, g.object_id, -1)
    pad = np.pad(key, r, mode="edge")
    out = np.zeros((H, W), bool)
    for dy in range(-r, r + 1):
        for dx in range(-r, r + 1):
            out |= pad[r + dy:r + dy + H, r + dx:r + dx + W] != key
    return out


def _measure_scene(name, res, repeats, quick, producers, sheets) -> List[dict]:
    """The truth, Cycles' pair and every sweep entry on sample ``name`` at
    ``res``: its rows; its contact sheet into ``sheets``."""
    from ..bridge import settings
    rows = []
    flt = settings.pixel_filter(open_sample(name), "scene")
    truth = cycles_truth(name, res, QUICK_TRUTH_SAMPLES if quick else TRUTH_SAMPLES)
    scene = load_sample(name, res)
    light = scene.lights[0]
    shape = auto_choice.scene_shape(scene, light)     # what auto's cost model scales from
    fb = FrameBuffers(scene, *res)
    lit = reach_mask(fb.gbuffer, light)
    edges = lit & silhouette_mask(fb.gbuffer, flt.radius)
    sheet = {f"Cycles {QUICK_TRUTH_SAMPLES if quick else TRUTH_SAMPLES} spp (truth)": truth}
    common = dict(scene=name, size=f"{res[0]}x{res[1]}", threads=numba.get_num_threads(),
                  load=round(os.getloadavg()[0], 2), light_kind=light.kind, light_extent=light.extent,
                  triangles=shape.triangles, light_relative=shape.light_relative, mattes=shape.mattes,
                  visibility="irradiance")

    def measured(row, v):
        e, es = errors(v, truth, lit), errors(v, truth, edges)
        row.update(rmse=e["rmse"], max_abs=e["max_abs"], mean_signed=e["mean_signed"],
                   rmse_penumbra=e["rmse_penumbra"], rmse_silhouette=es["rmse"])
        return row

    for n in (CYCLES_SAMPLES[:1] if quick else CYCLES_SAMPLES):
        v, seconds = cycles_pair(name, res, n)
        rows.append(measured(dict(common, method="cycles", setting=f"samples={n}", seconds=seconds,
                                  status="ok", repeats=1), v))
        print(f"{name} {res[0]}x{res[1]} cycles pair {n:5d} spp {seconds:.2f}s rmse {rows[-1]['rmse']:.4f}",
              flush=True)
    for mid in SWEEPS:
        if mid not in producers:
            continue
        m = producers[mid]
        entries = sweep(mid, light.kind)
        for label, params in (entries[:2] if quick else entries):
            row = dict(common, method=mid, setting=label, repeats=repeats, status="ok")
            try:
                p, unknown = _apply(m, params, fb)
                if unknown:
                    raise ValueError(f"unknown knob(s) {unknown}")
                pid = mid if mid in m.passes else next(iter(m.passes))
                pid = "embree_irr" if mid == "embree" else pid
                own = {k: v for k, v in params_of(p).items()}

                def frame():
                    return render_filtered(scene, [pid], pixel_filter=flt, method_overrides={mid: own},
                                           overrides={"visibility": "irradiance"})
                frame()                                     # warm: kernels compiled, caches filled
                walls, out = [], None
                for _ in range(repeats):
                    t = time.perf_counter()
                    out = frame()
                    walls.append(time.perf_counter() - t)
                rec = out.lights[0].record[pid]
                row["seconds"] = statistics.median(walls)
                row["phases"] = json.dumps({k: round(v, 5) for k, v in rec["time_s"].items() if k != "total"})
                v = np.where(lit, out.lights[0].passes[pid], 1.0)
                measured(row, v)
                if label == entries[0][0]:
                    sheet[mid] = v
            except Exception as exc:  # a failing method is shown, not dropped
                row.update(status="failed", error=f"{type(exc).__name__}: {exc}",
                           trace=traceback.format_exc(limit=2))
            rows.append(row)
            print(f"{name} {res[0]}x{res[1]} {mid:16s} {label:28s} "
                  + (f"{row['seconds']:.4f}s rmse {row['rmse']:.4f} silhouettes {row['rmse_silhouette']:.4f}"
                     if row["status"] == "ok" else row["error"]), flush=True)
    sheets[(name, res)] = (sheet, truth, lit)
    return rows


def params_of(p) -> dict:
    """A Params dataclass as the overrides that make it."""
    from ..core.methods.base import params_dict
    return params_dict(p)


#: study.csv's columns; the numbers among them (read back by ``kept_rows``)
CSV_KEYS = ["scene", "size", "method", "setting", "status", "visibility", "seconds", "phases", "rmse",
            "rmse_silhouette", "max_abs", "mean_signed", "rmse_penumbra", "threads", "repeats", "error",
            "light_kind", "light_extent", "triangles", "light_relative", "mattes", "load"]
_FLOATS = ("seconds", "rmse", "rmse_silhouette", "max_abs", "mean_signed", "rmse_penumbra", "light_extent",
           "light_relative", "load")
_INTS = ("threads", "repeats", "triangles", "mattes")


def kept_rows(csv_path: str, rerun) -> List[dict]:
    """The rows of ``csv_path`` (if any) of scenes not in ``rerun``, numbers
    parsed (a row without its light's columns has none of them)."""
    if not os.path.exists(csv_path):
        return []
    with open(csv_path, newline="") as f:
        rows = [r for r in csv.DictReader(f) if r["scene"] not in set(rerun)]
    for r in rows:
        for k in _FLOATS + _INTS:
            if r.get(k) in (None, ""):
                r.pop(k, None)
            else:
                r[k] = int(r[k]) if k in _INTS else float(r[k])
    return rows


def pareto(points):
    """Indices of the (time, error) points no other point beats in both."""
    order = sorted(range(len(points)), key=lambda i: (points[i][0], points[i][1]))
    front, best = [], float("inf")
    for i in order:
        if points[i][1] < best:
            front.append(i)
            best = points[i][1]
    return front


def front_of(rows, scene):
    """(the scene's ok rows at its largest size, their Pareto front as
    method / setting / seconds / rmse, fastest first)."""
    ok = [r for r in rows if r["scene"] == scene and r["status"] == "ok" and "reference" not in r["method"]
          and r["size"] == _largest_size(rows, scene)]
    pts = [(float(r["seconds"]), float(r["rmse"])) for r in ok]
    return ok, [dict(method=ok[i]["method"], setting=ok[i]["setting"], seconds=pts[i][0], rmse=pts[i][1])
                for i in sorted(pareto(pts), key=lambda i: pts[i])]


def write_outputs(rows, sheets, out_dir):
    rows = sorted(rows, key=lambda r: SCENES.index(r["scene"]) if r["scene"] in SCENES else len(SCENES))
    with open(os.path.join(out_dir, "study.csv"), "w", newline="") as f:
        w = csv.DictWriter(f, CSV_KEYS, extrasaction="ignore")
        w.writeheader()
        w.writerows(rows)
    import matplotlib                 # a dev dependency, needed only to draw the figures
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fronts = {}
    for scene in sorted({r["scene"] for r in rows}):
        fig, ax = plt.subplots(figsize=(7, 5))
        ok, fronts[scene] = front_of(rows, scene)
        for mid in sorted({r["method"] for r in ok}):
            pts = [r for r in ok if r["method"] == mid]
            ax.scatter([r["seconds"] for r in pts], [max(r["rmse"], 1e-5) for r in pts], label=mid)
        if ok:
            fr = fronts[scene]
            ax.plot([p["seconds"] for p in fr], [max(p["rmse"], 1e-5) for p in fr], "k--", lw=1, label="Pareto front")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("wall time per light (s, median of warm runs)")
        ax.set_ylabel(f"RMSE against Cycles' ratio at {TRUTH_SAMPLES} spp")
        ax.set_title(f"{scene}: accuracy versus time")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
        fig.tight_layout()
        fig.savefig(os.path.join(out_dir, f"pareto_{scene}.png"), dpi=110)
        plt.close(fig)
    for (scene, res), (sheet, ref, mask) in sheets.items():
        if res != max(r for (s, r) in sheets if s == scene):
            continue
        n = len(sheet)
        fig, axes = plt.subplots(2, n, figsize=(2.2 * n, 4.6))
        axes = np.atleast_2d(axes).reshape(2, n)
        for k, (label, img) in enumerate(sheet.items()):
            axes[0, k].imshow(img, cmap="gray", vmin=0, vmax=1)
            axes[0, k].set_title(label, fontsize=8)
            err = np.where(mask, np.abs(img - ref), 0.0)
            axes[1, k].imshow(err, cmap="inferno", vmin=0, vmax=0.5)
            axes[1, k].set_title("|error|" if k else "", fontsize=8)
            for a in axes[:, k]:
                a.axis("off")
        fig.tight_layout()
        fig.savefig(os.path.join(out_dir, f"sheet_{scene}.png"), dpi=100)
        plt.close(fig)
    _write_json(os.path.join(out_dir, "auto_table.json"), auto_table(rows, fronts))
    reps = sorted({int(r["repeats"]) for r in rows if r.get("repeats") not in (None, "") and "reference" not in r["method"]})
    threads = sorted({int(r["threads"]) for r in rows if r.get("threads") not in (None, "")})
    loads = [float(r["load"]) for r in rows if r.get("load") not in (None, "")]
    lines = [f"Times: median wall seconds of {'/'.join(map(str, reps))} warm frames (the method's filtered "
             f"irradiance pass; Cycles: its pair of renders), {'/'.join(map(str, threads))} Numba threads"
             + (f", 1-minute load average {min(loads):.1f}-{max(loads):.1f} (per scene in study.csv)" if loads else "")
             + f"; errors against Cycles' shadow ratio at {TRUTH_SAMPLES} samples filtered like the render, over"
             " the pixels the light reaches, and over the silhouette pixels (an edge in the filter's footprint).",
             "",
             "| scene | size | method | setting | time s | rmse | rmse silhouettes | max abs | mean signed "
             "| rmse penumbra |",
             "|---|---|---|---|---|---|---|---|---|---|"]

    def num(r, k, fmt=".4f"):
        return format(float(r[k]), fmt) if r.get(k) not in (None, "") else ""

    for r in rows:
        if r["status"] != "ok":
            lines.append(f"| {r['scene']} | {r['size']} | {r['method']} | {r['setting']} | FAILED: "
                         f"{r.get('error', '')[:60]} | | | | | |")
            continue
        lines.append(f"| {r['scene']} | {r['size']} | {r['method']} | {r['setting']} | {num(r, 'seconds')} | "
                     f"{num(r, 'rmse')} | {num(r, 'rmse_silhouette')} | {num(r, 'max_abs', '.3f')} | "
                     f"{num(r, 'mean_signed', '+.4f')} | {num(r, 'rmse_penumbra')} |")
    with open(os.path.join(out_dir, "study.md"), "w") as f:
        f.write("\n".join(lines) + "\n")


# --------------------------------------------------------------------------
# The planner's table (core/auto_choice.py reads it; format penumbra-auto-table/1)
AUTO_LIGHT_SAMPLES = DEFAULT_LIGHT_SAMPLES   # a light's default Light Samples (addon/properties.py)


def _pixels(size: str) -> int:
    w, h = (int(x) for x in str(size).lower().split("x"))
    return w * h


def _largest_size(rows, scene) -> str:
    return max((r["size"] for r in rows if r["scene"] == scene), key=_pixels)


def default_setting(mid: str):
    """The sweep label of ``mid`` at its default parameters (``AUTO_LIGHT_SAMPLES``
    where it samples): what a light runs when ``auto`` picks the method."""
    for label, params in sweep(mid):
        if params in ({}, {"samples": AUTO_LIGHT_SAMPLES}):
            return label
    return None


def auto_table(rows, fronts=None) -> dict:
    """Per scene (largest measured size): its light and, per method, the
    default setting's time and error. ``fronts``: the Pareto fronts, kept
    for readers (the planner does not use them)."""
    scenes = []
    for scene in sorted({r["scene"] for r in rows}):
        size = _largest_size(rows, scene)
        here = [r for r in rows if r["scene"] == scene and r["size"] == size]
        lit = next((r for r in here if r.get("light_kind")), None)
        if lit is None:
            continue                              # no light recorded: cannot be matched
        methods = {}
        for mid in SWEEPS:
            label = default_setting(mid)
            r = next((r for r in here if r["method"] == mid and r["setting"] == label), None)
            if r is None or r["status"] != "ok":
                continue
            pid = "embree_irr" if mid == "embree" and r["visibility"] == "irradiance" else mid
            methods[pid] = {"setting": label, "visibility": r["visibility"], "seconds": float(r["seconds"]),
                            "rmse": float(r["rmse"]), "rmse_penumbra": float(r["rmse_penumbra"])}
            if r.get("rmse_silhouette") not in (None, ""):
                methods[pid]["rmse_silhouette"] = float(r["rmse_silhouette"])
        entry = {"scene": scene, "size": size, "light_kind": lit["light_kind"],
                 "light_extent": float(lit["light_extent"]), "methods": methods}
        if lit.get("triangles") not in (None, ""):            # auto's rule 5 (SceneShape)
            entry["triangles"] = int(lit["triangles"])
            entry["light_relative"] = float(lit["light_relative"])
        if lit.get("mattes") not in (None, ""):               # auto's rule 3 (alpha mattes or not)
            entry["mattes"] = int(lit["mattes"])
        scenes.append(entry)
    out = {"format": "penumbra-auto-table/1",
           "reference": f"Cycles' shadow ratio at {TRUTH_SAMPLES} spp, filtered like the render",
           "settings": f"each method at its default parameters, {AUTO_LIGHT_SAMPLES} light samples",
           "threads": max((int(r.get("threads") or 0) for r in rows), default=0), "scenes": scenes}
    if fronts:
        out["fronts"] = fronts
    return out


def _write_json(path: str, data: dict) -> None:
    """Atomically: a temporary file, then a rename."""
    tmp = f"{path}.tmp{os.getpid()}"
    with open(tmp, "w") as f:
        json.dump(data, f, indent=2)
        f.write("\n")
    os.replace(tmp, path)


def install_table(src: str, dst: str = None) -> str:
    """Check ``src`` the way the planner reads it, then copy it to
    ``core/auto_table.json`` (shipped in the extension). Returns ``dst``."""
    dst = dst or auto_choice.TABLE_PATH
    auto_choice.load_table(src)                               # TableError: not installed
    with open(src) as f:
        _write_json(dst, json.load(f))
    auto_choice._packaged.cache_clear()
    return dst


def scene_columns(rows) -> List[dict]:
    """``rows`` (of a study.csv without these columns) with each
    scene's light kind and size, triangles, relative light size and alpha
    mattes filled in from the captured sample scene (what they are, not a
    measurement)."""
    shapes = {}
    for name in sorted({r["scene"] for r in rows}):
        sc = load_sample(name, (16, 16))
        lt = sc.lights[0]
        sh = auto_choice.scene_shape(sc, lt)
        shapes[name] = dict(light_kind=lt.kind, light_extent=lt.extent, triangles=sh.triangles,
                            light_relative=sh.light_relative, mattes=sh.mattes)
    for r in rows:
        for k, v in shapes[r["scene"]].items():
            if r.get(k) in (None, ""):
                r[k] = v
    return rows


def table_from_csv(csv_path: str, out: str) -> str:
    """Rebuild the table from a study.csv (a scene's missing light and shape
    columns are read from the sample scenes: ``scene_columns``)."""
    rows = scene_columns(kept_rows(csv_path, ()))
    _write_json(out, auto_table(rows, {name: front_of(rows, name)[1] for name in sorted({r["scene"] for r in rows})}))
    return out


def main(argv=None) -> int:
    """``python -m penumbra.bench.study install-table [SRC]`` (default
    bench/results/auto_table.json) or ``table-from-csv CSV OUT``."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["install-table"] and len(argv) <= 2:
        src = argv[1] if len(argv) == 2 else os.path.join(ROOT, "bench", "results", "auto_table.json")
        print(install_table(src))
        return 0
    if argv[:1] == ["table-from-csv"] and len(argv) == 3:
        print(table_from_csv(argv[1], argv[2]))
        return 0
    print("usage: python -m penumbra.bench.study install-table [SRC] | table-from-csv CSV OUT", file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main())
