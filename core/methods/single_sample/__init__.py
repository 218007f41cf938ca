"""Single sample soft shadows (Brabec & Seidel 2002), method id ``single_sample``.

The pass ``single_sample`` (plausible, not physical) from one depth and
object-id map seen from the light's centre (``LIGHT_VIEW``: cube faces for
point lights, orthographic for a sun) and the camera G-buffer.

Parameters (``SingleSampleParams``), name = default: meaning
  blocker = "sum"      the light every blocker texel hides, added up | "nearest"
  surfaces = "mesh"    one id per connected mesh piece | "object": object ids
  horizon = True       V x the light's share above the receiver's tangent plane
  auto_radius = True   r and r_max from the light's real shape and size
  adaptive = None      4.3's interpolation (None: on for "nearest" only); block = 4
  meet = 0.5           V where the inner and outer penumbrae meet (3.3)
  r_scale, r_bias, r_shrink = 2.0, 0.0, 0.25   3.2's knobs, texels (auto_radius off)
  max_radius = 64.0    search box half size cap, texels per 256 texels of map side
  jitter, seed = 0.0, 0  4.3's blocker texel jitter (texels) and its hash seed
  edge_distance = True r to the texel's square rather than to its centre
  layer = "constant"   3.2's layer P'_z | "plane": the receiver's tangent plane
  id_test = True       blockers carry another id than the receiver (3.2)
  bias_texels = 0.5    hard-test tolerance, texels of receiver slope + texel size
  map_size = None      the light map's larger side (``views.default_map_size``)
  visibility = "irradiance"  the pass: the irradiance ratio | "average" (eq. 2)

Algorithm. Each pixel is warped into the light view at float precision and
hard-tested (3.2, 4.3 "subpixel accuracy"; ``warp``). A lit pixel searches
for the nearest blocker texel (in front of the layer, another id), a
shadowed one for the nearest lit texel of its own id (3.3): the box around
P' in square rings until no nearer texel can exist (4.2; ``search``), 8 x 8
depth-range tiles passing over texels that cannot qualify (``tiles``). With
3.2's f = r / r_max: outer V = meet + (1 - meet) clamp(f), inner V = meet
(1 - clamp(f)); a failed search gives 1 / 0 (3.3). ``adaptive`` (4.3): groups
of block + 1 pixels along every block-th column, then every row, searched at
their ends, interpolated inside where hard results and ids agree, else split.
A light of size zero gives the hard test; outside the light view V = 1.

Departures from the paper
* 3.3's listing returns 0.5 f (inner) and 1 - 0.5 f (outer): 1 next to a
  blocker, a jump at r_max; above, 3.2's f folded at ``meet``; the inner
  rescale uses the blocker over P (3.2: "the distance between occluder and
  receiver").
* auto_radius (section 6's future work): a blocker texel at depth z_b hides
  light iff its offset lies in the light's shape (area rectangle / ellipse,
  the disk facing P, a sun's cone) scaled by s(z_b) = 1/z_b - 1/P'_z
  (P'_z - z_b for a sun); r is measured in that shape's norm with the true
  slope at a straight edge (1-norm on a rectangle's half axes, elliptic
  x 4/pi), r_max = s(z_b). The paper's: auto_radius=False.
* blocker="sum" back-projects every blocker texel of the box through the
  light's shape (``coverage``): 3.4's one ramp cannot add up several
  blockers. The paper's: blocker="nearest".
* surfaces="mesh" lets the leaves of one object shadow each other. The
  paper's: surfaces="object" (section 5 groups polygons by scene node).
* horizon: the id test leaves a surface turned partly away from the light
  fully lit; V x ``horizon.horizon_share``. The paper's: horizon=False.
* visibility="irradiance": the light below the receiver's plane weighs
  nothing (cos_r = 0): no horizon share; with the sum, a part of the light a
  blocker hides weighs the emission towards the receiver at its centre
  (``weight``: cos_l / d^2). cos_r is left out otherwise: the map misses
  blockers near the receiver's plane, to which cos_r would leave V. The
  paper's: visibility="average".
* edge_distance: r to the texel's square reaches ``meet`` at the hard edge
  (figure 4's centre distance leaves 5's "ring"). The paper's: False.
* adaptive=None searches every pixel for the sum, whose V is not linear
  between a group's ends. The paper's: adaptive=True.
* bias_texels: a slope-scaled hard-test tolerance in the map's texels (the
  listing compares depths directly). The paper's: bias_texels=0.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from ..base import IRRADIANCE, GBUFFER, LIGHT_VIEW, MESH_PIECES, Method, MethodResult, PhaseTimer
from ..horizon import scale_by_horizon
from ..registry import register
from .adaptive import _marks, adaptive_walk
from .packed import P_HARD, P_MAXRAD, pack_params
from .shade import hard_all, shade_all
from .tiles import tile_depth_range


@dataclass
class SingleSampleParams:
    r_scale: float = 2.0          # section 3.2: r_max texels per scene unit of |P'_z| (auto_radius off)
    r_bias: float = 0.0           # section 3.2: r_max's constant term, texels (its footnote 2)
    r_shrink: float = 0.25        # section 3.2: rescale per scene unit of blocker-receiver depth
    max_radius: float = 64.0      # search box half size cap, texels per 256 texels of the map's side
    meet: float = 0.5             # section 3.3: V where the inner and outer penumbrae meet
    auto_radius: bool = True      # radius from the light's real shape and size (False: the paper's knobs)
    adaptive: Optional[bool] = None  # section 4.3's interpolation; None: on unless blocker="sum"
    block: int = 4                # section 4.3: group step, groups of block + 1 pixels
    jitter: float = 0.0           # section 4.3: blocker texel jitter, texels (0: off)
    edge_distance: bool = True    # r to the texel's square (False: to its centre, figure 4)
    layer: str = "constant"       # "constant" (P'_z, section 3.2) | "plane" (receiver's tangent plane)
    id_test: bool = True          # section 3.2: blockers carry another id than the receiver
    bias_texels: float = 0.5      # hard-test tolerance, texels of receiver slope + texel size
    blocker: str = "sum"          # "sum" (the light every blocker texel hides; needs auto_radius,
                                  # else "nearest") | "nearest" (the paper's)
    surfaces: str = "mesh"        # one id per: "mesh" (connected mesh piece) | "object" (the paper's)
    horizon: bool = True          # V x the light's share above the tangent plane (False: the paper's)
    map_size: Optional[int] = None  # light map's larger side; None = views.default_map_size
    seed: int = 0                 # jitter hash seed

    visibility: str = "irradiance"   # the pass: "irradiance" (the ratio that composites, eq. 1) | "average" (eq. 2)

def resolved_adaptive(params: SingleSampleParams) -> bool:
    """``adaptive``, or when None: on for the paper's ramp, off for
    ``blocker="sum"`` (section 4.3's criterion, equal hard results and ids,
    is made for a ramp from the nearest texel; the summed V is not linear
    between a group's ends, and interpolating it blurs the penumbrae)."""
    if params.adaptive is not None:
        return bool(params.adaptive)
    return not (params.blocker == "sum" and params.auto_radius)


def face_info(lv, light) -> np.ndarray:
    """Per face: the area light's half axes in view coordinates (6), the
    nearest finite depth in the face (the nearest possible blocker; 7th), and
    the light's Z axis in view coordinates (8:11, ``weight``)."""
    F = len(lv.faces)
    out = np.zeros((F, 11), np.float64)
    ax, ay, az = light.axes
    hx, hy = light.half_size
    for k, face in enumerate(lv.faces):
        R = np.asarray(face.view_from_world, np.float64)[:3, :3]
        if light.kind == "area":
            out[k, 0:3] = R @ ax * hx
            out[k, 3:6] = R @ ay * hy
        out[k, 8:11] = R @ az
        d = lv.depth[k]
        fin = d[np.isfinite(d)]
        out[k, 6] = float(fin.min()) if fin.size else np.inf
    return out


def _coord_mag(bounds, light) -> float:
    """Largest coordinate magnitude of the scene (its ``bounds``) and the
    light (float32 ULPs)."""
    lo, hi = bounds
    m = float(max(np.abs(lo).max(), np.abs(hi).max()))
    return max(m if np.isfinite(m) else 0.0, float(np.abs(light.position).max()))


def single_sample_visibility(buffers, light, params: SingleSampleParams, hard_only: bool = False,
                             timer: PhaseTimer | None = None):
    """V float32[H,W] and stats. ``hard_only`` runs only the hard test."""
    timer = timer or PhaseTimer()
    g = buffers.gbuffer
    H, W = g.shape
    out = np.ones(H * W, np.float64)
    adaptive = resolved_adaptive(params) and g.pixel is None   # the walk needs an image: a packed
                                                               # G-buffer (sub-pixel receivers) is searched
    stats = {"searched": 0, "pixels": int(g.hit.sum()), "adaptive": adaptive,
             "searched_fraction": 0.0, "mean_search_radius_texels": 0.0, "clipped": 0,
             "texels_read": 0, "faces": 0, "map": [0, 0, 0], "hard_only": False}
    if params.surfaces not in ("object", "mesh"):
        raise ValueError(f"single_sample: surfaces must be 'object' or 'mesh', not {params.surfaces!r}")
    labels = buffers.mesh_pieces if params.surfaces == "mesh" else None
    if labels is None:
        lv = buffers.light_view(light, params.map_size)
    else:
        lv = buffers.light_view(light, params.map_size, key="centre:mesh", tri_label=labels)
    if not len(lv.faces) or not g.hit.any():     # nothing the light view can see: lit
        return out.reshape(H, W).astype(np.float32), stats
    with timer("setup"):
        P = np.ascontiguousarray(g.position.reshape(-1, 3), np.float64)
        Nrm = np.ascontiguousarray(g.normal.reshape(-1, 3))
        hit = np.ascontiguousarray(g.hit.reshape(-1))
        faces = lv.packed_faces()
        finfo = face_info(lv, light)
        if labels is None:
            pid = np.ascontiguousarray(g.object_id.reshape(-1), np.int32)
            casts = buffers.object_casts_shadow
        else:             # the receiver's mesh piece; a piece casts iff its object does
            pid = buffers.triangle_pieces(g.triangle_id.reshape(-1))
            casts = buffers.piece_casts_shadow
        nobj = max(len(casts), int(pid.max(initial=-1)) + 1, 1)
        in_map = np.zeros(nobj, np.bool_)
        in_map[:len(casts)] = casts
        prm = pack_params(params, light, hard_only, _coord_mag(buffers.bounds(), light))
        prm[P_MAXRAD] *= max(lv.depth.shape[1], lv.depth.shape[2]) / 256.0
        depth = np.ascontiguousarray(lv.depth, np.float32)
        ids = np.ascontiguousarray(lv.object_id, np.int32)
        rad = np.zeros(H * W, np.float64)
        vis = np.zeros(H * W, np.int64)
    n_hit = int(hit.sum())
    if prm[P_HARD] == 1.0 or not adaptive:
        with timer("hard" if prm[P_HARD] == 1.0 else "search"):
            tiles = tile_depth_range(depth, ids) if prm[P_HARD] == 0.0 else np.zeros((1, 1, 1, 3))
            sel = np.flatnonzero(hit).astype(np.int64)
            shade_all(P, Nrm, pid, sel, faces, finfo, depth, ids, tiles, in_map, prm, out, rad, vis)
        stats["searched"] = 0 if prm[P_HARD] == 1.0 else int(len(sel))
    else:
        with timer("hard"):
            hface = np.empty(H * W, np.int32)
            hinner = np.empty(H * W, np.int8)
            hid = np.empty(H * W, np.int32)
            hard_all(P, Nrm, hit, faces, depth, ids, prm, hface, hinner, hid, pid)
            b = max(1, int(params.block))
            colmarks = _marks(W, b)
            rowmarks = _marks(H, b)
            need = np.zeros(H * W, np.bool_)
            adaptive_walk(hface, hinner, hid, need, out, H, W, colmarks, rowmarks, False)
        with timer("search"):
            tiles = tile_depth_range(depth, ids)
            sel = np.flatnonzero(need & hit).astype(np.int64)
            shade_all(P, Nrm, pid, sel, faces, finfo, depth, ids, tiles, in_map, prm, out, rad, vis)
        with timer("interpolate"):
            adaptive_walk(hface, hinner, hid, need, out, H, W, colmarks, rowmarks, True)
        stats["searched"] = int(len(sel))
    if params.horizon and prm[P_HARD] == 0.0 and params.visibility != IRRADIANCE:   # (module doc)
        with timer("horizon"):
            scale_by_horizon(light, P, Nrm, hit, out)
    out[~np.isfinite(out)] = 1.0
    np.clip(out, 0.0, 1.0, out=out)
    rad_sel = rad[sel]                # rad and vis are 0 but where searched (sel: hit pixels, in order)
    searched_rad = np.minimum(rad_sel[rad_sel > 0], prm[P_MAXRAD])
    stats.update({
        "searched_fraction": float(stats["searched"] / n_hit) if n_hit else 0.0,
        "mean_search_radius_texels": float(searched_rad.mean()) if searched_rad.size else 0.0,
        "clipped": int((rad_sel > prm[P_MAXRAD]).sum()),
        "texels_read": int(vis[sel].sum()),
        "faces": len(lv.faces),
        "map": [int(s) for s in lv.depth.shape],
        "hard_only": bool(prm[P_HARD] == 1.0),
    })
    return out.reshape(H, W).astype(np.float32), stats


@register
class SingleSampleSoftShadows(Method):
    id = "single_sample"
    paper = "Brabec, Seidel 2002"
    passes = {"single_sample": IRRADIANCE}
    needs = frozenset({GBUFFER, LIGHT_VIEW, MESH_PIECES})
    packed = True                # shades each receiver of a packed G-buffer on its own
    #: the Preview: the paper's nearest blocker on object ids, section 4.3's adaptive
    #: groups every 8th pixel
    preview_params = {"blocker": "nearest", "surfaces": "object", "block": 8}
    Params = SingleSampleParams

    def run(self, buffers, light, params: SingleSampleParams) -> MethodResult:
        timer = PhaseTimer()
        v, stats = single_sample_visibility(buffers, light, params, timer=timer)
        return MethodResult(passes={"single_sample": v}, time_s=timer.result(), stats=stats)
