#!/usr/bin/env python3
"""Build Penumbra's Blender extension zips (``make extension``).

    python scripts/build_extension.py wheels [--platform linux-x64 ...]
    python scripts/build_extension.py build  [--platform linux-x64 ...] [--out dist]

``wheels`` fetches the unmodified PyPI wheels that ``blender_manifest.toml``
lists into ``./wheels/`` (only those not already there), one
``pip download --only-binary=:all: --python-version=3.X --implementation cp
--abi cp3X --platform=<tag> --no-deps <name>==<version>`` per package,
platform and Python (3.11 for Blender 5.0, 3.13 for 5.1 - 5.3), and checks
that pip produced exactly the files the manifest names. A wheel PyPI lacks
stops it with one line naming the package, version, Python and platform.

``build`` (which fetches missing wheels first) writes one zip per platform to
``dist/``, laid out the way ``blender --command extension build
--split-platforms`` lays it out (``bl_pkg/cli/blender_ext.py`` in Blender
5.0): ``<id>-<version>-<platform with _>.zip`` holding the manifest and
``__init__.py`` at the top level, the platform's wheels for both Pythons
(stored, not deflated) under ``wheels/``; Blender installs those matching its
own Python and skips the others, every other file not matched by ``[build]
paths_exclude_pattern``, and the source manifest with a ``[build.generated]``
table appended that narrows ``platforms`` and ``wheels`` to that platform
(Blender applies that table when it installs the zip).

Only the standard library is needed to build; ``wheels`` needs pip.
"""
from __future__ import annotations

import argparse
import fnmatch
import os
import re
import subprocess
import sys
import tomllib
import zipfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MANIFEST = "blender_manifest.toml"

#: pip ``--platform`` tag per Blender platform. pip expands each tag to every
#: older compatible one (manylinux_2_28 -> ..._2_17 / manylinux2014, macosx_13_0
#: -> ...10_x), so the newest tag any needed wheel demands is given:
#: embreex 4.4.0.post1 publishes manylinux_2_28 and macosx_13_0 wheels only.
PIP_PLATFORMS = {
    "linux-x64": "manylinux_2_28_x86_64",
    "macos-arm64": "macosx_13_0_arm64",
    "macos-x64": "macosx_13_0_x86_64",
    "windows-x64": "win_amd64",
}

#: Packages Blender ships itself (numpy 1.26 in 5.0, 2.x in 5.1+): not bundled.
BLENDER_SHIPS = {"numpy"}
#: Packages only the console script uses (the ``penumbra render`` progress
#: bar): not bundled; inside Blender the command runs without a bar.
CONSOLE_ONLY = {"tqdm"}

#: Where PyPI has no wheel of the pinned version for a platform: numba 0.68.1
#: and llvmlite 0.50.0 publish no macOS x86_64 wheels (numba's last Intel-Mac
#: wheels are 0.62.1, with llvmlite 0.45.1; cp311 and cp313 both exist).
VERSION_OVERRIDES = {
    "macos-x64": {"numba": "0.62.1", "llvmlite": "0.45.1"},
}

#: CPython tag per Python the supported Blenders run: 3.11 (Blender 5.0),
#: 3.13 (5.1, 5.2 LTS, 5.3).
PYTHON_TAGS = {"cp311": "3.11", "cp313": "3.13"}


class BuildError(Exception):
    pass


# ---------------------------------------------------------------------------
# Pins, wheel names and platforms

def _norm(name: str) -> str:
    return re.sub(r"[-_.]+", "_", name).lower()


def pinned_requirements(root: str = ROOT) -> dict[str, str]:
    """``{normalised name: version}`` from pyproject's ``name==version`` deps,
    less what Blender ships and what only the console script uses."""
    with open(os.path.join(root, "pyproject.toml"), "rb") as f:
        deps = tomllib.load(f)["project"]["dependencies"]
    out = {}
    for dep in deps:
        name = re.match(r"\s*([A-Za-z0-9_.\-]+)", dep)
        if name is not None and _norm(name.group(1)) in BLENDER_SHIPS:
            continue
        m = re.fullmatch(r"\s*([A-Za-z0-9_.\-]+)\s*==\s*([^\s;]+)\s*", dep)
        if m is None:
            raise BuildError(f"pyproject dependency {dep!r} is not pinned as name==version (no markers)")
        if _norm(m.group(1)) not in CONSOLE_ONLY:
            out[_norm(m.group(1))] = m.group(2)
    return out


def platform_requirements(platform: str, root: str = ROOT) -> dict[str, str]:
    reqs = pinned_requirements(root)
    reqs.update(VERSION_OVERRIDES.get(platform, {}))
    return reqs


def wheel_fields(path: str) -> tuple[str, str, str, str, str]:
    """(name, version, python tag, abi tag, platform tag) of a wheel file name."""
    parts = os.path.basename(path)[:-len(".whl")].split("-")
    if not path.endswith(".whl") or not 5 <= len(parts) <= 6:
        raise BuildError(f"not a wheel file name: {path!r}")
    return _norm(parts[0]), parts[1], parts[-3], parts[-2], parts[-1]


_SYSTEMS = {"macosx": "macos", "manylinux": "linux", "musllinux": "linux", "win": "windows"}
_MACHINES = {"x86_64": "x64", "amd64": "x64", "aarch64": "arm64", "aarch32": "arm32"}


def blender_platforms_of_wheel_platform(tag: str) -> list[str]:
    """Blender's mapping (``blender_platforms_from_wheel_platform`` in
    blender_ext.py): ``manylinux_2_28_x86_64`` -> linux-x64, ``win_amd64`` ->
    windows-x64, ``macosx_11_0_arm64`` -> macos-arm64, universal2 -> both Macs."""
    head, sep, tail = tag.partition("_")
    if not sep:
        return [tag]
    for src, dst in _SYSTEMS.items():
        if head == src or (head.startswith(src) and head[len(src):].isdigit()):
            head = dst
            break
    for src, dst in _MACHINES.items():
        if tail == src or tail.endswith("_" + src):
            tail = dst
            break
    else:
        tail = tail.rpartition("_")[2]
    tails = ["x64", "arm64"] if (head, tail) == ("macos", "universal2") else [tail]
    return [f"{head}-{t}" for t in tails]


def wheels_for_platform(wheels: list[str], platform: str) -> list[str]:
    """The manifest's wheels Blender keeps for ``platform`` when splitting."""
    out = []
    for w in wheels:
        tag = wheel_fields(w)[4]
        if tag == "any" or platform in blender_platforms_of_wheel_platform(tag):
            out.append(w)
    return out


# ---------------------------------------------------------------------------
# Manifest

def load_manifest(root: str = ROOT) -> dict:
    with open(os.path.join(root, MANIFEST), "rb") as f:
        return tomllib.load(f)


def check_manifest_wheels(manifest: dict, platforms: list[str], root: str = ROOT) -> None:
    """Each platform lists exactly one wheel per pinned package and Python
    (cp311, cp313), at the pinned (or overridden) version, under ./wheels/."""
    wheels = manifest.get("wheels", [])
    for w in wheels:
        if not w.startswith("./wheels/") or "/" in w[len("./wheels/"):]:
            raise BuildError(f"manifest wheel {w!r} is not directly under ./wheels/")
    for platform in platforms:
        if platform not in PIP_PLATFORMS:
            raise BuildError(f"no pip platform tag known for {platform!r}")
        want = platform_requirements(platform, root)
        have = {}
        for w in wheels_for_platform(wheels, platform):
            name, version, py, abi, _ = wheel_fields(w)
            tags = [t for t in PYTHON_TAGS if t in py.split(".") and t in abi.split(".")]
            if len(tags) != 1:
                raise BuildError(f"{platform}: {w} is not a wheel for one of {sorted(PYTHON_TAGS)}")
            key = (name, tags[0])
            if key in have:
                raise BuildError(f"{platform}: two {tags[0]} wheels for {name}: {have[key][1]} and {w}")
            have[key] = (version, w)
        need = {(name, tag) for name in want for tag in PYTHON_TAGS}
        if set(have) != need:
            raise BuildError(f"{platform}: manifest wheels {sorted(have)} != needed {sorted(need)}")
        for (name, _tag), (version, w) in have.items():
            if version != want[name]:
                raise BuildError(f"{platform}: {w} is version {version}, pinned {want[name]}")


# ---------------------------------------------------------------------------
# Wheels

def pip_download_command(name: str, version: str, platform: str, tag: str, dest: str) -> list[str]:
    return [sys.executable, "-m", "pip", "download", "--quiet", "--disable-pip-version-check",
            "--only-binary=:all:", f"--python-version={PYTHON_TAGS[tag]}", "--implementation=cp",
            f"--abi={tag}", f"--platform={PIP_PLATFORMS[platform]}", "--no-deps",
            "--dest", dest, f"{name}=={version}"]


def fetch_wheels(platforms: list[str], root: str = ROOT, log=print) -> list[str]:
    """Download the manifest's wheels for ``platforms`` that ./wheels/ lacks;
    returns the manifest paths of the wheels for those platforms."""
    manifest = load_manifest(root)
    check_manifest_wheels(manifest, platforms, root)
    dest = os.path.join(root, "wheels")
    os.makedirs(dest, exist_ok=True)
    needed = []
    for platform in platforms:
        listed = {(wheel_fields(w)[0], wheel_fields(w)[2].split(".")[0]): w
                  for w in wheels_for_platform(manifest["wheels"], platform)}
        for name, version in sorted(platform_requirements(platform, root).items()):
            for tag in PYTHON_TAGS:
                rel = listed[(name, tag)]
                needed.append(rel)
                path = os.path.join(root, rel)
                if os.path.isfile(path) and zipfile.is_zipfile(path):
                    continue
                log(f"pip download {name}=={version} for {platform} ({PIP_PLATFORMS[platform]}, {tag})")
                before = set(os.listdir(dest))
                proc = subprocess.run(pip_download_command(name, version, platform, tag, dest),
                                      capture_output=True, text=True)
                if proc.returncode != 0:
                    raise BuildError(f"no wheel of {name}=={version} for Python {PYTHON_TAGS[tag]} on "
                                     f"{platform} ({PIP_PLATFORMS[platform]}) on the package index")
                if not os.path.isfile(path):
                    got = sorted(set(os.listdir(dest)) - before)
                    raise BuildError(f"pip fetched {got or 'nothing new'} for {name}=={version} on "
                                     f"{platform}, but the manifest lists {rel}: update blender_manifest.toml")
    return needed


# ---------------------------------------------------------------------------
# Paths (``[build] paths_exclude_pattern``, gitignore-like as in blender_ext.py)

def _pattern_matches(pattern: str, rel: str, is_dir: bool) -> bool:
    """A leading ``/`` anchors at the extension root, a trailing ``/`` matches
    directories only, otherwise the pattern matches the path's last
    components; ``*``/``?``/``[]`` never cross a ``/`` (case-sensitive)."""
    anchored = pattern.startswith("/")
    dir_only = pattern.endswith("/")
    if dir_only and not is_dir:
        return False
    pparts = [p for p in pattern.strip("/").split("/") if p]
    parts = rel.split("/")
    if len(pparts) > len(parts):
        return False
    starts = [0] if anchored else range(len(parts) - len(pparts) + 1)
    for s in starts:
        if s + len(pparts) == len(parts) and all(
                fnmatch.fnmatchcase(parts[s + i], p) for i, p in enumerate(pparts)):
            return True
    return False


def is_excluded(rel: str, is_dir: bool, patterns: list[str]) -> bool:
    for p in patterns:
        if p.startswith("!") or "**" in p:
            raise BuildError(f"paths_exclude_pattern {p!r}: negation and ** are not supported here")
    return any(_pattern_matches(p, rel, is_dir) for p in patterns)


def source_files(root: str = ROOT, patterns: list[str] | None = None) -> list[str]:
    """Root-relative paths ('/'-separated) of every file going into the zip
    besides the manifest and wheels."""
    if patterns is None:
        patterns = load_manifest(root).get("build", {}).get("paths_exclude_pattern", [])
    out = []
    for folder, dirs, files in os.walk(root):
        rel_folder = os.path.relpath(folder, root).replace(os.sep, "/")
        rel_folder = "" if rel_folder == "." else rel_folder + "/"
        # like Blender's builder: symbolic links are skipped
        dirs[:] = sorted(d for d in dirs if not os.path.islink(os.path.join(folder, d))
                         and not is_excluded(rel_folder + d, True, patterns))
        for name in sorted(files):
            rel = rel_folder + name
            if os.path.islink(os.path.join(folder, name)) or rel == MANIFEST:
                continue
            if not is_excluded(rel, False, patterns):
                out.append(rel)
    return out


# ---------------------------------------------------------------------------
# Zips

def _toml_str(s: str) -> str:
    return '"' + s.replace("\\", "\\\\").replace('"', '\\"') + '"'


def generated_table(platform: str, wheels: list[str]) -> bytes:
    """What blender_ext.py appends to the manifest of a split-platform zip."""
    return (
        "\n\n# BEGIN GENERATED CONTENT.\n"
        "# This must not be included in source manifests.\n"
        "[build.generated]\n"
        f"platforms = [{_toml_str(platform)}]\n"
        f"wheels = [{', '.join(_toml_str(w) for w in wheels)}]\n"
        "# END GENERATED CONTENT.\n"
    ).encode("utf-8")


def zip_name(manifest: dict, platform: str) -> str:
    return f"{manifest['id']}-{manifest['version']}-{platform.replace('-', '_')}.zip"


def build_zip(platform: str, out_dir: str, root: str = ROOT, log=print) -> str:
    manifest = load_manifest(root)
    if platform not in manifest.get("platforms", []):
        raise BuildError(f"{platform!r} is not in the manifest's platforms {manifest.get('platforms')}")
    if "generated" in manifest.get("build", {}):
        raise BuildError("the source manifest must not contain [build.generated]")
    check_manifest_wheels(manifest, [platform], root)
    wheels = wheels_for_platform(manifest.get("wheels", []), platform)
    files = source_files(root, manifest.get("build", {}).get("paths_exclude_pattern", []))
    if "__init__.py" not in files:
        raise BuildError("not a Python package: __init__.py is missing or excluded")
    with open(os.path.join(root, MANIFEST), "rb") as f:
        manifest_bytes = f.read() + generated_table(platform, wheels)
    os.makedirs(out_dir, exist_ok=True)
    out = os.path.join(out_dir, zip_name(manifest, platform))
    tmp = os.path.join(out_dir, "." + os.path.basename(out))
    try:
        with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED, compresslevel=9) as zf:
            zf.writestr(MANIFEST, manifest_bytes)
            for w in wheels:
                rel = w[2:] if w.startswith("./") else w
                path = os.path.join(root, rel)
                if not os.path.isfile(path):
                    raise BuildError(f"wheel missing: {rel} (run `make wheels`)")
                zf.write(path, rel, compress_type=zipfile.ZIP_STORED)
            for rel in files:
                zf.write(os.path.join(root, rel), rel)
        os.replace(tmp, out)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    log(f"built {os.path.relpath(out, root)} ({os.path.getsize(out) / 1e6:.1f} MB, "
        f"{len(wheels)} wheels, {len(files)} files)")
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("command", choices=("wheels", "build"))
    ap.add_argument("--platform", action="append", dest="platforms", metavar="PLATFORM",
                    help="a Blender platform (linux-x64, macos-arm64, macos-x64, windows-x64); "
                         "repeatable; default: every platform in the manifest")
    ap.add_argument("--out", default=os.path.join(ROOT, "dist"), help="output folder for zips")
    args = ap.parse_args(argv)
    try:
        platforms = args.platforms or list(load_manifest().get("platforms", []))
        if not platforms:
            raise BuildError("the manifest lists no platforms")
        fetch_wheels(platforms)
        if args.command == "build":
            for p in platforms:
                build_zip(p, args.out)
    except BuildError as exc:
        print(f"build_extension: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
