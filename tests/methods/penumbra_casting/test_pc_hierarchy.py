"""The receiver side of penumbra casting: the point hierarchy (midpoint
and SAH splits, leaves; ``hierarchy``) and the receiver chunks cast in
parallel (median splits; ``chunks``)."""
import numpy as np
import pytest

from penumbra.core.methods.penumbra_casting.chunks import chunk_receivers
from penumbra.core.methods.penumbra_casting.hierarchy import _stable_order, build_hierarchy


def test_hierarchy_midpoint_sah_and_leaves():
    """Every point in one leaf, every box holding its points, leaves of 1-16
    points, and nodes of more than 1024 points split at their box's midpoint
    along the longest axis."""
    rng = np.random.default_rng(5)
    pts = np.concatenate([rng.uniform(0, 1, (3000, 3)) * [4, 2, 0.01], rng.uniform(0, 1, (500, 3)) + [3, 0, 0]])
    perm, bb, left, right, start, count, depth = build_hierarchy(pts, np.arange(len(pts)), 16, 1024)
    assert sorted(perm) == list(range(len(pts)))
    assert depth < 40
    for n in range(len(left)):
        P = pts[perm[start[n]:start[n] + count[n]]]
        assert (P >= bb[n, :3]).all() and (P <= bb[n, 3:]).all()
        if left[n] < 0:
            assert 1 <= count[n] <= 16
            continue
        l, r = left[n], right[n]
        assert count[l] + count[r] == count[n] and count[l] > 0 and count[r] > 0
        if count[n] > 1024:      # midpoint split of the longest axis
            ax = int(np.argmax(bb[n, 3:] - bb[n, :3]))
            mid = 0.5 * (bb[n, ax] + bb[n, 3 + ax])
            assert bb[l, 3 + ax] < mid <= bb[r, ax]


@pytest.mark.parametrize("c", [0, 1, 2, 7, 64, 1000])
def test_sah_key_order_is_numpys_stable_argsort(c):
    """The hierarchy's own merge sort orders keys as np.argsort(kind="mergesort"):
    ascending, ties in index order (the SAH split depends on it)."""
    rng = np.random.default_rng(c)
    for keys in (rng.integers(0, 4, 1024).astype(float), rng.normal(0, 1, 1024), np.zeros(1024)):
        order, tmp = np.empty(1024, np.int64), np.empty(1024, np.int64)
        _stable_order(keys, c, order, tmp, np.empty(1024), np.empty(1024))
        assert np.array_equal(order[:c], np.argsort(keys[:c], kind="mergesort"))


def test_receiver_chunks_are_median_splits():
    """The chunks partition the receivers with rows in increasing order; the
    first split halves them (sizes within one) across the longest axis (x)."""
    rng = np.random.default_rng(8)
    pts = rng.normal(0, 1, (10_000, 3)) * [4.0, 1.0, 0.5]
    for n in (1, 2, 5, 8):
        parts = chunk_receivers(pts, n)
        assert len(parts) == n
        rows = np.concatenate(parts)
        assert np.array_equal(np.sort(rows), np.arange(len(pts)))
        assert all((np.diff(p) > 0).all() for p in parts)
    a, b = chunk_receivers(pts, 2)
    assert abs(len(a) - len(b)) <= 1
    assert pts[a, 0].max() <= pts[b, 0].min() or pts[b, 0].max() <= pts[a, 0].min()
