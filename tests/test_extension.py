"""The Blender extension: the manifest against the extension schema's rules,
the per-platform zips ``make extension`` builds (cp311 and cp313 wheels in
each), Blender's own validator on every zip, and the linux-x64 zip installed
by Blender's own extensions API into a fresh bpy session (in subprocesses
whose HOME and BLENDER_USER_RESOURCES are temporary folders, so the real user
folder is never touched), where Compute Passes, Set Up Compositor and a
render with "Passes in Every Render" run on a copy of a sample scene.
``make test`` runs this file with each tested bpy (5.0.1, 5.2.3, 5.3.0).

The wheels are downloaded from PyPI into ./wheels on the first run and
reused after that.
"""
from __future__ import annotations

import copy
import glob
import shutil
import hashlib
import importlib.util
import json
import os
import re
import subprocess
import sys
import tomllib
import zipfile

import numpy as np
import pytest

from penumbra.core import exr
from helpers import ROOT
from scenes import sample_path

PLATFORM = "linux-x64"


def _load(name, path):
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


build = _load("penumbra_build_extension", os.path.join(ROOT, "scripts", "build_extension.py"))


def _bpy_scripts() -> str:
    """Blender's bundled scripts folder inside the installed bpy module
    (found without importing bpy)."""
    bpy_dir = os.path.dirname(importlib.util.find_spec("bpy").origin)
    found = glob.glob(os.path.join(bpy_dir, "[0-9]*.[0-9]*", "scripts"))
    assert len(found) == 1, found
    return found[0]


def _bpy_version() -> tuple:
    """The bpy module's (major, minor), from its scripts folder's name."""
    return tuple(int(x) for x in os.path.basename(os.path.dirname(_bpy_scripts())).split("."))


BLENDER_EXT = os.path.join(_bpy_scripts(), "addons_core", "bl_pkg", "cli", "blender_ext.py")
BLENDER_TAGS = os.path.join(_bpy_scripts(), "modules", "_bpy_internal", "extensions", "tags.py")


@pytest.fixture(scope="module")
def blender_ext():
    """Blender's own extension CLI module (build/validate), loaded from bpy."""
    return _load("blender_ext_for_tests", BLENDER_EXT)


def _manifest() -> dict:
    with open(os.path.join(ROOT, "blender_manifest.toml"), "rb") as f:
        return tomllib.load(f)


# ---------------------------------------------------------------------------
# The manifest against the schema's rules

REQUIRED = ("schema_version", "id", "version", "name", "tagline", "maintainer", "type",
            "blender_version_min", "license")
SEMVER = re.compile(
    r"^(0|[1-9]\d*)\.(0|[1-9]\d*)\.(0|[1-9]\d*)"
    r"(?:-((?:0|[1-9]\d*|\d*[a-zA-Z-][0-9a-zA-Z-]*)(?:\.(?:0|[1-9]\d*|\d*[a-zA-Z-][0-9a-zA-Z-]*))*))?"
    r"(?:\+([0-9a-zA-Z-]+(?:\.[0-9a-zA-Z-]+)*))?$")
PERMISSIONS = {"files", "network", "clipboard", "camera", "microphone"}
PLATFORMS = {"linux-x64", "macos-arm64", "macos-x64", "windows-x64"}
PYTHON_TAGS = ("cp311", "cp313")        # Blender 5.0; 5.1 - 5.3
#: the newest Blender tested is 5.3.x; blender_version_max is exclusive
VERSION_MAX = "5.4.0"


def _empty_values(value, where=""):
    if isinstance(value, str):
        return [where] if not value.strip() else []
    if isinstance(value, (list, dict)) and not value:
        return [where]
    if isinstance(value, list):
        return [e for i, v in enumerate(value) for e in _empty_values(v, f"{where}[{i}]")]
    if isinstance(value, dict):
        return [e for k, v in value.items() for e in _empty_values(v, f"{where}.{k}")]
    return []


def _terse_error(text: str):
    if len(text) > 64:
        return f"longer than 64 characters ({len(text)})"
    if text != text.strip() or not text:
        return "empty or padded"
    if not (text[-1].isalnum() or text[-1] in ")]}"):
        return "ends with punctuation"
    return None


def _version_triple(v: str):
    parts = v.split(".")
    assert len(parts) == 3 and all(p.isdigit() for p in parts), v
    return tuple(int(p) for p in parts)


def manifest_errors(m: dict) -> list[str]:
    """The extension schema's rules (docs.blender.org "Extensions: Getting
    started" / blender_ext.py), as a list of broken ones."""
    errs = [f"missing {k}" for k in REQUIRED if k not in m]
    errs += [f"empty value at {w}" for w in _empty_values(m)]
    if errs:
        return errs
    if m["schema_version"] != "1.0.0":
        errs.append("schema_version")
    ident = m["id"]
    if not (ident.isidentifier() and "__" not in ident and not ident.startswith("_")
            and not ident.endswith("_")):
        errs.append("id is not a valid identifier")
    if not SEMVER.match(m["version"]):
        errs.append("version is not semver")
    if (e := _terse_error(m["tagline"])) is not None:
        errs.append(f"tagline {e}")
    if m["type"] != "add-on":
        errs.append("type")
    if _version_triple(m["blender_version_min"]) < (4, 2, 0):
        errs.append("blender_version_min below 4.2.0")
    if m.get("blender_version_max") != VERSION_MAX:
        errs.append(f"blender_version_max must be {VERSION_MAX} (tested up to 5.3)")
    if not all(lic.startswith("SPDX:") for lic in m["license"]):
        errs.append("license must be SPDX identifiers")
    if not set(m.get("platforms", [])) <= PLATFORMS:
        errs.append("unknown platform")
    for w in m.get("wheels", []):
        fields = os.path.basename(w)[:-4].split("-")
        if not (w.startswith("./wheels/") and w.endswith(".whl") and "\\" not in w
                and 5 <= len(fields) <= 6):
            errs.append(f"wheel path {w}")
        elif not any(t in fields[-3].split(".") and t in fields[-2].split(".") for t in PYTHON_TAGS):
            errs.append(f"not a cp311 or cp313 wheel: {w}")
        elif fields[0].lower() == "numpy":
            errs.append("numpy is shipped by Blender")
    for key, reason in m.get("permissions", {}).items():
        if key not in PERMISSIONS:
            errs.append(f"permission {key}")
        elif not isinstance(reason, str) or (e := _terse_error(reason)) is not None:
            errs.append(f"permission {key} reason {e}")
    return errs


def test_manifest_follows_the_schema_rules():
    m = _manifest()
    assert manifest_errors(m) == []
    assert m["id"] == "penumbra" and m["platforms"] == sorted(PLATFORMS)
    assert m["permissions"]["files"]
    # one cp311 and one cp313 wheel per pinned package (numpy excluded) for every platform
    build.check_manifest_wheels(m, m["platforms"])
    assert _version_triple(m["blender_version_min"]) == (5, 0, 0)
    pins = build.pinned_requirements()
    assert set(pins) == {"numba", "llvmlite", "embreex", "openexr"}
    assert pins["embreex"] == "4.4.0.post1"


@pytest.mark.parametrize("mutate, broken", [
    (lambda m: m.pop("maintainer"), "missing maintainer"),
    (lambda m: m.update(name=" "), "empty value at .name"),
    (lambda m: m.update(tagline="Soft shadow passes for the compositor."), "tagline ends with punctuation"),
    (lambda m: m.update(tagline="x" * 65), "tagline longer than 64 characters (65)"),
    (lambda m: m.update(version="0.1"), "version is not semver"),
    (lambda m: m.update(id="penumbra-ext"), "id is not a valid identifier"),
    (lambda m: m.update(blender_version_max="5.5.0"), "blender_version_max must be 5.4.0 (tested up to 5.3)"),
    (lambda m: m["wheels"].append("./wheels/numba-0.68.1-cp312-cp312-win_amd64.whl"),
     "not a cp311 or cp313 wheel: ./wheels/numba-0.68.1-cp312-cp312-win_amd64.whl"),
    (lambda m: m["wheels"].append("wheels/x-1.0-cp311-cp311-win_amd64.whl"),
     "wheel path wheels/x-1.0-cp311-cp311-win_amd64.whl"),
    (lambda m: m["permissions"].update(internet="Downloads things"), "permission internet"),
    (lambda m: m["permissions"].update(files="Writes passes."), "permission files reason ends with punctuation"),
])
def test_manifest_rules_reject_broken_manifests(mutate, broken, blender_ext):
    m = copy.deepcopy(_manifest())
    mutate(m)
    assert broken in manifest_errors(m)
    # Blender's strict validator rejects the same manifests (it does not
    # know about the wheel-tag/5.4 rules, which are ours)
    if "cp311" not in broken and "5.4.0" not in broken and "wheel path" not in broken:
        assert blender_ext.pkg_manifest_is_valid_or_error(m, from_repo=False, strict=True) is not None


def test_blenders_validator_accepts_the_manifest():
    proc = subprocess.run([sys.executable, BLENDER_EXT, "validate", "--valid-tags", BLENDER_TAGS, ROOT],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "Success" in proc.stdout


# ---------------------------------------------------------------------------
# The builder against Blender's own rules

def test_exclusions_and_platform_split_match_blenders_builder(blender_ext):
    patterns = _manifest()["build"]["paths_exclude_pattern"]
    matcher = blender_ext.PathPatternMatch(patterns)

    def keep(rel, is_dir):     # as blender_ext.py's build() filters its scan
        rel = rel.replace(os.sep, "/")
        return not matcher.test_path(rel + "/" if is_dir else rel)

    blender_files = sorted(rel.replace(os.sep, "/") for _, rel in
                           blender_ext.scandir_recursive(ROOT, filter_fn=keep)
                           if rel != "blender_manifest.toml")
    ours = build.source_files(ROOT, patterns)
    assert sorted(ours) == blender_files
    assert "__init__.py" in ours and "core/frame.py" in ours and "operators/compute.py" in ours
    assert "bridge/pipeline.py" in ours
    assert "core/auto_table.json" in ours          # auto's measured table ships with the code
    # the farm runner ships (cli.py imports it), the farm job definitions do not
    assert "farm/command.py" in ours and "farm/dask_farm.py" in ours
    assert not [rel for rel in ours if rel.startswith(("farm/flamenco/", "farm/openjd/"))]
    for rel in ours:
        assert not rel.startswith(("tests/", "sample_blends/", "scripts/", "bench/", "wheels/",
                                   "dist/", ".venv/", ".git/", "demo_out/")), rel
        assert "__pycache__" not in rel and not rel.endswith((".pyc", ".blend", ".blend1"))
    assert "Makefile" not in ours and "pyproject.toml" not in ours
    # the benchmark and the study are one package in the tree, none of it shipped
    assert os.path.isfile(os.path.join(ROOT, "bench", "__init__.py"))
    assert not [rel for rel in ours if rel.split("/")[0] in ("bench", "bench.py", "bench_methods.py", "study.py")]

    wheels = _manifest()["wheels"]
    for platform in PLATFORMS:
        mine = build.wheels_for_platform(wheels, platform)
        assert mine == blender_ext.paths_filter_wheels_by_platform(wheels, platform)
        assert len(mine) == 8
        assert sorted(build.wheel_fields(w)[2] for w in mine) == ["cp311"] * 4 + ["cp313"] * 4


def test_a_missing_wheel_stops_the_build_with_one_line(tmp_path, monkeypatch):
    """A wheel PyPI lacks (here: numba 0.68.1 for macOS x86_64, which PyPI does
    not publish) stops ``make wheels`` / ``make extension`` with one line
    naming package, version, Python and platform (``main`` prints it and
    exits 2)."""
    root = tmp_path / "src"
    (root / "wheels").mkdir(parents=True)
    for name in ("pyproject.toml", "__init__.py"):
        (root / name).write_bytes(open(os.path.join(ROOT, name), "rb").read())
    for w in glob.glob(os.path.join(ROOT, "wheels", "*macosx*x86_64.whl")):
        os.symlink(w, root / "wheels" / os.path.basename(w))     # no second download
    text = open(os.path.join(ROOT, "blender_manifest.toml")).read()
    for tag in PYTHON_TAGS:
        text = text.replace(f"numba-0.62.1-{tag}-{tag}-macosx_10_15_x86_64", f"numba-0.68.1-{tag}-{tag}-macosx_10_15_x86_64")
    (root / "blender_manifest.toml").write_text(text)
    monkeypatch.setattr(build, "VERSION_OVERRIDES", {"macos-x64": {"llvmlite": "0.45.1"}})
    with pytest.raises(build.BuildError) as exc:
        build.fetch_wheels(["macos-x64"], root=str(root), log=lambda *_: None)
    assert str(exc.value) == ("no wheel of numba==0.68.1 for Python 3.11 on macos-x64 "
                              "(macosx_13_0_x86_64) on the package index")


@pytest.fixture(scope="module")
def zips(tmp_path_factory):
    """Every platform's zip, as ``make extension`` builds them."""
    platforms = sorted(PLATFORMS)
    build.fetch_wheels(platforms)
    out = str(tmp_path_factory.mktemp("dist"))
    return {p: build.build_zip(p, out, log=lambda *_: None) for p in platforms}


@pytest.fixture(scope="module")
def linux_zip(zips):
    return zips[PLATFORM]


def _sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def test_linux_zip_layout_and_wheels(linux_zip):
    assert os.path.basename(linux_zip) == "penumbra-0.1.0-linux_x64.zip"
    source = _manifest()
    linux_wheels = build.wheels_for_platform(source["wheels"], PLATFORM)
    with zipfile.ZipFile(linux_zip) as zf:
        names = zf.namelist()
        # Blender's layout: manifest and __init__.py at the top level
        assert "blender_manifest.toml" in names and "__init__.py" in names
        zipped = tomllib.loads(zf.read("blender_manifest.toml").decode())
        # the split build narrows platforms/wheels in [build.generated], as
        # `blender --command extension build --split-platforms` does
        generated = zipped["build"]["generated"]
        assert generated["platforms"] == [PLATFORM]
        assert generated["wheels"] == linux_wheels
        assert {k: v for k, v in zipped.items() if k != "build"} == \
            {k: v for k, v in source.items() if k != "build"}
        for w in linux_wheels:
            rel = w[2:]
            assert rel in names, rel
            info = zf.getinfo(rel)
            assert info.compress_type == zipfile.ZIP_STORED
            with open(os.path.join(ROOT, rel), "rb") as f:      # unmodified
                assert _sha256(zf.read(rel)) == _sha256(f.read())
        zipped_wheels = sorted("./" + n for n in names if n.endswith(".whl"))
        assert zipped_wheels == sorted(linux_wheels)
        assert set(names) == {"blender_manifest.toml", *(w[2:] for w in linux_wheels),
                              *build.source_files(ROOT)}
        # the accuracy table ``auto`` reads is in the zip, byte for byte, and loads
        from penumbra.core import auto_choice
        with open(auto_choice.TABLE_PATH, "rb") as f:
            assert zf.read("core/auto_table.json") == f.read()
        assert auto_choice.parse_table(json.loads(zf.read("core/auto_table.json"))).scenes
        excluded = ("tests/", "sample_blends/", "scripts/", "bench/", ".venv/", ".git/", "dist/")
        assert not [n for n in names if n.startswith(excluded) or "__pycache__" in n
                    or n in ("Makefile", "pyproject.toml")]


def test_blenders_validator_accepts_every_zip(zips):
    assert sorted(zips) == sorted(PLATFORMS)
    for platform, path in zips.items():
        proc = subprocess.run([sys.executable, BLENDER_EXT, "validate", "--valid-tags", BLENDER_TAGS,
                               path], capture_output=True, text=True, timeout=120)
        assert proc.returncode == 0 and "Success" in proc.stdout, (platform, proc.stdout + proc.stderr)
        with zipfile.ZipFile(path) as zf:
            generated = tomllib.loads(zf.read("blender_manifest.toml").decode())["build"]["generated"]
            wheels = sorted(n for n in zf.namelist() if n.endswith(".whl"))
        assert generated["platforms"] == [platform]
        assert sorted(build.wheel_fields(w)[2] for w in wheels) == ["cp311"] * 4 + ["cp313"] * 4


# ---------------------------------------------------------------------------
# Installing the zip into a fresh bpy session

_INSTALL = r'''
import json, os, sys
import bpy
out = {"user_extensions": bpy.utils.user_resource("EXTENSIONS")}
out["registered_before"] = "PENUMBRA_OT_compute_passes" in dir(bpy.types)
out["install"] = sorted(bpy.ops.extensions.package_install_files(
    filepath=sys.argv[1], repo="user_default", enable_on_install=True))
out["addons"] = sorted(k for k in bpy.context.preferences.addons.keys() if "penumbra" in k)
out["registered"] = "PENUMBRA_OT_compute_passes" in dir(bpy.types)
print("RESULT " + json.dumps(out))
'''

# Blender started again after the install puts the extensions'
# site-packages before its own (here: before the venv's, which also has numba),
# so the add-on runs on the wheels Blender installed from the zip.
_RUN = r'''
import glob, json, os, sys, warnings
import bpy
import numpy as np
warnings.simplefilter("always")
caught = warnings.catch_warnings(record=True)
seen = caught.__enter__()
out = {"registered_before": "PENUMBRA_OT_compute_passes" in dir(bpy.types)}
out["blender"] = bpy.app.version_string
out["imported_before"] = [m for m in ("numba", "llvmlite", "embreex", "OpenEXR") if m in sys.modules]
out["enable"] = sorted(bpy.ops.preferences.addon_enable(module="bl_ext.user_default.penumbra"))
out["registered"] = "PENUMBRA_OT_compute_passes" in dir(bpy.types)
bpy.ops.wm.open_mainfile(filepath=sys.argv[1], load_ui=False)
scene = bpy.context.scene
scene.render.resolution_x, scene.render.resolution_y = 32, 24
scene.render.resolution_percentage = 100
out["op"] = sorted(bpy.ops.penumbra.compute_passes(samples=4, methods="pcf,embree"))
ahead = sys.modules["bl_ext.user_default.penumbra.core.compile_ahead"]
out["ahead_pkg"], out["ahead_done"] = ahead._PKG, ahead.helper_done()
out["ahead_work"] = [w for w, _ in ahead._jobs]
pcf = next(i for i in bpy.data.images if i.name.startswith("Penumbra") and i.name.endswith(" pcf"))
px = np.empty(len(pcf.pixels), np.float32)
pcf.pixels.foreach_get(px)
out["pcf_size"], out["pcf_range"] = list(pcf.size), [float(px[0::4].min()), float(px[0::4].max())]
out["setup"] = sorted(bpy.ops.penumbra.setup_compositor())
compat = sys.modules["bl_ext.user_default.penumbra.bridge.compat"]
out["setup_nodes"] = sorted(n.name for n in compat.compositor_tree(scene, create=False).nodes
                            if n.name.startswith("Penumbra:"))
for lt in bpy.data.lights:
    lt.penumbra.method = "pcf"
    lt.penumbra.light_samples = 4
scene.penumbra.references = {"embree"}
scene.penumbra.render_passes = True
scene.render.engine = "CYCLES"
scene.cycles.samples = 1
scene.cycles.use_denoising = False
render_dir = os.path.join(sys.argv[2], "render")
scene.render.filepath = os.path.join(render_dir, "frame_")
scene.render.image_settings.file_format = "OPEN_EXR"
bpy.ops.render.render(write_still=True)
out["render_errors"] = sys.modules["bl_ext.user_default.penumbra.addon.handlers"].state["errors"]
out["written"] = sorted(os.listdir(render_dir))
ac = sys.modules["bl_ext.user_default.penumbra.core.auto_choice"]
out["auto_table"] = ac.TABLE_PATH
out["auto_choice"] = ac.choose("area", 1.0).rule
out["images"] = sorted(i.name for i in bpy.data.images if i.name.startswith("Penumbra"))
import OpenEXR
out["modules"] = {m: sys.modules[m].__file__ for m in ("numba", "llvmlite", "embreex", "OpenEXR")}
ext = sys.modules["bl_ext.user_default.penumbra"]
out["ext_dir"] = os.path.dirname(ext.__file__)
out["ext_user"] = bpy.utils.extension_path_user("bl_ext.user_default.penumbra")
out["cache_root"] = os.environ.get("PENUMBRA_NUMBA_CACHE_ROOT")
out["cache_in_user"] = glob.glob(os.path.join(out["ext_user"], "**", "*.nbi"), recursive=True)
out["cache_in_ext"] = [p for pat in ("*.nbi", "*.nbc")
                       for p in glob.glob(os.path.join(out["ext_dir"], "**", pat), recursive=True)]
out["deprecations"] = [f"{w.filename}:{w.lineno}: {w.message}" for w in seen
                       if issubclass(w.category, DeprecationWarning) and w.filename.startswith(out["ext_dir"])]
print("RESULT " + json.dumps(out))
'''


def _run_bpy(code, args, env):
    proc = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True,
                          env=env, timeout=900, cwd=env["HOME"])
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT ")]
    assert proc.returncode == 0 and lines, proc.stdout[-3000:] + proc.stderr[-3000:]
    return json.loads(lines[-1][len("RESULT "):]), proc.stdout + proc.stderr


def test_zip_installs_and_runs_in_a_fresh_bpy_session(linux_zip, tmp_path):
    home = tmp_path / "home"
    home.mkdir()
    res = tmp_path / "blender"
    env = {k: v for k, v in os.environ.items()
           if k not in ("PENUMBRA_NUMBA_CACHE_ROOT", "NUMBA_CACHE_DIR", "PYTHONPATH")
           and not k.startswith("BLENDER_USER_")}
    env.update(HOME=str(home), BLENDER_USER_RESOURCES=str(res),
               XDG_CONFIG_HOME=str(home / ".config"), XDG_CACHE_HOME=str(home / ".cache"),
               PENUMBRA_COMPILE_PROCESSES="2")      # one helper process, whatever the cores

    first, log = _run_bpy(_INSTALL, [linux_zip], env)
    user_ext = first["user_extensions"]
    assert user_ext.startswith(str(res)), user_ext          # not the real user folder
    assert not first["registered_before"]
    assert first["install"] == ["FINISHED"], log
    assert first["addons"] == ["bl_ext.user_default.penumbra"]
    assert first["registered"]
    # Blender unpacked the extension's code into the user repository ...
    ext_dir = os.path.join(user_ext, "user_default", "penumbra")
    assert os.path.isfile(os.path.join(ext_dir, "__init__.py"))
    assert os.path.isfile(os.path.join(ext_dir, "core", "frame.py"))
    assert not os.path.exists(os.path.join(ext_dir, "tests"))
    # ... and installed the wheels into the extensions' own site-packages
    site = os.path.join(user_ext, ".local", "lib", "python{}.{}".format(*sys.version_info[:2]),
                        "site-packages")
    dist_infos = sorted(d for d in os.listdir(site) if d.endswith(".dist-info"))
    assert dist_infos == ["embreex-4.4.0.post1.dist-info", "llvmlite-0.50.0.dist-info",
                          "numba-0.68.1.dist-info", "openexr-3.5.3.dist-info"]

    work = tmp_path / "work"
    work.mkdir()
    blend = work / "shot.blend"                 # a copy: the sample itself is never opened for writing
    shutil.copyfile(sample_path("sphere_plane"), blend)
    second, log = _run_bpy(_RUN, [str(blend), str(work)], env)
    assert second["blender"].startswith("{}.{}.".format(*_bpy_version()))
    assert not second["registered_before"] and second["imported_before"] == []
    assert second["enable"] == ["FINISHED"] and second["registered"]
    assert second["op"] == ["FINISHED"], log
    assert [n for n in second["images"] if n.endswith(" pcf")]
    # the first Compute on a cold cache shared its compilation with a helper process,
    # which imported the extension under Blender's own name (bl_ext.user_default.penumbra)
    assert second["ahead_pkg"] == "bl_ext.user_default.penumbra"
    assert second["ahead_work"] and second["ahead_done"] > 0, log
    assert [n for n in second["images"] if n.endswith(" embree")]
    # Compute Passes: a 32 x 24 visibility image with shadow and light in it
    assert second["pcf_size"] == [32, 24]
    assert second["pcf_range"][0] < 0.5 < second["pcf_range"][1] <= 1.0
    # Set Up Compositor: Penumbra's Render Layers, group node and Viewer
    assert second["setup"] == ["FINISHED"], log
    assert {"Penumbra:~Penumbra", "Penumbra:~Render Layers", "Penumbra:~Viewer"} <= set(second["setup_nodes"])
    # a render with passes: the render and the passes (EXR + JSON) of its frame
    assert second["render_errors"] == []
    assert second["written"] == ["frame_.exr", "shot.0001.exr", "shot.0001.json"], log
    passes = exr.read_multilayer(str(work / "render" / "shot.0001.exr"))
    assert {"pcf", "embree"} <= set(next(iter(passes.values())))
    for layer in passes.values():
        for v in layer.values():
            assert v.shape == (24, 32) and np.isfinite(v).all() and 0.0 <= v.min() and v.max() <= 1.0
    rec = json.loads((work / "render" / "shot.0001.json").read_text())
    assert rec["frame"] == 1 and rec["lights"]
    assert second["deprecations"] == []
    # auto reads the table installed with the extension, not a fallback
    assert second["auto_table"] == os.path.join(ext_dir, "core", "auto_table.json")
    assert second["auto_choice"] in ("meets budget", "most accurate")
    for mod, path in second["modules"].items():
        assert path.startswith(site + os.sep), (mod, path)
    # the Numba cache lives in the extension's user folder, not beside its code
    assert second["ext_dir"] == ext_dir
    assert second["ext_user"].startswith(user_ext) and not second["ext_user"].startswith(ext_dir)
    assert second["cache_root"] == os.path.join(second["ext_user"], "numba")
    assert second["cache_in_user"], "no Numba cache written"
    assert second["cache_in_ext"] == []
