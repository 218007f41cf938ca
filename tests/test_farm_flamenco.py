"""The Flamenco job type ``farm/flamenco/penumbra_render.js`` under node, with
the job-compiler globals Flamenco documents (``author.Task``,
``author.Command``, ``frameChunker``: tests/flamenco_job_compiler.js)."""
import json
import os
import shutil
import subprocess

import pytest

from penumbra.cli import build_parser
from helpers import PENUMBRA, ROOT
from scenes import sample_path

NODE = shutil.which("node")
JOB_TYPE = os.path.join(ROOT, "farm", "flamenco", "penumbra_render.js")
COMPILER = os.path.join(ROOT, "tests", "flamenco_job_compiler.js")


def compile_job(**settings):
    p = subprocess.run([NODE, COMPILER, JOB_TYPE, json.dumps(settings)], capture_output=True, text=True,
                       timeout=60)
    out = json.loads(p.stdout)
    assert (p.returncode == 0) == ("error" not in out), p.stdout + p.stderr
    return out


def job(**settings):
    return compile_job(**{"blendfile": "/shared/shot.blend", "out_dir": "/shared/passes", **settings})


def test_job_type_settings_and_defaults():
    settings = {s["key"]: s for s in job(frames="1")["jobType"]["settings"]}
    assert set(settings) == {"frames", "chunk_size", "out_dir", "methods", "resolution", "pixel_filter",
                             "blendfile"}
    assert settings["frames"]["eval"] == "f'{C.scene.frame_start}-{C.scene.frame_end}'"
    assert settings["chunk_size"]["type"] == "int32" and settings["chunk_size"]["default"] == 10
    assert settings["methods"]["default"] == "auto" and settings["resolution"]["default"] == ""
    assert settings["pixel_filter"]["default"] == "scene"
    assert all(settings[k]["required"] for k in ("frames", "out_dir", "blendfile"))


@pytest.mark.parametrize("frames, chunk_size, chunks", [
    ("47", None, ["47"]),
    ("9,10,20,21", None, ["9,10,20,21"]),
    ("1-4,9,20-22", None, ["1-4,9,20-22"]),
    ("1-25", None, ["1-10", "11-20", "21-25"]),            # the default chunk of 10
    ("1..4, 9, 20..22", 3, ["1-3", "4,9,20", "21,22"]),    # Blender notation in, regular out
])
def test_one_exec_task_per_chunk_that_penumbra_render_accepts(frames, chunk_size, chunks):
    settings = {"frames": frames} if chunk_size is None else {"frames": frames, "chunk_size": chunk_size}
    tasks = job(**settings)["tasks"]
    assert [t["name"] for t in tasks] == [f"penumbra-{c}" for c in chunks]
    covered = []
    for task, chunk in zip(tasks, chunks):
        assert task["type"] == "penumbra" and task["dependencies"] == []
        (cmd,) = task["commands"]
        assert cmd["name"] == "exec" and cmd["parameters"]["exe"] == "{penumbra}"
        args = cmd["parameters"]["args"]
        assert args[:6] == ["render", "/shared/shot.blend", "--frames", chunk, "--out", "/shared/passes"]
        parsed = build_parser().parse_args(args)        # penumbra's own parser takes the whole command
        assert parsed.command == "render" and parsed.methods == "auto" and parsed.resolution is None
        assert parsed.pixel_filter == "scene"
        assert len(parsed.frames) <= (chunk_size or 10)
        covered += parsed.frames
    wanted = build_parser().parse_args(["render", "x", "--frames", frames.replace("..", "-").replace(" ", "")]).frames
    assert covered == wanted                             # every frame once, in order


def test_methods_resolution_and_pixel_filter_are_passed_on():
    (task,) = job(frames="5", methods="pcf,embree", resolution=" 1920x1080 ",
                  pixel_filter=" Gaussian:1.5 ")["tasks"]
    args = task["commands"][0]["parameters"]["args"]
    assert args[6:] == ["--methods", "pcf,embree", "--pixel-filter", "gaussian:1.5", "--resolution", "1920x1080"]
    parsed = build_parser().parse_args(args)
    assert parsed.methods == "pcf,embree" and parsed.resolution == (1920, 1080) and parsed.frames == [5]
    assert parsed.pixel_filter == "gaussian:1.5"
    for spec in ("none", "scene", "blackman-harris:2", "box:1:8", "scene:8", "gaussian:.5"):
        (task,) = job(frames="5", pixel_filter=spec)["tasks"]
        assert build_parser().parse_args(task["commands"][0]["parameters"]["args"]).pixel_filter == spec


@pytest.mark.parametrize("spec", ["sinc:1", "gaussian", "box:x", "none:2"])
def test_a_bad_pixel_filter_fails_the_submission(spec):
    assert "pixel_filter must be" in job(frames="1-3", pixel_filter=spec)["error"]


@pytest.mark.parametrize("resolution", ["1920", "3x", "axb", "1920x1080x2"])
def test_a_bad_resolution_fails_the_submission(resolution):
    out = job(frames="1-3", resolution=resolution)
    assert "resolution must be WxH" in out["error"]


def test_an_emitted_task_renders_its_chunk(tmp_path):
    """The exec command of one task, with {penumbra} the console script, as a
    Worker runs it."""
    (task,) = compile_job(frames="9,10", blendfile=sample_path("torus_plane"), out_dir=str(tmp_path),
                          methods="pcf", resolution="32x32")["tasks"]
    params = task["commands"][0]["parameters"]
    exe = params["exe"].replace("{penumbra}", PENUMBRA)
    p = subprocess.run([exe, *params["args"]], capture_output=True, text=True, timeout=300,
                       stdin=subprocess.DEVNULL)
    assert p.returncode == 0, p.stdout + p.stderr
    names = sorted(n for n in os.listdir(tmp_path) if n.endswith((".exr", ".json")))
    assert names == [f"torus_plane.{f:04d}.{e}" for f in (9, 10) for e in ("exr", "json")]
