"""The frame's output (no bpy): the EXR and JSON contract, the frame
pipeline's records, external passes, files written whole with the umask's
modes (the planner's rules: test_core_planner.py)."""
import json
import os

import numpy as np
import pytest

from penumbra.core import exr
from penumbra.core.frame import render_frame
from penumbra.core.output import write_frame
from penumbra.core.planner import PlanError, resolve_passes
from synthetic import area_light, half_plane_scene


def test_exr_round_trip(tmp_path):
    rng = np.random.default_rng(0)
    layers = {"Key_Light": {"pcf": rng.random((7, 5), dtype=np.float32),
                            "embree": rng.random((7, 5), dtype=np.float32)},
              "Fill": {"pcf": np.ones((7, 5), np.float32)}}
    p = str(tmp_path / "x.exr")
    exr.write_multilayer(p, layers)
    back = exr.read_multilayer(p)
    assert set(back) == set(layers)
    for layer, passes in layers.items():
        assert set(back[layer]) == set(passes)
        for k, v in passes.items():
            np.testing.assert_array_equal(back[layer][k], v)


def test_exr_refuses_nan_and_leaves_nothing(tmp_path):
    p = tmp_path / "bad.exr"
    img = np.ones((4, 4), np.float32)
    img[1, 1] = np.nan
    with pytest.raises(ValueError):
        exr.write_multilayer(str(p), {"L": {"pcf": img}})
    assert os.listdir(tmp_path) == []


def test_frame_json_contract(tmp_path):
    sc = half_plane_scene(area_light(1.0, name="Key.Light"), res=24)
    res = render_frame(sc, ["pcf", "embree", "embree_irr"], overrides={"samples": 16})
    paths = write_frame(res, str(tmp_path))
    assert os.path.basename(paths["exr"]) == "scene.0001.exr"
    rec = json.loads(open(paths["json"]).read())
    assert rec["frame"] == 1 and rec["resolution"] == [24, 24]
    (light,) = rec["lights"]
    assert light["name"] == "Key.Light" and light["layer"] == "Key_Light"
    m = light["methods"]
    assert set(m) == {"pcf", "embree", "embree_irr"}
    assert m["pcf"]["visibility"] == "irradiance" and m["embree_irr"]["visibility"] == "irradiance"
    assert m["embree"]["visibility"] == "average"
    assert m["pcf"]["error"]["reference"] == "embree_irr"
    assert "error" not in m["embree"]
    for k in ("rmse", "max_abs", "mean_signed"):
        assert np.isfinite(m["pcf"]["error"][k])
    assert m["pcf"]["params"]["NumSamples"] == 16
    assert m["embree"]["params"]["samples"] == 16
    assert m["pcf"]["time_s"]["total"] >= m["pcf"]["time_s"]["filter"] > 0
    back = exr.read_multilayer(paths["exr"])
    np.testing.assert_array_equal(back["Key_Light"]["pcf"], res.lights[0].passes["pcf"])
    assert os.path.exists(tmp_path / "scene.0001.Key_Light.pcf.png")
    assert not [f for f in os.listdir(tmp_path) if f.startswith(".penumbra-")]


def test_scene_without_shadows_writes_ones(tmp_path):
    sc = half_plane_scene(area_light(1.0), res=8)
    sc.lights[0].casts_shadow = False
    res = render_frame(sc, ["pcf", "embree"])
    assert all((v == 1).all() for v in res.lights[0].passes.values())
    assert "no light casts shadows" in " ".join(res.plan.notes)


def test_external_pass_hook():
    """``cycles`` comes from a producer outside core; it is an irradiance
    ratio compared with ``embree_irr``, and refused where none is given."""
    from penumbra.core.methods.base import MethodResult
    sc = half_plane_scene(area_light(1.0), res=16)
    with pytest.raises(PlanError, match="needs Blender"):
        resolve_passes("embree,cycles")
    passes = resolve_passes("embree,embree_irr,cycles", external=["cycles"])
    assert "cycles" in resolve_passes("all", external=["cycles"]) and "cycles" not in resolve_passes("all")
    calls = []

    def fake(light):
        calls.append(light.name)
        return MethodResult({"cycles": np.full((16, 16), 0.5, np.float32)}, {"render": 0.25},
                            params={"samples": 4})
    res = render_frame(sc, passes, overrides={"samples": 8}, external={"cycles": fake})
    rec = res.lights[0].record["cycles"]
    assert calls == ["Area"]
    assert rec["visibility"] == "irradiance" and rec["params"] == {"samples": 4}
    assert rec["time_s"] == {"render": 0.25, "total": 0.25}
    assert rec["error"]["reference"] == "embree_irr"


@pytest.mark.parametrize("umask, mode", [(0o022, 0o644), (0o027, 0o640), (0o077, 0o600)])
def test_written_files_honour_the_umask(tmp_path, umask, mode):
    """EXR, JSON and PNG get 0666 less the process umask (as ``open`` would
    create them), not the 0600 of a ``mkstemp`` temporary file."""
    sc = half_plane_scene(area_light(1.0), res=8)
    res = render_frame(sc, ["pcf"])
    old = os.umask(umask)
    try:
        paths = write_frame(res, str(tmp_path))
    finally:
        os.umask(old)
    files = sorted(os.listdir(tmp_path))
    assert files == ["scene.0001.Area.pcf.png", "scene.0001.exr", "scene.0001.json"]
    assert {f: os.stat(tmp_path / f).st_mode & 0o777 for f in files} == {f: mode for f in files}
    assert exr.read_multilayer(paths["exr"])["Area"]["pcf"].shape == (8, 8)


@pytest.mark.parametrize("where", ["create", "close", "write", "replace"])
def test_an_interrupt_anywhere_leaves_no_temporary_file(tmp_path, monkeypatch, where):
    """A farm's SIGTERM becomes KeyboardInterrupt at any bytecode: raised
    inside the temporary file's creation (after the file exists), its close,
    the write or the rename, it leaves no file but the old one (not even an
    empty ``.penumbra-*.json`` from an interrupt between the temporary
    file's creation and its clean-up)."""
    target = tmp_path / "frame.json"
    target.write_bytes(b"old")
    real = {"create": os.open, "close": os.close, "replace": os.replace}

    def interrupted(name):
        def fn(*a, **k):
            real[name](*a, **k)                  # the side effect happens, then the signal
            raise KeyboardInterrupt
        return fn

    if where == "create":
        monkeypatch.setattr(exr.os, "open", interrupted("create"))
    elif where == "close":
        monkeypatch.setattr(exr.os, "close", interrupted("close"))
    elif where == "replace":
        monkeypatch.setattr(exr.os, "replace", interrupted("replace"))
    with pytest.raises(KeyboardInterrupt):
        if where == "write":
            with exr.atomic_file(str(target)) as tmp:
                open(tmp, "wb").write(b"half")
                raise KeyboardInterrupt
        else:
            exr.atomic_write_bytes(str(target), b"new")
    monkeypatch.undo()
    left = sorted(p.name for p in tmp_path.iterdir())
    assert left == ["frame.json"]
    assert target.read_bytes() == (b"new" if where == "replace" else b"old")
