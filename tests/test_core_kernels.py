"""``kernels.each_dealt_chunk`` and ``kernels.each_range`` (serial ``nogil``
kernels on worker threads): the chunks hold
every item exactly once, in ``block``-long runs of consecutive items (the
ranges: contiguous, one per thread), whatever the thread count; so kernels
writing disjoint outputs give the same result."""
from __future__ import annotations

import threading

import numpy as np
import pytest

from penumbra.core.kernels import each_dealt_chunk, each_range


@pytest.mark.parametrize("n, block, threads", [(0, 1, 2), (5, 1, 1), (1000, 1, 2), (1000, 256, 2),
                                               (777, 16, 1), (5, 256, 2), (65536, 256, 2)])
def test_chunks_cover_every_item_once_in_blocks(n, block, threads):
    got, lock = [], threading.Lock()

    def take(idx):
        assert idx.dtype == np.int64
        with lock:
            got.append(idx.copy())

    each_dealt_chunk(take, n, threads=threads, block=block)
    allidx = np.concatenate(got) if got else np.zeros(0, np.int64)
    assert np.array_equal(np.sort(allidx), np.arange(n))
    for idx in got:
        assert np.all(np.diff(idx) > 0)                       # in order within a chunk
        starts = np.unique(idx // block)
        for s in starts:                                       # whole blocks (the last may be short)
            run = idx[idx // block == s]
            assert np.array_equal(run, np.arange(s * block, min((s + 1) * block, n)))
    if n >= block * threads * 8:
        assert len(got) == threads * 8                         # per_worker chunks per thread


@pytest.mark.parametrize("n, grain, threads", [(0, 4096, 2), (1, 4096, 2), (4095, 4096, 2), (10000, 4096, 2),
                                               (10000, 4096, 1), (7, 1, 2), (7, 1, 5)])
def test_ranges_cover_every_item_once(n, grain, threads):
    got, lock = [], threading.Lock()

    def take(i0, i1):
        with lock:
            got.append((i0, i1))

    each_range(take, n, threads=threads, grain=grain)
    got.sort()
    assert got[0][0] == 0 and got[-1][1] == n                  # contiguous, in order, nothing twice
    assert all(a[1] == b[0] for a, b in zip(got, got[1:]))
    assert len(got) <= max(1, threads)
    assert len(got) == max(1, min(threads, -(-n // grain)))    # one per thread when each gets grain items


def test_ranged_kernels_match_one_point_at_a_time():
    """Ranged kernels (offset_points, overlap_from_counts) give each point
    what the per-point formula gives, for 1 and 2 threads."""
    from penumbra.core.methods.irregular.geom import overlap_from_counts
    from penumbra.core.sampling import offset_origin, offset_points
    rng = np.random.default_rng(3)
    P = rng.normal(size=(9000, 3)) * 10.0
    N = rng.normal(size=(9000, 3))
    N /= np.linalg.norm(N, axis=1)[:, None]
    for f32 in (False, True):
        one = offset_points(P, N, 20.0, f32, threads=1)
        assert np.array_equal(one, offset_points(P, N, 20.0, f32, threads=2))
        for i in (0, 4500, 8999):
            want = np.array(offset_origin(*P[i], *N[i], 20.0))
            assert np.array_equal(one[i], want.astype(np.float32).astype(np.float64) if f32 else want)
    umbra = rng.integers(0, 3, 9000)
    counts = rng.integers(-1, 3, (9000, 5))
    want = np.maximum(umbra[:, None] + counts - 1, 0).sum(axis=1) / 5
    for th in (1, 2):
        assert np.array_equal(overlap_from_counts(umbra, counts, threads=th), want)
