"""``penumbra`` command line: the same ``main(argv) -> int`` backs the
``.venv/bin/penumbra`` console script (PyPI bpy module) and
``blender --command penumbra ...`` (registered in ``__init__.register``).

Bad input exits 2 with one line on stderr; bpy is imported only once the
arguments are known to be good.
"""
from __future__ import annotations

import argparse
import os
import signal
import sys
import threading
from typing import List, Optional

from .farm import watchdog
from .farm.command import add_farm_parser, cmd_farm

MAX_SIDE = 16384
VISIBILITY_CHOICES = ("irradiance", "average")      # core.methods.base.VISIBILITIES (no core import here)
DEFAULT_BUDGET = 0.02                                # core.auto_choice.DEFAULT_BUDGET
DEFAULT_LIGHT_SAMPLES = 256                          # core.methods.base.DEFAULT_LIGHT_SAMPLES


class UsageError(Exception):
    """A one-line message for the user; exit status 2."""


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # argparse would print usage + message and exit itself
        raise UsageError(message)


def _resolution(text: str):
    try:
        w, h = (int(x) for x in text.lower().split("x"))
    except ValueError:
        raise UsageError(f"bad --resolution {text!r}: expected WxH, e.g. 512x512")
    if not (1 <= w <= MAX_SIDE and 1 <= h <= MAX_SIDE):
        raise UsageError(f"bad --resolution {text!r}: each side must be 1..{MAX_SIDE}")
    return w, h


def _frame_list(text: str):
    """'1-250', '1-250:5', '3', '1,4,9-12' -> sorted unique frame numbers."""
    frames = set()
    try:
        for part in text.split(","):
            part = part.strip()
            step = 1
            if ":" in part:
                part, st = part.split(":")
                step = int(st)
                if step < 1:
                    raise ValueError
            if "-" in part[1:]:
                i = part.index("-", 1)
                a, b = int(part[:i]), int(part[i + 1:])
                if b < a:
                    raise ValueError
                frames.update(range(a, b + 1, step))
            else:
                frames.add(int(part))
    except ValueError:
        raise UsageError(f"bad --frames {text!r}: expected e.g. 1-250, 1-250:5 or 1,5,9")
    if len(frames) > 1_000_000:
        raise UsageError(f"bad --frames {text!r}: too many frames")
    return sorted(frames)


def _positive(name, lo, hi):
    def conv(text):
        try:
            v = int(text)
        except ValueError:
            raise UsageError(f"bad {name} {text!r}: expected a whole number")
        if not lo <= v <= hi:
            raise UsageError(f"bad {name} {text!r}: must be {lo}..{hi}")
        return v
    return conv


def _pixel_filter(text: str) -> str:
    from .core.pixel_filter import PixelFilter, PixelFilterError, parse
    try:
        parse(text, PixelFilter())          # the grammar; "scene" is resolved per scene
    except PixelFilterError as exc:
        raise UsageError(str(exc))
    return text.strip().lower()


def _error_budget(text: str) -> float:
    import math
    try:
        v = float(text)
    except ValueError:
        v = float("nan")
    if not (math.isfinite(v) and 0.0 < v <= 1.0):
        raise UsageError(f"bad --error-budget {text!r}: expected an RMSE in (0, 1], e.g. 0.02")
    return v


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="penumbra", description="Soft-shadow passes for Blender scenes.")
    sub = p.add_subparsers(dest="command")
    r = sub.add_parser("render", help="compute shadow passes of one frame into a multilayer EXR + JSON")
    r.add_argument("scene", help="the .blend file (never modified)")
    r.add_argument("--out", default="penumbra_out", help="output folder (default: penumbra_out)")
    r.add_argument("--methods", default="auto",
                   help="comma-separated method ids, 'all', or 'auto' (the default: picked per light, "
                        "written under the picked id)")
    r.add_argument("--lights", default=None, help="comma-separated light names (default: all)")
    fr = r.add_mutually_exclusive_group()
    fr.add_argument("--frame", type=_positive("--frame", -1048574, 1048574), default=None,
                    help="the frame to compute (default: the scene's current frame)")
    fr.add_argument("--frames", type=_frame_list, default=None,
                    help="frames, e.g. 1-250, 1-250:5 or 1,5,9; frames already written are skipped")
    r.add_argument("--force", action="store_true", help="recompute frames whose files already exist")
    r.add_argument("--resolution", type=_resolution, default=None, help="WxH (default: the scene's)")
    r.add_argument("--samples", type=_positive("--samples", 1, 65536), default=None,
                   help=f"light samples per pixel for sampling methods (default: {DEFAULT_LIGHT_SAMPLES})")
    r.add_argument("--seed", type=_positive("--seed", 0, 2**31 - 1), default=0)
    r.add_argument("--visibility", choices=VISIBILITY_CHOICES, default="irradiance",
                   help="which V every method's pass is: irradiance (the default: the shadowed / unshadowed "
                        "irradiance ratio, what the unshadowed render is multiplied by) or average (the "
                        "visible share of the light)")
    r.add_argument("--pixel-filter", type=_pixel_filter, default="scene",
                   help="scene (the default: filtered like the scene's render, Cycles' pixel filter "
                        "or EEVEE's filter size), none (one receiver per pixel centre), box:W, "
                        "gaussian:W or blackman-harris:W (W in pixels)")
    r.add_argument("--map-size", type=_positive("--map-size", 8, MAX_SIDE), default=None,
                   help="light depth-map resolution (larger side); default: as many texels as the "
                        "output has pixels (a sun's: the output's larger side)")
    r.add_argument("--threads", type=_positive("--threads", 1, 1024), default=None)
    r.add_argument("--no-previews", action="store_true", help="skip the PNG previews")
    r.add_argument("--error-budget", type=_error_budget, default=None,
                   help=f"RMSE over lit pixels against the compositing truth that 'auto' must meet, "
                        f"twice it over silhouettes (default: {DEFAULT_BUDGET})")
    r.add_argument("--quiet", action="store_true", help="no progress bar and no compiling notice")
    pl = sub.add_parser("plan", help="print what the scene calls for, and why")
    pl.add_argument("scene")
    pl.add_argument("--methods", default="auto",
                    help="comma-separated method ids, 'all', or 'auto' (the default: picked per light)")
    pl.add_argument("--lights", default=None)
    pl.add_argument("--resolution", type=_resolution, default=None,
                    help="WxH the lights' reach is judged at, as render's (default: the scene's)")
    pl.add_argument("--error-budget", type=_error_budget, default=None,
                    help=f"RMSE over lit pixels against the compositing truth that 'auto' must meet, "
                        f"twice it over silhouettes (default: {DEFAULT_BUDGET})")
    pl.add_argument("--visibility", choices=VISIBILITY_CHOICES, default="irradiance",
                    help="as render's: which V the passes would be (auto is judged for it)")
    pl.add_argument("--pixel-filter", type=_pixel_filter, default="scene",
                    help="as render's: the filter the passes would get (default: the scene's)")
    pl.add_argument("--quiet", action="store_true", help="accepted for symmetry with render (plan "
                                                         "compiles nothing and shows no bar)")
    b = sub.add_parser("bench", help="accuracy-versus-time study / per-phase timings")
    b.add_argument("--out", default=os.path.join("bench", "results"))
    b.add_argument("--repeats", type=_positive("--repeats", 1, 100), default=3)
    b.add_argument("--quick", action="store_true", help="small sizes, for a smoke run")
    b.add_argument("--study-scenes", type=_study_scenes, default=None,
                   help="comma-separated sample scenes for --part study, filter and cycles (default: each "
                        "part's own); study keeps the other scenes' rows of --out's study.csv")
    b.add_argument("--startup-methods", type=_startup_methods, default=None,
                   help="comma-separated rows of the start-up table: method ids and 'all' (the seven in one "
                        "run; default: every row)")
    b.add_argument("--part", choices=("all", "skeleton", "startup", "methods", "scaling", "study", "filter",
                                      "cycles", "instancing", "camera_effects"),
                   default="all", help="pipeline phases (with buffers, Preview and start-up), the start-up table "
                   "alone, per-method tables, triangle-count scaling, the accuracy-versus-time study, filtered "
                   "passes, penumbra render against Cycles' shadow pair, an instanced scatter at production "
                   "scale (plan, render and Cycles: time and peak memory), or motion blur and depth of field "
                   "against Cycles' pair with the effect on")
    add_farm_parser(sub)
    return p


def _startup_methods(text: str):
    from .bench.phases import STARTUP_TARGETS
    names = [n.strip() for n in text.split(",") if n.strip()]
    bad = [n for n in names if n != "all" and n not in STARTUP_TARGETS]
    if bad or not names:
        raise UsageError(f"bad --startup-methods {text!r}: expected some of {','.join(STARTUP_TARGETS)},all")
    return names


def _study_scenes(text: str):
    from .bench.study import SCENES
    names = tuple(n.strip() for n in text.split(",") if n.strip())
    bad = [n for n in names if n not in SCENES]
    if bad or not names:
        raise UsageError(f"bad --study-scenes {text!r}: expected some of {','.join(SCENES)}")
    return names


def _check_blend(path: str) -> str:
    if not os.path.exists(path):
        raise UsageError(f"no such file: {path}")
    if not os.path.isfile(path):
        raise UsageError(f"not a file: {path}")
    if not os.access(path, os.R_OK):
        raise UsageError(f"cannot read {path}")
    with open(path, "rb") as f:
        head = f.read(12)
    # .blend files start with BLENDER (uncompressed) or a gzip / zstd header
    if not (head.startswith(b"BLENDER") or head.startswith(b"\x1f\x8b") or head.startswith(b"\x28\xb5\x2f\xfd")):
        raise UsageError(f"not a .blend file: {path}")
    return os.path.abspath(path)


def open_blend(path: str):
    """Open the .blend in this Blender session (read only: nothing is ever
    saved); returns its scene."""
    import bpy
    from .bridge.pipeline import first_line
    try:
        bpy.ops.wm.open_mainfile(filepath=path, load_ui=False)
    except Exception as exc:  # bpy raises RuntimeError with Blender's report
        raise UsageError(f"cannot open {path}: {first_line(exc)}")
    scene = bpy.context.scene
    if scene is None:
        raise UsageError(f"{path} has no scene")
    return scene


def _available_external():
    import importlib
    try:
        importlib.import_module(f"{__package__}.bridge.cycles_reference")
    except ModuleNotFoundError as exc:
        if exc.name != f"{__package__}.bridge.cycles_reference":
            raise
        return []
    return ["cycles"]


class _Progress:
    """Progress on stderr: a tqdm bar over the frames (and, within a frame, the
    lights and methods) when stderr is a terminal and not ``--quiet``; the
    notice that kernels are compiling (``core.warmup.CompileNotice``) as its
    own line unless ``--quiet``."""

    def __init__(self, n_frames: int, quiet: bool = False):
        self.quiet = quiet
        self.bar = None
        if not quiet and sys.stderr.isatty():
            try:
                from tqdm import tqdm
            except ModuleNotFoundError:      # the extension bundles no tqdm: no bar in Blender
                return
            self.bar = tqdm(total=n_frames, unit="frame", file=sys.stderr, dynamic_ncols=True,
                            bar_format="{l_bar}{bar}| {n:.2f}/{total_fmt} frames [{elapsed}<{remaining}]")

    def frame(self, k: int, frame: int):
        """The callback for ``job.run`` of the ``k``-th frame (number ``frame``)."""
        def progress(message, fraction):
            from .core.warmup import CompileNotice
            if isinstance(message, CompileNotice):
                if not self.quiet:
                    self.write(f"penumbra: {message}", sys.stderr)
                return
            if self.bar is not None:
                self.bar.set_description_str(f"frame {frame}: {message}"[:48], refresh=False)
                self.bar.update(k + max(0.0, min(1.0, fraction)) - self.bar.n)
        return progress

    def write(self, line: str, file=None):
        """A line on stdout (or ``file``), above the bar."""
        file = file or sys.stdout
        if self.bar is not None:
            self.bar.write(line, file=file)
        else:
            print(line, file=file, flush=True)

    def close(self):
        if self.bar is not None:
            self.bar.close()


def _summary(result) -> str:
    rows = [("light", "method", "V", "time s", "rmse", "reference")]
    for lr in result.lights:
        for pid, rec in lr.record.items():
            err = rec.get("error", {})
            rows.append((lr.name, pid, rec["visibility"], f"{rec['time_s']['total']:.3f}",
                         f"{err['rmse']:.4f}" if err else "-", err.get("reference", "-")))
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    lines = ["  ".join(c.ljust(w) for c, w in zip(r, widths)) for r in rows]
    lines.insert(1, "  ".join("-" * w for w in widths))
    if result.pixel_filter is not None:
        f = result.pixel_filter
        lines.append(f"pixel filter: {f['type']} {f['width_px']:g} px (--pixel-filter none: pixel centres)")
    if result.compile_s > 0:
        lines.append(f"kernel compilation: {result.compile_s:.3f} s (in no method's time)")
    return "\n".join(lines)


def _light_names(text: Optional[str]) -> Optional[List[str]]:
    """``--lights``: comma-separated light names (None: every light)."""
    return [s.strip() for s in text.split(",") if s.strip()] if text else None


def _request(args, passes, frame=None):
    """The frame request of ``render`` / ``plan`` (``FrameRequest.from_command_line``)."""
    from .bridge.pipeline import FrameRequest
    return FrameRequest.from_command_line(
        passes, frame=frame, resolution=args.resolution, lights=_light_names(args.lights),
        samples=getattr(args, "samples", None), seed=getattr(args, "seed", 0),
        map_size=getattr(args, "map_size", None), error_budget=args.error_budget, pixel_filter=args.pixel_filter,
        visibility=args.visibility)


def _prepare(bpy_scene, path, request):
    """``prepare_frame``, its refusals as one-line usage errors."""
    from .bridge.pipeline import NoCamera, prepare_frame
    try:
        return prepare_frame(bpy_scene, request)
    except NoCamera:
        at = f" at frame {request.frame}" if request.frame is not None else ""
        raise UsageError(f"{path}: the scene has no camera{at}")
    except ValueError as exc:
        raise UsageError(str(exc))


def cmd_render(args) -> int:
    from .core.planner import resolve_passes
    passes = resolve_passes(args.methods, _available_external(), allow_auto=True)
    path = _check_blend(args.scene)
    from .bridge.pipeline import check_out_dir, set_threads
    out, err = check_out_dir(os.path.abspath(args.out))
    if err:
        raise UsageError(err)
    from .core.compile_ahead import start_helpers
    from .core.warmup import kernels_cached
    start_helpers(passes, kernels_cached)   # a cold cache: helpers start while the .blend opens
    if args.threads:
        set_threads(args.threads)
    bpy_scene = open_blend(path)
    frames = args.frames or [args.frame if args.frame is not None else bpy_scene.frame_current]
    bar = _Progress(len(frames), args.quiet)
    try:
        for k, frame in enumerate(frames):
            _render_one(args, bpy_scene, path, out, passes, k, frame, bar)
    finally:
        bar.close()
    return 0


def _render_one(args, bpy_scene, path, out, passes, k, frame, bar):
    """One frame of ``penumbra render``: skipped when written (unless --force)."""
    from .bridge.capture import blend_stem
    from .bridge.pipeline import finish_frame
    from .core.output import output_paths
    done = output_paths(out, blend_stem(bpy_scene), frame)["json"]
    if os.path.exists(done) and not args.force:
        bar.write(f"frame {frame}: already written ({os.path.basename(done)}), skipped; --force recomputes it")
        return
    job = _prepare(bpy_scene, path, _request(args, passes, frame)).run(bar.frame(k, frame))
    result, paths = finish_frame(bpy_scene, job, out, store=False, previews=not args.no_previews)
    if paths is None:
        raise UsageError(job.warnings[-1] if job.warnings else f"frame {frame}: nothing was computed")
    for n in result.plan.notes:
        bar.write(f"penumbra: {n}")
    bar.write(_summary(result))
    bar.write(f"wrote {paths.get('exr', '(no EXR: no lights)')} and {paths['json']}")


def cmd_plan(args) -> int:
    """The decisions ``render`` makes, from the same functions: the request,
    the capture and the steps of ``render``, then the planner on the camera
    G-buffer at the plan's resolution (``--resolution``, default the
    scene's; ``core.planner.plan_frame``)."""
    from .core.buffers import FrameBuffers
    from .core.camera_effects import effects_line
    from .core.planner import plan_frame, resolve_passes
    passes = resolve_passes(args.methods, _available_external(), allow_auto=True)
    path = _check_blend(args.scene)
    job = _prepare(open_blend(path), path, _request(args, passes))
    scene = job.captured
    instances, unique, placed = scene.geometry_counts()
    print(f"geometry: {instances:,} instance(s), {unique:,} unique / {placed:,} instanced triangles")
    for step in job.steps:
        plan, _reach = plan_frame(scene, step.passes, step.names, step.error_budget,
                                  FrameBuffers(scene, *scene.resolution), step.overrides["visibility"])
        print(plan.describe())
    print(f"pixel filter: {job.pixel_filter.describe()}")
    effects = effects_line(scene, sampled=not job.pixel_filter.is_none)
    if effects:
        print(effects)
    return 0


def cmd_bench(args) -> int:
    from .bench import run_bench
    return run_bench(args)


def main(argv: Optional[List[str]] = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        from .core.planner import PlanError
        from .core.scene import GeometryTooLarge
        args = build_parser().parse_args(argv)
        if not args.command:
            raise UsageError("expected a command: render, plan, bench or farm")
        return {"render": cmd_render, "plan": cmd_plan, "bench": cmd_bench, "farm": cmd_farm}[args.command](args)
    except (UsageError, PlanError, GeometryTooLarge) as exc:
        print(f"penumbra: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("penumbra: interrupted", file=sys.stderr)
        return 130
    except Exception:
        if not _TERMINATED.is_set():
            raise
        # the SIGTERM's KeyboardInterrupt landed inside a Blender callback (the
        # capture render's), which Blender catches and prints; what failed after
        # it is its echo: the run was interrupted, not broken
        print("penumbra: interrupted", file=sys.stderr)
        return 130


#: set by SIGTERM (``_interrupt``): a farm stopping the task
_TERMINATED = threading.Event()


def _interrupt(signum, frame):
    _TERMINATED.set()
    raise KeyboardInterrupt


def console_main() -> None:
    # A farm stops a task with SIGTERM (OpenJD's NOTIFY_THEN_TERMINATE, a Dask
    # worker gone): handle it as Ctrl-C, so no half-written temporary file stays.
    signal.signal(signal.SIGTERM, _interrupt)
    if os.environ.get(watchdog.ENV):        # a farm chunk: exit with the worker that started it
        watchdog.exit_with_parent()
    sys.exit(main())


if __name__ == "__main__":
    console_main()
