"""The benchmark package (``penumbra.bench``, not shipped): the study's Pareto
front against brute force, the planner's table rebuilt from the committed
study.csv, ``install-table`` refusing a bad table without touching the
installed one, and ``python -m penumbra.bench.study``'s usage error.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest
from hypothesis import given, settings, strategies as st

from penumbra.bench import study
from penumbra.core import auto_choice
from helpers import ROOT

RESULTS = os.path.join(ROOT, "bench", "results")


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.floats(0.001, 10.0), st.floats(0.0, 1.0)), min_size=1, max_size=30))
def test_pareto_front_is_the_points_nothing_beats(points):
    front = set(study.pareto(points))

    def beaten(i):
        ti, ei = points[i]
        return any((t <= ti and e <= ei) and (t < ti or e < ei) for t, e in points)

    for i, p in enumerate(points):
        if i in front:
            assert not beaten(i)
        elif not beaten(i):                       # an exact duplicate of a front point
            assert any(points[j] == p for j in front)


@pytest.mark.bpy    # the study captures each scene's light (bench/harness.py -> tests/scenes.py)
def test_table_rebuilt_from_the_committed_study_is_the_committed_table(tmp_path):
    out = study.table_from_csv(os.path.join(RESULTS, "study.csv"), str(tmp_path / "auto_table.json"))
    with open(out) as f, open(os.path.join(RESULTS, "auto_table.json")) as g:
        rebuilt, committed = json.load(f), json.load(g)
    assert auto_choice.parse_table(rebuilt).scenes == auto_choice.parse_table(committed).scenes


def test_install_table_refuses_a_bad_table_and_keeps_the_installed_one(tmp_path):
    dst = tmp_path / "installed.json"
    dst.write_text('{"kept": true}\n')
    bad = tmp_path / "bad.json"
    bad.write_text('{"format": "something else"}\n')
    with pytest.raises(auto_choice.TableError):
        study.install_table(str(bad), str(dst))
    assert json.loads(dst.read_text()) == {"kept": True}
    assert study.install_table(os.path.join(RESULTS, "auto_table.json"), str(dst)) == str(dst)
    assert auto_choice.load_table(str(dst)).scenes


def test_study_module_usage_error_exits_2_with_one_line():
    env = dict(os.environ, PYTHONWARNINGS="error::RuntimeWarning")   # runpy: imported twice
    p = subprocess.run([sys.executable, "-m", "penumbra.bench.study", "no-such-command"],
                       capture_output=True, text=True, env=env, timeout=300)
    assert p.returncode == 2
    assert p.stderr.strip().splitlines() == [
        "usage: python -m penumbra.bench.study install-table [SRC] | table-from-csv CSV OUT"]


def test_study_csv_alone_rebuilds_the_committed_table():
    """study.csv carries each row's light and scene shape: the kept rows of a
    scene-subset run (``kept_rows``) give the planner's table without
    re-capturing the scenes."""
    rows = study.kept_rows(os.path.join(RESULTS, "study.csv"), ())
    assert {r["scene"] for r in rows} == set(study.SCENES)
    assert all(isinstance(r["seconds"], float) and isinstance(r["triangles"], int) for r in rows
               if r["status"] == "ok")
    with open(os.path.join(RESULTS, "auto_table.json")) as g:
        committed = json.load(g)
    assert auto_choice.parse_table(study.auto_table(rows)).scenes == auto_choice.parse_table(committed).scenes
    # a re-run of one scene drops only that scene's rows
    kept = study.kept_rows(os.path.join(RESULTS, "study.csv"), ("leaf_cards",))
    assert {r["scene"] for r in kept} == set(study.SCENES) - {"leaf_cards"}
    assert len(kept) == len(rows) - sum(r["scene"] == "leaf_cards" for r in rows)


def test_every_study_scene_has_two_sizes_and_its_light_kinds_sweeps(monkeypatch):
    assert set(study.SIZES) == set(study.SCENES)
    for name, sizes in study.SIZES.items():
        assert len(sizes) == 2 and study._pixels("%dx%d" % sizes[1]) > study._pixels("%dx%d" % sizes[0])
    # an entry for one light kind runs only there; the others run for every kind
    entries = study.SWEEPS["depth_raytrace"] + [("sun only", {"samples": 16}, ("sun",))]
    monkeypatch.setitem(study.SWEEPS, "depth_raytrace", entries)
    sun = [label for label, _ in study.sweep("depth_raytrace", "sun")]
    area = [label for label, _ in study.sweep("depth_raytrace", "area")]
    assert set(area) < set(sun) and set(sun) - set(area) == {"sun only"}


def test_each_sweep_entry_is_a_distinct_configuration_and_the_default_is_labelled():
    """No two entries of a method's sweep run the same parameters (a label
    that no longer changes anything would measure the default twice), and
    the auto table's row of each method is its defaults at 64 light
    samples."""
    from penumbra.core import methods as registry
    producers = registry.producers()
    for mid in study.SWEEPS:
        m = producers[mid]
        configs = [(params.get("map_scale"), m.make_params({k: v for k, v in params.items() if k != "map_scale"}))
                   for _, params in study.sweep(mid)]
        assert len({repr(c) for c in configs}) == len(configs), mid
        label = study.default_setting(mid)
        assert label is not None, mid
        (params,) = [p for lab, p in study.sweep(mid) if lab == label]
        assert m.make_params(params) == m.make_params({"samples": study.AUTO_LIGHT_SAMPLES}), mid


def test_bench_study_scenes_bad_name_exits_2_with_one_line(capsys):
    from penumbra.cli import main
    assert main(["bench", "--part", "study", "--study-scenes", "grids,nosuch", "--out", "/nonexistent"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "bad --study-scenes" in err[0] and "leaf_cards" in err[0]


def test_bench_startup_methods_bad_name_exits_2_with_one_line(capsys):
    from penumbra.cli import main
    assert main(["bench", "--part", "startup", "--startup-methods", "pcf,nosuch", "--out", "/nonexistent"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "bad --startup-methods" in err[0] and "penumbra_casting" in err[0]


# --------------------------------------------------------------------------
# --part instancing: the guarded children and the table
def test_instancing_child_over_the_memory_limit_is_killed_and_recorded():
    from penumbra.bench import instancing
    t = __import__("time").perf_counter()
    run = instancing.run_guarded([sys.executable, "-c", "import time; b = b'x' * 400_000_000; time.sleep(60)"],
                                 "render", timeout_s=60, memory_limit=150e6)
    assert run.failure == "out of memory (> 0.15 GB) during render"
    assert run.returncode == -9 and 150e6 < run.peak_bytes < 1e9
    assert __import__("time").perf_counter() - t < 30
    row = {"scene": "scatter", "light": "sun", "instances": 100000, "geometry": list(instancing.expected_geometry(100000)),
           "geometry_measured": False, "render": instancing._step(run)}
    md = instancing.table([row], {"cpu": "Test CPU", "cores": 2, "date": "2026-01-01"})
    (line,) = [ln for ln in md.splitlines() if ln.startswith("| scatter")]
    assert "| failed: out of memory (> 0.15 GB) during render |" in line
    assert "4,824 / 482,200,002* |" in line
    assert "* counted from make_scatter.py's geometry" in md


def test_instancing_child_timeout_and_exit_status_are_one_line_failures():
    from penumbra.bench import instancing
    run = instancing.run_guarded([sys.executable, "-c", "import time; time.sleep(60)"], "plan", timeout_s=1.0)
    assert run.failure == "timed out (> 1 s) during plan" and run.seconds < 20
    run = instancing.run_guarded([sys.executable, "-c", "import sys; print('x', file=sys.stderr); "
                                  "sys.exit('no camera in scene')"], "plan")
    assert run.failure == "exit 1 during plan: no camera in scene" and run.returncode == 1
    run = instancing.run_guarded([sys.executable, "-c", "print('geometry: 2,001 instance(s), 4,824 unique / "
                                  "9,644,002 instanced triangles')"], "plan")
    assert run.ok and instancing.parse_geometry(run.stdout) == (2001, 4824, 9644002)
    assert instancing.expected_geometry(2000) == (2001, 4824, 9644002)


def test_instancing_results_table_and_json(tmp_path):
    from penumbra.bench import instancing
    ok = {"status": "ok", "seconds": 46.9, "peak_gb": 4.86}
    sidecar = {"plan": {"lights": [{"auto": {"method": "embree_irr"}}]}, "compile_s": 1.18, "total_time_s": 40.4,
               "lights": [{"name": "AreaLight", "layer": "AreaLight", "methods": {"embree_irr": {
                   "time_s": {"gbuffer": 5.18, "bvh": 4.02, "trace": 10.04, "total": 19.3}}}}]}
    row = {"scene": "scatter", "light": "area", "instances": 2000, "geometry": [2001, 4824, 9644002],
           "geometry_measured": True, "plan": {"status": "ok", "seconds": 11.1, "peak_gb": 2.64},
           "render": dict(ok, **instancing.sidecar_summary(sidecar)),
           "cycles": {"samples": 64, "status": "ok", "seconds": 35.0, "peak_gb": 0.41, "render_shadowed": 15.29,
                      "render_unshadowed": 13.8},
           "accuracy": {"status": "ok", "rmse_pass": 0.01234, "rmse_cycles64": 0.04567}}
    small = dict(row, light="sun", instances=200, accuracy=None,
                 cycles={"samples": 64, "status": "failed: timed out (> 1200 s) during Cycles' pair",
                         "seconds": 1200, "peak_gb": 1.0})
    md = instancing.write_results([row, small], str(tmp_path), mach={"cpu": "Test CPU", "cores": 2,
                                                                        "date": "2026-01-01"})
    lines = md.splitlines()
    assert lines[0].startswith("| scene | light | instances | unique / instanced triangles | plan s |")
    assert lines[2].startswith("| scatter | sun | 200 |")                     # sun before area
    assert "| failed: timed out (> 1200 s) during Cycles' pair | - |" in lines[2]
    assert lines[3] == ("| scatter | area | 2,000 | 4,824 / 9,644,002 | 11.1 | 2.64 | 46.9 | 4.86 | embree_irr | "
                        "gbuffer 5.18, bvh 4.02, trace 10.04, compile 1.18 | 15.3 + 13.8 | 0.41 | 0.0123 / 0.0457 |")
    assert lines[-1] == "Test CPU, 2 cores, 2026-01-01"
    assert row["render"]["pass"] == "embree_irr" and row["render"]["layer"] == "AreaLight"
    assert (tmp_path / "instancing.md").read_text() == md
    saved = json.loads((tmp_path / "instancing.json").read_text())
    assert saved["machine"]["cpu"] == "Test CPU" and [r["instances"] for r in saved["rows"]] == [2000, 200]
