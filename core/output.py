"""Writes one frame's result as DESIGN.md's contract says:
``DIR/<stem>.<frame:04d>.exr`` (multilayer), the JSON sidecar beside it, and
PNG previews ``DIR/<stem>.<frame:04d>.<layer>.<method>.png``. Every file is
written to a temporary name and renamed, so a crash leaves no half file.
"""
from __future__ import annotations

import json
import os
from typing import Dict

from . import exr, png
from .frame import FrameResult


def frame_stem(scene_name: str, frame: int) -> str:
    return f"{scene_name}.{int(frame):04d}"


def output_paths(out_dir: str, scene_name: str, frame: int) -> Dict[str, str]:
    stem = os.path.join(out_dir, frame_stem(scene_name, frame))
    return {"exr": stem + ".exr", "json": stem + ".json"}


def write_frame(result: FrameResult, out_dir: str, previews: bool = True) -> Dict[str, str]:
    os.makedirs(out_dir, exist_ok=True)
    paths = output_paths(out_dir, result.scene_name, result.frame)
    layers = {lr.layer: lr.passes for lr in result.lights}
    if result.coverage is not None:       # a filtered frame: its alpha in every layer
        layers = {k: {**v, exr.ALPHA_PASS: result.coverage} for k, v in layers.items()}
    if result.data_passes:                # the Z and vector passes in every layer, as Blender's
        layers = {k: {**v, **result.data_passes} for k, v in layers.items()}
    record = result.to_json()
    if layers and any(layers.values()):
        definitions = {lr.layer: {pid: rec["visibility"] for pid, rec in lr.record.items()} for lr in result.lights}
        exr.write_multilayer(paths["exr"], layers, {"scene": result.scene_name, "frame": result.frame,
                                                    "visibility": json.dumps(definitions, sort_keys=True)})
        record["exr"] = os.path.basename(paths["exr"])
    else:
        paths.pop("exr")
        record["exr"] = None
    if previews:
        for lr in result.lights:
            for pid, img in lr.passes.items():
                p = os.path.join(out_dir, f"{frame_stem(result.scene_name, result.frame)}.{lr.layer}.{pid}.png")
                png.write_gray(p, img)
    exr.atomic_write_bytes(paths["json"], (json.dumps(record, indent=2, allow_nan=False) + "\n").encode())
    return paths
