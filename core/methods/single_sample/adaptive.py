"""Adaptive sampling (section 4.3): the group walk along columns and rows that
marks the pixels to search and interpolates the others.
"""
import numpy as np

from ...jit import HOT, inner, kernel
from ...kernels import borrowed, each_range


@inner
def _same(hface, hinner, hid, idx0, stride, a, b):
    """Section 4.3's group criterion over pixels a..b: equal hard results and
    ids (and, conservatively, the same light-view face)."""
    i0 = idx0 + a * stride
    for k in range(a + 1, b + 1):
        j = idx0 + k * stride
        if hinner[j] != hinner[i0] or hid[j] != hid[i0] or hface[j] != hface[i0]:
            return False
    return True


@inner
def _walk(hface, hinner, hid, need, out, idx0, stride, marks, ends, interpolate):
    """Section 4.3 along one column or row: groups [marks[k], marks[k+1]]
    (5 pixels for blocks of 4). Where the group criterion holds the inner
    pixels are interpolated linearly between the ends, else the middle pixel
    is searched and both halves are treated the same way.

    The subdivision depends on the hard test and ids only, so the walk runs
    twice: first (``interpolate`` False) it marks the pixels to search in
    ``need`` (the group ends too if ``ends``), then, once those are searched,
    it interpolates ``out`` along the same subdivision."""
    stack = np.empty((64, 2), np.int64)
    for g in range(marks.shape[0] - 1):
        a0 = marks[g]
        b0 = marks[g + 1]
        if ends and not interpolate:
            need[idx0 + a0 * stride] = True
            need[idx0 + b0 * stride] = True
        stack[0, 0] = a0
        stack[0, 1] = b0
        sp = 1
        while sp > 0:
            sp -= 1
            a = stack[sp, 0]
            b = stack[sp, 1]
            if b - a <= 1:
                continue
            if _same(hface, hinner, hid, idx0, stride, a, b):
                if interpolate:
                    ja = idx0 + a * stride
                    jb = idx0 + b * stride
                    for k in range(a + 1, b):
                        out[idx0 + k * stride] = out[ja] + (out[jb] - out[ja]) * ((k - a) / (b - a))
                continue
            m = (a + b) // 2
            if not interpolate:
                need[idx0 + m * stride] = True
            if sp + 2 > stack.shape[0]:
                grown = np.empty((2 * stack.shape[0], 2), np.int64)
                for q in range(sp):    # element copy: a slice assignment pulls in a slow-compiling shape check
                    grown[q, 0] = stack[q, 0]
                    grown[q, 1] = stack[q, 1]
                stack = grown
            stack[sp, 0] = a
            stack[sp, 1] = m
            stack[sp + 1, 0] = m
            stack[sp + 1, 1] = b
            sp += 2


def _marks(n: int, step: int) -> np.ndarray:
    """Group ends along a line of n pixels: every ``step``-th and the last."""
    m = list(range(0, n, step))
    if m[-1] != n - 1 or len(m) == 1:
        m.append(n - 1)
    return np.asarray(m, np.int64)


def adaptive_walk(hface, hinner, hid, need, out, H, W, colmarks, rowmarks, interpolate, threads=None):
    """Section 4.3: every ``block``-th column first (groups along y, their
    ends searched), then every row between those columns (groups along x).
    Each phase over ranges of lines on Numba's thread count
    (``kernels.each_range``, ``_walk_lines``): lines write disjoint pixels."""
    each_range(lambda k0, k1: _walk_lines(k0, k1, hface, hinner, hid, need, out, W, colmarks, rowmarks, True,
                                          interpolate), colmarks.shape[0], threads, grain=16, per_worker=2)
    each_range(lambda k0, k1: _walk_lines(k0, k1, hface, hinner, hid, need, out, W, colmarks, rowmarks, False,
                                          interpolate), H, threads, grain=64, per_worker=2)


@kernel(opt=HOT, nogil=True)
def _walk_lines(k0, k1, hface, hinner, hid, need, out, W, colmarks, rowmarks, columns, interpolate):
    """``adaptive_walk``'s columns colmarks[k0:k1] (``columns``) or rows k0..k1-1."""
    hface, hinner, hid, need, out, colmarks, rowmarks = borrowed((hface, hinner, hid, need, out, colmarks, rowmarks))
    marks = rowmarks if columns else colmarks
    stride = W if columns else 1
    for k in range(k0, k1):
        idx0 = colmarks[k] if columns else k * W
        # ``columns`` rather than a literal True / False: one compile of _walk, not one per value
        _walk(hface, hinner, hid, need, out, idx0, stride, marks, columns, interpolate)
