"""Percentage-closer filtering (Reeves, Salesin, Cook 1987), method id ``pcf``:
visibility from one depth map seen from the light's centre (``LIGHT_VIEW``;
cube faces for a point light). Sizes in map texels, depths -z in the light's view.

Parameters (``PCFParams``):
  NumSamples       16       samples per region (figure 4; 4.2: "normally 16")
  ResFactor        3.0      enlargement of the pixel's region (4.2: 2 to 4)
  MinSamples       2        fewest samples per axis of a region (4.2: 2 or 3)
  MinSize          2.0      smallest half size of a region (4.2)
  MaxSize          64.0     largest half size of a region (grazing views)
  Bias0, Bias1     None     bias range, scene units (None: 0.003, 0.004 x the light's extent)
  map_size         None     the map's larger side; None: views.default_map_size
  region           "light"  the region's size: the light's ("light") | "figure4"
  BlockerSamples, PenumbraSamples  16, 64  region="light": samples of the search, the filter
  receiver_plane, tiles  True, True  the receiver's tangent plane per texel; the tile test
  pixel_step       0        anchors' spacing (1: every pixel; 0: 2, or 4 from 1280 px)
  step_fill  "interpolate"  pixels between anchors: "interpolate" | "copy" (Preview)
  step_tolerance   0.2      largest span of the anchors' V that is blended
  seed             0        the random streams' seed
  visibility  "irradiance"  the pass: the irradiance ratio | "average" (eq. 2)

Algorithm (3.2, figure 4). Each camera pixel's shading region is mapped into
the map (its corners carried onto the receiver's tangent plane: ``footprint``);
its box, ResFactor times as large and at least MinSize, is split into ns x nt
cells (about NumSamples, at least MinSamples per axis), each sampled once with
jitter (2's method (c)). A sample is in shadow when the receiver is deeper
than the map plus a bias drawn in [Bias0, Bias1]: V = 1 - (samples in shadow)
/ (ns nt) (``samples``). Outside the map's box of finite depths: lit (3.3). A
light of size zero shrinks the region to a texel: Williams' hard test.

Departures from the paper:
  * region="light" (percentage-closer soft shadows, Fernando 2005): the paper's
    edges "are not true penumbrae" (2). BlockerSamples samples over the light's
    reach from the receiver (at the nearest depth the tiles hold there) give
    the mean blocker depth z_b (none: lit); the filter region is the light's
    extent at z_b, L (z_r - z_b) / (z_r z_b) for a light of half extent L in a
    perspective face's view plane, tan(half angle) (z_r - z_b) for a sun
    (``light_region``), at least figure 4's, with PenumbraSamples samples.
    The paper's region: region="figure4".
  * receiver_plane: a sample compares the map with the receiver's tangent
    plane along its texel's light ray, not with z, so a flat receiver never
    shadows itself (4.2's Moire); the bias is left for curvature. The paper's:
    receiver_plane=False.
  * tiles: 3.3 proposes a maximum z per tile; the min, max and a fitted plane
    per 8 x 8 block decide regions lit or shadowed exactly (``tiles``: the same
    V). The paper's figure 4 samples every region: tiles=False.
  * pixel_step: V is filtered at anchor pixels, then lattice by lattice a pixel
    between anchors on its surface takes their bilinear blend where they span
    at most step_tolerance without mixing a decided 0 or 1 with another; other
    pixels are filtered (``anchors``). The paper's: pixel_step=1.
  * visibility="irradiance" (region="light"): a filter sample weighs the
    light's emission towards the receiver at the light point it stands for
    (``weight``: cos_l / d^2, nothing past the light's shape); V = the lit
    samples' weight over all of theirs. cos_r is left out: the map misses
    blockers in directions grazing the receiver's plane, and cos_r (0 below
    it) would leave V to them where the plane cuts the light. Figure 4's
    region stays the average. The paper's: visibility="average".
  * Figure 4's listing, fixed without a switch: ns is computed before it is
    clamped; a sample is jittered over its whole cell (the listing's ``Rand()
    * js`` spans half a cell on one side); one 32-bit random word per sample
    gives both jitters and the bias. The map's window is fitted to the visible
    receivers (samples past it read the border texel); a region crossing a
    cube face's edge samples only the face holding the pixel.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from ... import views
from ...kernels import finite_bbox
from ..registry import register
from ..base import IRRADIANCE, GBUFFER, LIGHT_VIEW, Method, MethodResult, PhaseTimer
from .anchors import auto_pixel_step
from .footprint import pixel_ray_terms
from .light_region import light_reach
from .pixels import PIXEL_TILE, CameraPixels, Filter, ShadowMap, filter_pixels
from .tiles import TILE, tile_minmax, tile_planes, tile_tables
from .weight import light_frames

# 4.2: "In worlds measuring 100 by 100 by 100 units, typical bias values we
# use are (0.3, 0.4)": fractions of the light's extent (FrameBuffers.light_extent)
BIAS0_PER_EXTENT = 0.003
BIAS1_PER_EXTENT = 0.004


@dataclass
class PCFParams:
    NumSamples: int = 16            # samples per region (figure 4)
    ResFactor: float = 3.0          # enlargement of the pixel's region
    MinSamples: int = 2             # fewest samples per axis of a region
    MinSize: float = 2.0            # smallest half size of a region (texels)
    Bias0: Optional[float] = None   # scene units; None: BIAS0_PER_EXTENT x the light's extent
    Bias1: Optional[float] = None   # scene units; None: BIAS1_PER_EXTENT x the light's extent
    map_size: Optional[int] = None  # the depth map's larger side; None: views.default_map_size
    MaxSize: float = 64.0           # largest half size of a region (texels), for grazing views
    receiver_plane: bool = True     # compare with the receiver's tangent plane per texel (False: its z)
    tiles: bool = True              # the tile test decides regions without samples (the same V)
    region: str = "light"           # "light": the light's extent at the blocker depth | "figure4"
    BlockerSamples: int = 16        # region="light": samples of the blocker search
    PenumbraSamples: int = 64       # region="light": samples of the filter region (NumSamples' role)
    pixel_step: int = 0             # anchors' spacing, a power of 2 dividing PIXEL_TILE; 1: every
                                    # pixel; 0: auto_pixel_step
    step_fill: str = "interpolate"  # pixels between anchors: "interpolate" (their blend, where they
                                    # agree) | "copy" (the V of the block's first pixel)
    step_tolerance: float = 0.2     # "interpolate": the largest span of the anchors' V that is blended
    seed: int = 0

    visibility: str = "irradiance"   # the pass: "irradiance" (the ratio that composites, eq. 1) | "average" (eq. 2)

def resolved_bias(params: PCFParams, extent: float):
    """(Bias0, Bias1) in scene units for a light of extent ``extent``
    (Bias1 at least Bias0)."""
    b0 = params.Bias0 if params.Bias0 is not None else BIAS0_PER_EXTENT * extent
    b1 = params.Bias1 if params.Bias1 is not None else BIAS1_PER_EXTENT * extent
    return float(b0), float(max(b1, b0))


@register
class PercentageCloserFiltering(Method):
    id = "pcf"
    paper = "Reeves, Salesin, Cook 1987"
    passes = {"pcf": IRRADIANCE}
    needs = frozenset({GBUFFER, LIGHT_VIEW})
    packed = True                # shades each receiver of a packed G-buffer on its own
    runs_on_instances = True     # a G-buffer and one light view
    #: the Preview: a quarter of the light-sized region's samples, V at one pixel in each 2 x 2
    #: block shared by the block's pixels on its surface, no pixel footprint in the region
    preview_params = {"BlockerSamples": 8, "PenumbraSamples": 16, "pixel_step": 2, "step_fill": "copy",
                      "ResFactor": 0.0}
    Params = PCFParams

    def subpixel_overrides(self, params, share: int):
        """Each sub-pixel receiver its share of the region's samples (at least
        a 2 x 2 grid of them)."""
        def shared(n):
            return max(4, -(-int(n) // max(1, int(share))))
        return {"NumSamples": shared(params.NumSamples), "BlockerSamples": shared(params.BlockerSamples),
                "PenumbraSamples": shared(params.PenumbraSamples)}

    def run(self, buffers, light, params: PCFParams) -> MethodResult:
        timer = PhaseTimer()
        g = buffers.gbuffer
        W, H = buffers.width, buffers.height          # the camera's view (g may be packed)
        n = g.hit.size
        lv = buffers.light_view(light, params.map_size)
        with timer("filter"):
            out = np.ones(n, np.float32)
            if len(lv.faces) and g.hit.any():
                b0, b1 = resolved_bias(params, buffers.light_extent(light))
                res, minsize, minsamp = float(params.ResFactor), float(params.MinSize), int(params.MinSamples)
                if light.is_zero_size:   # hard shadows only (DESIGN.md)
                    res, minsize, minsamp = 0.0, 0.0, 1
                tlo, thi = tile_minmax(lv.depth)
                tt = tile_tables(tlo, thi, int(2.0 * params.MaxSize + 2.0) // TILE + 2)
                if params.region not in ("light", "figure4"):
                    raise ValueError(f"pcf: unknown region {params.region!r} (light | figure4)")
                step = int(params.pixel_step) or auto_pixel_step(W, H)
                if step < 1 or PIXEL_TILE % step:
                    raise ValueError(f"pcf: pixel_step {params.pixel_step!r} must be a power of 2 dividing "
                                     f"{PIXEL_TILE}")
                if params.step_fill not in ("interpolate", "copy"):
                    raise ValueError(f"pcf: unknown step_fill {params.step_fill!r} (interpolate | copy)")
                lsize = light_reach(light, lv.faces)
                if light.is_zero_size:
                    lsize[:] = 0.0
                zmin = np.array([float(np.min(lo, initial=np.inf)) for lo in tlo], np.float64)
                pixel = np.zeros(0, np.int64) if g.pixel is None else np.ascontiguousarray(g.pixel, np.int64)
                rays = pixel_ray_terms(views.pack_camera(buffers.camera, W, H))
                cam = CameraPixels(g.position.reshape(-1, 3), g.normal.reshape(-1, 3), g.hit.reshape(-1),
                                   g.object_id.reshape(-1), W, rays, pixel)
                faces = lv.packed_faces()
                planes = tile_planes(lv.depth, faces[:, 16] == 1.0)
                smap = ShadowMap(faces, lv.depth, finite_bbox(lv.depth), tt, planes, lsize, zmin,
                                 light_frames(light, lv.faces))
                flt = Filter(res, minsize, float(params.MaxSize), int(params.NumSamples), minsamp,
                             b0, b1, int(params.seed), bool(params.receiver_plane), bool(params.tiles),
                             params.region == "light", max(1, int(params.BlockerSamples)),
                             max(1, int(params.PenumbraSamples)), step, params.step_fill == "interpolate",
                             float(params.step_tolerance), params.visibility == IRRADIANCE)
                filter_pixels(cam, smap, flt, out, H)
        return MethodResult(passes={"pcf": out.reshape(g.shape)}, time_s=timer.result(),
                            stats={"map": [lv.depth.shape[0], lv.depth.shape[1], lv.depth.shape[2]]})
