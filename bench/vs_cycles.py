"""``penumbra bench --part cycles``: the default pass against the workflow it
replaces, Cycles' pair of renders with and without the light's shadow.

Per sample scene (``SCENES``, or those ``--study-scenes`` names) at
``RESOLUTION`` 1920x1080 (``--quick``: 480x270):

- ``penumbra_s``: the wall time of ``penumbra render SCENE --resolution WxH
  --no-previews`` in its own process (start-up, capture, ``auto``'s pass
  filtered like the render, the EXR and JSON; a warm Numba cache), the median
  of ``--repeats`` runs;
- ``cycles_s``: Cycles' shadowed and unshadowed renders of the light
  (``truth.cycles_pair``, the scene's pixel filter), one run, at
  ``cycles_spp``: the samples at which Cycles' pair has the pass's RMSE,
  from the pair's RMSE at ``EQUAL_FROM`` (64) samples against the truth at
  256x256 (``study.csv``) and Monte Carlo's 1 / sqrt(samples):
  ceil(64 (rmse_64 / pass_rmse)^2) (the pass's RMSE: the method ``auto``
  picked, from the shipped table);
- ``speedup`` = cycles_s / penumbra_s.

Equal error is taken from the 256x256 study: a 1024-spp truth at 1080p takes
about 25 minutes a scene. Both errors are Monte Carlo and pixel-filter
errors per pixel, which the resolution does not grow. The truth's own noise
is in both RMSEs; it makes the estimate of ``cycles_spp`` low, the speedup
conservative.
"""
from __future__ import annotations

import csv
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time

from .harness import ROOT, machine

SCENES = ("foliage",)
RESOLUTION = (1920, 1080)
QUICK_RESOLUTION = (480, 270)
STUDY_SIZE = "256x256"
EQUAL_FROM = 64
HEAD = ("scene", "resolution", "method", "pass_rmse", "cycles_rmse_64", "cycles_spp", "penumbra_s", "cycles_s",
        "speedup")


def bench_vs_cycles(out_dir: str, repeats: int, quick: bool, scenes=SCENES) -> str:
    """Time both; write ``vs_cycles.md`` / ``.json``; return the table."""
    from .truth import cycles_pair
    res = QUICK_RESOLUTION if quick else RESOLUTION
    cycles_rmse = _study_cycles_rmse(os.path.join(out_dir, "study.csv"))
    rows = []
    for name in scenes:
        runs, method = [], None
        for _ in range(max(1, repeats) + 1):              # the first run warms the Numba cache
            with tempfile.TemporaryDirectory() as tmp:
                t = time.perf_counter()
                subprocess.run([os.path.join(os.path.dirname(sys.executable), "penumbra"), "render",
                                os.path.join(ROOT, "sample_blends", f"{name}.blend"), "--out", tmp,
                                "--resolution", f"{res[0]}x{res[1]}", "--no-previews", "--quiet"], check=True)
                runs.append(time.perf_counter() - t)
                rec = json.load(open(next(os.path.join(tmp, f) for f in os.listdir(tmp) if f.endswith(".json"))))
                method = rec["plan"]["lights"][0]["auto"]["method"]
        pass_rmse = _table_rmse(name, method)
        c64 = cycles_rmse[name][EQUAL_FROM]
        spp = max(1, math.ceil(EQUAL_FROM * (c64 / pass_rmse) ** 2))
        _, cyc = cycles_pair(name, res, spp)
        pen = statistics.median(runs[1:])
        rows.append({"scene": name, "resolution": f"{res[0]}x{res[1]}", "method": method,
                     "pass_rmse": round(pass_rmse, 4), "cycles_rmse_64": round(c64, 4), "cycles_spp": spp,
                     "penumbra_s": round(pen, 2), "cycles_s": round(cyc, 1), "speedup": round(cyc / pen, 1)})
    md = "\n".join(["| " + " | ".join(HEAD) + " |", "|" + "---|" * len(HEAD)]
                   + ["| " + " | ".join(str(r[k]) for k in HEAD) + " |" for r in rows])
    md += (f"\n\npenumbra_s: `penumbra render` at its defaults, median of {max(1, repeats)} warm runs; cycles_s: "
           f"Cycles' shadow pair at the samples of equal error, one run; errors: RMSE over the lit pixels against Cycles' 1024-spp ratio at "
           f"{STUDY_SIZE} (study.csv, the shipped auto table); {machine()['cpu']}, {os.cpu_count()} cores\n")
    os.makedirs(out_dir, exist_ok=True)
    with open(os.path.join(out_dir, "vs_cycles.md"), "w") as f:
        f.write(md)
    with open(os.path.join(out_dir, "vs_cycles.json"), "w") as f:
        json.dump({"machine": machine(), "rows": rows}, f, indent=2)
    return md


def _study_cycles_rmse(path: str) -> dict:
    """scene -> Cycles samples -> RMSE of its pair at ``STUDY_SIZE``."""
    out: dict = {}
    with open(path) as f:
        for r in csv.DictReader(f):
            if r["method"] == "cycles" and r["size"] == STUDY_SIZE and r["status"] == "ok":
                out.setdefault(r["scene"], {})[int(r["setting"].split("=")[1])] = float(r["rmse"])
    return out


def _table_rmse(scene: str, method: str) -> float:
    """The shipped auto table's RMSE of ``method`` on ``scene``."""
    with open(os.path.join(ROOT, "core", "auto_table.json")) as f:
        table = json.load(f)
    (row,) = [s for s in table["scenes"] if s["scene"] == scene]
    return float(row["methods"][method]["rmse"])
