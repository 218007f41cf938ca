"""Alpha-matte blockers for penumbra casting (issue 18; Laine & Aila 2005,
section 4, "Alpha matte textures").

The paper: a texture fetch at the intersection of the l_i -> r_j ray with
the blocker, and the alpha-textured blockers processed only after all
opaque ones (separate buckets in the coarse sort). Here the opaque blockers
are cast as before (``cast``), and the matte blockers come last: each
relation (l_i, r_j) that no opaque blocker took gets its transmittance
through the matte blockers, the product of (1 - alpha) of the texture
fetched at each intersection of the ray with a matte blocker (as Cycles and
``embree`` compute it, ``alpha_rays.transmittance``). The intersections are
found with an Embree BVH over the matte blockers only (a departure: not by
the hierarchical traversal, whose umbra shortcuts do not hold for a partly
clear blocker), so every relation a blocker would take is tested exactly
once; relations in an opaque umbra are never traced.

V_j = (1 / S) sum over the relations of r_j left open by the opaque
blockers of their transmittance: with binary mattes the same relations as
``embree``'s rays (``shared_samples_with_reference``) give the same V.
"""
from __future__ import annotations

from typing import Optional, Tuple

import numpy as np
from numba import njit

from ... import alpha_rays, raycast
from .light import sample_point

#: relations traced per Embree batch
RELATIONS_PER_BATCH = 1 << 18
SUN_TFAR = np.float32(1e30)


def split_blockers(scene, casting: np.ndarray) -> Tuple[np.ndarray, Optional[raycast.TriangleScene]]:
    """(the shadow-casting triangles ``casting`` without a matte, a BVH of
    those with one, or None when there are none: then ``casting`` itself)."""
    has, mattes = raycast.TriangleScene.matte_casters(scene)
    return (casting, None) if has is None else (casting[~has], mattes)


@njit(cache=True, nogil=True)
def _open_relations(fu, slot, pool, S, count):
    """Per receiver: how many of its S relations no opaque blocker took
    (full umbra: none; no mask: all)."""
    for r in range(fu.shape[0]):
        if fu[r]:
            count[r] = 0
        elif slot[r] < 0:
            count[r] = S
        else:
            c = 0
            for i in range(S):
                if not (pool[slot[r], i >> 6] >> np.uint64(i & 63)) & np.uint64(1):
                    c += 1
            count[r] = c


@njit(cache=True, nogil=True)
def _relation_rays(smp, rec, r0, r1, fu, slot, pool, S, org, dirs, tfar, owner):
    """The rays r_j -> l_i of the open relations of receivers [r0, r1), as
    the reference casts them (from the receiver point, float32, to the light
    sample; a sun's samples are directions); ``owner``: each ray's receiver."""
    k = 0
    for r in range(r0, r1):
        if fu[r]:
            continue
        px, py, pz = rec.pts[r, 0], rec.pts[r, 1], rec.pts[r, 2]
        for i in range(S):
            if slot[r] >= 0 and (pool[slot[r], i >> 6] >> np.uint64(i & 63)) & np.uint64(1):
                continue
            x, y, z, w = sample_point(smp, i, r, rec)
            if w != 0.0:
                dx, dy, dz = x / w - px, y / w - py, z / w - pz
            else:
                dx, dy, dz = x, y, z
            ln = np.sqrt(dx * dx + dy * dy + dz * dz)
            if ln > 0:
                dx, dy, dz = dx / ln, dy / ln, dz / ln
            org[k, 0], org[k, 1], org[k, 2] = px, py, pz
            dirs[k, 0], dirs[k, 1], dirs[k, 2] = dx, dy, dz
            tfar[k] = ln * (1.0 - 1e-6) if w != 0.0 else SUN_TFAR
            owner[k] = r
            k += 1


def transmitted_visibility(bvh: raycast.TriangleScene, smp, rec, fu, slot, pool, S: int) -> np.ndarray:
    """V per receiver of one chunk (float64): its open relations'
    transmittance through the matte blockers ``bvh``, summed, over S."""
    m = len(fu)
    count = np.empty(m, np.int64)
    _open_relations(fu, slot, pool, S, count)
    none = raycast.TriangleScene(np.zeros((0, 3, 3), np.float32))
    total = np.zeros(m, np.float64)
    ends = np.cumsum(count)
    r0 = 0
    while r0 < m:
        base = ends[r0 - 1] if r0 else 0
        r1 = int(np.searchsorted(ends, base + RELATIONS_PER_BATCH, side="right"))
        r1 = max(r1, r0 + 1)
        n = int(ends[r1 - 1] - base)
        if n:
            org = np.empty((n, 3), np.float32)
            dirs = np.empty((n, 3), np.float32)
            tfar = np.empty(n, np.float32)
            owner = np.empty(n, np.int64)
            _relation_rays(smp, rec, r0, r1, fu, slot, pool, S, org, dirs, tfar, owner)
            trans = alpha_rays.transmittance(none, bvh, org, dirs, tfar)
            total += np.bincount(owner, weights=trans, minlength=m)
        r0 = r1
    return total / S
