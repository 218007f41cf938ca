"""The Open Job Description template ``farm/openjd/penumbra-render.yaml``,
checked and run for real with ``openjd-cli`` on this machine."""
import json
import os
import re
import subprocess
import sys

import numpy as np
import yaml

from penumbra.core import exr
from helpers import PENUMBRA, ROOT
from scenes import sample_path

TEMPLATE = os.path.join(ROOT, "farm", "openjd", "penumbra-render.yaml")
BIN = os.path.dirname(sys.executable)
OPENJD = os.path.join(BIN, "openjd")


def openjd_run(template, out, frames, chunk, timeout=300, extra="--no-previews --threads 1"):
    """``openjd run ... --step Render``; its process, log messages and the
    chunk strings the tasks were given."""
    p = subprocess.run([OPENJD, "run", str(template), "--step", "Render", "--verbose",
                        "-p", f"SceneFile={sample_path('torus_plane')}", "-p", f"OutputDir={out}",
                        "-p", f"Frames={frames}", "-p", f"ChunkSize={chunk}", "-p", "Methods=pcf",
                        "-p", "Resolution=32x32", "-p", f"ExtraArgs={extra}", "-p", f"PenumbraCommand={PENUMBRA}"],
                       capture_output=True, text=True, timeout=timeout, stdin=subprocess.DEVNULL)
    messages = [line.split("\t", 1)[1] for line in p.stdout.splitlines() if "\t" in line]
    chunks = [m.split(" = ", 1)[1] for m in messages if m.startswith("Frame(CHUNK[INT]) = ")]
    return p, chunks, messages


def written_frames(out):
    """Frames whose JSON exists; each one's EXR exists and reads back."""
    frames = []
    for name in sorted(os.listdir(out)):
        if name.endswith(".json"):
            rec = json.loads((out / name).read_text())
            layers = exr.read_multilayer(str(out / rec["exr"]))
            v = layers["Spot"]["pcf"]
            assert v.shape == (32, 32) and np.isfinite(v).all()
            assert rec["pixel_filter"]["type"] != "none" and "Alpha" in layers["Spot"]   # the default: filtered
            frames.append(rec["frame"])
    return frames


def test_openjd_check_passes():
    p = subprocess.run([OPENJD, "check", TEMPLATE], capture_output=True, text=True, timeout=60)
    assert p.returncode == 0 and "passes validation checks" in p.stdout, p.stdout + p.stderr


def test_template_parameters_step_and_chunking():
    t = yaml.safe_load(open(TEMPLATE))
    assert t["specificationVersion"] == "jobtemplate-2023-09" and t["extensions"] == ["TASK_CHUNKING"]
    params = {p["name"]: p for p in t["parameterDefinitions"]}
    assert {k: params[k]["type"] for k in ("SceneFile", "OutputDir", "Frames", "ChunkSize", "Methods",
                                           "Resolution", "PixelFilter")} == \
        {"SceneFile": "PATH", "OutputDir": "PATH", "Frames": "STRING", "ChunkSize": "INT",
         "Methods": "STRING", "Resolution": "STRING", "PixelFilter": "STRING"}
    assert (params["Frames"]["default"], params["ChunkSize"]["default"], params["Methods"]["default"],
            params["Resolution"]["default"], params["PixelFilter"]["default"]) == ("1-250", 10, "auto", "", "scene")
    (step,) = t["steps"]
    assert step["name"] == "Render"
    (frame,) = step["parameterSpace"]["taskParameterDefinitions"]
    assert frame["type"] == "CHUNK[INT]" and frame["range"] == "{{Param.Frames}}"
    assert frame["chunks"] == {"defaultTaskCount": "{{Param.ChunkSize}}", "rangeConstraint": "CONTIGUOUS"}
    run = step["script"]["actions"]["onRun"]
    assert isinstance(run["timeout"], int) and run["timeout"] > 0
    assert run["cancelation"]["mode"] == "NOTIFY_THEN_TERMINATE"


def test_openjd_run_renders_every_chunk(tmp_path):
    out = tmp_path / "out"
    p, chunks, messages = openjd_run(TEMPLATE, out, "1-3", 2)
    assert p.returncode == 0, p.stdout[-3000:] + p.stderr
    assert "Open Job Description CLI: All actions completed successfully!" in messages
    assert chunks == ["1-2", "3-3"] and "Chunks run: 2" in p.stdout     # a one-frame chunk comes as 3-3
    assert written_frames(out) == [1, 2, 3]
    assert sorted(os.listdir(out)) == [f"torus_plane.{f:04d}.{e}" for f in (1, 2, 3) for e in ("exr", "json")]


def test_a_timed_out_chunk_is_stopped_cleanly(tmp_path):
    """NOTIFY_THEN_TERMINATE: at the timeout penumbra gets SIGTERM, stops
    between frames or removes the file it was writing, and exits; every frame
    it finished is whole and no temporary file is left."""
    template = tmp_path / "short-timeout.yaml"
    text = open(TEMPLATE).read()
    assert len(re.findall(r"timeout: \d+", text)) == 1
    template.write_text(re.sub(r"timeout: \d+", "timeout: 10", text))
    out = tmp_path / "out"
    p, chunks, messages = openjd_run(template, out, "1-1000", 1000)
    assert p.returncode != 0 and "Session ended with errors" in p.stdout
    assert chunks == ["1-1000"]
    # openjd logs a task's output line by line as it arrives: a line penumbra had not
    # ended yet when the timeout came gets openjd's own message glued after it
    assert any("TIMEOUT - Runtime limit reached" in m for m in messages), p.stdout[-3000:]
    assert any('INTERRUPT: Sending signal "term"' in m for m in messages)
    assert "penumbra: interrupted" in messages
    assert any(m.startswith("Process pid") and "exited with code: 130" in m for m in messages)
    frames = written_frames(out)
    assert len(frames) < 1000 and frames == list(range(1, len(frames) + 1))
    assert not [n for n in os.listdir(out) if n.startswith(".penumbra-")]
