"""The README's two tables, speed and accuracy, made from ``bench/results/``:
each method at its defaults (``study.default_setting``: its filtered
irradiance pass at ``study.AUTO_LIGHT_SAMPLES`` light samples) and Cycles' own pair of renders
(``study.CYCLES_SAMPLES``) on every study scene at the study's larger size,
against the compositing truth, and the machine they were measured on
(``machine.json``).

    python -m penumbra.bench.readme_tables            # rewrite README.md's tables
    python -m penumbra.bench.readme_tables --check    # exit 1 when README.md is not current

``make bench`` rewrites them after the study; ``tests/test_readme.py`` checks
that the committed README shows the committed results.
"""
from __future__ import annotations

import csv
import json
import os
import sys
from typing import Dict, List, Optional

from .harness import ROOT
from .study import AUTO_LIGHT_SAMPLES, CYCLES_SAMPLES, SCENES, SIZES, SWEEPS, default_setting
from .truth import TRUTH_SAMPLES

RESULTS = os.path.join(ROOT, "bench", "results")
README = os.path.join(ROOT, "README.md")
BEGIN, END = "<!-- tables: python -m penumbra.bench.readme_tables -->", "<!-- end of tables -->"


def _rows(results: str) -> List[dict]:
    with open(os.path.join(results, "study.csv"), newline="", encoding="utf-8") as f:
        return [r for r in csv.DictReader(f) if r.get("status") == "ok"]


def _grid(rows: List[dict], columns, fmt: str) -> Dict[str, Dict[str, str]]:
    """row label -> scene -> the formatted ``columns`` (joined by " / ") of
    each method's default row and of Cycles' pairs at the scene's larger
    study size."""
    out: Dict[str, Dict[str, str]] = {}
    wanted = [(f"`{'embree_irr' if mid == 'embree' else mid}`", mid, default_setting(mid)) for mid in SWEEPS]
    wanted += [(f"Cycles pair, {n} spp", "cycles", f"samples={n}") for n in CYCLES_SAMPLES]
    for label, mid, setting in wanted:
        for scene in SCENES:
            size = "x".join(str(v) for v in SIZES[scene][-1])
            hit = [r for r in rows if r["method"] == mid and r["scene"] == scene and r["size"] == size
                   and r["setting"] == setting]
            if hit and all(hit[0].get(c) not in (None, "") for c in columns):
                out.setdefault(label, {})[scene] = " / ".join(format(float(hit[0][c]), fmt) for c in columns)
    return out


def _table(grid: Dict[str, Dict[str, str]]) -> List[str]:
    scenes = [s for s in SCENES if any(s in g for g in grid.values())]
    lines = ["| pass | " + " | ".join(scenes) + " |", "|---|" + "---|" * len(scenes)]
    for label, by_scene in grid.items():
        lines.append(f"| {label} | " + " | ".join(by_scene.get(s, "-") for s in scenes) + " |")
    return lines


def machine_line(results: str) -> str:
    try:
        with open(os.path.join(results, "machine.json"), encoding="utf-8") as f:
            m = json.load(f)
    except FileNotFoundError:
        return "machine: not recorded"
    return (f"{m.get('cores', '?')} cores ({m.get('cpu', '?')}), Python {m.get('python', '?')}, "
            f"numpy {m.get('numpy', '?')}, numba {m.get('numba', '?')}, {m.get('numba_threads', '?')} "
            f"Numba threads; measured {m.get('date', '?')}")


def tables(results: str = RESULTS) -> str:
    """The markdown between the README's markers."""
    rows = _rows(results)
    size = "x".join(str(v) for v in SIZES[SCENES[0]][-1])
    lines = [BEGIN, "", f"Speed: wall seconds of a frame's pass at {size} (the filtered irradiance ratio, "
                        f"{AUTO_LIGHT_SAMPLES} light samples, warm, median of the study's runs; Cycles: its two renders); "
                        f"{machine_line(results)}.", ""]
    lines += _table(_grid(rows, ("seconds",), ".3f"))
    lines += ["", f"Accuracy: RMSE against Cycles' shadow ratio at {TRUTH_SAMPLES} samples (filtered like "
                  f"the render) over the pixels the light reaches / over the silhouette pixels, the same runs.",
              ""]
    lines += _table(_grid(rows, ("rmse", "rmse_silhouette"), ".3f"))
    lines += ["", END]
    return "\n".join(lines)


def rewrite(readme: str = README, results: str = RESULTS, check: bool = False) -> bool:
    """Put ``tables(results)`` between the markers of ``readme``; with
    ``check`` only say whether it is current. Returns True when it was."""
    with open(readme, encoding="utf-8") as f:
        text = f.read()
    a, b = text.index(BEGIN), text.index(END) + len(END)
    new = text[:a] + tables(results) + text[b:]
    if check or new == text:
        return new == text
    with open(readme, "w", encoding="utf-8") as f:
        f.write(new)
    return False


def main(argv: Optional[List[str]] = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    current = rewrite(check="--check" in argv)
    if "--check" in argv and not current:
        print("README.md's tables are not those of bench/results/: python -m penumbra.bench.readme_tables",
              file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
