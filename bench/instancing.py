"""``penumbra bench --part instancing``: a production-scale instanced scatter.

The scene is ``sample_blends/make_scatter.py``'s ``build_scatter``: one tree
of 4,822 triangles placed N times by a Geometry Nodes Instance on Points
scatter, at its own 480x270. The .blend files are built on demand, each by
the script in a child process, into ``<cache>/penumbra/scatter`` (keyed on
the builder's sources; never into ``sample_blends/``). Rows (``ROWS``): the
sun and the area light at 2,000 instances, and the sun at 1,000, 10,000 and
100,000; ``--quick``: the sun at 200 and 1,000, without the accuracy.

Per row, every step is a child process of its own, so its peak RSS is that
step's alone (``os.wait4``'s ``ru_maxrss``, or the watchdog's largest poll
when larger):

- ``penumbra plan FILE --resolution 480x270``: wall, peak RSS, and the
  geometry counts of its ``geometry:`` line;
- ``penumbra render FILE --out TMP --no-previews --quiet`` at its defaults
  (``auto``, filtered like the scene renders; a warm Numba cache): wall, peak
  RSS, and from the JSON sidecar the method ``auto`` chose, its phase times
  and ``compile_s``;
- Cycles' shadow pair at ``CYCLES_SAMPLES`` samples as the other parts render
  it (``truth.cycles_pair_of``: ``bridge/cycles_reference.py``'s
  ``render_light_reference``, the scene's pixel filter), in a process of its
  own: the seconds of each render (``bpy.ops.render.render``, as ``--part
  cycles`` times it; the process's wall in the JSON) and the process's peak
  RSS.

Every child runs under ``run_guarded``: a timeout (``TIMEOUT_S``) and a
memory watchdog polling the RSS of the child's process tree (psutil, or
``/proc/<pid>/status``) that kills it above ``MEMORY_LIMIT``. A child killed
or failing is recorded in its row as ``failed: <why>`` (``out of memory
(> 20 GB) during render``); the bench goes on with the next step.

Accuracy (the 2,000-instance rows, not ``--quick``): Cycles' truth at
``truth.TRUTH_SAMPLES`` (1024) with the same settings and the truth's own
seed (cached like the study's truth), when affordable: not cached and
estimated above ``TRUTH_BUDGET_S`` (16 x the 64-sample pair's render seconds)
it is skipped with a note. Then the RMSE over the lit pixels (``reach_mask``
on the pixel-centre G-buffer, as the study) of the default pass read back
from the render's EXR and of the 64-sample pair's ratio, against the truth.

Writes ``instancing.md`` / ``.json`` (``--quick``: ``instancing_quick.*``)
after every row.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from typing import List, Optional

from .harness import ROOT, cache_dir, machine

RESOLUTION = (480, 270)
#: (light, instances): the two 2,000-instance rows, then the sun's scaling
ROWS = (("sun", 2000), ("area", 2000), ("sun", 1000), ("sun", 10000), ("sun", 100000))
QUICK_ROWS = (("sun", 200), ("sun", 1000))
ACCURACY_ROWS = (("sun", 2000), ("area", 2000))
LIGHT_NAMES = {"sun": "Sun", "area": "AreaLight"}      # make_scatter.py's light objects
CYCLES_SAMPLES = 64
TIMEOUT_S = 20 * 60
TRUTH_BUDGET_S = 15 * 60
TRUTH_TIMEOUT_S = 40 * 60
MEMORY_LIMIT = 20e9                                   # bytes (20 GB)
POLL_S = 0.1
GB = 1e9
#: make_scatter.py's geometry: the tree's triangles (8 trunk quads, its octagon cap, 2,400 leaf quads)
#: and the ground's, for a row whose plan did not finish
TREE_TRIANGLES = 2 * 8 + 6 + 2 * 2400
GROUND_TRIANGLES = 2
BUILDER = os.path.join(ROOT, "sample_blends", "make_scatter.py")
BUILDER_SOURCES = (BUILDER, os.path.join(ROOT, "sample_blends", "make_samples.py"))

_GEOMETRY = re.compile(r"geometry: ([\d,]+) instance\(s\), ([\d,]+) unique / ([\d,]+) instanced triangles")


# --------------------------------------------------------------------------
# guarded children
@dataclass
class ChildRun:
    """One child process: what it was, its wall seconds, peak RSS (bytes),
    exit code, and ``failure`` (None, or why it failed / was killed)."""
    what: str
    seconds: float
    peak_bytes: int
    returncode: int
    failure: Optional[str] = None
    stdout: str = ""
    stderr: str = ""

    @property
    def ok(self) -> bool:
        return self.failure is None


def tree_rss(pid: int) -> int:
    """Resident bytes of process ``pid`` and all its descendants (0 once gone)."""
    try:
        import psutil
    except ImportError:
        return _proc_tree_rss(pid)
    try:
        p = psutil.Process(pid)
        procs = [p] + p.children(recursive=True)
    except psutil.Error:
        return 0
    total = 0
    for q in procs:
        try:
            total += q.memory_info().rss
        except psutil.Error:
            pass
    return total


def _proc_tree_rss(pid: int) -> int:
    """``tree_rss`` from /proc: VmRSS of ``pid`` and, through
    ``/proc/<pid>/task/*/children``, of its descendants."""
    total, todo, seen = 0, [pid], set()
    while todo:
        p = todo.pop()
        if p in seen:
            continue
        seen.add(p)
        try:
            with open(f"/proc/{p}/status") as f:
                for line in f:
                    if line.startswith("VmRSS:"):
                        total += int(line.split()[1]) * 1024
                        break
            for task in os.listdir(f"/proc/{p}/task"):
                with open(f"/proc/{p}/task/{task}/children") as f:
                    todo.extend(int(c) for c in f.read().split())
        except (OSError, ValueError):
            continue
    return total


def _gb(n: float) -> str:
    return f"{n / GB:g}"


def run_guarded(argv: List[str], what: str, timeout_s: float = TIMEOUT_S, memory_limit: float = MEMORY_LIMIT,
                env=None, poll_s: float = POLL_S) -> ChildRun:
    """Run ``argv`` in a session of its own, its output to files, polling its
    process tree's RSS every ``poll_s``: above ``memory_limit`` bytes, or
    after ``timeout_s``, the whole session is killed (SIGKILL). Never
    raises for the child's sake: a failure is ``ChildRun.failure``, one line
    naming ``what``."""
    env = dict(os.environ if env is None else env, PYTHONUNBUFFERED="1")   # a killed child's lines stay
    with tempfile.TemporaryFile("w+") as out, tempfile.TemporaryFile("w+") as err:
        t0 = time.perf_counter()
        try:
            p = subprocess.Popen(argv, stdout=out, stderr=err, stdin=subprocess.DEVNULL, env=env,
                                 start_new_session=True)
        except OSError as exc:
            return ChildRun(what, 0.0, 0, -1, f"could not start {what}: {exc}")
        polled, why = 0, None
        while True:
            pid, status, ru = os.wait4(p.pid, os.WNOHANG)
            if pid:
                break
            rss = tree_rss(p.pid)
            polled = max(polled, rss)
            if rss > memory_limit:
                why = f"out of memory (> {_gb(memory_limit)} GB) during {what}"
            elif time.perf_counter() - t0 > timeout_s:
                why = f"timed out (> {timeout_s:g} s) during {what}"
            if why:
                try:
                    os.killpg(p.pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
                pid, status, ru = os.wait4(p.pid, 0)
                break
            time.sleep(poll_s)
        seconds = time.perf_counter() - t0
        p.returncode = code = os.waitstatus_to_exitcode(status)   # reaped here: Popen must not wait again
        out.seek(0)
        err.seek(0)
        stdout, stderr = out.read(), err.read()
    peak = max(int(ru.ru_maxrss) * 1024, polled)
    if why is None and code != 0:
        why = exit_failure(code, what, stderr, peak, memory_limit)
    return ChildRun(what, seconds, peak, code, why, stdout, stderr)


def exit_failure(code: int, what: str, stderr: str, peak: float = 0, memory_limit: float = MEMORY_LIMIT) -> str:
    """One line for a child that ended with exit status ``code`` (negative:
    killed by that signal) by itself."""
    if code < 0:
        name = signal.Signals(-code).name if -code in signal.valid_signals() else f"signal {-code}"
        if -code == signal.SIGKILL:
            return (f"killed by SIGKILL during {what} at {peak / GB:.1f} GB "
                    f"(the kernel's out-of-memory killer, below the {_gb(memory_limit)} GB watchdog)")
        return f"killed by {name} during {what}"
    lines = [ln.strip() for ln in stderr.splitlines() if ln.strip()]
    return f"exit {code} during {what}" + (f": {lines[-1][:200]}" if lines else "")


# --------------------------------------------------------------------------
# scenes
def builder_key() -> str:
    h = hashlib.sha256()
    for path in BUILDER_SOURCES:
        with open(path, "rb") as f:
            h.update(f.read())
    return h.hexdigest()[:12]


def scatter_blend(light: str, instances: int, folder: Optional[str] = None) -> tuple:
    """(path, None) of the cached scatter .blend, built first when missing;
    (None, failure) when the build failed."""
    folder = folder or cache_dir("scatter")
    path = os.path.join(folder, f"scatter_{light}_{instances}_{RESOLUTION[0]}x{RESOLUTION[1]}_{builder_key()}.blend")
    if os.path.exists(path):
        return path, None
    os.makedirs(folder, exist_ok=True)
    tmp = path[:-len(".blend")] + f".{os.getpid()}.tmp.blend"
    run = run_guarded([sys.executable, BUILDER, tmp, "--instances", str(instances), "--light", light],
                      "the scene's build")
    if not run.ok or not os.path.exists(tmp):
        for junk in (tmp, tmp + "1"):
            if os.path.exists(junk):
                os.remove(junk)
        return None, run.failure or "the scene's build wrote no .blend"
    os.replace(tmp, path)
    return path, None


def expected_geometry(instances: int) -> tuple:
    """(instances, unique, instanced triangles) the plan prints for the
    scatter: the trees and the ground."""
    return instances + 1, TREE_TRIANGLES + GROUND_TRIANGLES, instances * TREE_TRIANGLES + GROUND_TRIANGLES


def parse_geometry(stdout: str) -> Optional[tuple]:
    """(instances, unique, instanced triangles) of ``penumbra plan``'s
    ``geometry:`` line, or None."""
    m = _GEOMETRY.search(stdout)
    return None if m is None else tuple(int(g.replace(",", "")) for g in m.groups())


def sidecar_summary(rec: dict) -> dict:
    """What the table takes from a frame's JSON sidecar: the method auto
    chose, its pass id and layer, its phase times, compile and total."""
    lp = rec["plan"]["lights"][0]
    light = rec["lights"][0]
    method = (lp.get("auto") or {}).get("method") or next(iter(light["methods"]))
    pid = method if method in light["methods"] else next(iter(light["methods"]))
    times = dict(light["methods"][pid]["time_s"])
    total = times.pop("total", None)
    return {"method": method, "pass": pid, "layer": light["layer"], "phases_s": times, "method_s": total,
            "compile_s": rec.get("compile_s"), "frame_s": rec.get("total_time_s"),
            "buffers_time_s": rec.get("buffers_time_s", {})}


# --------------------------------------------------------------------------
# rows
def _step(run: ChildRun) -> dict:
    return {"status": "ok" if run.ok else f"failed: {run.failure}", "seconds": round(run.seconds, 2),
            "peak_gb": round(run.peak_bytes / GB, 2)}


def _child(*args: str) -> List[str]:
    return [sys.executable, "-m", "penumbra.bench.instancing", *args]


def measure_row(light: str, instances: int, accuracy: bool, log=print) -> dict:
    """Every step of one row, each in its own guarded process."""
    W, H = RESOLUTION
    row = {"scene": "scatter", "light": light, "instances": instances, "resolution": f"{W}x{H}",
           "load": round(os.getloadavg()[0], 2)}
    blend, failure = scatter_blend(light, instances)
    if blend is None:
        row["failure"] = f"failed: {failure}"
        return row
    row["blend"] = blend
    exe = os.path.join(os.path.dirname(sys.executable), "penumbra")
    run = run_guarded([exe, "plan", blend, "--resolution", f"{W}x{H}"], "plan")
    row["plan"] = _step(run)
    geometry = parse_geometry(run.stdout)
    row["geometry"] = list(geometry or expected_geometry(instances))
    row["geometry_measured"] = geometry is not None
    log(f"  plan: {row['plan']}")
    with tempfile.TemporaryDirectory(prefix="penumbra_instancing_") as tmp:
        out = os.path.join(tmp, "out")
        run = run_guarded([exe, "render", blend, "--out", out, "--no-previews", "--quiet"], "render")
        row["render"] = _step(run)
        sidecars = sorted(f for f in os.listdir(out) if f.endswith(".json")) if os.path.isdir(out) else []
        if run.ok and sidecars:
            with open(os.path.join(out, sidecars[0])) as f:
                row["render"].update(sidecar_summary(json.load(f)))
        elif run.ok:
            row["render"]["status"] = "failed: render wrote no JSON sidecar"
        log(f"  render: {row['render']}")
        res = os.path.join(tmp, "cycles.json")
        run = run_guarded(_child("cycles", blend, LIGHT_NAMES[light], "--samples", str(CYCLES_SAMPLES),
                                 "--save", os.path.join(tmp, "cycles.npy"), "--result", res), "Cycles' pair")
        row["cycles"] = dict(_step(run), samples=CYCLES_SAMPLES)
        if run.ok:
            with open(res) as f:
                row["cycles"].update(json.load(f))
        log(f"  Cycles: {row['cycles']}")
        if accuracy:
            row["accuracy"] = _accuracy(row, blend, light, tmp, out)
            log(f"  accuracy: {row['accuracy']}")
    return row


def _accuracy(row, blend, light, tmp, out) -> dict:
    from .truth import TRUTH_SAMPLES
    r, c = row["render"], row["cycles"]
    if "pass" not in r or "render_shadowed" not in c:
        return {"status": "skipped: the render or Cycles' pair failed"}
    estimate = (TRUTH_SAMPLES / CYCLES_SAMPLES) * (c["render_shadowed"] + c["render_unshadowed"])
    exr = os.path.join(out, next(f for f in os.listdir(out) if f.endswith(".exr")))
    res = os.path.join(tmp, "accuracy.json")
    run = run_guarded(_child("accuracy", blend, LIGHT_NAMES[light], "--exr", exr, "--layer", r["layer"],
                             "--pass", r["pass"], "--cycles", os.path.join(tmp, "cycles.npy"),
                             "--samples", str(TRUTH_SAMPLES), "--estimate-s", f"{estimate:.1f}",
                             "--budget-s", str(TRUTH_BUDGET_S), "--result", res),
                      f"the {TRUTH_SAMPLES}-sample truth", timeout_s=TRUTH_TIMEOUT_S)
    if not run.ok:
        return {"status": f"failed: {run.failure}", "truth_estimate_s": round(estimate)}
    with open(res) as f:
        return dict(json.load(f), truth_estimate_s=round(estimate))


# --------------------------------------------------------------------------
# the table
HEAD = ("scene", "light", "instances", "unique / instanced triangles", "plan s", "plan peak GB", "render s",
        "render peak GB", "auto's method", "its phases s", "Cycles pair s (shadowed + unshadowed)",
        "Cycles peak GB", "rmse pass / cycles64")


def _cell_time(step) -> str:
    if not step:
        return "-"
    return f"{step['seconds']:.1f}" if step["status"] == "ok" else step["status"]


def _cell_peak(step) -> str:
    return f"{step['peak_gb']:.2f}" if step else "-"


def _phases(r: dict) -> str:
    if not r or r.get("status") != "ok" or "phases_s" not in r:
        return "-"
    parts = [f"{k} {v:.2f}" for k, v in r["phases_s"].items()]
    if r.get("compile_s"):
        parts.append(f"compile {r['compile_s']:.2f}")
    return ", ".join(parts)


def _cycles_cells(c: dict) -> tuple:
    if not c:
        return "-", "-"
    if c.get("status", "ok") != "ok":
        return c["status"], "-"
    return f"{c['render_shadowed']:.1f} + {c['render_unshadowed']:.1f}", f"{c['peak_gb']:.2f}"


def _rmse_cell(a: Optional[dict]) -> str:
    if not a:
        return "-"
    if a.get("status", "ok") != "ok":
        return a["status"]
    return f"{a['rmse_pass']:.4f} / {a['rmse_cycles64']:.4f}"


def table(rows: List[dict], mach: dict) -> str:
    """The Markdown table of ``rows`` (sorted: sun then area, by instances)
    with its footnotes and the machine line."""
    order = {"sun": 0, "area": 1}
    lines = ["| " + " | ".join(HEAD) + " |", "|" + "---|" * len(HEAD)]
    estimated = False
    for r in sorted(rows, key=lambda r: (order.get(r["light"], 9), r["instances"])):
        if "failure" in r:
            cells = [r["scene"], r["light"], f"{r['instances']:,}", r["failure"]] + ["-"] * (len(HEAD) - 4)
        else:
            _, unique, placed = r["geometry"]
            star = "" if r.get("geometry_measured") else "*"
            estimated |= bool(star)
            render = r.get("render") or {}
            cyc_s, cyc_gb = _cycles_cells(r.get("cycles"))
            cells = [r["scene"], r["light"], f"{r['instances']:,}", f"{unique:,} / {placed:,}{star}",
                     _cell_time(r.get("plan")), _cell_peak(r.get("plan")), _cell_time(render), _cell_peak(render),
                     render.get("method", "-") if render.get("status") == "ok" else "-", _phases(render),
                     cyc_s, cyc_gb, _rmse_cell(r.get("accuracy"))]
        lines.append("| " + " | ".join(cells) + " |")
    notes = [
        "",
        f"`sample_blends/make_scatter.py` scenes at {RESOLUTION[0]}x{RESOLUTION[1]}, one process per step: "
        "plan s / render s: the wall of `penumbra plan` / `penumbra render` (defaults: auto, filtered; start-up, "
        "load, capture, EXR and JSON included, warm Numba cache); peak GB: the process's peak RSS; phases: the "
        "JSON sidecar's times of auto's method and `compile_s`; a failed step's peak GB: up to its end (the "
        "watchdog's kill). Cycles: the shadowed and the unshadowed render "
        f"at {CYCLES_SAMPLES} samples (the scene's pixel filter, as `--part cycles`), in one process: "
        "the seconds of each render, the process's peak RSS. rmse: over the lit pixels against Cycles' "
        "1024-sample ratio (the truth's own seed), of the default pass and of the 64-sample pair. Every child "
        f"is killed above {_gb(MEMORY_LIMIT)} GB of RSS or after {TIMEOUT_S // 60} min.",
    ]
    if estimated:
        notes.append("* counted from make_scatter.py's geometry: the plan did not finish.")
    loads = [r["load"] for r in rows if "load" in r]
    if loads:
        notes.append(f"1-minute load average at the rows' starts: {min(loads):g} to {max(loads):g}.")
    notes.append(f"{mach.get('cpu', '?')}, {mach.get('cores', '?')} cores, {mach.get('date', '?')}")
    return "\n".join(lines + notes) + "\n"


def source_state() -> dict:
    """The commit measured and the files changed on top of it (``git status``), or {}."""
    try:
        head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True,
                              timeout=30).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=ROOT,
                               capture_output=True, text=True, timeout=30).stdout.splitlines()
    except (OSError, subprocess.SubprocessError):
        return {}
    return {"commit": head, "modified": [ln[3:] for ln in dirty]}


def write_results(rows: List[dict], out_dir: str, quick: bool = False, mach: Optional[dict] = None) -> str:
    """``instancing.md`` / ``.json`` (``_quick`` for ``--quick``) under ``out_dir``; returns the table."""
    mach = mach or machine()
    md = table(rows, mach)
    os.makedirs(out_dir, exist_ok=True)
    stem = os.path.join(out_dir, "instancing" + ("_quick" if quick else ""))
    with open(stem + ".md", "w") as f:
        f.write(md)
    with open(stem + ".json", "w") as f:
        json.dump({"machine": mach, "source": source_state(), "resolution": list(RESOLUTION), "memory_limit_gb": MEMORY_LIMIT / GB,
                   "timeout_s": TIMEOUT_S, "cycles_samples": CYCLES_SAMPLES,
                   "rows": [{k: v for k, v in r.items() if k != "blend"} for r in rows]}, f, indent=2)
    return md


def bench_instancing(out_dir: str, quick: bool = False) -> str:
    """Every row of ``ROWS`` (``QUICK_ROWS``), written after each; returns the table."""
    rows = []
    md = ""
    for light, n in (QUICK_ROWS if quick else ROWS):
        print(f"scatter, {light}, {n:,} instances", flush=True)
        t = time.perf_counter()
        rows.append(measure_row(light, n, accuracy=not quick and (light, n) in ACCURACY_ROWS))
        print(f"  ({time.perf_counter() - t:.0f} s)", flush=True)
        md = write_results(rows, out_dir, quick)
    return md


# --------------------------------------------------------------------------
# the children that need bpy (``python -m penumbra.bench.instancing ...``)
def _open(path: str):
    import bpy
    bpy.ops.wm.open_mainfile(filepath=path, load_ui=False)
    return bpy.context.scene


def _write_json(path: str, data: dict) -> None:
    tmp = path + ".tmp"
    with open(tmp, "w") as f:
        json.dump(data, f)
    os.replace(tmp, path)


def _child_cycles(a) -> None:
    import numpy as np
    from .truth import cycles_pair_of
    scene = _open(a.blend)
    renders: dict = {}
    v, _ = cycles_pair_of(scene, a.light, RESOLUTION, a.samples, 0, renders)
    np.save(a.save, v)
    _write_json(a.result, {k: round(s, 2) for k, s in renders.items()})


def _child_accuracy(a) -> None:
    import numpy as np
    from ..bridge.capture import capture_scene
    from ..core.buffers import FrameBuffers
    from ..core.exr import read_multilayer
    from ..core.metrics import errors, reach_mask
    from .truth import cycles_truth_file, truth_file_cached
    if not truth_file_cached(a.blend, a.light, RESOLUTION, a.samples) and a.estimate_s > a.budget_s:
        _write_json(a.result, {"status": f"truth skipped: {a.samples} samples estimated at "
                                         f"{a.estimate_s / 60:.0f} min > {a.budget_s / 60:.0f} min"})
        return
    scene = _open(a.blend)
    t = time.perf_counter()
    truth = cycles_truth_file(scene, a.blend, a.light, RESOLUTION, a.samples)
    truth_s = time.perf_counter() - t
    captured = capture_scene(scene, resolution=RESOLUTION)
    light = next(lt for lt in captured.lights if lt.name == a.light)
    lit = reach_mask(FrameBuffers(captured, *RESOLUTION).gbuffer, light)
    del captured
    v = read_multilayer(a.exr)[a.layer][a.pass_id]
    c64 = np.load(a.cycles)
    _write_json(a.result, {"status": "ok", "truth_samples": a.samples, "truth_s": round(truth_s, 1),
                           "lit_pixels": int(lit.sum()),
                           "rmse_pass": errors(np.where(lit, v, 1.0), truth, lit)["rmse"],
                           "rmse_cycles64": errors(c64, truth, lit)["rmse"]})


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m penumbra.bench.instancing",
                                 description="the instancing benchmark's child processes")
    sub = ap.add_subparsers(dest="command", required=True)
    c = sub.add_parser("cycles", help="Cycles' shadow pair")
    c.add_argument("blend")
    c.add_argument("light")
    c.add_argument("--samples", type=int, default=CYCLES_SAMPLES)
    c.add_argument("--save", required=True, help="the pair's shadow ratio (.npy)")
    c.add_argument("--result", required=True)
    q = sub.add_parser("accuracy", help="the truth and both RMSEs")
    q.add_argument("blend")
    q.add_argument("light")
    q.add_argument("--exr", required=True)
    q.add_argument("--layer", required=True)
    q.add_argument("--pass", dest="pass_id", required=True)
    q.add_argument("--cycles", required=True, help="the 64-sample pair's ratio (.npy)")
    q.add_argument("--samples", type=int, required=True)
    q.add_argument("--estimate-s", type=float, required=True)
    q.add_argument("--budget-s", type=float, required=True)
    q.add_argument("--result", required=True)
    a = ap.parse_args(argv)
    {"cycles": _child_cycles, "accuracy": _child_accuracy}[a.command](a)
    return 0


if __name__ == "__main__":
    sys.exit(main())
