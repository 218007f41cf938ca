"""Hierarchical penumbra casting (Laine & Aila 2005), method id ``penumbra_casting``.

V of every camera G-buffer hit from S light samples (``visibility`` below)
as the transpose of ray tracing: each blocker T finds the relations l_i -> r_j
it blocks by traversing the receiver hierarchy and the three-level light
sample hierarchy (L, groups G_k, samples l_i) at once (section 3).

Parameters, default [the paper's value where it gives one]:
  samples 256 [256], GroupSize 32 [32]   light samples; samples per group G_k
  LeafSize 16 [16], MidpointLimit 1024 [1K]   receiver hierarchy: points per
                      leaf; midpoint splits above, SAH splits below
  SampleSets 8 [8]    light sample sets, one per receiver by a pixel hash
  umbra_bits, active_plane_sets, lazy_volumes, masks_on_demand  True [True]:
                      optimizations A-D (all off: the basic algorithm)
  coarse_sort True [True], SortBuckets 32   blockers bucketed by area
  RebuildFraction 0.25   umbra share of its points that rebuilds the hierarchy
  coplanar_blockers, interior_blockers, hidden_behind_cores, backface_cull,
  group_backface_cull  True [False]   the departures below
  CoreSlices 16, CoreCorners 128   interior slices per solid, corners per slice
  materialize_hard_volumes False [True]   line 70 on built V_li planes
  alpha_fetch True [True]   matte blockers by texture fetch (False: Embree rays)
  shared_samples_with_reference False   the reference's own per-pixel samples
  chunks 0 (automatic), seed 0; visibility irradiance [average] (below)

Algorithm (sections 3.1-3.3, figures 2 and 3): receivers r_j, each with a bit
mask of blocked samples, in a BVH (``receivers``, ``hierarchy``); jittered
samples in groups G_k under convex bounding polygons Delta_Gk and Delta_L
that bound the groups in every sample set (``light``, section 3.4). Per
blocker T (``cast``): the penumbra volume V_L (separating planes of Delta_L
and T, capped by T's plane), V_Gk per group, the hard volumes V_li; boxes
are tested against V_L and V_Gk, points against V_li (line 70). A: group /
full umbra bits on points and nodes, the hierarchy rebuilt without full-umbra
points (line 29); B: active plane sets; C: V_Gk and V_li built on first need;
D: masks allocated on first need, freed in full umbra. Blockers that cannot
shadow a receiver are culled first (``culling``). Section 3.4: sphere lights
use bounding volumes; alpha-matte blockers follow the opaque ones
(``alpha_blockers``); the receivers are cast in parallel chunks (``chunks``);
V from the masks and transmittances (``visibility``).

Departures from the paper (switch [the paper's value]):
* visibility [average]: the paper's V = 1 - blocked / S (Agrawala et al.
  eq. 2, ``embree``'s); by default each sample counts with the reference's
  weight w_i = cos_r cos_l / d^2, V = sum w_i v_i / sum w_i (eq. 1 with and
  without V, ``embree_irr``'s): unshadowed render x V = shadowed render.
* materialize_hard_volumes [True]: line 70 with sample and receiver exchanged
  (``geometry.receiver_edge_functions``): per receiver and blocker its edge
  forms, per sample one dot product each, a 64-bit mask word at a time.
* coplanar_blockers [False: triangles]: coplanar edge-adjacent triangles that
  form a convex polygon of up to ``MAXB`` corners are one blocker (section 5;
  ``blockers``): one traversal, no false penumbra along the inner edges.
* interior_blockers [False]: convex slices inside closed meshes, cast first
  (``cores``): they block only what the mesh blocks, and put most umbra
  receivers in full umbra before the mesh's small triangles are cast.
* hidden_behind_cores [False]: a (blocker, receiver) pair, or a small box of
  receivers, is skipped when every ray through the blocker crosses a disk in
  a slice of its solid.
* backface_cull, group_backface_cull [False]: a closed solid's triangles that
  face away from all of Delta_L (or of Delta_Gk) are dropped (for that G_k):
  a segment from a sample outside the solid enters it through a face facing
  the sample (no inside-out parts assumed, not checked).
Each keeps the blocked relations up to rays within rounding of an edge or
surface. Without a switch: SAH areas weighted by point counts; the texture
fetch per receiver after the traversal; sun (directions, w = 0) and sphere
lights (a disk set rotated per receiver) beyond the paper's planar lights.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Dict, Optional

import numba
import numpy as np

from ...kernels import each_in_threads
from ..base import DEFAULT_LIGHT_SAMPLES, IRRADIANCE, GBUFFER, SHADOW_TRIANGLES, Method, MethodResult, PhaseTimer
from ..registry import register
from .alpha_blockers import matte_blockers, split_blockers
from .cast import CastSwitches, LightGroups, cast_chunk_for
from .chunks import CastJob, build_chunk, chunk_stats, make_chunks, run_chunk
from .culling import cast_blockers, receiver_box
from .light import MODE_SPHERE
from .receivers import Setup, prepare


@dataclass
class PenumbraCastingParams:
    samples: int = DEFAULT_LIGHT_SAMPLES   # light samples per receiver
    GroupSize: int = 32               # light samples per group G_k
    LeafSize: int = 16                # receiver points per leaf
    MidpointLimit: int = 1024         # midpoint splits above, SAH below
    SampleSets: int = 8               # distinct light sample sets (section 3.4)
    umbra_bits: bool = True           # optimization A
    active_plane_sets: bool = True    # optimization B
    lazy_volumes: bool = True         # optimization C
    masks_on_demand: bool = True      # optimization D
    coarse_sort: bool = True          # coarse blocker sorting by area, largest first
    coplanar_blockers: bool = True    # coplanar convex triangle groups cast as one polygon
    interior_blockers: bool = True    # convex slices inside closed meshes, cast first
    backface_cull: bool = True        # closed meshes: drop triangles facing away from the whole light
    hidden_behind_cores: bool = True  # skip (blocker, receiver) pairs whose rays all pass an interior blocker
    group_backface_cull: bool = True  # closed meshes: a blocker skips the groups G_k it faces away from
    CoreSlices: int = 16              # at most this many interior slices per closed solid
    CoreCorners: int = 128            # corners of each slice's convex polygon
    SortBuckets: int = 32             # area buckets of the coarse sort
    RebuildFraction: float = 0.25     # A, line 29: umbra share of the points that rebuilds the hierarchy
    shared_samples_with_reference: bool = False   # the embree reference's own per-pixel samples
    materialize_hard_volumes: bool = False  # line 70 on the 4 planes of every V_li (the paper's)
    alpha_fetch: bool = True          # matte blockers by a texture fetch (False: Embree rays)
    chunks: int = 0                   # receiver chunks processed in parallel; 0 = automatic
    seed: int = 0

    visibility: str = "irradiance"   # the pass: "irradiance" (the ratio that composites, eq. 1) | "average" (eq. 2)

def cast(setup: Setup, tris: np.ndarray, params: PenumbraCastingParams, timer: PhaseTimer,
         threads: Optional[int] = None, mattes=None):
    """Run the casting for ``tris`` (float64[T,3,3], the shadow-casting
    triangles); returns V per receiver (float64) and stats. ``mattes``: a
    BVH of the alpha-matte blockers, processed after ``tris``
    (``alpha_blockers``)."""
    L = setup.light
    n = len(setup.idx)
    stats: Dict[str, object] = {"receivers": int(n), "samples": int(L.S), "groups": int(L.G),
                                "sample_sets": int(L.nsets), "triangles_in": int(len(tris))}
    V = np.ones(n)
    if n == 0:
        return V, stats
    leaf = max(1, int(params.LeafSize))
    blk = cast_blockers(setup, tris, params, timer, stats)
    workers = max(1, int(threads or numba.get_num_threads()))
    n_ch = int(params.chunks) if params.chunks else min(4 * workers, max(1, n // 4096))
    with timer("build"):                 # the chunks are the hierarchy's top median splits
        chunks = make_chunks(setup, max(1, n_ch))
    stats["chunks"] = len(chunks)
    mb = None
    if mattes is not None and params.alpha_fetch:
        with timer("cull"):
            mb = matte_blockers(mattes, L, setup.eps, receiver_box(setup.pts), setup.tol)
        stats["matte_blockers"] = int(len(mb.tri))
    switches = CastSwitches(bool(params.umbra_bits), bool(params.active_plane_sets), bool(params.lazy_volumes),
                            bool(params.masks_on_demand), float(params.RebuildFraction), leaf, setup.tol, setup.eps,
                            bool(params.materialize_hard_volumes), bool(blk.solid.size and blk.solid.max() >= 0))
    job = CastJob(blk, LightGroups(L.DVg, L.nvg, L.DEg, L.neg, L.g_start), setup.light_samples(), switches,
                  cast_chunk_for(L.mode, switches.materialize), L.G, L.S, L.mode == MODE_SPHERE,
                  max(leaf, int(params.MidpointLimit)), (L.S + 63) // 64, mb, mattes)
    with timer("build"):
        each_in_threads(lambda c: build_chunk(c, job), chunks, workers)
    with timer("cast"):
        each_in_threads(lambda c: run_chunk(c, job), chunks, workers)
    for c in chunks:
        V[c.rows] = c.V
    stats.update(chunk_stats(chunks, job, n))
    return V, stats


def scene_blockers(scene) -> np.ndarray:
    """Shadow-casting, finite triangles as float64[T,3,3]."""
    return finite_blockers(scene.triangles[scene.tri_casts_shadow])


def finite_blockers(tris) -> np.ndarray:
    """The finite ones of shadow-casting triangles ``tris``, as float64[T,3,3]."""
    ok = np.isfinite(tris.reshape(len(tris), 9)).all(axis=1)
    return np.ascontiguousarray(tris[ok], np.float64)


@register
class PenumbraCasting(Method):
    id = "penumbra_casting"
    paper = "Laine, Aila 2005: Hierarchical Penumbra Casting"
    passes = {"penumbra_casting": IRRADIANCE}
    needs = frozenset({GBUFFER, SHADOW_TRIANGLES})   # it casts the triangles themselves: no BVH
    packed = True                # shades each receiver of a packed G-buffer on its own
    Params = PenumbraCastingParams
    physical = True

    def subpixel_overrides(self, params, share: int):
        """Each sub-pixel receiver its share of the light samples (at least one)."""
        return {"samples": max(1, -(-int(params.samples) // max(1, int(share))))}

    def run(self, buffers, light, params: PenumbraCastingParams) -> MethodResult:
        timer = PhaseTimer()
        g = buffers.gbuffer
        H, W = g.shape
        with timer("setup"):
            setup = prepare(buffers, light, params)
            tris, mattes = split_blockers(buffers.matte_casters, buffers.shadow_triangles[0])
            tris = finite_blockers(tris)
        V, stats = cast(setup, tris, params, timer, mattes=mattes)
        out = np.ones(H * W, np.float32)
        out[setup.idx] = np.clip(V, 0.0, 1.0).astype(np.float32)
        return MethodResult(passes={"penumbra_casting": out.reshape(H, W)}, time_s=timer.result(),
                            stats=stats)
