"""One frame filtered the way the scene renders (``pixel_filter``).

Two stages, both ``frame.render_frame`` with the methods unchanged:

1. pixel centres: every pass at one receiver per pixel centre (the
   ``--pixel-filter none`` pass, bit for bit, in a still frame);
2. sub-pixel samples: where a pixel's footprint holds a discontinuity or a
   shadow edge (``pixel_filter.refine_mask``), the G-buffer is traced at the
   ``grid`` x ``grid`` sub-pixel samples of every footprint that needs them
   (the pixel centres of a supersampled view, as a packed list:
   ``raycast.camera_gbuffer_at(packed=True)``); a method that shades each
   receiver on its own (``Method.packed``) runs on that packed G-buffer, any
   other on the supersampled image with only those pixels set
   (``raycast.unpack_gbuffer``). The light views and BVHs of stage 1 are
   shared.

Camera effects. With the camera's depth of field (or a camera that moves
over the shutter) every pixel is refined on the full grid; each sub-sample's
ray starts at its own lens point and is taken at its own shutter time
(``camera_samples``; ``GBuffer.time``). With objects that move and a still
camera, the pixels their images can reach are refined on the full grid
(``_moving_images``); elsewhere a receiver holds still over the shutter and
stands for all of it (``GBuffer.over_shutter``): a method that traces each
receiver's time (``Method.shutter_time``) spreads its shadow rays over the
shutter, any other averages ``motion.TIME_SLICES`` slices of it, at the
pixel centres whose shadows something moving can change (``_moving_shadows``,
``_slice_centres``) as at the sub-samples. Such a method shades a moving
receiver with the occluders where they are at the middle of its time's span
(``_time_slices``; light views and precomputes of the slice's own:
``FrameBuffers.supersampled``'s ``at_time``).

The resolve (``pixel_filter.resolve``) filters the sub-pixel passes into the
refined pixels: an average pass by the filter weights, an irradiance pass by
the weights times the unshadowed irradiance E0 at each sub-sample
(``embree_ref.unshadowed_irradiance``), so unshadowed x V = shadowed holds
for the filtered renders. External passes (``cycles``) arrive already
filtered by their renderer. The frame gets a coverage (alpha) image.
"""
from __future__ import annotations

import dataclasses
import time
from typing import Dict, Optional, Sequence

import numpy as np

from . import camera_effects, camera_samples, raycast
from . import methods as method_registry
from .buffers import FrameBuffers
from .frame import REFERENCE_FOR, FrameResult, render_frame
from .methods.base import IRRADIANCE
from .methods.embree_ref import unshadowed_irradiance
from .metrics import errors, reach_mask
from .pixel_filter import (DEPTH_JUMP, NORMAL_COS, PixelFilter, coverage, footprint_flat, refine_mask,
                           resolve_samples)
from .scene import GBuffer, Scene
from .compile_ahead import frame_keys, prefetch
from .data_passes import raster
from .motion import TIME_SLICES, box_corners, retime_points, step_corners
from .warmup import ensure_filter_compiled

E0_SAMPLES = 16      # stratified light samples per sub-pixel receiver for its unshadowed irradiance (E0)


def render_filtered(scene: Scene, passes: Sequence[str], light_names: Optional[Sequence[str]] = None,
                    pixel_filter: Optional[PixelFilter] = None, **options) -> FrameResult:
    """``frame.render_frame(scene, passes, light_names, **options)`` with the
    passes filtered by ``pixel_filter`` (None or ``none``: exactly
    ``render_frame``); ``time_slices`` (default ``TIME_SLICES``): the
    shutter spans a method that does not trace each receiver's time takes
    the moving occluders at (1: at the frame). Each light's producer (a method with its passes) gets
    its own sub-pixel samples, the footprints that the geometry or its own
    pixel-centre passes need refined (``refine_mask``), so a method's
    filtered pass does not depend on what else the frame computes; the
    G-buffer is traced once at the union of them all."""
    flt = pixel_filter or PixelFilter()
    slices = int(options.pop("time_slices", TIME_SLICES))
    if flt.is_none:
        return render_frame(scene, passes, light_names, **options)
    W, H = scene.resolution
    progress = options.get("progress")
    prefetch(frame_keys(scene, _warmup_passes(passes), True))   # helper processes compile from the end
    compile_s = ensure_filter_compiled(scene, flt, render_filtered,
                                       None if progress is None else (lambda msg: progress(msg, 0.0)),
                                       _warmup_passes(passes))
    buffers = FrameBuffers(scene, W, H, options.get("map_size"))
    buffers.share_precomputed()           # layered's LDI, depth_raytrace's maps: built once for both stages
    m0, taps = flt.taps()
    moves = scene.motion is not None and scene.motion.moves
    # every footprint sees through the lens, or the camera moves: all pixels; moving objects: theirs
    everywhere = scene.camera.has_depth_of_field or (moves and scene.motion.camera is not None)
    objects_move = moves and len(scene.motion.objects) > 0
    swept, casts, corners = (_swept_boxes(scene) if objects_move
                             else (np.zeros((0, 2, 3)), np.zeros(0, bool), np.zeros((0, 0, 8, 3))))
    seen = None                           # the pixels a moving object's image can reach
    if objects_move and not everywhere and taps.size > 0:
        seen = _moving_images(scene, buffers, swept, corners, flt.reach)
        buffers.stand_for_shutter()       # elsewhere a pixel centre's receiver holds still over the shutter
    base = render_frame(scene, passes, light_names, buffers=buffers, **options)
    base.compile_s += compile_s           # the filter's kernels: compiled before anything was timed
    t0 = time.perf_counter()
    g = buffers.gbuffer
    s = int(flt.grid)
    SW, SH = s * W, s * H
    units = []                            # (light result, producer id, its computed passes)
    for lr in base.lights:
        by_producer: Dict[str, list] = {}
        for pid, rec in lr.record.items():
            if not method_registry.is_external(pid) and "skipped" not in rec:
                by_producer.setdefault(method_registry.producer_of(pid).id, []).append(pid)
        units += [(lr, prod, pids) for prod, pids in by_producer.items()]
    moving = {}
    slice_bounds = _slice_bounds(buffers.bounds(), swept)

    def sliced(m) -> bool:
        """Producer ``m`` takes the occluders at time slices (objects move, it does not trace each
        time; one slice: the frame)."""
        return objects_move and not m.shutter_time
    overrides, method_overrides = options.get("overrides"), options.get("method_overrides")
    sliced_s = {}                         # (light, producer) -> seconds of its pixel centres' time slices
    if seen is not None:
        moving = {lr.name: seen | _moving_shadows(buffers, scene.light(lr.name), swept[casts], flt.reach)
                  for lr in base.lights}
        for lr, prod, pids in units:      # a still receiver in a moving shadow: its pixel centre over the shutter
            if sliced(method_registry.producers()[prod]) and slices > 1:
                still = moving[lr.name] & ~seen & buffers.reach(scene.light(lr.name))
                sliced_s[lr.name, prod] = _slice_centres(scene, buffers, lr, method_registry.producers()[prod],
                                                         still, slices, slice_bounds, overrides, method_overrides)
    # each unit's footprints (the geometry's and its passes' V); the coverage's are those
    # of the pixels beside a change of hit, which every unit refines on the full grid (the
    # geometry's own when there is no unit). What moves is refined on the full grid where its
    # image can reach; a still receiver's pixel centre already stands for the shutter (its
    # rays spread over it, or its time slices)
    masks = [_refined(flt, g, [lr.computed[q] for q in method_registry.producers()[prod].passes], taps.size > 0,
                      everywhere, seen) for lr, prod, pids in units]
    if not units:
        masks = [_refined(flt, g, [], taps.size > 0, everywhere,
                          np.logical_or.reduce(list(moving.values())) if moving else None)]
    flat = [footprint_flat(refine, s, int(m0), int(taps.shape[0]), full, flt.shade_lattice)
            for refine, full in masks]
    samples = [(f // SW, f % SW) for f in flat]
    traced = np.zeros(SH * SW, bool)      # the union of every list: one flag per sub-pixel
    for f in flat:
        traced[f] = True
    union = np.flatnonzero(traced)
    del traced
    sub_scene = scene.at_resolution(SW, SH)
    tg = time.perf_counter()
    lens = (camera_samples.lens_points(scene.camera, union, SW, s, _seed(options))
            if scene.camera.has_depth_of_field else None)
    times = camera_samples.shutter_times(union, SW, s, _seed(options)) if moves else None
    sub_g = raycast.camera_gbuffer_at(sub_scene, SW, SH, union % SW, union // SW, buffers.camera_scene,
                                      packed=True, lens=lens, time=times)
    del lens, times
    if seen is not None:                  # a sub-sample away from the moving images stands for the shutter
        sub_g.over_shutter = ~seen.reshape(-1)[(union // SW // s) * W + (union % SW) // s].reshape(1, -1)
    tg = time.perf_counter() - tg
    setup_s = time.perf_counter() - t0 - tg - sum(sliced_s.values())    # refine masks, footprints, union
    for i, (lr, prod, pids) in enumerate(units):
        t1 = time.perf_counter()
        at = np.searchsorted(union, flat[i])      # the unit's samples in the traced union
        g_u = sub_g if len(at) == len(union) else _take(sub_g, at)    # the whole union: itself
        refine, full = masks[i]
        rows, cols = samples[i]
        sub_v, sub_t = {}, {}
        t2 = time.perf_counter()
        if len(at):
            m = method_registry.producers()[prod]
            on_full = full[rows // s, cols // s]     # a sub-sample's own pixel is on the full grid
            groups = [(np.flatnonzero(on_full), _shared(m, overrides, method_overrides, s * s)),
                      (np.flatnonzero(~on_full), _shared(m, overrides, method_overrides, flt.shade_grid ** 2))]
            if groups[0][1] == groups[1][1]:           # one run over every sub-sample
                groups = [(np.arange(len(at)), groups[0][1])]
            for part, mo in groups:
                for at_time, sl, share in (_time_slices(g_u, part, slices, scene.motion) if sliced(m)
                                           else [(None, part, None)]):
                    if not len(sl):
                        continue
                    g_p = g_u if len(sl) == len(at) else _take(g_u, sl)
                    if share is not None:         # the receivers where the slice's occluders are
                        g_p = _retimed(g_p, scene.motion, scene.motion.frame_time if at_time is None else at_time)
                    gb = g_p if m.packed else raycast.unpack_gbuffer(g_p, SW, SH)
                    sub_buffers = buffers.supersampled(sub_scene, SW, SH, gb, tg * len(sl) / len(union), at_time,
                                                       slice_bounds)
                    sub = render_frame(sub_scene, pids, [lr.name], overrides, mo, buffers=sub_buffers)
                    for pid in (sub.lights[0].passes if sub.lights else ()):
                        v = sub.lights[0].passes[pid]
                        v = v.reshape(-1) if m.packed else v[rows[sl], cols[sl]]
                        acc = sub_v.setdefault(pid, np.zeros(len(at), np.float32))
                        acc[sl] = v if share is None else acc[sl] + share * v
                        sub_t[pid] = sub_t.get(pid, 0.0) + sub.lights[0].record[pid]["time_s"]["total"]
        sub_s = time.perf_counter() - t2
        stats = {"refined_pixels": int(refine.sum()), "subpixel_samples": int(len(rows)),
                 "subpixel_receivers": int(g_u.hit.sum())}
        own_s = setup_s / len(units) + time.perf_counter() - t1 - sub_s
        _resolve_unit(scene, flt, lr, pids, sub_v, sub_t, g_u, buffers, refine, rows, cols, stats, own_s,
                      slices if objects_move else 1, sliced_s.get((lr.name, prod), 0.0))
    for lr in base.lights:
        _errors(lr, buffers.reach(scene.light(lr.name)))   # the pixel-centre stage's mask, as its errors used
    rows, cols = samples[0]
    edges = hit_edges(g.hit, flt.reach) if taps.size else np.zeros((H, W), bool)
    first_hit = sub_g.hit[0] if len(samples) == 1 else _take(sub_g, np.searchsorted(union, flat[0])).hit
    base.coverage = coverage(flt, edges, g.hit, rows, cols, first_hit)
    base.pixel_filter = flt.to_json()
    base.camera_effects = camera_effects.describe_effects(scene, sampled=(everywhere or moves) and taps.size > 0)
    base.total_s += time.perf_counter() - t0
    return base


def shutter_words(method, slices: int) -> str:
    """How ``method``'s filtered pass finds the occluders over the shutter
    (the record's ``shutter``), with objects moving at ``slices`` time slices."""
    if method.shutter_time:
        return "occluders at the receiver's time"
    return f"occluders at {slices} time slices" if slices > 1 else "occluders at the frame"


def _slice_centres(scene: Scene, buffers: FrameBuffers, lr, m, pixels: np.ndarray, slices: int, bounds,
                   overrides, method_overrides) -> float:
    """Producer ``m``'s pixel-centre passes of light ``lr`` at ``pixels``
    (bool[H, W]: still receivers whose shadows something moving can change)
    as the mean of its values at the ``slices`` time slices, each with the
    occluders where they are then (``FrameBuffers.supersampled``'s
    ``at_time``, fitted to ``bounds``; the slice at the frame's own time is
    the pixel-centre stage's). In place in ``lr.computed`` (and so in its
    passes); returns the seconds it took."""
    t0 = time.perf_counter()
    H, W = pixels.shape
    idx = np.flatnonzero(pixels.reshape(-1))
    own = [q for q in m.passes if q in lr.computed]
    if not len(idx) or not own:
        return 0.0
    g = buffers.gbuffer
    centres = _take(GBuffer(position=g.position.reshape(1, -1, 3), normal=g.normal.reshape(1, -1, 3),
                            depth=g.depth.reshape(1, -1), object_id=g.object_id.reshape(1, -1),
                            triangle_id=g.triangle_id.reshape(1, -1), hit=g.hit.reshape(1, -1),
                            pixel=np.arange(H * W, dtype=np.int64)), idx)
    gb = centres if m.packed else raycast.unpack_gbuffer(centres, W, H)
    rows, cols = idx // W, idx % W
    total = {q: np.zeros(len(idx), np.float64) for q in own}
    for j in range(slices):
        t = (j + 0.5) / slices
        if abs(t - scene.motion.frame_time) < 1e-12:
            for q in own:
                total[q] += lr.computed[q][rows, cols]
            continue
        sub = render_frame(scene, own, [lr.name], overrides, method_overrides,
                           buffers=buffers.supersampled(scene, W, H, gb, 0.0, t, bounds))
        for q in own:
            v = sub.lights[0].passes[q]
            total[q] += v.reshape(-1) if m.packed else v[rows, cols]
    for q in own:
        lr.computed[q][rows, cols] = (total[q] / slices).astype(np.float32)
    return time.perf_counter() - t0


def _time_slices(g: GBuffer, part: np.ndarray, slices: int, motion):
    """[(shutter time or None, entries of ``part``, float32 share of each)]:
    the sub-samples ``part`` of the packed G-buffer ``g`` split by their
    time (``GBuffer.time``) into ``slices`` equal spans of the shutter,
    each taken at its span's middle (None: the frame's own time, whose
    buffers the pixel-centre stage built), with share 1; a sub-sample that
    stands for the whole shutter (``GBuffer.over_shutter``) is in every
    slice with share 1 / ``slices``."""
    if slices <= 1:
        return [(None, part, np.ones(len(part), np.float32))]
    k = np.minimum((g.time.reshape(-1)[part] * slices).astype(np.int64), slices - 1)
    spread = g.spread(part)
    if spread is None:
        spread = np.zeros(len(part), bool)
    out = []
    for j in range(slices):
        t = (j + 0.5) / slices
        sel = (k == j) | spread
        share = np.where(spread[sel], np.float32(1.0 / slices), np.float32(1.0)).astype(np.float32)
        out.append((None if abs(t - motion.frame_time) < 1e-12 else t, part[sel], share))
    return out


def _retimed(g: GBuffer, motion, t: float) -> GBuffer:
    """Packed G-buffer ``g`` with its receivers on moving objects moved from
    their own time (``GBuffer.time``) to shutter time ``t`` (a time
    slice's, whose occluders shade them: a surface does not shadow itself
    for being taken at another time than its receiver)."""
    pos = np.array(g.position.reshape(-1, 3), np.float64)
    nrm = np.array(g.normal.reshape(-1, 3), np.float32)
    retime_points(motion, pos, nrm, g.object_id.reshape(-1), g.time.reshape(-1), t)
    return dataclasses.replace(g, position=pos.reshape(g.position.shape), normal=nrm.reshape(g.normal.shape))


def _slice_bounds(bounds, swept: np.ndarray):
    """The frame's ``bounds`` grown to hold the ``swept`` boxes (a time
    slice's light views are fitted to them)."""
    lo, hi = np.asarray(bounds[0], np.float64), np.asarray(bounds[1], np.float64)
    if len(swept):
        lo, hi = np.minimum(lo, swept[:, 0].min(0)), np.maximum(hi, swept[:, 1].max(0))
    return lo, hi


def _seed(options) -> int:
    """The frame's seed (``--seed``; 0 unset): the lens samples'."""
    return int(((options.get("overrides") or {}).get("seed")) or 0)


def _warmup_passes(passes: Sequence[str]) -> list:
    """The passes the filter's warm-up renders: the frame's own core passes
    (their kernels are compiled for the frame anyway), ``embree`` and
    ``embree_irr`` when the frame has none or asks for ``auto`` (whose
    method is chosen per light of the real scene)."""
    own = [p for p in passes if p != "auto" and not method_registry.is_external(p)
           and p in method_registry.pass_ids(external=False)]
    return own if own and "auto" not in passes else ["embree", "embree_irr"]


def _refined(flt: PixelFilter, g: GBuffer, values, any_taps: bool, everywhere: bool = False,
             moving: Optional[np.ndarray] = None):
    """(refine, full) bool[H, W] of ``refine_mask`` for the pixel-centre
    passes ``values`` (none: the geometry alone); nothing refined when the
    filter is narrower than the sub-sample spacing; everything (full grid)
    for ``threshold`` < 0 (the full supersampled pass: bench, tests) or
    ``everywhere`` (a thin lens, a moving camera: no pixel centre stands for
    its footprint); the pixels ``moving`` marks on the full grid too (what
    moves over the shutter can change them: ``_moving_images``, ``_moving_shadows``)."""
    H, W = g.shape
    refine = np.zeros((H, W), bool)
    full = np.zeros((H, W), bool)
    if any_taps and (flt.threshold < 0 or everywhere):
        refine[:] = True
        full[:] = True
    elif any_taps:
        stack = np.ascontiguousarray(np.stack(values) if len(values) else np.zeros((0, H, W)), np.float32)
        refine_mask(g.hit, g.object_id, g.depth, g.normal, stack, flt.reach, float(flt.threshold),
                    DEPTH_JUMP, NORMAL_COS, refine, float(flt.sharp), full, float(flt.geo_v))
    if any_taps and moving is not None:
        refine |= moving
        full |= moving
    return refine, full


def _moving_images(scene: Scene, buffers: FrameBuffers, swept: np.ndarray, corners: np.ndarray,
                   reach: int) -> np.ndarray:
    """bool[H, W]: the pixels a moving object's image can reach over the
    shutter, and so what it hides or shows, within ``reach``: those in the
    image of a box in ``swept`` (each moving object's over the shutter) and
    near one whose centre sees a moving object at one of the motion's steps
    (the pixel-centre G-buffer at the step's time), as near as the image of
    a moving object's box (its ``corners`` at each step, ``_swept_boxes``)
    moves between two steps (every pixel when a swept box reaches behind the
    camera's plane). With ``_moving_shadows``: the
    pixels whose footprint something moving can change (the camera still); a
    pixel left out keeps its pixel-centre value, which motion cannot change."""
    g = buffers.gbuffer
    H, W = g.shape
    cam, motion = scene.camera, scene.motion
    if not len(swept):
        return np.zeros((H, W), bool)
    swept_corners = box_corners(swept).reshape(-1, 3)
    local = (swept_corners - cam.position) @ np.asarray(cam.world_from_camera, np.float64)[:3, :3]
    if cam.kind != "ORTHO" and (local[:, 2] > -max(cam.clip_start, 1e-9)).any():
        return np.ones((H, W), bool)
    in_boxes = np.zeros((H, W), bool)
    for xy in raster(cam, cam.world_from_camera, swept_corners, W, H).reshape(-1, 8, 2):
        c0, c1 = int(np.floor(xy[:, 0].min())) - reach, int(np.ceil(xy[:, 0].max())) + reach
        r0, r1 = int(np.floor(H - xy[:, 1].max())) - reach, int(np.ceil(H - xy[:, 1].min())) + reach
        in_boxes[max(r0, 0):max(min(r1, H), 0), max(c0, 0):max(min(c1, W), 0)] = True
    shift = 0.0                           # the farthest a box corner's image moves between two steps
    prev = None
    for moved in corners:                 # [m, 8, 3] each step
        xy = raster(cam, cam.world_from_camera, moved.reshape(-1, 3), W, H)
        if prev is not None:
            shift = max(shift, float(np.max(np.linalg.norm(xy - prev, axis=1))))
        prev = xy
    step_t = np.linspace(0.0, 1.0, motion.steps)
    idx = np.arange(H * W, dtype=np.int64)
    seen = np.zeros(H * W, bool)
    for t in step_t:
        at = g if abs(t - motion.frame_time) < 1e-12 else raycast.camera_gbuffer_at(
            scene, W, H, idx % W, idx // W, buffers.camera_scene, packed=True,
            time=np.full(H * W, t, np.float32))
        seen |= (motion.slot_of(at.object_id.reshape(-1)) >= 0) & at.hit.reshape(-1)
    return in_boxes & _dilate(seen.reshape(H, W), reach + int(np.ceil(shift)) + 1)


def _dilate(mask: np.ndarray, r: int) -> np.ndarray:
    """bool like ``mask``: the pixels within ``r`` (in x and in y) of a set one."""
    out = mask.copy()
    for axis in (0, 1):
        grown = out.copy()
        n = out.shape[axis]
        for d in range(1, min(r, n - 1) + 1):
            if axis == 0:
                grown[d:] |= out[:-d]
                grown[:-d] |= out[d:]
            else:
                grown[:, d:] |= out[:, :-d]
                grown[:, :-d] |= out[:, d:]
        out = grown
    return out


def _moving_shadows(buffers: FrameBuffers, light, casters: np.ndarray, reach: int) -> np.ndarray:
    """bool[H, W]: the pixels within ``reach`` of a pixel-centre receiver
    whose shadow rays to ``light`` (the box from it to the light's; a sun:
    swept towards it across the scene, widened by the cone) can meet one of
    the ``casters`` boxes (moving objects that cast shadows, swept over the
    shutter)."""
    g = buffers.gbuffer
    H, W = g.shape
    if not len(casters) or not light.casts_shadow or not g.hit.any():
        return np.zeros((H, W), bool)
    idx = np.flatnonzero(g.hit.reshape(-1))
    P = g.position.reshape(-1, 3)[idx]
    if light.kind == "sun":
        reach_d = 2.0 * buffers.scale
        far = P - light.direction * reach_d
        spread = light.sun_spread * reach_d
        lo, hi = np.minimum(P, far) - spread, np.maximum(P, far) + spread
    else:
        blo, bhi = light.box()
        lo, hi = np.minimum(P, blo), np.maximum(P, bhi)
    near = np.zeros(len(idx), bool)
    for clo, chi in casters:
        near |= np.all((hi >= clo) & (lo <= chi), axis=1)
    shadow = np.zeros(H * W, bool)
    shadow[idx[near]] = True
    shadow = shadow.reshape(H, W)
    return _dilate(shadow, reach)


def _swept_boxes(scene: Scene):
    """(float64[m, 2, 3] the boxes holding each moving object with geometry
    over the shutter, bool[m] whether it casts shadows, float64[K, m, 8, 3]
    the corners of its box at each step)."""
    boxes, casts = _moving_boxes(scene)
    corners = step_corners(scene.motion.delta, boxes)
    swept = np.stack([corners.min(axis=(0, 2)), corners.max(axis=(0, 2))], 1)
    ok = np.isfinite(swept).all(axis=(1, 2))
    return swept[ok], casts[ok], corners[:, ok]


def _moving_boxes(scene: Scene):
    """(float64[m, 2, 3] the box of each moving object at the frame, in
    ``motion.objects``' order (+-inf: no geometry), bool[m] whether it
    casts shadows)."""
    motion = scene.motion
    m = len(motion.objects)
    boxes = np.empty((m, 2, 3), np.float64)
    boxes[:, 0], boxes[:, 1] = np.inf, -np.inf
    if scene.is_flattened:
        slot = motion.slot_of(scene.tri_object)
        sel = slot >= 0
        tris = scene.triangles[sel].astype(np.float64)
        np.minimum.at(boxes[:, 0], slot[sel], tris.min(axis=1))
        np.maximum.at(boxes[:, 1], slot[sel], tris.max(axis=1))
    else:
        ins = scene.instances
        slot = motion.slot_of(ins.object_id)
        sel = slot >= 0
        ib = ins.instance_boxes()[sel]
        np.minimum.at(boxes[:, 0], slot[sel], ib[:, 0])
        np.maximum.at(boxes[:, 1], slot[sel], ib[:, 1])
    casts = np.array([scene.objects[int(o)].casts_shadow for o in motion.objects], bool)
    return boxes, casts


def hit_edges(hit: np.ndarray, reach: int) -> np.ndarray:
    """bool[H, W]: pixels with a neighbour within ``reach`` (in the frame)
    whose centre sees a surface where theirs sees the world, or the other way
    round: ``refine_mask``'s first geometry test, which puts them on the full
    grid in every producer's list."""
    H, W = hit.shape
    pad = np.pad(hit, reach, mode="edge")       # beyond the frame: the border pixel again, no edge
    out = np.zeros((H, W), bool)
    for dy in range(-reach, reach + 1):
        for dx in range(-reach, reach + 1):
            out |= pad[reach + dy:reach + dy + H, reach + dx:reach + dx + W] != hit
    return out


def _take(g: GBuffer, at: np.ndarray) -> GBuffer:
    """Entries ``at`` of the packed G-buffer ``g`` (a packed G-buffer)."""
    return GBuffer(position=g.position[:, at], normal=g.normal[:, at], depth=g.depth[:, at],
                   object_id=g.object_id[:, at], triangle_id=g.triangle_id[:, at], hit=g.hit[:, at],
                   pixel=g.pixel[at], time=None if g.time is None else g.time[:, at],
                   over_shutter=None if g.over_shutter is None else g.over_shutter[:, at])


def _shared(m, overrides, method_overrides, share: int):
    """``method_overrides`` with producer ``m``'s light samples shared among
    the ``share`` sub-pixel receivers of a pixel (``Method.subpixel_overrides``):
    a pixel's receivers together take about the light samples one pixel-centre
    receiver does, as a renderer draws pixel position and light sample jointly."""
    own = dict((method_overrides or {}).get(m.id, {}))
    own.update(m.subpixel_overrides(m.make_params({**(overrides or {}), **own}), share))
    return {**(method_overrides or {}), m.id: own}


def _resolve_unit(scene: Scene, flt: PixelFilter, lr, pids, sub_v, sub_t, sub_g: GBuffer, buffers: FrameBuffers,
                  refine: np.ndarray, rows: np.ndarray, cols: np.ndarray, stats: Dict[str, int],
                  own_s: float, slices: int = 1, sliced_s: float = 0.0) -> None:
    """Filter light ``lr``'s passes ``pids`` (one producer's) in place from
    the sub-pixel stage's values ``sub_v[pid]`` (float32 per sub-sample, in
    ``sub_g``'s order; empty: nothing to refine) that took ``sub_t[pid]``
    seconds; record the filter, the sub-pixel sample counts and the
    sub-pixel stage's time (``own_s``: the producer's share of the refine
    masks, footprints and G-buffer lists; ``slices``: the time slices its
    occluders were taken at, when objects move; ``sliced_s``: the seconds
    its pixel centres' time slices took, ``_slice_centres``)."""
    light = scene.light(lr.name)
    e0 = None
    for pid in pids:
        rec = lr.record[pid]
        t = time.perf_counter()
        sub_time = 0.0
        if pid in sub_v:
            weight = None
            if rec["visibility"] == IRRADIANCE:
                if e0 is None:
                    e0 = _unshadowed(sub_g, light, rec.get("params", {}).get("seed", 0), buffers.scale)
                weight = e0
            lr.passes[pid] = np.clip(resolve_samples(flt, refine, lr.passes[pid], rows, cols, sub_v[pid], weight),
                                     0.0, 1.0).astype(np.float32)
            sub_time = sub_t[pid]
        phases = {k: v for k, v in rec["time_s"].items() if k != "total"}
        if sliced_s:
            phases["time_slices"] = round(sliced_s / len(pids), 6)
        phases["subpixel"] = round(sub_time + own_s / len(pids), 6)
        phases["resolve"] = round(time.perf_counter() - t, 6)
        phases["total"] = round(sum(phases.values()), 6)
        rec["time_s"] = phases
        rec["pixel_filter"] = {**flt.to_json(), **stats}
        if scene.motion is not None and scene.motion.moves:
            rec["shutter"] = shutter_words(method_registry.producer_of(pid), slices)


def _errors(lr, mask: np.ndarray) -> None:
    """Light ``lr``'s errors again, on its filtered passes and references."""
    for pid in lr.record:
        ref = REFERENCE_FOR[lr.record[pid]["visibility"]]
        if "error" in lr.record[pid] and ref in lr.passes:
            lr.record[pid]["error"] = {"reference": ref, **errors(lr.passes[pid], lr.passes[ref], mask)}


def _unshadowed(sub_g: GBuffer, light, seed, scale: float) -> np.ndarray:
    """E0 at every sub-pixel receiver the light reaches (0 elsewhere), packed."""
    reach = reach_mask(sub_g, light).reshape(-1)
    idx = np.flatnonzero(reach).astype(np.int64)
    out = np.zeros(reach.size, np.float64)
    if len(idx):
        P = sub_g.position.reshape(-1, 3)[idx]
        N = sub_g.normal.reshape(-1, 3)[idx].astype(np.float64)
        out[idx] = unshadowed_irradiance(P, N, sub_g.seed_ids(idx), light, 1 if light.is_zero_size else E0_SAMPLES,
                                         int(seed or 0), scale)
    return out
