#!/usr/bin/env python3
"""The test matrix ``make test`` runs: the core tests once, every test that
touches bpy on each tested Blender (tests/conftest.py decides which is which).

    python scripts/test_matrix.py --core .venv --bpy .venv .venv-5.0 .venv-5.3 [-- PYTEST ARGS]

Each run is ``VENV/bin/python -m pytest --part core|bpy`` with a JUnit XML
report; afterwards the script checks that the core run and each bpy run
together ran every test the default venv collects (none dropped, none run
twice in one venv), prints one line per run (Blender, Python, numpy, tests,
failures, seconds) and exits 1 when anything failed or is missing.
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
import xml.etree.ElementTree as ET

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
VERSIONS = ("import bpy, numpy, sys; print(bpy.app.version_string, '|', "
            "'Python %d.%d.%d' % sys.version_info[:3], '|', 'numpy', numpy.__version__)")


def _python(venv: str) -> str:
    return os.path.join(venv, "bin", "python")


def junit_id(nodeid: str) -> str:
    """``tests/test_x.py::Cls::test[p]`` -> ``tests.test_x.Cls::test[p]``, the
    (classname, name) pair a JUnit report gives."""
    path, *rest = nodeid.split("::")
    cls = ".".join([path[:-3].replace("/", ".")] + rest[:-1])
    return f"{cls}::{rest[-1]}"


def collected(venv: str, part: str) -> list[str]:
    proc = subprocess.run([_python(venv), "-m", "pytest", "--collect-only", "-q", "--part", part, "tests"],
                          cwd=ROOT, capture_output=True, text=True)
    if proc.returncode != 0:
        sys.exit(f"test_matrix: collecting in {venv} failed:\n{proc.stdout[-3000:]}{proc.stderr[-3000:]}")
    return [junit_id(ln.strip()) for ln in proc.stdout.splitlines() if "::" in ln]


def start(venv: str, part: str, extra: list[str], tmp: str, log: bool) -> dict:
    """Start one pytest run (its output to a log file in ``tmp`` when ``log``)."""
    versions = subprocess.run([_python(venv), "-c", VERSIONS], capture_output=True, text=True,
                              cwd=ROOT).stdout.strip()
    name = f"{part}-{os.path.basename(venv.rstrip('/'))}"
    xml = os.path.join(tmp, f"{name}.xml")
    print(f"=== {part} tests on {venv} ({versions})", flush=True)
    out = open(os.path.join(tmp, f"{name}.log"), "w") if log else None
    # a temp folder per run: tests check what they leave in theirs, and
    # parallel runs must not see each other's files
    run_tmp = os.path.join(tmp, f"{name}-tmp")
    os.makedirs(run_tmp)
    proc = subprocess.Popen([_python(venv), "-m", "pytest", "-q", "--part", part,
                             f"--junitxml={xml}", *extra, "tests"], cwd=ROOT, stdout=out, stderr=out,
                            env={**os.environ, "TMPDIR": run_tmp})
    return {"venv": venv, "part": part, "versions": versions, "xml": xml, "proc": proc,
            "t0": time.monotonic(), "log": out}


def ended(r: dict, block: bool) -> bool:
    """Whether the run's pytest has ended (reaped here, with its wall and CPU
    seconds, children included)."""
    if "rc" in r:
        return True
    pid, status, usage = os.wait4(r["proc"].pid, 0 if block else os.WNOHANG)
    if pid == 0:
        return False
    r["rc"] = r["proc"].returncode = os.waitstatus_to_exitcode(status)
    r["secs"] = time.monotonic() - r["t0"]
    r["cpu"] = usage.ru_utime + usage.ru_stime
    return True


def finish(r: dict) -> dict:
    """Wait for a run; what it ran and how it went."""
    ended(r, block=True)
    if r["log"] is not None:
        r["log"].close()
        with open(r["log"].name) as f:
            print(f"\n=== {r['part']} tests on {r['venv']}:\n" + f.read()[-4000:], flush=True)
    r["ran"], r["bad"] = [], []
    if os.path.exists(r["xml"]):
        for case in ET.parse(r["xml"]).getroot().iter("testcase"):
            tid = f"{case.get('classname')}::{case.get('name')}"
            r["ran"].append(tid)
            if case.find("failure") is not None or case.find("error") is not None \
                    or case.find("skipped") is not None:
                r["bad"].append(tid)
    return r


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--core", required=True, metavar="VENV", help="venv for the core tests (run once)")
    ap.add_argument("--bpy", required=True, nargs="+", metavar="VENV", help="venvs for the bpy tests")
    ap.add_argument("--parallel", action="store_true",
                    help="start every run at once (output shown when each ends)")
    ap.add_argument("pytest_args", nargs="*", help="after --: passed to every pytest run")
    args = ap.parse_args(argv)

    every = collected(args.core, "all")
    plan = [(args.core, "core")] + [(v, "bpy") for v in args.bpy]
    with tempfile.TemporaryDirectory() as tmp:
        if args.parallel:
            started = [start(v, part, args.pytest_args, tmp, True) for v, part in plan]
            while not all([ended(r, block=False) for r in started]):
                time.sleep(1.0)
            runs = [finish(r) for r in started]
        else:
            runs = [finish(start(v, part, args.pytest_args, tmp, False)) for v, part in plan]

    problems = []
    core_ran = set(runs[0]["ran"])
    for r in runs:
        if len(set(r["ran"])) != len(r["ran"]):
            problems.append(f"{r['venv']} ({r['part']}): a test ran twice")
        if r["rc"] != 0 or r["bad"]:
            problems.append(f"{r['venv']} ({r['part']}): {len(r['bad'])} failed, errored or skipped "
                            f"(pytest exit {r['rc']})")
        if r["part"] == "bpy":
            missing = set(every) - core_ran - set(r["ran"])
            if missing:
                problems.append(f"{r['venv']}: {len(missing)} collected tests ran neither in the core "
                                f"run nor here, e.g. {sorted(missing)[:3]}")
            both = core_ran & set(r["ran"])
            if both:
                problems.append(f"{r['venv']}: {len(both)} tests ran in the core run and here")

    print(f"\n=== test matrix: {len(every)} tests collected; core tests once, bpy tests per Blender")
    for r in runs:
        print(f"  {r['part']:4s} {r['venv']:10s} {r['versions']:45s} {len(r['ran']):4d} tests "
              f"{len(r['bad']):3d} bad {r['secs']:6.0f} s wall {r['cpu']:6.0f} s CPU")
    print(f"  total {sum(r['secs'] for r in runs):.0f} s wall, {sum(r['cpu'] for r in runs):.0f} s CPU")
    for p in problems:
        print(f"test_matrix: {p}", file=sys.stderr)
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
