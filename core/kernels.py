"""Small Numba helpers shared by the image-space methods: projecting a world
point into a packed ``ViewFace``, picking the face that holds it, the
bounding box of a map's finite depths and of a G-buffer's hits, the prange chunk size, and running
chunks of work on worker threads (kernels with ``nogil=True``, ray casts),
cancellable between chunks (``core/cancel.py``), and ``borrowed`` array
arguments for the inner loops of such kernels."""
from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager

import numba
import numpy as np
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

from . import cancel
from .jit import inner, kernel


@contextmanager
def parallel_chunks(size: int):
    """Kernels called inside hand their ``prange`` iterations to the threads
    ``size`` at a time (dynamic), for loops whose iterations differ widely in
    cost; the previous size is restored after. (Numba's own
    ``with numba.parallel_chunksize(n)`` inside a ``cache=True`` kernel
    breaks caching, so it is set here, around the call.)"""
    prev = numba.get_parallel_chunksize()
    numba.set_parallel_chunksize(size)
    try:
        yield
    finally:
        numba.set_parallel_chunksize(prev)


def each_in_threads(fn, items, workers: int) -> None:
    """``fn(item)`` for every item, on ``workers`` threads (in turn in this
    thread when there is one worker or one item); the first error is raised.
    ``fn`` must release the GIL for the threads to pay (Numba ``nogil=True``
    kernels, ``embree4``'s ray casts) and write disjoint outputs. Before each
    item the calling thread's cancel token is checked (``cancel.check``):
    once it is cancelled no further item starts and ``cancel.Cancelled`` is
    raised (the items already running finish first)."""
    items = list(items)
    token = cancel.current()

    def one(it):
        if token is not None:
            token.check()
        fn(it)

    if workers <= 1 or len(items) <= 1:
        for it in items:
            one(it)
        return
    with ThreadPoolExecutor(max_workers=workers) as pool:
        futures = [pool.submit(one, it) for it in items]
        try:
            for f in futures:
                f.result()
        finally:
            for f in futures:
                f.cancel()


def each_dealt_chunk(fn, n: int, threads=None, per_worker: int = 8, block: int = 1) -> None:
    """``fn(idx)`` for chunks ``idx`` (int64 arrays) that together hold
    0..n-1, on Numba's thread count (or ``threads``) through
    ``each_in_threads``: ``per_worker`` chunks per thread, chunk c holding
    blocks c, c + m, c + 2m, ... (m chunks) of ``block`` consecutive items,
    so items of unequal cost that are alike when neighbours (tiles, bins)
    spread over the chunks; ``block`` > 1 keeps neighbours (pixels reading
    the same map texels) together. For serial ``nogil`` kernels replacing a
    ``prange`` loop whose iterations write disjoint outputs: the result is
    the same for any thread count."""
    workers = max(1, int(threads or numba.get_num_threads()))
    block = max(1, int(block))
    nb = -(-int(n) // block)
    m = max(1, min(nb, workers * int(per_worker)))
    within = np.arange(block, dtype=np.int64)
    chunks = []
    for c in range(m):                     # chunk c: blocks c, c + m, ..., each block's items in order
        items = (np.arange(c, nb, m, dtype=np.int64)[:, None] * block + within).reshape(-1)
        chunks.append(items[items < n])
    each_in_threads(fn, chunks, workers)


def each_range(fn, n: int, threads=None, grain: int = 4096, per_worker: int = 1) -> None:
    """``fn(i0, i1)`` for contiguous ranges that together cover 0..n-1,
    ``per_worker`` per thread (Numba's thread count, or ``threads``) of at
    least ``grain`` items, through ``each_in_threads``: for serial ``nogil``
    kernels replacing a ``prange`` loop of equal, independent iterations
    (a parfor's lowering costs more compile time than the loop takes);
    ``per_worker`` > 1 lets a thread that finishes early take the
    next range (iterations cheap in one part of the image, e.g. sky)."""
    workers = max(1, int(threads or numba.get_num_threads()))
    n = int(n)
    k = max(1, min(workers * max(1, int(per_worker)), -(-n // max(1, int(grain)))))
    cuts = [n * j // k for j in range(k + 1)]
    each_in_threads(lambda j: fn(cuts[j], cuts[j + 1]), range(k), workers)


def _borrow(context, builder, ty, value):
    if isinstance(ty, types.Array):
        a = cgutils.create_struct_proxy(ty)(context, builder, value=value)
        a.meminfo = cgutils.get_null_value(a.meminfo.type)
        a.parent = cgutils.get_null_value(a.parent.type)
        return a._getvalue()
    if isinstance(ty, types.BaseTuple):
        for i, t in enumerate(ty):
            value = builder.insert_value(value, _borrow(context, builder, t, builder.extract_value(value, i)), i)
    return value


@intrinsic
def borrowed(typingctx, value):
    """``value`` (an array, or a (named) tuple of arrays and scalars) with the
    arrays' reference counts dropped: the same data, shape and strides, no
    owner, as Numba hands arrays to the body of a ``prange`` loop. Every
    copy of an array variable a kernel makes (an inlined call's argument, a
    tuple field) otherwise costs an atomic increment and decrement of its
    count, which a serial ``nogil`` kernel replacing a ``parallel=True`` one
    pays in its inner loops (threads also contend for the shared counts'
    cache lines). Only for a kernel's
    own arguments, whose owner (the caller) outlives the call; never
    returned or stored."""
    if not isinstance(value, (types.Array, types.BaseTuple)):
        return None

    def codegen(context, builder, sig, args):
        return _borrow(context, builder, sig.args[0], args[0])
    return value(value), codegen


@kernel(inline="always")
def face_project(fp, x, y, z):
    """World point -> (u, v, depth) in face pixels; depth = -z_view.
    For perspective faces points at depth <= 0 get u = v = nan."""
    vx = fp[0] * x + fp[1] * y + fp[2] * z + fp[3]
    vy = fp[4] * x + fp[5] * y + fp[6] * z + fp[7]
    vz = fp[8] * x + fp[9] * y + fp[10] * z + fp[11]
    depth = -vz
    if fp[16] == 0.0:
        if depth <= 0.0:
            return np.nan, np.nan, depth
        vx /= depth
        vy /= depth
    u = (vx - fp[17]) / (fp[18] - fp[17]) * fp[21]
    v = (fp[20] - vy) / (fp[20] - fp[19]) * fp[22]
    return u, v, depth


@inner
def pick_face(faces, x, y, z):
    """Index of the first face whose window holds the point, or -1."""
    for f in range(faces.shape[0]):
        u, v, d = face_project(faces[f], x, y, z)
        if d > 0.0 and u >= 0.0 and v >= 0.0 and u < faces[f, 21] and v < faces[f, 22]:
            return f
        if faces[f, 16] == 1.0 and u >= 0.0 and v >= 0.0 and u < faces[f, 21] and v < faces[f, 22]:
            return f
    return -1


@kernel(nogil=True)
def hit_box(points, hit):
    """(xmin, ymin, zmin, xmax, ymax, zmax): the least and greatest
    ``points[i]`` (float64[N, 3]) per axis over the i with ``hit[i]``;
    (+inf, ..., -inf, ...) where there is none. One pass, no gather
    (NumPy would copy the hits, then read them once per axis and bound);
    scalars, not arrays, so it compiles no allocation."""
    x0, y0, z0 = np.inf, np.inf, np.inf
    x1, y1, z1 = -np.inf, -np.inf, -np.inf
    for i in range(points.shape[0]):
        if hit[i]:
            x, y, z = points[i, 0], points[i, 1], points[i, 2]
            x0, y0, z0 = min(x0, x), min(y0, y), min(z0, z)
            x1, y1, z1 = max(x1, x), max(y1, y), max(z1, z)
    return x0, y0, z0, x1, y1, z1


@kernel
def finite_bbox(depth):
    """Per face: (umin, umax, vmin, vmax) of finite depths (Reeves et al. 3.3),
    (1, 0, 1, 0) for an empty face."""
    F, h, w = depth.shape
    out = np.empty((F, 4), np.int64)
    for f in range(F):
        umin, umax, vmin, vmax = w, -1, h, -1
        for r in range(h):
            for c in range(w):
                if depth[f, r, c] < np.inf:
                    if c < umin:
                        umin = c
                    if c > umax:
                        umax = c
                    if r < vmin:
                        vmin = r
                    if r > vmax:
                        vmax = r
        out[f, 0], out[f, 1], out[f, 2], out[f, 3] = umin, umax, vmin, vmax
    return out
