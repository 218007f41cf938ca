"""Refactors must not change a pass: render every core method on two sample
scenes through the CLI and compare the EXR channels bit for bit.

    python scripts/check_identical.py save DIR     # this commit's passes -> DIR
    python scripts/check_identical.py compare DIR  # this commit against DIR (exit 1 on any difference)

Small (64x64, 16 samples) so it runs in seconds once the kernels are cached.
Pixel-centre passes (``--pixel-filter none``), whatever ``render``'s default.
"""
from __future__ import annotations

import os
import subprocess
import sys
import tempfile

import numpy as np

HERE = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SCENES = ("grids", "torus_plane")
METHODS = "pcf,single_sample,layered,depth_raytrace,penumbra_casting,irregular,embree,embree_irr"


def _penumbra():
    exe = os.path.join(os.path.dirname(sys.executable), "penumbra")
    return [exe] if os.path.exists(exe) else [sys.executable, "-m", "penumbra.cli"]


def render_all(out: str) -> dict:
    import OpenEXR
    chans = {}
    for s in SCENES:
        blend = os.path.join(HERE, "sample_blends", f"{s}.blend")
        subprocess.run(_penumbra() + ["render", blend, "--out", out, "--methods", METHODS,
                                      "--resolution", "64x64", "--samples", "16", "--no-previews",
                                      "--force", "--frame", "1", "--pixel-filter", "none"], check=True, stdout=subprocess.DEVNULL)
        with OpenEXR.File(os.path.join(out, f"{s}.0001.exr"), separate_channels=True) as f:
            for part in f.parts:
                for name, ch in part.channels.items():
                    chans[f"{s}/{name}"] = np.array(ch.pixels)
    return chans


def main(argv):
    if len(argv) != 2 or argv[0] not in ("save", "compare"):
        print(__doc__, file=sys.stderr)
        return 2
    mode, ref = argv
    with tempfile.TemporaryDirectory() as tmp:
        now = render_all(tmp)
    if mode == "save":
        os.makedirs(ref, exist_ok=True)
        np.savez(os.path.join(ref, "passes.npz"), **now)
        print(f"saved {len(now)} channels to {ref}")
        return 0
    old = dict(np.load(os.path.join(ref, "passes.npz")))
    bad = [k for k in sorted(set(old) | set(now))
           if k not in old or k not in now or not np.array_equal(old[k], now[k])]
    for k in bad:
        print(f"DIFFERENT: {k}")
    print(f"{len(now)} channels, {len(bad)} different")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
