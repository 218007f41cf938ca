"""``penumbra bench``: the benchmark and the accuracy study (not shipped in
the extension; ``blender_manifest.toml`` excludes ``/bench/``).

- :mod:`.phases`: per-phase wall times of the pipeline and the start-up table (``--part skeleton``),
- :mod:`.methods`: each method's table of its switches against ``embree`` (``--part methods``),
- :mod:`.scaling`: embree and penumbra_casting against triangle count (``--part scaling``),
- :mod:`.study`: accuracy versus time and the planner's table (``--part study``),
- :mod:`.pixel_filter`: the cost and error of filtered passes (``--part filter``),
- :mod:`.vs_cycles`: ``penumbra render`` against Cycles' shadow pair at 1080p (``--part cycles``),
- :mod:`.instancing`: an instanced scatter at production scale, plan / render / Cycles' pair, time and
  peak memory (``--part instancing``),
- :mod:`.camera_effects`: motion blur and depth of field against Cycles' pair with the effect on
  (``--part camera_effects``),
- :mod:`.harness`: what they share (sample scenes, machine, median of warm runs).

Medians of ``--repeats`` warm runs; thread counts stated. Results go to
``bench/results/`` (or ``--out``) as CSV, Markdown, PNG and JSON, with the machine.
"""
from __future__ import annotations

import json

from .harness import machine
from .methods import run_method_benchmarks
from .phases import (BUFFER_COLUMNS, STARTUP_COLUMNS, bench_buffers, bench_preview, bench_skeleton, bench_startup,
                     write_results)


def run_bench(args) -> int:
    """The ``bench`` command: ``args.part`` (all, skeleton, startup, methods, scaling, study, filter, cycles,
    instancing, camera_effects),
    ``args.out``, ``args.repeats``, ``args.quick``."""
    repeats = max(1, args.repeats)
    print(f"machine: {json.dumps(machine())}")
    if args.part in ("all", "skeleton"):
        rows = bench_skeleton(repeats, args.quick)
        md = write_results(rows, args.out, "skeleton")
        print(f"pipeline phases, medians of {repeats} warm runs")
        print(md)
        rows = bench_buffers(repeats, args.quick) + bench_preview(repeats, args.quick)
        md = write_results(rows, args.out, "buffers", BUFFER_COLUMNS)
        print(f"buffers and the Preview beside raw embreex (one thread, same rays), medians of {repeats} warm runs")
        print(md)
    if args.part in ("all", "skeleton", "startup"):
        md = write_results(bench_startup(args.quick, repeats=repeats,
                                         methods=getattr(args, "startup_methods", None)),
                           args.out, "startup", STARTUP_COLUMNS)
        print(f"start-up: penumbra render from a fresh Numba cache (cold) and again (warm), one process each; "
              f"medians of {repeats} runs")
        print(md)
    if args.part in ("all", "methods"):
        run_method_benchmarks(args.out, repeats, args.quick)
    if args.part in ("all", "filter"):
        from .pixel_filter import bench_pixel_filter
        print("filtered passes")
        from .pixel_filter import SCENES as FILTER_SCENES
        print(bench_pixel_filter(args.out, repeats, args.quick,
                                 getattr(args, "study_scenes", None) or FILTER_SCENES))
    if args.part in ("all", "scaling"):
        from .scaling import COLUMNS as SCALING_COLUMNS, bench_scaling
        # scaling_run.md: scaling.md is a hand-written analysis the run must not overwrite
        md = write_results(bench_scaling(repeats, args.quick), args.out, "scaling_run", SCALING_COLUMNS)
        print(f"triangle-count scaling, embree beside penumbra_casting, medians of {repeats} warm runs")
        print(md)
    if args.part in ("all", "study"):
        # imported here, not above: ``python -m penumbra.bench.study`` runs the
        # module as __main__, and runpy warns when the package imported it first
        from .study import run_study
        from .study import SCENES
        run_study(args.out, repeats=repeats, quick=args.quick, scenes=getattr(args, "study_scenes", None) or SCENES)
    if args.part in ("all", "cycles"):
        from .vs_cycles import SCENES as CYCLES_SCENES, bench_vs_cycles
        print("penumbra render against Cycles' shadow pair")
        print(bench_vs_cycles(args.out, repeats, args.quick, getattr(args, "study_scenes", None) or CYCLES_SCENES))
    if args.part in ("all", "instancing"):
        from .instancing import bench_instancing
        print("an instanced scatter at production scale: plan, render and Cycles' pair, time and peak memory")
        print(bench_instancing(args.out, args.quick))
    if args.part in ("all", "camera_effects"):
        from .camera_effects import bench_camera_effects
        print("motion blur and depth of field against Cycles' pair with the effect on")
        print(bench_camera_effects(args.out, repeats, args.quick))
    return 0
