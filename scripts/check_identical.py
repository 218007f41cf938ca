"""Refactors must not change a pass: render every core method on every sample
scene, pixel centres and filtered, through the CLI, and the add-on's Compute
Passes and Preview on two scenes, then compare every channel and image bit for bit.

    python scripts/check_identical.py save DIR     # this commit's passes -> DIR
    python scripts/check_identical.py compare DIR  # this commit against DIR (exit 1 on any difference)
    ... [--scenes grids,torus_plane] [--no-addon]  # a quicker subset
    ... [--visibility average]                     # the passes in that definition

Small (64x64, 16 samples) so it runs in a few minutes once the kernels are cached.
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile

import numpy as np

HERE = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SCENES = ("grids", "torus_plane", "sphere_plane", "sun_pillars", "foliage", "leaf_cards",
          "dense_foliage", "dense_sphere")
FILTERS = ("none", "scene")
METHODS = "pcf,single_sample,layered,depth_raytrace,penumbra_casting,irregular,embree,embree_irr"
ADDON_SCENES = ("sphere_plane", "torus_plane")

#: the add-on's side, run in a child process: Compute Passes with the listed
#: methods and with each light's own (auto), then a Preview; every image
#: Penumbra made, as float32 pixels
_ADDON = r"""
import sys, numpy as np, bpy, penumbra
blend, out = sys.argv[1], sys.argv[2]
penumbra.register()
bpy.ops.wm.open_mainfile(filepath=blend, load_ui=False)
scene = bpy.context.scene
scene.penumbra.visibility = sys.argv[4].upper()
scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = 64, 64, 100
images = {}
def grab(tag):
    for img in bpy.data.images:
        if img.name.startswith("Penumbra"):
            px = np.empty(img.size[0] * img.size[1] * 4, np.float32)
            img.pixels.foreach_get(px)
            images[f"{tag}/{img.name}"] = px
            bpy.data.images.remove(img)
for tag, kw in (("compute", dict(methods=sys.argv[3], samples=16)), ("compute_auto", dict(samples=16)),
                ("preview", dict())):
    op = bpy.ops.penumbra.preview if tag == "preview" else bpy.ops.penumbra.compute_passes
    assert op(**kw) == {"FINISHED"}, tag
    grab(tag)
np.savez(out, **images)
"""


def _penumbra():
    exe = os.path.join(os.path.dirname(sys.executable), "penumbra")
    return [exe] if os.path.exists(exe) else [sys.executable, "-m", "penumbra.cli"]


def render_all(out: str, scenes, addon: bool, visibility: str = "irradiance") -> dict:
    import OpenEXR
    chans = {}
    for s in scenes:
        blend = os.path.join(HERE, "sample_blends", f"{s}.blend")
        for flt in FILTERS:
            d = os.path.join(out, flt)
            subprocess.run(_penumbra() + ["render", blend, "--out", d, "--methods", METHODS,
                                          "--resolution", "64x64", "--samples", "16", "--no-previews",
                                          "--force", "--frame", "1", "--pixel-filter", flt, "--quiet",
                                          "--visibility", visibility],
                           check=True, stdout=subprocess.DEVNULL)
            with OpenEXR.File(os.path.join(d, f"{s}.0001.exr"), separate_channels=True) as f:
                for part in f.parts:
                    for name, ch in part.channels.items():
                        chans[f"{s}/{flt}/{name}"] = np.array(ch.pixels)
    for s in (ADDON_SCENES if addon else ()):
        npz = os.path.join(out, f"addon_{s}.npz")
        subprocess.run([sys.executable, "-c", _ADDON, os.path.join(HERE, "sample_blends", f"{s}.blend"), npz,
                        METHODS, visibility], check=True, stdout=subprocess.DEVNULL)
        chans.update({f"addon/{s}/{k}": v for k, v in np.load(npz).items()})
    return chans


def main(argv):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mode", choices=("save", "compare"))
    ap.add_argument("dir")
    ap.add_argument("--scenes", default=",".join(SCENES))
    ap.add_argument("--no-addon", action="store_true")
    ap.add_argument("--visibility", choices=("irradiance", "average"), default="irradiance")
    args = ap.parse_args(argv)
    scenes = [s for s in args.scenes.split(",") if s]
    with tempfile.TemporaryDirectory() as tmp:
        now = render_all(tmp, scenes, not args.no_addon, args.visibility)
    if args.mode == "save":
        os.makedirs(args.dir, exist_ok=True)
        np.savez(os.path.join(args.dir, "passes.npz"), **now)
        print(f"saved {len(now)} channels to {args.dir}")
        return 0
    old = dict(np.load(os.path.join(args.dir, "passes.npz")))
    wanted = {f"{s}/" for s in scenes} | ({f"addon/{s}/" for s in ADDON_SCENES} if not args.no_addon else set())
    old = {k: v for k, v in old.items() if any(k.startswith(w) for w in wanted)}
    bad = [k for k in sorted(set(old) | set(now))
           if k not in old or k not in now or not np.array_equal(old[k], now[k])]
    for k in bad:
        print(f"DIFFERENT: {k}")
    print(f"{len(now)} channels, {len(bad)} different")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
