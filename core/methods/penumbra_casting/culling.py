"""The blockers the traversal gets, in cast order (``cast_blockers``).

A triangle that cannot shadow a visible receiver never enters the
traversal: first a box test against the hull of the light and the receivers,
then its penumbra volume V_L (section 3.2) against the receivers' bounding
box. Between the two, closed solids are found (``cores``): their triangles
facing away from the whole light are dropped (``backface_cull``), their
interior blockers are put first (``interior_blockers``), and coplanar
triangles are merged into convex polygons (``blockers``). Last, the coarse
sort by area (section 3.3).

The culling tests only ever keep too much (slack ``tol``), so the exact
per-sample test alone decides the output.
"""
from __future__ import annotations

from typing import Dict

import numpy as np

from ... import sampling
from ...jit import kernel
from ...kernels import borrowed, each_dealt_chunk
from .blockers import MAXB, bucket_sort_by_area, coplanar_blockers, pad_triangles, sub_mesh
from .cast import Blockers
from .cores import closed_solids
from .geometry import MAXP, box_vs_volume, penumbra_volume
from .light import MODE_SPHERE, LightSetup

#: candidates per batch of V_L construction (bounds the MAXP-wide temporary)
VL_BATCH = 1 << 16


def light_volumes(tris, nverts, DV, nv, DE, ne, eps, root_bb, tol, VL, nVL, keep, threads=None):
    """V_L of every candidate blocker and the test against the receivers'
    bounding box: ``keep`` = T may shadow some receiver. ``_light_volumes_of``
    on Numba's thread count (``kernels.each_dealt_chunk``)."""
    each_dealt_chunk(lambda ts: _light_volumes_of(ts, tris, nverts, DV, nv, DE, ne, eps, root_bb, tol, VL, nVL,
                                                  keep), tris.shape[0], threads)


@kernel(nogil=True, error_model="numpy")
def _light_volumes_of(ts, tris, nverts, DV, nv, DE, ne, eps, root_bb, tol, VL, nVL, keep):
    """``light_volumes`` for blockers ``ts``: a serial ``nogil`` kernel with
    ``kernels.borrowed`` arguments (a ``prange`` loop's parfor lowering would
    cost most of its compile time)."""
    tris, nverts, DV, nv, DE, ne, root_bb, VL, nVL, keep = borrowed(
        (tris, nverts, DV, nv, DE, ne, root_bb, VL, nVL, keep))
    for t in ts:
        k = penumbra_volume(tris[t], nverts[t], DV, nv, DE, ne, eps, VL[t])
        nVL[t] = k
        if k < 0:
            keep[t] = False
            continue
        ok, _ = box_vs_volume(root_bb, np.int64(0), VL, t, k, np.int64(-1), np.bool_(False), tol)
        keep[t] = ok


def receiver_box(pts: np.ndarray) -> np.ndarray:
    """float64[1, 6]: the receivers' bounding box (lo, hi), the root of every
    V_L test."""
    return np.concatenate([pts.min(0), pts.max(0)])[None, :]


def backfacing(tris, facing, verts, tol: float, nverts=None) -> np.ndarray:
    """Triangles (polygons with ``nverts`` corners) of a closed solid
    (``facing`` != 0: the sign that orients (b - a) x (c - a), or Newell's
    normal, outward) whose plane has every homogeneous vertex ``verts`` (of
    the light's bounding polygon / volume, or of a group's) strictly behind
    it. A segment from a light sample outside the solid to any receiver that
    meets the solid enters it first (going from the sample) through a
    triangle facing the sample, so such triangles block nothing from those
    samples the rest of the solid does not (provided the solid's winding
    number is never negative: no inside-out parts)."""
    a = tris[:, 0]
    n = np.cross(tris[:, 1] - a, tris[:, 2] - a)
    if nverts is not None and (nverts > 3).any():
        big = np.flatnonzero(nverts > 3)
        q = tris[big]
        nn = np.zeros((len(big), 3))
        for j in range(q.shape[1]):                  # Newell's normal (the kernel's triangle_plane)
            k = np.where(j + 1 < nverts[big], j + 1, 0)
            r = q[np.arange(len(big)), k]
            on = j < nverts[big]
            p = q[:, j]
            nn[:, 0] += on * (p[:, 1] - r[:, 1]) * (p[:, 2] + r[:, 2])
            nn[:, 1] += on * (p[:, 2] - r[:, 2]) * (p[:, 0] + r[:, 0])
            nn[:, 2] += on * (p[:, 0] - r[:, 0]) * (p[:, 1] + r[:, 1])
        n[big] = nn
    n = n * facing[:, None]
    if not len(verts):
        return np.zeros(len(tris), np.bool_)
    h = n @ verts[:, :3].T - np.einsum("ij,ij->i", n, a)[:, None] * verts[None, :, 3]
    margin = np.linalg.norm(n, axis=1) * tol
    return (facing != 0) & np.all(h < -margin[:, None], axis=1)


def light_box(L: LightSetup):
    """``cores.closed_solids``' view of the light: (centre, direction,
    box lo, box hi); the sun's samples are at infinity (no box)."""
    verts = L.DVL[:L.nvl]
    if L.lp[0] == sampling.KIND_SUN and L.mode != MODE_SPHERE:
        d = verts[:, :3].mean(0) if L.nvl else np.zeros(3)
        return None, d, None, None
    fin = verts[verts[:, 3] != 0.0, :3]
    pts = np.vstack([fin, L.centre[None, :]])
    return L.centre, None, pts.min(0), pts.max(0)


def _in_light_hull_box(setup, tris: np.ndarray, root_bb: np.ndarray) -> np.ndarray:
    """Triangles whose box meets the box of the receivers (``root_bb``) and
    the light's bounding polygon / volume (unbounded towards a direction at
    infinity)."""
    L = setup.light
    blo, bhi = root_bb[0, :3].copy(), root_bb[0, 3:].copy()
    verts = L.DVL[:L.nvl]
    fin = verts[verts[:, 3] != 0.0, :3]
    if len(fin):
        blo = np.minimum(blo, fin.min(0))
        bhi = np.maximum(bhi, fin.max(0))
    dirs = verts[verts[:, 3] == 0.0, :3]
    if L.nvl == 0 and L.mode != MODE_SPHERE and L.lp[0] == sampling.KIND_SUN:
        blo[:] = -np.inf
        bhi[:] = np.inf
    if len(dirs):
        blo[(dirs < 0).any(0)] = -np.inf
        bhi[(dirs > 0).any(0)] = np.inf
    tmin = tris.min(1)
    tmax = tris.max(1)
    return np.all((tmax >= blo - setup.tol) & (tmin <= bhi + setup.tol), axis=1)


def _volume_cull(setup, cand, cand_nv, cand_core, cand_facing, root_bb):
    """V_L of every candidate, in batches of ``VL_BATCH``; the survivors
    (V_L meets the receivers' box), each keeping only as many plane slots as
    the widest one uses: (blockers, nverts, VL, nVL, solid, facing)."""
    L = setup.light
    parts, nparts, widest = [], [], 1
    blocker_parts, nv_parts, core_parts, facing_parts = [], [], [], []
    for a in range(0, len(cand), VL_BATCH):
        cb = np.ascontiguousarray(cand[a:a + VL_BATCH])
        cnv = np.ascontiguousarray(cand_nv[a:a + VL_BATCH])
        VLb = np.zeros((len(cb), 4, MAXP))
        nVLb = np.zeros(len(cb), np.int64)
        keep = np.zeros(len(cb), np.bool_)
        light_volumes(cb, cnv, L.DVL, L.nvl, L.DEL, L.nel, setup.eps, root_bb, setup.tol, VLb, nVLb, keep)
        w = int(nVLb[keep].max()) if keep.any() else 0
        widest = max(widest, w)
        parts.append(VLb[keep, :, :max(w, 1)])
        nparts.append(nVLb[keep])
        blocker_parts.append(cb[keep])
        nv_parts.append(cnv[keep])
        core_parts.append(cand_core[a:a + VL_BATCH][keep])
        facing_parts.append(cand_facing[a:a + VL_BATCH][keep])
    VL = np.zeros((sum(len(q) for q in parts), 4, widest))
    o = 0
    for q in parts:
        VL[o:o + len(q), :, :q.shape[2]] = q
        o += len(q)
    nVL = np.concatenate(nparts) if nparts else np.zeros(0, np.int64)
    blockers = np.ascontiguousarray(np.concatenate(blocker_parts)) if blocker_parts else np.zeros((0, MAXB, 3))
    blocker_nv = np.ascontiguousarray(np.concatenate(nv_parts)) if nv_parts else np.zeros(0, np.int64)
    blocker_core = np.ascontiguousarray(np.concatenate(core_parts)) if core_parts else np.zeros(0, np.int64)
    blocker_facing = np.concatenate(facing_parts) if facing_parts else np.zeros(0, np.int8)
    return blockers, blocker_nv, VL, nVL, blocker_core, blocker_facing


def cast_blockers(setup, tris: np.ndarray, params, timer, stats: Dict[str, object]) -> Blockers:
    """The blockers of ``tris`` (float64[T,3,3]) for ``setup``'s receivers
    and light under ``params`` (``PenumbraCastingParams``), with their V_L,
    solids, facing groups and cast order; counts go to ``stats``."""
    L = setup.light
    with timer("cull"):
        root_bb = receiver_box(setup.pts)
        inbox = _in_light_hull_box(setup, tris, root_bb)
        cand_tris = tris[inbox]
    n_cores = 0
    n_back = 0
    solids = None
    mesh = None
    if (params.interior_blockers or params.backface_cull) and len(cand_tris):
        with timer("cores"):             # every triangle: the box cull may open a closed mesh
            solids = closed_solids(tris, *light_box(L), params.CoreSlices, params.CoreCorners)
            sel = np.flatnonzero(inbox)
            facing = solids.facing[sel]
            core_of = solids.solid_of[sel] if (params.interior_blockers and params.hidden_behind_cores) \
                else np.full(len(cand_tris), -1, np.int64)
            if params.backface_cull and facing.any():
                back = backfacing(cand_tris, facing, L.DVL[:L.nvl], setup.tol)
                n_back = int(back.sum())
                cand_tris, core_of, sel, facing = cand_tris[~back], core_of[~back], sel[~back], facing[~back]
            if solids.mesh is not None:
                mesh = sub_mesh(solids.mesh, sel)   # the merge reuses the vertex ids and adjacency
    with timer("merge"):
        if params.coplanar_blockers:
            cand, cand_nv, poly_of = coplanar_blockers(cand_tris, mesh=mesh)
        else:
            cand, cand_nv = pad_triangles(cand_tris)
            poly_of = np.arange(len(cand_tris))
        cand_core = np.full(len(cand), -1, np.int64)
        cand_facing = np.zeros(len(cand), np.int8)
        if solids is not None:
            cand_core[poly_of] = core_of     # a polygon's triangles are edge-adjacent: one solid
            if params.backface_cull:
                cand_facing[poly_of] = facing
    if params.interior_blockers and solids is not None:
        n_cores = len(solids.polys)
        if n_cores:
            cand = np.concatenate([solids.polys, cand])
            cand_nv = np.concatenate([solids.nverts, cand_nv])
            cand_core = np.concatenate([np.full(n_cores, -1, np.int64), cand_core])
            cand_facing = np.concatenate([np.zeros(n_cores, np.int8), cand_facing])
    with timer("cull"):
        blockers, blocker_nv, VL, nVL, blocker_core, blocker_facing = _volume_cull(
            setup, cand, cand_nv, cand_core, cand_facing, root_bb)
        # per blocker of a solid: the groups G_k it may face (the others' samples all see its back)
        gface = np.ones((len(blockers), L.G), np.uint8)
        solid_b = np.flatnonzero(blocker_facing != 0)
        for g in range(L.G if len(solid_b) and params.group_backface_cull else 0):
            gface[solid_b, g] = ~backfacing(blockers[solid_b], blocker_facing[solid_b], L.DVg[g, :L.nvg[g]],
                                            setup.tol, blocker_nv[solid_b])
    stats["interior_blockers"] = int(n_cores)
    stats["triangles_backface_culled"] = int(n_back)
    stats["group_backface_culled"] = int((gface == 0).sum())      # (blocker, G_k) pairs
    stats["triangles_box_culled"] = int(len(tris) - int(inbox.sum()))
    stats["blocker_polygons"] = int(len(cand))
    stats["triangles_volume_culled"] = int(len(cand) - len(blockers))   # blockers (polygons)
    stats["blockers"] = int(len(blockers))
    with timer("sort"):
        if params.coarse_sort and len(blockers):
            order = bucket_sort_by_area(blockers, blocker_nv, max(1, int(params.SortBuckets)))
        else:
            order = np.arange(len(blockers), dtype=np.int64)
    sol = solids if solids is not None else closed_solids(np.zeros((0, 3, 3)), None, None, None, None)
    return Blockers(order, blockers, blocker_nv, VL, nVL, blocker_core, sol.solids, sol.disks, gface)
