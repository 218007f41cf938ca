"""``penumbra bench --part camera_effects``: passes with the render's motion
blur and depth of field against Cycles' own shadow pair with the effect on.

The scene (``build_scene``, made in bpy, not a sample .blend): a sphere of
radius 0.5 resting on a ground, lit by a 1 m square area light, seen at
256 x 256 (``--quick``: 96 x 96); Blackman-Harris 1.5 px, Cycles' default.
Three variants:

- ``still``: no effect;
- ``motion``: the sphere slides 0.6 m over two frames (linear keys), the
  render's motion blur on (shutter 0.5 frames, centred);
- ``dof``: the camera focused at half the distance to the sphere, f/0.2.

Per variant: Cycles' truth at ``TRUTH_SAMPLES`` (cached in
``<cache>/penumbra/truth`` by the variant's settings), Cycles' pair at
``PAIR_SAMPLES`` (wall seconds of both renders and its error), and
Penumbra's filtered passes ``REQUESTS`` (the reference ``embree_irr``, the
default ``auto``, ``pcf`` and ``penumbra_casting``, which take moving
occluders at time slices) at ``LIGHT_SAMPLES`` light samples (median wall seconds of ``repeats`` warm
runs of ``render_filtered`` on the captured scene, compilation excluded;
their error). Errors: RMSE against the truth over the pixels the light
reaches (``reach_mask`` on the pixel-centre G-buffer) and over the
silhouette pixels among them (``study.silhouette_mask``). The motion row's
cost is also given as a multiple of the still row's (the same pass without
the effect).

Writes ``camera_effects.md`` / ``.json`` (``--quick``: ``camera_effects_quick.*``).
"""
from __future__ import annotations

import json
import math
import os
import statistics
import time
from typing import List

import numpy as np

from .harness import cache_dir, machine
from .study import silhouette_mask

RES, QUICK_RES = (256, 256), (96, 96)
TRUTH_SAMPLES, QUICK_TRUTH_SAMPLES = 1024, 256
PAIR_SAMPLES = 64
LIGHT_SAMPLES = 64
VARIANTS = ("still", "motion", "dof")
#: Penumbra's passes per variant: the reference, the default, a map method, a world-triangle method
REQUESTS = ("embree_irr", "auto", "pcf", "penumbra_casting")
LIGHT = "Area"


def build_scene(variant: str, res) -> object:
    """The bench's scene in a fresh factory file (bpy), with ``variant``'s effect."""
    import bpy
    from bpy_extras import anim_utils
    bpy.ops.wm.read_factory_settings(use_empty=True)
    sc = bpy.context.scene
    bpy.ops.mesh.primitive_plane_add(size=12.0)
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.5, segments=48, ring_count=24, location=(0.0, 0.0, 0.5))
    sphere = bpy.context.active_object
    light = bpy.data.objects.new(LIGHT, bpy.data.lights.new(LIGHT, "AREA"))
    light.data.size, light.data.energy = 1.0, 400.0
    light.location = (1.5, -1.0, 3.0)
    light.rotation_euler = (math.radians(20.0), math.radians(25.0), 0.0)
    sc.collection.objects.link(light)
    cam = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    cam.location = (0.0, -4.0, 2.2)
    cam.rotation_euler = (math.radians(64.0), 0.0, 0.0)
    cam.data.lens = 40.0
    sc.collection.objects.link(cam)
    sc.camera = cam
    sc.render.engine = "CYCLES"
    sc.cycles.pixel_filter_type = "BLACKMAN_HARRIS"
    sc.cycles.filter_width = 1.5
    sc.render.resolution_x, sc.render.resolution_y = res
    sc.render.resolution_percentage = 100
    if variant == "motion":
        for x, f in ((-0.3, 1), (0.3, 3)):
            sphere.location.x = x
            sphere.keyframe_insert("location", frame=f)
        ad = sphere.animation_data
        for fc in anim_utils.action_get_channelbag_for_slot(ad.action, ad.action_slot).fcurves:
            for kp in fc.keyframe_points:
                kp.interpolation = "LINEAR"
        sc.render.use_motion_blur = True
        sc.render.motion_blur_shutter = 0.5
    if variant == "dof":
        dist = float(np.linalg.norm(np.array(cam.location) - np.array(sphere.location)))
        cam.data.dof.use_dof = True
        cam.data.dof.focus_distance = 0.5 * dist
        cam.data.dof.aperture_fstop = 0.2
    sc.frame_set(2)
    return sc


def _truth(variant: str, res, samples: int) -> np.ndarray:
    from .truth import cycles_pair_of
    path = os.path.join(cache_dir("truth"), f"camera_effects_{variant}_{res[0]}x{res[1]}_{samples}.npy")
    if os.path.exists(path):
        return np.load(path)
    sc = build_scene(variant, res)
    v, _ = cycles_pair_of(sc, LIGHT, res, samples, seed=7)
    os.makedirs(os.path.dirname(path), exist_ok=True)
    np.save(path, v)
    return v


def _errors(v, truth, lit, edge) -> tuple:
    return (float(np.sqrt(np.mean((v[lit] - truth[lit]) ** 2))),
            float(np.sqrt(np.mean((v[edge] - truth[edge]) ** 2))) if edge.any() else float("nan"))


def _measure(variant: str, res, repeats: int, quick: bool) -> List[dict]:
    from ..bridge import settings
    from ..bridge.capture import capture_scene
    from ..core.buffers import FrameBuffers
    from ..core.filtered_frame import render_filtered
    from ..core.metrics import reach_mask
    from .truth import cycles_pair_of
    truth = _truth(variant, res, QUICK_TRUTH_SAMPLES if quick else TRUTH_SAMPLES)
    sc = build_scene(variant, res)
    flt = settings.pixel_filter(sc, "scene")
    captured = capture_scene(sc, resolution=res)
    g = FrameBuffers(captured, *res).gbuffer
    lit = reach_mask(g, captured.lights[0])
    edge = lit & silhouette_mask(g, flt.radius)
    pair, pair_s = cycles_pair_of(build_scene(variant, res), LIGHT, res, PAIR_SAMPLES, seed=0)
    rows = [{"variant": variant, "request": "cycles", "pass": f"Cycles pair {PAIR_SAMPLES} spp", "seconds": pair_s,
             **dict(zip(("rmse_lit", "rmse_silhouette"), _errors(pair, truth, lit, edge)))}]
    for passes in ([m] for m in REQUESTS):
        over = {"samples": LIGHT_SAMPLES, "seed": 1}
        times, res_ = [], None
        for _ in range(repeats + 1):                    # the first run compiles: not counted
            t = time.perf_counter()
            res_ = render_filtered(captured, passes, overrides=over, pixel_filter=flt)
            times.append(time.perf_counter() - t - res_.compile_s)
        lr = res_.lights[0]
        pid = next(iter(lr.passes)) if passes == ["auto"] else passes[0]
        rows.append({"variant": variant, "request": passes[0],
                     "pass": pid if passes != ["auto"] else f"auto -> {pid}",
                     "seconds": statistics.median(times[1:]),
                     **dict(zip(("rmse_lit", "rmse_silhouette"), _errors(lr.passes[pid], truth, lit, edge)))})
    return rows


def bench_camera_effects(out_dir: str, repeats: int, quick: bool) -> str:
    """Measure every variant; write the tables; return the Markdown."""
    res = QUICK_RES if quick else RES
    rows: List[dict] = []
    for variant in VARIANTS:
        rows += _measure(variant, res, repeats, quick)
    still = {r["request"]: r["seconds"] for r in rows if r["variant"] == "still"}
    for r in rows:
        r["x_still"] = r["seconds"] / still[r["request"]]
    lines = [f"Camera effects at {res[0]}x{res[1]}: Penumbra's filtered passes ({LIGHT_SAMPLES} light samples, "
             f"median of {repeats} warm runs, compilation excluded) and Cycles' pair at {PAIR_SAMPLES} samples "
             f"against Cycles' truth at {QUICK_TRUTH_SAMPLES if quick else TRUTH_SAMPLES} samples with the "
             f"effect on; RMSE over the lit / silhouette pixels. Machine: {json.dumps(machine())}", "",
             "| variant | pass | seconds | x still | RMSE lit | RMSE silhouette |", "|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['variant']} | {r['pass']} | {r['seconds']:.2f} | {r['x_still']:.2f} | "
                     f"{r['rmse_lit']:.4f} | {r['rmse_silhouette']:.4f} |")
    md = "\n".join(lines) + "\n"
    stem = "camera_effects_quick" if quick else "camera_effects"
    os.makedirs(out_dir, exist_ok=True)
    with open(os.path.join(out_dir, stem + ".md"), "w") as f:
        f.write(md)
    with open(os.path.join(out_dir, stem + ".json"), "w") as f:
        json.dump({"machine": machine(), "resolution": list(res), "rows": rows}, f, indent=1)
    return md
