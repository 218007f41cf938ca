"""Receiver chunks: the parallel part of penumbra casting (ours, not the
paper's).

The receivers are split into spatial chunks by median splits along the
longest axis (the receiver hierarchy's top splits); each chunk has its own
hierarchy, umbra bits and masks, and casts every blocker on a worker thread
(the kernels release the GIL). A relation's status is a geometric fact, so
any chunking gives the same bits. Per chunk: build the hierarchy
(``build_chunk``), cast with the rebuilds of line 29 (``run_chunk``), then
the visibility (``visibility``) and the alpha-matte blockers
(``alpha_blockers``).
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable, Dict, List, Optional

import numpy as np

from .alpha_blockers import MatteBlockers, fetch_visibility, matte_pairs, transmitted_visibility
from .cast import (N_ST, ST_GROUP_TESTS, ST_GROUP_VOLUMES, ST_HARD_BUILT, ST_HARD_TESTS, ST_HIDDEN, ST_HIDDEN_NODES,
                   ST_LEAF_VISITS, ST_LIVE, ST_NODES, ST_PAIRS, ST_PEAK, ST_POINT_TESTS, ST_POINTS, ST_ROOT_CULLED,
                   ST_SLOTS, ST_UMBRA, Blockers, CastSwitches, Hierarchy, LightGroups, Masks, Receivers, UmbraBits)
from .hierarchy import build_hierarchy, node_umbra_bits
from .light import MODE_SPHERE, LightSamples
from .visibility import chunk_visibility


@dataclass
class Chunk:
    """One chunk's receivers (``rows`` of the setup's, in leaf order after
    ``build_chunk``; ``cast.Receivers``' fields), its hierarchy, umbra bits
    (A), masks (D), counters (``cast.ST_*``), thread times and visibility ``V``."""

    rows: np.ndarray
    pts: np.ndarray
    set_id: np.ndarray
    pix: np.ndarray
    Pg: np.ndarray
    M: np.ndarray
    N: np.ndarray
    hier: Hierarchy = None
    fu: np.ndarray = None
    gu: np.ndarray = None
    node_gu: np.ndarray = None
    node_fu: np.ndarray = None
    slot: np.ndarray = None
    pool: np.ndarray = None
    free: np.ndarray = None
    st: np.ndarray = None
    build_s: float = 0.0
    rebuild_s: float = 0.0
    cast_s: float = 0.0
    rebuilds: int = 0
    hier_nodes_peak: int = 0
    leaves: int = 0
    V: np.ndarray = None
    matte_pairs: int = 0


@dataclass
class CastJob:
    """What every chunk casts: the blockers, the light's groups and samples,
    the switches and the ``cast.cast_chunk_for`` kernel; the group and sample
    counts, the mask width in 64-bit words, the hierarchy's midpoint limit;
    the alpha-matte blockers (``mb`` for the texture fetch, else ``mattes``
    for Embree rays, or neither)."""

    blk: Blockers
    grp: LightGroups
    smp: LightSamples
    switches: CastSwitches
    kernel: Callable
    G: int
    S: int
    sphere: bool
    midpoint_limit: int
    nwords: int
    mb: Optional[MatteBlockers] = None
    mattes: object = None


def chunk_receivers(pts, n_chunks):
    """Median splits along the longest axis into about ``n_chunks`` pieces."""
    parts = [np.arange(len(pts))]
    coords = np.ascontiguousarray(pts.T)     # rows x, y, z: NumPy reduces (N, 3) columns slowly
    while len(parts) < n_chunks:
        parts.sort(key=len)
        big = parts.pop()
        if len(big) < 2:
            parts.append(big)
            break
        p = np.take(coords, big, axis=1)         # C order (coords[:, big] is not)
        ax = int(np.argmax(p.max(1) - p.min(1)))
        h = len(big) // 2
        low = np.zeros(len(big), np.bool_)
        low[np.argpartition(p[ax], h)[:h]] = True
        parts += [big[low], big[~low]]          # rows stay in increasing order
    return [c for c in parts if len(c)]


def make_chunks(setup, n_chunks: int) -> List[Chunk]:
    """``setup``'s receivers in about ``n_chunks`` chunks (``chunk_receivers``)."""
    sphere = setup.light.mode == MODE_SPHERE
    weighted = len(setup.N) > 0
    return [Chunk(rows, np.ascontiguousarray(setup.pts[rows]), setup.set_id[rows].copy(), setup.idx[rows].copy(),
                  np.ascontiguousarray(setup.Pg[rows]), np.ascontiguousarray(setup.M[rows]) if sphere else setup.M,
                  np.ascontiguousarray(setup.N[rows]) if weighted else setup.N)
            for rows in chunk_receivers(setup.pts, n_chunks)]


def build_chunk(c: Chunk, job: CastJob) -> None:
    """The chunk's hierarchy (its receivers reordered into leaf order), umbra
    bits, counters and mask pool."""
    t = time.perf_counter()
    leaf = job.switches.leaf_size
    m = len(c.rows)
    c.hier = Hierarchy(*build_hierarchy(c.pts, np.arange(m, dtype=np.int64), leaf, job.midpoint_limit))
    # receivers stored in leaf order: a leaf's points are contiguous in memory
    perm = c.hier.perm
    c.rows, c.pts, c.set_id, c.pix, c.Pg = (c.rows[perm], np.ascontiguousarray(c.pts[perm]), c.set_id[perm],
                                            c.pix[perm], np.ascontiguousarray(c.Pg[perm]))
    if job.sphere:
        c.M = np.ascontiguousarray(c.M[perm])
    if len(c.N):
        c.N = np.ascontiguousarray(c.N[perm])
    c.hier = c.hier._replace(perm=np.arange(m, dtype=np.int64))
    nn = len(c.hier.left)
    c.hier_nodes_peak = nn
    c.leaves = int((c.hier.left < 0).sum())
    c.fu = np.zeros(m, np.uint8)
    c.gu = np.zeros((m, job.G), np.uint8)
    c.node_gu = np.zeros((nn, job.G), np.uint8)
    c.node_fu = np.zeros(nn, np.uint8)
    c.st = np.zeros(N_ST, np.int64)
    # zeroed on allocation: pages are committed on first touch (see cast)
    c.pool = np.zeros((m, job.nwords), np.uint64)
    if job.switches.optD:
        c.free = np.empty(m, np.int64)
        c.slot = np.full(m, -1, np.int64)
    else:
        c.free = np.zeros(1, np.int64)
        c.slot = np.arange(m, dtype=np.int64)
        c.st[ST_LIVE] = c.st[ST_PEAK] = c.st[ST_SLOTS] = m
    c.st[ST_POINTS] = m
    c.build_s = time.perf_counter() - t


def run_chunk(c: Chunk, job: CastJob) -> None:
    """Cast every blocker against the chunk, rebuilding its hierarchy where
    optimization A asks (line 29); then its visibility ``c.V``, through the
    alpha-matte blockers last."""
    t_start = time.perf_counter()
    leaf = job.switches.leaf_size
    t0 = 0
    rec = Receivers(c.pts, c.set_id, c.pix, c.Pg, c.M, c.N)
    masks = Masks(c.slot, c.pool, c.free)
    while True:
        t0 = job.kernel(t0, job.blk, job.grp, job.smp, rec, c.hier, UmbraBits(c.fu, c.gu, c.node_gu, c.node_fu),
                        masks, c.st, job.switches)
        if t0 >= len(job.blk.tri_sel):
            break
        # line 29 (A): rebuild the hierarchy over the points not in full umbra
        tr = time.perf_counter()
        live = np.flatnonzero(c.fu == 0).astype(np.int64)
        c.hier = Hierarchy(*build_hierarchy(c.pts, live, leaf, job.midpoint_limit))
        nn = len(c.hier.left)
        c.node_gu = np.zeros((nn, job.G), np.uint8)
        c.node_fu = np.zeros(nn, np.uint8)
        if len(live):
            node_umbra_bits(c.hier.left, c.hier.right, c.hier.start, c.hier.count, c.hier.perm, c.gu, c.fu,
                            c.node_gu, c.node_fu)
        c.st[ST_UMBRA] = 0
        c.st[ST_POINTS] = len(live)
        c.rebuilds += 1
        c.rebuild_s += time.perf_counter() - tr
    c.V = np.empty(len(c.rows))
    chunk_visibility(job.smp, rec, c.fu, c.slot, c.pool, job.S, c.V)
    if job.mb is not None:
        ptr, lists = matte_pairs(job.mb, c.hier, c.pts, c.fu, job.switches.tol)
        c.matte_pairs = int(ptr[-1])
        fetch_visibility(job.smp, rec, c.fu, c.slot, c.pool, job.S, ptr, lists, job.mb, job.mattes.alpha.mattes,
                         c.V)
    elif job.mattes is not None:
        c.V = transmitted_visibility(job.mattes, job.smp, rec, c.fu, c.slot, c.pool, job.S)
    c.cast_s = time.perf_counter() - t_start - c.rebuild_s


def chunk_stats(chunks: List[Chunk], job: CastJob, n: int) -> Dict[str, object]:
    """The counters of all chunks (``n`` receivers): work, memory, and where
    the cast time goes (blockers per receiver leaf and per receiver, V_Gk
    tests, per-sample tests)."""
    st = np.sum([c.st for c in chunks], axis=0)
    out: Dict[str, object] = {}
    if job.mb is not None:
        out["matte_pairs"] = int(sum(c.matte_pairs for c in chunks))   # (receiver, matte blocker) in V_L
    bytes_per_mask = job.nwords * 8
    out.update({
        "rebuilds": int(sum(c.rebuilds for c in chunks)),
        "rebuild_thread_s": float(sum(c.rebuild_s for c in chunks)),
        "cast_thread_s": float(sum(c.cast_s for c in chunks)),
        "build_thread_s": float(sum(c.build_s for c in chunks)),
        "peak_masks": int(st[ST_PEAK]),
        "peak_mask_bytes": int(st[ST_PEAK] * bytes_per_mask),
        "mask_pool_bytes": int(st[ST_SLOTS] * bytes_per_mask),
        "hierarchy_bytes": int(sum(c.hier_nodes_peak * (6 * 8 + 4 * 8 + job.G + 1) + 8 * len(c.rows)
                                   for c in chunks)),
        "receiver_bytes": int(n * (3 * 8 + 8 + 1 + job.G)),
        "nodes_visited": int(st[ST_NODES]),
        "point_tests": int(st[ST_POINT_TESTS]),
        "hard_volume_tests": int(st[ST_HARD_TESTS]),
        "triangles_with_group_volumes": int(st[ST_GROUP_VOLUMES]),
        "hard_volumes_built": int(st[ST_HARD_BUILT]),
        "triangles_root_culled": int(st[ST_ROOT_CULLED]),
        "leaf_visits": int(st[ST_LEAF_VISITS]),
        "receiver_blocker_pairs": int(st[ST_PAIRS]),
        "group_volume_tests": int(st[ST_GROUP_TESTS]),
        "hidden_pairs": int(st[ST_HIDDEN]),
        "hidden_nodes": int(st[ST_HIDDEN_NODES]),
        "blockers_per_leaf": float(st[ST_LEAF_VISITS] / max(1, sum(c.leaves for c in chunks))),
        "blockers_per_receiver": float(st[ST_PAIRS] / max(1, n)),
        "sample_tests_per_relation": float(st[ST_HARD_TESTS] / max(1, n * job.S)),
    })
    return out
