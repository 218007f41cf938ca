"""``kernels.each_dealt_chunk`` (issue 15: serial ``nogil`` kernels on
worker threads instead of parfors): the chunks hold every item exactly
once, in ``block``-long runs of consecutive items, whatever the thread
count; so kernels writing disjoint outputs give the same result."""
from __future__ import annotations

import threading

import numpy as np
import pytest

from penumbra.core.kernels import each_dealt_chunk


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
