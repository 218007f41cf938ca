"""Single sample soft shadows (Brabec & Seidel 2002), method id ``single_sample``.

One depth map and one object-ID map from the light centre (``LIGHT_VIEW``)
and the camera G-buffer with object ids (``GBUFFER``). Every camera pixel is
warped into the light view at float precision (P'_x, P'_y, P'_z; P'_z is the
depth along the face's axis), then (section 3.3):

* hard test (section 3.2): the texel under P' is nearer than the receiver ->
  *inner* (umbra side), else *outer* (lit side);
* outer: search the nearest *blocker* texel (nearer than the receiver's layer
  and a different object id); inner: the nearest *lit* texel (at or behind
  the layer and the receiver's own id); radius r_max = r_scale |P'_z| + r_bias
  rescaled by r_shrink and the blocker-receiver depth difference;
* the two halves meet at ``meet`` = 0.5:
  outer V = meet + (1 - meet) clamp(r / r_max),  inner V = meet (1 - clamp(r / r_max));
  a failed search gives 1 (outer) or 0 (inner), as in the listing.

Search as section 4.2 / 4.3 does it: an axis-aligned box scanned in square
rings around P' (so it stops as soon as no nearer texel can exist), the
distance measured from the float P' (figure 4), texels optionally jittered
(``jitter``, section 4.3, for very low-resolution maps). Before scanning, the
least / largest depth and the single object id of the 8x8 tiles under the
box (not in the paper; ``tile_skip``) rule out boxes that cannot hold a
candidate, and tighten the outer box to s(least depth under it).

Adaptive sampling (section 4.3, ``adaptive``): the hard test and its id (the
blocker's where inner, the receiver's where lit) on every pixel; in every
``block``-th column, groups of ``block`` + 1 pixels with both ends searched;
where hard results and ids (and, conservatively, the light-view face) agree
over the group the inner pixels are interpolated linearly, else the middle
is searched and both halves are treated the same way; then every row fills
the gaps between those columns. The subdivision depends only on the hard
test, so it is walked twice: once to mark the pixels to search (all
searched in one parallel pass), once to interpolate. ``stats["searched"]``
counts the searched pixels, ``stats["texels_read"]`` the texels scanned.

Departures from the printed listing (each keeps the paper's stated intent):

* the listing's return values ``0.5 clamp(r/r_max)`` (inner) and
  ``1 - 0.5 clamp(r/r_max)`` (outer) run the wrong way: they are 1 next to a
  blocker and jump to the failure values 0 / 1 at r_max, against section
  3.2's f = r / r_max "rises from 0 (no illumination) to 1". The formulas
  above are section 3.2's f folded at ``meet``: continuous at r_max and at
  the hard edge;
* the inner rescale uses the depth of the blocker over P (the hard test's
  texel): the listing's ``depth_light[s,t] - P'_z`` is the *lit* texel's own
  depth, about P'_z on any receiver facing the light, which would make r_max
  0 and every umbra 0.5; section 3.2 describes the rescale as "the distance
  between occluder and receiver";
* searches use the paper's constant virtual layer P'_z (``layer="constant"``,
  default); ``layer="plane"`` tests texels against the receiver's tangent
  plane extended over the search box instead, so on a receiver tilted to
  the light the nearer side's own texels still count as lit in the inner
  search. Measured on the sample scenes it changes RMSE by under 2% (slightly
  worse), so the paper's layer stays the default;
* the hard test compares the map with the receiver's tangent plane at the
  texel centre, less a slope-scaled tolerance of ``bias_texels`` texels of the
  receiver's depth slope and world texel size plus float32 precision: the
  offset scheme is in units of the map's own sampling, not per scene;
* with ``edge_distance`` (default) r is the distance from P' to the texel's
  square rather than to its centre, so inner and outer both reach ``meet`` at
  the texel boundary of the hard test (the paper's "ring" artifact, section 5,
  is the half-texel jump the centre distance leaves there).

Beyond the paper (its section 6 future work): ``auto_radius`` (default) takes
the radius from the light's real size. A blocker at depth z_b and texel
offset d from P' blocks part of the light iff d lies in the light's shape
scaled by s(z_b) = 1/z_b - 1/P'_z (perspective faces; s = P'_z - z_b for a
sun's orthographic face): similar triangles, to first order in the light's
size, with the shape projected into the face along the ray from P. So r is
measured in a norm of the light's own shape and r_max = s(blocker depth).
``ramp`` picks the norm:

* ``"slope"`` (default): the ramp has the true slope of V at the hard edge
  of a straight occluder edge (full width = light area / the light's chord
  through its centre along the edge): the 1-norm on the half axes for
  squares and rectangles (exact for edges along an axis), the Euclidean /
  elliptic norm scaled by 4/pi for disks, ellipses, spheres and suns;
* ``"extent"``: the ramp spans the whole penumbra (Parker's outer hull: the
  max-norm for rectangles, the plain Euclidean / elliptic norm otherwise).
  Its tails are too long: measured RMSE against ``embree`` is 10-30% higher.

The search box is the unit ball scaled by s(nearest depth under the box) for
outer searches, by s(blocker over P) for inner ones, capped at
``max_radius`` texels; a penumbra wider than the cap is narrowed to it (V
still reaches 0 / 1 at the box edge; ``stats["clipped"]`` counts those
pixels). In this mode r_scale, r_bias and r_shrink are unused: the paper's
linear r_scale |P'_z| + r_bias with a constant r_shrink cannot express
1/z_b - 1/P'_z. ``auto_radius=False`` is the paper's formula with its raw
knobs, in texels (the same narrowing applies when r_shrink asks for a
radius beyond the search box).

Lights (the paper assumes a point light with a size knob):

* area lights: the light's rectangle / ellipse (its real half sizes and axes,
  projected into the face along the ray from P);
* point / spot lights of radius r: the disk of radius r facing P (DESIGN.md's
  light domain). Point lights use cube faces: P is searched in the face that
  holds it (``kernels.pick_face``), texels beyond that face's border count as
  neither blocker nor lit;
* sun: the orthographic view along the sun; the cone of half-angle angle/2
  around the sun direction has a disk cross-section of radius
  tan(angle/2) (P'_z - z_b) at the blocker's depth.

Several blockers (issue 17; section 3.4's single ramp from the nearest
texel cannot add them up): ``blocker="sum"`` replaces the inner / outer
searches by the light each blocker texel in the box hides, back-projected
through the light's real shape and added up (``_coverage``; clamped to 1,
renormalised where the box is clipped; with ``auto_radius`` off, the
paper's knobs, the nearest blocker). Exact for disjoint planar blockers
(two half-planes each hiding half of the light: V = 0 where the paper's
ramp says 0.5 or more); it still sees only what the light's centre sees.
``surfaces="mesh"`` gives every connected mesh piece its own id
(``surfaces.mesh_pieces``; "object": object ids, the paper's grouping), so a
shrub's leaves, one object, shadow each other. Measured on foliage (256 x
256): RMSE 0.075 (paper) -> 0.044 (sum + mesh).

The receiver's own surface (issue 17; ``horizon``, default on): the id
test keeps a receiver from shadowing itself, so a surface turned partly
away from the light (a leaf at a steep angle, a curved object's
terminator) got the light below its tangent plane as lit. V is multiplied
by the share of the light above that plane (``horizon.horizon_share``,
closed forms; computed only where V > 0), as if the blockers hid the light
above and below it alike. On issue 17's foliage (256 x 256, against 1024-sample
embree) 2 % of the pixels the light reaches do not see the whole light and
held 79 % of the squared error: RMSE over every pixel the light reaches
0.080 -> 0.046; over the pixels that see the whole light (issue 17's
measure) 0.037, unchanged. ``horizon=False`` is the paper's.

A light of size zero gives exactly the hard test (no search, no horizon). Pixels outside
every face of the view, behind a perspective eye, or with no G-buffer hit
get V = 1. The pass is average-visibility-like (AVERAGE) but not physical:
the attenuation is a linear ramp from the nearest texel, the umbra of an
occluder is never lit through, and an object never soft-shadows itself
(id test; its hard self-shadows stay).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from ..base import AVERAGE, GBUFFER, LIGHT_VIEW, Method, MethodResult, PhaseTimer
from ..horizon import scale_by_horizon
from ..registry import register
from ..surfaces import mesh_pieces
from .adaptive import _marks, adaptive_walk
from .packed import P_HARD, P_MAXRAD, pack_params
from .shade import hard_all, shade_all
from .tiles import tile_depth_range


@dataclass
class SingleSampleParams:
    # raw knobs of section 3.2 (used when auto_radius is False); the paper
    # gives no values except the 20-texel r_max of its torus scene (section 5)
    r_scale: float = 2.0          # texels per scene unit of |P'_z|
    r_bias: float = 0.0           # texels (footnote 2: a minimum penumbra width)
    r_shrink: float = 0.25        # per scene unit of blocker-receiver depth
    max_radius: float = 64.0      # search box half size cap, texels of a 256-texel map, scaled
                                  # with the map's side (section 5 used r_max = 20 at 256x256)
    meet: float = 0.5             # section 3.3: inner and outer penumbra meet at 0.5
    auto_radius: bool = True      # radius from the light's real size (section 6 future work)
    adaptive: Optional[bool] = None  # section 4.3 interpolation over 4x4 blocks; None: on for the
                                  # ramps ("nearest", "ratio"), off for "sum" (not linear there)
    block: int = 4                # section 4.3: groups of 5 pixels, every 4th column
    jitter: float = 0.0           # section 4.3: blocker texel jitter (texels; 0 = off)
    edge_distance: bool = True    # distance to the texel's square (else its centre, figure 4)
    layer: str = "constant"       # "constant" (P'_z, section 3.2) | "plane" (receiver's tangent plane)
    id_test: bool = True          # section 3.2: blockers must have another object id
    bias_texels: float = 0.5      # hard-test tolerance, texels of receiver slope + texel size
    blocker: str = "sum"          # "sum" (adds up the light every blocker texel hides; needs
                                  # auto_radius, else "nearest") | "nearest" (paper)
    surfaces: str = "mesh"        # what one id is: "mesh" (connected mesh pieces) | "object" (paper)
    horizon: bool = True          # V x the share of the light above the receiver's tangent plane (issue 17;
                                  # False: the paper, an object never shadows itself softly)
    map_size: Optional[int] = None  # light map's larger side; None = views.default_map_size
    seed: int = 0                 # jitter hash seed


def resolved_adaptive(params: SingleSampleParams) -> bool:
    """``adaptive``, or when None: on for the paper's ramps, off for
    ``blocker="sum"`` (section 4.3's criterion, equal hard results and ids,
    is made for a ramp from the nearest texel; the summed V is not linear
    between the group's ends: torus_plane's ground RMSE 0.015 -> 0.048)."""
    if params.adaptive is not None:
        return bool(params.adaptive)
    return not (params.blocker == "sum" and params.auto_radius)


def face_info(lv, light) -> np.ndarray:
    """Per face: the area light's half axes in view coordinates (6) and the
    nearest finite depth in the face (the nearest possible blocker)."""
    F = len(lv.faces)
    out = np.zeros((F, 8), np.float64)
    ax, ay, _ = light.axes
    hx, hy = light.half_size
    for k, face in enumerate(lv.faces):
        R = np.asarray(face.view_from_world, np.float64)[:3, :3]
        if light.kind == "area":
            out[k, 0:3] = R @ ax * hx
            out[k, 3:6] = R @ ay * hy
        d = lv.depth[k]
        fin = d[np.isfinite(d)]
        out[k, 6] = float(fin.min()) if fin.size else np.inf
    return out


def _coord_mag(scene, light) -> float:
    """Largest coordinate magnitude of the scene and the light (float32 ULPs)."""
    t = scene.triangles
    m = float(np.abs(t).max()) if t.size else 0.0
    m = m if np.isfinite(m) else float(np.abs(t[np.isfinite(t)]).max(initial=0.0))
    return max(m, float(np.abs(light.position).max()))


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
    labels = mesh_pieces(buffers.scene) if params.surfaces == "mesh" else None
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
            casts = np.array([o.casts_shadow for o in buffers.scene.objects], bool)
        else:             # the receiver's mesh piece; a piece casts iff its object does
            tri = g.triangle_id.reshape(-1)
            pid = np.ascontiguousarray(np.where(tri >= 0, labels[np.maximum(tri, 0)], -1), np.int32)
            casts = np.zeros(len(labels), bool)
            casts[labels] = buffers.scene.tri_casts_shadow
        nobj = max(len(casts), int(pid.max(initial=-1)) + 1, 1)
        in_map = np.zeros(nobj, np.bool_)
        in_map[:len(casts)] = casts
        prm = pack_params(params, light, hard_only, _coord_mag(buffers.scene, light))
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
    if params.horizon and prm[P_HARD] == 0.0:
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
    passes = {"single_sample": AVERAGE}
    needs = frozenset({GBUFFER, LIGHT_VIEW})
    Params = SingleSampleParams

    def run(self, buffers, light, params: SingleSampleParams) -> MethodResult:
        timer = PhaseTimer()
        v, stats = single_sample_visibility(buffers, light, params, timer=timer)
        return MethodResult(passes={"single_sample": v}, time_s=timer.result(), stats=stats)
