"""Coherence-based ray tracing of depth images (Agrawala, Ramamoorthi,
Heirich, Moll 2000, section 5), method id ``depth_raytrace``: average
visibility (equation 2, pass ``depth_raytrace``) and the irradiance ratio
(equation 1 with / without V, pass ``depth_raytrace_irr``, weights as
``embree_irr``'s), from shadow rays traced through depth images.

Parameters (``DepthRaytraceParams``):

  ==========================  ========  ======================================
  samples                     256       light samples per pixel (section 6)
  seed                        0         seed of the samples' counter hash
  map_scale / map_size        2 / None  map side: x the output's side / given
  ref_points                  4         reference eyes on a round light / sun
  shadow_bias                 None      floor bias, scene units (6.1)
  bias_texels / slope_bias    0.5 / 1   else: texel footprints + slope term
  gap_bias / gap_texels       None / 8  gap bias, scene units / footprints
  normal_offset               1.5       origin offset, texels x (1 - cos)
  coherence                   True      coherence-based sampling (5.2)
  subgrid / subgrid_shortcut  3 / True  5.2.2's high-resolution grid per cell
  reset_pixels                4.0       reset tolerance (5.2.1), camera pixels
  reset_distance              None      the same in scene units
  tile                        16        coherent order in tile x tile blocks
  tracer                      "depth"   "depth" images | "embree" triangles
  ==========================  ========  ======================================

and the accelerations, each True and a switch for the ablation:
``hierarchical_connectedness`` (off while coherence is on, 5.2.2),
``minmax_clipping`` (5.1.1), ``rank_images``, ``clear_miss``,
``occlusion_intervals`` (5.1.2).

Algorithm. Precompute (independent of ``samples``): depth maps from a few
points on the light - a rectangle's 4 corners, boundary points of the other
shapes (``maps.reference_eyes``) - with floors Z + bias and min / max and
connectedness quadtrees (``maps``). Per G-buffer point, moved off its
surface by ``sampling.offset_origin``: one ray per stratum of the light's
unit square to the reference's own jittered sample (same counter hash, so
with coherence off the method shoots the reference's rays), traced through
the images (``trace``: hierarchical epipolar traversal, floors and walls);
with ``coherence`` only the cells the sampler of 5.2 queues (``coherence``),
points in coherent order per tile (``tiles``). ``tracer="embree"`` drives
the same sampler with Embree rays (``waves``).

Departures from the paper:
  * floor bias: ``bias_texels`` texel footprints plus ``slope_bias`` x the
    depth change across half a texel (6.1 asks only for a user bias); the
    paper's version: ``shadow_bias`` in scene units. Likewise ``gap_texels``
    against the paper's ``gap_bias``;
  * ray origins move ``normal_offset`` footprints x (1 - cos theta) along
    the normal, out of the texel a surface seen edge-on shares with its
    neighbour (a bar's side with its top); the paper's: ``normal_offset=0``;
  * a ray into the point's own surface (cos theta_r <= 0) is blocked
    without tracing;
  * cube faces (wide lights) overlap by 3 texels, their outer ring unused;
  * a sun's views are fitted to the geometry the receivers' rays can pass
    behind (``window``; views are left open, footnote 4), its maps at least
    ``SUN_MIN_MAP`` (the paper's 1024) on a side, up to
    ``SUN_MIN_MAP_REACH`` x the ``map_scale`` side.

Limitation: under a light far wider than its height above an occluder, a
far corner's image sees the occluder at a grazing angle; its slope-scaled
bias can swallow the sliver of a ray just under it and that image, trusted
by the clear miss and occlusion intervals, reports the ray clear (too bright).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Dict, Optional

import numpy as np

from ... import sampling
from ...sampling import strata
from ...scene import Light
from ..base import (AVERAGE, DEFAULT_LIGHT_SAMPLES, GBUFFER, IRRADIANCE, LIGHT_SAMPLE_VIEWS, PRECOMPUTE, SHADOW_GEOMETRY,
                    SHADOW_TRIANGLES, Method, MethodResult, PhaseTimer)
from ..registry import register
from .coherence import M_BLK, M_ERR, M_FLOOD, M_FULL, M_FULLRAYS, M_RAYS, M_SEEDED, M_SIZE, Points, Sampler
from .maps import ReferenceMaps, build_reference_maps
from .tiles import camera_footprint, casters_box, coherent_order, normal_offsets, trace_tiles
from .trace import ReferenceImages, TraceSwitches
from .waves import embree_waves

SUN_MIN_MAP = 1024        # a sun's map side at least this: the paper's 1024^2 maps (section 6)
SUN_MIN_MAP_REACH = 4     # ... but at most this many times the map_scale side (a tiny output keeps tiny maps)


@dataclass
class DepthRaytraceParams:
    samples: int = DEFAULT_LIGHT_SAMPLES   # light samples per pixel (section 6: "the equivalent of 256")
    seed: int = 0
    # reference images (5.1)
    map_scale: float = 2.0        # map side / output side: the paper's 1024^2 maps for 512^2 images
    map_size: Optional[int] = None  # overrides map_scale
    ref_points: int = 4           # boundary points for disk / ellipse / sun (rectangle: its 4 corners)
    shadow_bias: Optional[float] = None  # scene units; None = bias_texels + slope_bias terms
    bias_texels: float = 0.5      # constant part, in texel footprints at the texel's depth
    slope_bias: float = 1.0       # x the depth change across half a texel
    gap_bias: Optional[float] = None     # scene units; None = gap_texels footprints
    gap_texels: float = 8.0       # connected while |dZ| < gap_texels texel footprints
    normal_offset: float = 1.5    # ray origins move this many texel footprints x (1 - cos theta) along the normal
    # accelerations (5.1.1, 5.1.2)
    hierarchical_connectedness: bool = True
    minmax_clipping: bool = True
    rank_images: bool = True
    clear_miss: bool = True
    occlusion_intervals: bool = True
    # coherence-based sampling (5.2)
    coherence: bool = True
    subgrid: int = 3              # "typically 3x3" high-resolution grid per light cell
    subgrid_shortcut: bool = True
    reset_pixels: float = 4.0     # tolerance, in camera pixel footprints at the point
    reset_distance: Optional[float] = None  # tolerance in scene units (overrides reset_pixels)
    tile: int = 16                # coherent order: serpentine scan inside tile x tile blocks
    tracer: str = "depth"         # "depth" (reference images) | "embree" (real triangles)

    visibility: str = "irradiance"   # the pass: "irradiance" (the ratio that composites, eq. 1) | "average" (eq. 2)

def resolve_map_size(params: DepthRaytraceParams, W: int, H: int, light: Optional[Light] = None) -> int:
    """The reference maps' side: ``map_size``, else ``map_scale`` x the
    output's larger side -- for a sun at least ``SUN_MIN_MAP`` (up to
    ``SUN_MIN_MAP_REACH`` times that side): its windows hold only the
    blockers (``window``), so its texel follows their extent, not the
    output's pixels, and a small output's maps would quantise thin
    blockers' silhouettes into their penumbrae."""
    if params.map_size:
        return int(params.map_size)
    side = max(8, int(round(float(params.map_scale) * max(W, H))))
    if light is not None and light.kind == "sun":
        side = max(side, min(SUN_MIN_MAP, SUN_MIN_MAP_REACH * side))
    return side


@register
class DepthRaytrace(Method):
    id = "depth_raytrace"
    paper = "Agrawala, Ramamoorthi, Heirich, Moll 2000, section 5"
    passes = {"depth_raytrace": IRRADIANCE, "depth_raytrace_irr": IRRADIANCE}
    needs = frozenset({GBUFFER, SHADOW_GEOMETRY, SHADOW_TRIANGLES, LIGHT_SAMPLE_VIEWS, PRECOMPUTE})
    packed = True                # shades each receiver of a packed G-buffer on its own
    Params = DepthRaytraceParams
    physical = True

    def subpixel_overrides(self, params, share: int):
        """Each sub-pixel receiver its share of the light samples (at least one)."""
        return {"samples": max(1, -(-int(params.samples) // max(1, int(share))))}

    def run(self, buffers, light, params: DepthRaytraceParams, maps: Optional[ReferenceMaps] = None
            ) -> MethodResult:
        """``maps`` lets a caller reuse reference maps built by ``build_maps``
        (they do not depend on the sample count)."""
        timer = PhaseTimer()
        g = buffers.gbuffer
        H, W = g.shape
        out_a = np.ones(H * W, np.float32)
        out_i = np.ones(H * W, np.float32)
        idx = np.flatnonzero(g.hit.reshape(-1))
        ns = 1 if light.is_zero_size else max(1, int(params.samples))
        nx, ny = strata(ns)
        C = nx * ny
        coherent = bool(params.coherence) and C > 1
        S = max(1, int(params.subgrid))
        stats: Dict[str, object] = {"samples": C, "strata": [nx, ny], "pixels": int(len(idx)),
                                    "tracer": params.tracer, "coherence": coherent}
        box = casters_box(buffers.shadow_triangles[0], buffers.scale)
        if len(idx) == 0 or box is None:
            stats["rays_per_pixel"] = 0.0
            return MethodResult(self._passes(params, out_a, out_i, H, W), timer.result(), stats)
        with timer("order"):
            gid = g.seed_ids(idx)             # pixels of the view (a packed G-buffer's sub-pixels)
            order, tile_ptr = coherent_order(gid, buffers.width, params.tile)
            sel = idx[order]
            P = np.ascontiguousarray(g.position.reshape(-1, 3)[sel], np.float64)
            Nrm = np.ascontiguousarray(g.normal.reshape(-1, 3)[sel], np.float64)
            pix = np.ascontiguousarray(gid[order], np.int64)
            if params.reset_distance is not None:
                tol = np.full(len(sel), float(params.reset_distance))
            else:
                tol = float(params.reset_pixels) * camera_footprint(buffers)[sel]
            lp = sampling.pack_light(light)
            big = 4.0 * buffers.scale
        if params.tracer == "embree":
            tri = buffers.shadow_scene
            with timer("trace"):
                va, vi, rays, waves = embree_waves(tri, tile_ptr, P, Nrm, pix, tol, lp, nx, ny,
                                                   int(params.seed), float(buffers.scale), big,
                                                   coherent, S, bool(params.subgrid_shortcut))
            stats["waves"] = waves
        elif params.tracer == "depth":
            if maps is None:
                with timer("reference_maps"):
                    maps = buffers.precomputed("depth_raytrace.maps", light, params,
                                              lambda: self.build_maps(buffers, light, params))
            stats["reference_faces"] = maps.face_count
            stats["reference_eyes"] = int(len(maps.eyes))
            stats["map_texels"] = maps.map_texels
            hier = bool(params.hierarchical_connectedness) and not coherent
            va = np.ones(len(sel))
            vi = np.ones(len(sel))
            rays_t = np.zeros((len(tile_ptr) - 1, M_SIZE), np.int64)
            with timer("trace"):
                noff = normal_offsets(P, Nrm, lp, maps.faces, float(params.normal_offset))
                smp = Sampler(lp, int(params.seed), float(buffers.scale), nx, ny, S, coherent,
                              bool(params.subgrid_shortcut), big)
                refs = ReferenceImages(maps.faces, maps.offs, maps.dims, maps.mn, maps.mx, maps.conn, maps.zp)
                sw = TraceSwitches(hier, bool(params.minmax_clipping), bool(params.rank_images),
                                   bool(params.clear_miss), bool(params.occlusion_intervals))
                trace_tiles(tile_ptr, Points(P, Nrm, pix, tol), noff, smp, box[0], box[1], refs, sw, va, vi,
                            rays_t)
            rays = int(rays_t[:, M_RAYS].sum())
            n_pts = max(1, len(sel))
            stats["full_trace_points"] = int(rays_t[:, M_FULL].sum())
            stats["full_trace_rays_per_pixel"] = float(rays_t[:, M_FULLRAYS].sum() / n_pts)
            stats["predicted_rays_per_pixel"] = float(rays_t[:, M_SEEDED].sum() / n_pts)
            stats["flood_fill_rays_per_pixel"] = float(rays_t[:, M_FLOOD].sum() / n_pts)
            stats["prediction_errors_per_pixel"] = float(rays_t[:, M_ERR].sum() / n_pts)
            stats["blockers_per_pixel"] = float(rays_t[:, M_BLK].sum() / n_pts)
            stats["hierarchical_connectedness_used"] = hier
        else:
            raise ValueError(f"depth_raytrace: unknown tracer {params.tracer!r}")
        out_a[sel] = np.clip(va, 0.0, 1.0)
        out_i[sel] = np.clip(vi, 0.0, 1.0)
        t = timer.result()
        stats["rays"] = rays
        stats["rays_per_pixel"] = float(rays / len(sel))
        stats["precompute_s"] = float(t.get("reference_maps", 0.0))
        stats["trace_s"] = float(t.get("trace", 0.0))
        return MethodResult(passes=self._passes(params, out_a, out_i, H, W), time_s=t, stats=stats)

    @staticmethod
    def _passes(params: DepthRaytraceParams, out_a, out_i, H, W):
        """The method's pass in its ``visibility``, and the irradiance ratio."""
        own = out_a if params.visibility == AVERAGE else out_i
        return {"depth_raytrace": own.reshape(H, W), "depth_raytrace_irr": out_i.reshape(H, W)}

    @staticmethod
    def build_maps(buffers, light, params: DepthRaytraceParams) -> ReferenceMaps:
        W, H = buffers.width, buffers.height
        return build_reference_maps(buffers, light, resolve_map_size(params, W, H, light), params.ref_points,
                                    params.shadow_bias, params.bias_texels, params.slope_bias,
                                    params.gap_bias, params.gap_texels)
