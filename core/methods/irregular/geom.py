"""Geometry kernels of soft irregular shadow mapping (Johnson et al. 2009).

* ``minor_segment_area``: equation 3, the normalized area of the unit disk
  inside the wedge spanned from its centre by a segment AB and beyond AB
  (the minor circular segment when A, B lie on the circle).
* ``rect_segment_area``: the same quantity for the square [-1, 1]^2 (the
  rectangle occlusion kernel section 2.3 allows, after Assarsson et al. 2003;
  a rectangle maps to the square by an affine map, which keeps area ratios).
* ``edge_occlusion``: one silhouette edge projected from a receiver onto the
  light's plane (homogeneous coordinates, so edges that reach the receiver's
  depth stay finite), clipped to the light and measured by one of the two.
* ``edge_side`` / ``blocks_centre``: the watertight orientation tests shared
  by the umbra (hard irregular shadow mapping: does the segment from the
  receiver to the light centre cross a triangle?) and the sign of each
  penumbra term (section 2.3: "the sign of the dot product of the edge
  equation and p"). Both use the same canonical edge orientation, so a
  receiver exactly on a shadow boundary is counted consistently by both.

* ``light_samples`` / ``count_beyond`` / ``overlap_from_counts``: equation 5's
  overlap C from the depth complexity at light samples (the region each
  term K_e measures, tested at the samples, counted with its sign).

Summing ``U + sum_e s_e K_e`` over the edges of one triangle gives the exact
fraction of the light covered by that triangle seen from the receiver (Green's
theorem over the projected triangle); equation 4 sums that over occluders.
"""
from __future__ import annotations

import math

import numpy as np

from ...jit import inner, kernel
from ...kernels import each_range

SHAPE_DISK = 0      # unit disk (disk, ellipse, sphere and sun lights)
SHAPE_SQUARE = 1    # [-1, 1]^2 (square and rectangle area lights)

# ``mode``: where silhouettes and "inside" are decided from (``silhouette_from``)
SILHOUETTE_CENTRE = 0   # the light centre (the paper)
SILHOUETTE_LIGHT = 1    # any point of the light; inside decided from each receiver

INV_2PI = 1.0 / (2.0 * math.pi)


# --------------------------------------------------------------------------
# 2D occlusion kernels (segment already clipped to the light shape)
@inner
def minor_segment_area(ax, ay, bx, by):
    """Equation 3 for a segment A-B inside the unit disk.

    d is the distance from the disk's centre to the line AB, w0 and w1 the
    signed distances of A and B from the foot of the perpendicular (w0
    measured backwards, so w0 + w1 = |AB|):

        theta = acos((d^2 - w0 w1) / sqrt((d^2 + w0^2)(d^2 + w1^2)))
        V''   = (theta - d (w0 + w1)) / (2 pi)

    i.e. (sector AOB - triangle AOB) / (disk area).
    """
    ex = bx - ax
    ey = by - ay
    L = math.sqrt(ex * ex + ey * ey)
    if not (L > 0.0):
        return 0.0
    ux = ex / L
    uy = ey / L
    ta = ax * ux + ay * uy
    tb = bx * ux + by * uy
    fx = ax - ta * ux
    fy = ay - ta * uy
    d = math.sqrt(fx * fx + fy * fy)
    w0 = -ta
    w1 = tb
    den = math.sqrt((d * d + w0 * w0) * (d * d + w1 * w1))
    if not (den > 0.0):
        return 0.0
    c = (d * d - w0 * w1) / den
    if c > 1.0:
        c = 1.0
    elif c < -1.0:
        c = -1.0
    theta = math.acos(c)
    v = (theta - d * (w0 + w1)) * INV_2PI
    return v if v > 0.0 else 0.0


@inner(forceinline=True)
def _square_exit(x, y):
    """Where the ray from the origin along (x, y) leaves [-1,1]^2, and the
    side: 0 (x = 1), 1 (y = 1), 2 (x = -1), 3 (y = -1)."""
    if abs(x) >= abs(y):
        m = abs(x)
        side = 0 if x > 0.0 else 2
    else:
        m = abs(y)
        side = 1 if y > 0.0 else 3
    return x / m, y / m, side


@inner
def square_sector(ax, ay, bx, by):
    """Area of the square [-1,1]^2 inside the wedge from the origin between
    directions A and B (the smaller angle): triangles from the origin to the
    boundary path exit(A) -> corners -> exit(B), walked counter-clockwise
    side by side (side s ends at corner s: (1,1), (-1,1), (-1,-1), (1,-1))."""
    if ax * by - ay * bx < 0.0:
        ax, ay, bx, by = bx, by, ax, ay
    px, py, sa = _square_exit(ax, ay)
    ex, ey, sb = _square_exit(bx, by)
    area = 0.0
    k = sa
    for _ in range(4):          # the wedge is under pi wide: at most 2 corners
        if k == sb:
            break
        qx = 1.0 if (k == 0 or k == 3) else -1.0
        qy = 1.0 if k < 2 else -1.0
        area += 0.5 * (px * qy - py * qx)
        px, py = qx, qy
        k = (k + 1) % 4
    area += 0.5 * (px * ey - py * ex)
    return area


@inner(forceinline=True)
def _square_sector_moment(ax, ay, bx, by):
    """``square_sector``'s region (A, B in counter-clockwise order): (area,
    first moments x, y), triangle by triangle from the origin."""
    px, py, sa = _square_exit(ax, ay)
    ex, ey, sb = _square_exit(bx, by)
    area, mx, my = 0.0, 0.0, 0.0
    k = sa
    for _ in range(5):
        last = k == sb
        qx = ex if last else (1.0 if (k == 0 or k == 3) else -1.0)
        qy = ey if last else (1.0 if k < 2 else -1.0)
        a = 0.5 * (px * qy - py * qx)
        area += a
        mx += a * (px + qx) / 3.0
        my += a * (py + qy) / 3.0
        if last:
            break
        px, py = qx, qy
        k = (k + 1) % 4
    return area, mx, my


@inner
def region_centroid(shape, ax, ay, bx, by):
    """Centroid of the region whose share ``segment_area`` measures for a
    clipped segment AB (the light's part in the wedge AOB beyond AB): the
    sector's first moment less the triangle OAB's, over their areas'
    difference; the segment's midpoint where that region is empty."""
    cab = ax * by - ay * bx
    if cab < 0.0:
        ax, ay, bx, by = bx, by, ax, ay
        cab = -cab
    tri = 0.5 * cab
    if shape == SHAPE_SQUARE:
        if (ax == 0.0 and ay == 0.0) or (bx == 0.0 and by == 0.0):
            return 0.5 * (ax + bx), 0.5 * (ay + by)
        sec, mx, my = _square_sector_moment(ax, ay, bx, by)
    else:
        ra = math.sqrt(ax * ax + ay * ay)
        rb = math.sqrt(bx * bx + by * by)
        if not (ra > 0.0) or not (rb > 0.0):
            return 0.5 * (ax + bx), 0.5 * (ay + by)
        ux, uy = ax / ra + bx / rb, ay / ra + by / rb        # the bisector
        un = math.sqrt(ux * ux + uy * uy)
        half = 0.5 * math.atan2(cab / (ra * rb), (ax * bx + ay * by) / (ra * rb))
        sec = half                                           # the unit disk's sector of angle 2 half
        m = (2.0 / 3.0) * math.sin(half) / un if un > 0.0 else 0.0
        mx, my = m * ux, m * uy
    area = sec - tri
    if not (area > 1e-12 * sec):
        return 0.5 * (ax + bx), 0.5 * (ay + by)
    return (mx - tri * (ax + bx) / 3.0) / area, (my - tri * (ay + by) / 3.0) / area


@inner
def rect_segment_area(ax, ay, bx, by):
    """Rectangle kernel: (square sector AOB - triangle AOB) / 4 for a segment
    inside [-1,1]^2 (the square's analogue of equation 3)."""
    if (ax == 0.0 and ay == 0.0) or (bx == 0.0 and by == 0.0):
        return 0.0
    tri = 0.5 * abs(ax * by - ay * bx)
    v = (square_sector(ax, ay, bx, by) - tri) * 0.25
    return v if v > 0.0 else 0.0


# --------------------------------------------------------------------------
# clipping a homogeneous 2D segment H(t) = H0 + t (H1 - H0), H = (x, y, w)
@inner(forceinline=True)
def _lb(f0, f1, t0, t1):
    """Liang-Barsky step for the constraint f(t) = f0 + t (f1 - f0) <= 0."""
    if f0 <= 0.0 and f1 <= 0.0:
        return t0, t1
    if f0 > 0.0 and f1 > 0.0:
        return 1.0, 0.0
    tc = f0 / (f0 - f1)
    if f0 > 0.0:
        return max(t0, tc), t1
    return t0, min(t1, tc)


@inner
def clip_homogeneous(shape, x0, y0, w0, x1, y1, w1, wmax):
    """Parameter interval [ta, tb] of the segment where 0 <= w <= wmax and
    (x/w, y/w) lies in the light shape; ta > tb when empty."""
    t0, t1 = _lb(-w0, -w1, 0.0, 1.0)
    if wmax < np.inf:
        t0, t1 = _lb(w0 - wmax, w1 - wmax, t0, t1)
    if t0 > t1:
        return 1.0, 0.0
    if shape == SHAPE_SQUARE:
        t0, t1 = _lb(x0 - w0, x1 - w1, t0, t1)
        t0, t1 = _lb(-x0 - w0, -x1 - w1, t0, t1)
        t0, t1 = _lb(y0 - w0, y1 - w1, t0, t1)
        t0, t1 = _lb(-y0 - w0, -y1 - w1, t0, t1)
        return t0, t1
    # disk: x^2 + y^2 - w^2 <= 0 on the w >= 0 nappe (a convex cone)
    dx = x1 - x0
    dy = y1 - y0
    dw = w1 - w0
    A = dx * dx + dy * dy - dw * dw
    B = x0 * dx + y0 * dy - w0 * dw
    C = x0 * x0 + y0 * y0 - w0 * w0
    # q(t) = A t^2 + 2 B t + C <= 0
    if A == 0.0:
        if B == 0.0:
            return (t0, t1) if C <= 0.0 else (1.0, 0.0)
        r = -C / (2.0 * B)
        if B > 0.0:
            return t0, min(t1, r)
        return max(t0, r), t1
    disc = B * B - A * C
    if disc < 0.0:
        if A > 0.0:
            return 1.0, 0.0
        return t0, t1
    s = math.sqrt(disc)
    qq = -(B + (s if B >= 0.0 else -s))
    if qq != 0.0:
        r1 = qq / A
        r2 = C / qq
    else:
        r1 = 0.0
        r2 = 0.0
    lo = min(r1, r2)
    hi = max(r1, r2)
    if A > 0.0:
        return max(t0, lo), min(t1, hi)
    # A < 0: q <= 0 outside [lo, hi]; on the w >= 0 part only one side is
    # inside the cone: keep the longer piece
    a0, a1 = t0, min(t1, lo)
    b0, b1 = max(t0, hi), t1
    if a1 - a0 >= b1 - b0:
        return a0, a1
    return b0, b1


@inner
def clipped_edge(shape, x0, y0, w0, x1, y1, w1, wmax):
    """One projected edge (homogeneous endpoints) clipped to the light:
    (ok, ax, ay, bx, by), the endpoints in unit-shape coordinates."""
    ta, tb = clip_homogeneous(shape, x0, y0, w0, x1, y1, w1, wmax)
    if not (tb > ta):
        return False, 0.0, 0.0, 0.0, 0.0
    xa = x0 + ta * (x1 - x0)
    ya = y0 + ta * (y1 - y0)
    wa = w0 + ta * (w1 - w0)
    xb = x0 + tb * (x1 - x0)
    yb = y0 + tb * (y1 - y0)
    wb = w0 + tb * (w1 - w0)
    if not (wa > 0.0) or not (wb > 0.0):
        return False, 0.0, 0.0, 0.0, 0.0
    ax, ay = xa / wa, ya / wa
    bx, by = xb / wb, yb / wb
    if shape != SHAPE_SQUARE:
        # clipping is exact up to rounding: keep the points in the disk
        ra = ax * ax + ay * ay
        if ra > 1.0:
            ra = math.sqrt(ra)
            ax /= ra
            ay /= ra
        rb = bx * bx + by * by
        if rb > 1.0:
            rb = math.sqrt(rb)
            bx /= rb
            by /= rb
    return True, ax, ay, bx, by


@inner(forceinline=True)
def segment_area(shape, ax, ay, bx, by):
    """Equation 3 (disk) or the rectangle kernel of a clipped segment."""
    if shape == SHAPE_SQUARE:
        return rect_segment_area(ax, ay, bx, by)
    return minor_segment_area(ax, ay, bx, by)


@inner
def edge_occlusion(shape, x0, y0, w0, x1, y1, w1, wmax):
    """Unsigned occlusion term of one projected edge (homogeneous endpoints):
    clip to the light, then equation 3 (disk) or the rectangle kernel."""
    ok, ax, ay, bx, by = clipped_edge(shape, x0, y0, w0, x1, y1, w1, wmax)
    if not ok:
        return 0.0
    return segment_area(shape, ax, ay, bx, by)


# --------------------------------------------------------------------------
# occluder overlap (equation 5's C) from the depth complexity at light samples
def light_samples(shape: int, m: int):
    """The light samples of the overlap estimate, in rows: the centres of an
    m x m grid of equal cells over [-1, 1]^2 that lie in the unit light
    shape (all of them for the square; symmetric about both axes). Returns
    rows float64[R, 3] (y, x of the row's first sample, spacing) and first
    int64[R + 1] (index of each row's first sample; first[-1] = count)."""
    if m <= 0:
        return np.zeros((0, 3)), np.zeros(1, np.int64)
    dx = 2.0 / m
    u = -1.0 + dx * (np.arange(m) + 0.5)
    rows, first = [], [0]
    for y in u:
        x = u if shape == SHAPE_SQUARE else u[u * u + y * y <= 1.0]
        if len(x):
            rows.append((y, x[0], dx))
            first.append(first[-1] + len(x))
    return np.array(rows, np.float64).reshape(-1, 3), np.array(first, np.int64)


@inner(forceinline=True)
def _half_line(a, b, lo, hi):
    """Intersect the interval [lo, hi] with {x : a x + b >= 0}."""
    if a > 0.0:
        return max(lo, -b / a), hi
    if a < 0.0:
        return lo, min(hi, -b / a)
    if b < 0.0:
        return 1.0, 0.0
    return lo, hi


@inner
def count_beyond(ax, ay, bx, by, sign, ls, s):
    """Add ``sign`` to the depth complexity ``ls.counts[s, j]`` of every light
    sample j in the region whose area the edge's term measures: inside the
    wedge from the light centre O between OA and OB and beyond AB (so that
    umbra count + these counts = the number of occluders covering sample j,
    Laine et al. 2005's depth complexity). Per sample row the region is an
    interval of x (three half-planes). int8 counts wrap: exact while fewer
    than 128 layers separate a sample from the centre."""
    cab = ax * by - ay * bx
    if cab == 0.0:
        return
    if cab < 0.0:
        ax, ay, bx, by = bx, by, ax, ay
    ex = bx - ax
    ey = by - ay
    rows, first, counts = ls.rows, ls.first, ls.counts
    for r in range(rows.shape[0]):
        y, x0, dx = rows[r, 0], rows[r, 1], rows[r, 2]
        k = first[r + 1] - first[r]
        lo, hi = _half_line(-ay, ax * y, x0 - dx, x0 + k * dx)      # left of OA
        lo, hi = _half_line(by, -bx * y, lo, hi)                     # right of OB
        lo, hi = _half_line(ey, -ex * (y - ay) - ey * ax, lo, hi)    # beyond AB
        if not (hi >= lo):
            continue
        i0 = max(int(math.ceil((lo - x0) / dx)), 0)
        i1 = min(int(math.floor((hi - x0) / dx)), k - 1)
        for i in range(first[r] + i0, first[r] + i1 + 1):
            counts[s, i] += sign


def overlap_from_counts(umbra, counts, threads=None, rows=None, first=None, RF=None):
    """Equation 5's C per receiver: the mean over the light samples of the
    occluders counted beyond the first, max(U + count_j - 1, 0); with the
    samples' ``rows`` and ``first`` (``light_samples``) and the receivers'
    frames ``RF`` (``light.receiver_frames``), the mean weighted by the
    light's emission, linear over it: sample j at (x_j, y_j) weighs 1 +
    RF[s, 12:14] . (x_j, y_j) (the samples are symmetric about the centre:
    the weights' mean is 1). Ranges of receivers on Numba's thread count
    (``kernels.each_range``)."""
    C = np.zeros(counts.shape[0])
    if counts.shape[1] and RF is not None:
        xs = np.concatenate([x0 + dx * np.arange(first[r + 1] - first[r]) for r, (_, x0, dx) in enumerate(rows)])
        ys = np.repeat(rows[:, 0], np.diff(first))
        each_range(lambda i0, i1: _overlap_weighted(i0, i1, umbra, counts, xs, ys, RF, C), counts.shape[0],
                   threads)
    elif counts.shape[1]:
        each_range(lambda i0, i1: _overlap_from_counts(i0, i1, umbra, counts, C), counts.shape[0], threads)
    return C


@kernel(nogil=True)
def _overlap_weighted(i0, i1, umbra, counts, xs, ys, RF, C):
    """``overlap_from_counts`` weighted, for receivers i0..i1-1 into ``C``
    (the samples at (xs[j], ys[j]))."""
    m = counts.shape[1]
    for s in range(i0, i1):
        acc, accx, accy = 0.0, 0.0, 0.0
        for j in range(m):
            d = umbra[s] + counts[s, j] - 1
            if d > 0:
                acc += d
                accx += d * xs[j]
                accy += d * ys[j]
        C[s] = (acc + RF[s, 12] * accx + RF[s, 13] * accy) / m


@kernel(nogil=True)
def _overlap_from_counts(i0, i1, umbra, counts, C):
    """``overlap_from_counts`` for receivers i0..i1-1 into ``C``."""
    m = counts.shape[1]
    for s in range(i0, i1):
        acc = 0
        for j in range(m):
            d = umbra[s] + counts[s, j] - 1
            if d > 0:
                acc += d
        C[s] = acc / m


@inner
def clip_and_occlude_2d(shape, ax, ay, bx, by):
    """Occlusion term of a plain 2D segment (w = 1) against the unit light
    shape; for tests and for the closed-form checks."""
    return edge_occlusion(shape, ax, ay, 1.0, bx, by, 1.0, np.inf)


# --------------------------------------------------------------------------
# watertight orientation tests
@inner(forceinline=True)
def edge_side(px, py, pz, dx, dy, dz, ax, ay, az, bx, by, bz):
    """Sign (+1/-1) of d . ((a - p) x (b - p)): which side of the directed
    edge a->b the line from p along d passes. The product is always computed
    with the edge's endpoints in lexicographic order and negated for the
    other direction, and 0 counts as +1 in that canonical order, so the two
    triangles sharing an edge always disagree (no double counts, no gaps)."""
    flip = 1
    if bx < ax or (bx == ax and (by < ay or (by == ay and bz < az))):
        ax, ay, az, bx, by, bz = bx, by, bz, ax, ay, az
        flip = -1
    ux = ax - px
    uy = ay - py
    uz = az - pz
    vx = bx - px
    vy = by - py
    vz = bz - pz
    val = dx * (uy * vz - uz * vy) + dy * (uz * vx - ux * vz) + dz * (ux * vy - uy * vx)
    return flip if val >= 0.0 else -flip


@inner(forceinline=True)
def tri_side_of_receiver(px, py, pz, tv, nv, t):
    """Sign of D_p = (v0 - p) . N_T (0 when p lies in the triangle's plane)."""
    dp = ((tv[t, 0, 0] - px) * nv[t, 0] + (tv[t, 0, 1] - py) * nv[t, 1]
          + (tv[t, 0, 2] - pz) * nv[t, 2])
    if dp > 0.0:
        return 1
    if dp < 0.0:
        return -1
    return 0


@inner(forceinline=True)
def blocks_centre(px, py, pz, dx, dy, dz, tv, nv, side_light, t, is_sun):
    """Hard irregular shadow mapping test: does triangle t lie on the segment
    from p to the light centre (local lights: d = c - p, ``side_light`` =
    sign of (v0 - c) . N) or on the ray from p towards the sun (d = the
    direction, ``side_light`` = sign of d . N)?"""
    sd = tri_side_of_receiver(px, py, pz, tv, nv, t)
    if sd == 0:
        return False
    if is_sun:
        if side_light != sd:
            return False
    elif side_light * sd >= 0:
        return False
    for k in range(3):
        k1 = (k + 1) % 3
        if edge_side(px, py, pz, dx, dy, dz,
                     tv[t, k, 0], tv[t, k, 1], tv[t, k, 2],
                     tv[t, k1, 0], tv[t, k1, 1], tv[t, k1, 2]) != sd:
            return False
    return True


@inner(forceinline=True)
def penumbra_term(px, py, pz, dx, dy, dz, tv, nv, fl, ot, mode, t, k, lit, RF, s, ls):
    """Signed term of edge k of triangle t at receiver p (section 2.3):
    + minor-segment area when p is outside the edge, - when inside.
    ``lit``: grid.KernelLight; ``RF[s]``: receiver s's frame (below).

    ``mode`` SILHOUETTE_CENTRE (the paper): "inside" is decided by the edge equation in the
    light view (p' on the triangle's side of the edge's image from the light
    centre; ``fl`` = the triangle's facing towards the light). Interior edges
    of a consistently wound mesh then cancel exactly for every receiver, so
    silhouettes only need to be found from the centre (2.1); each triangle
    contributes its projected area signed by whether it lies between p and
    the light's centre plane (5.1's single point of projection).
    ``mode`` SILHOUETTE_LIGHT (receiver): "inside" is decided in the projection from p
    itself, which makes the sum over a triangle's edges its exact projected
    area; triangles of closed meshes only count when they face p (``ot`` =
    orientation of the closed component, 0 = open surface: always).

    Local lights: the edge is projected from p onto the light's plane (frame
    c, e1/s1, e2/s2 scaled so the light is the unit shape, n towards p,
    h_p = (p - c).n); a point q maps to the homogeneous point
    ((q-c).e1 - lam p2x, (q-c).e2 - lam p2y, 1 - lam), lam = (q-c).n / h_p,
    and only 0 <= lam <= 1 (between the light and the receiver) occludes.
    Sun: gnomonic projection of the direction q - p (e1, e2 scaled by
    1/tan(half angle), n = direction to the sun).
    ``ls``: grid.LightSamples (no rows: the paper's C = 0); the term's sign
    is added to ``ls.counts[s]`` at the samples inside the region it measures."""
    shape, cx, cy, cz, is_sun = lit.shape, lit.cx, lit.cy, lit.cz, lit.is_sun
    e1x, e1y, e1z, e2x, e2y, e2z = RF[s, 0], RF[s, 1], RF[s, 2], RF[s, 3], RF[s, 4], RF[s, 5]
    nx, ny, nz, hp, p2x, p2y = RF[s, 6], RF[s, 7], RF[s, 8], RF[s, 9], RF[s, 10], RF[s, 11]
    if mode == SILHOUETTE_CENTRE:
        ref = fl
        if ref == 0:
            return 0.0
    else:
        ref = tri_side_of_receiver(px, py, pz, tv, nv, t)
        if ref == 0 or ref * ot > 0:
            return 0.0
    k1 = (k + 1) % 3
    ax, ay, az = tv[t, k, 0], tv[t, k, 1], tv[t, k, 2]
    bx, by, bz = tv[t, k1, 0], tv[t, k1, 1], tv[t, k1, 2]
    if is_sun:
        rx, ry, rz = ax - px, ay - py, az - pz
        x0 = rx * e1x + ry * e1y + rz * e1z
        y0 = rx * e2x + ry * e2y + rz * e2z
        w0 = rx * nx + ry * ny + rz * nz
        rx, ry, rz = bx - px, by - py, bz - pz
        x1 = rx * e1x + ry * e1y + rz * e1z
        y1 = rx * e2x + ry * e2y + rz * e2z
        w1 = rx * nx + ry * ny + rz * nz
        wmax = np.inf
    else:
        rx, ry, rz = ax - cx, ay - cy, az - cz
        lam = (rx * nx + ry * ny + rz * nz) / hp
        x0 = rx * e1x + ry * e1y + rz * e1z - lam * p2x
        y0 = rx * e2x + ry * e2y + rz * e2z - lam * p2y
        w0 = 1.0 - lam
        rx, ry, rz = bx - cx, by - cy, bz - cz
        lam = (rx * nx + ry * ny + rz * nz) / hp
        x1 = rx * e1x + ry * e1y + rz * e1z - lam * p2x
        y1 = rx * e2x + ry * e2y + rz * e2z - lam * p2y
        w1 = 1.0 - lam
        wmax = 1.0
    ok, ax2, ay2, bx2, by2 = clipped_edge(shape, x0, y0, w0, x1, y1, w1, wmax)
    if not ok:
        return 0.0
    K = segment_area(shape, ax2, ay2, bx2, by2)
    if K == 0.0:
        return 0.0
    gx, gy = RF[s, 12], RF[s, 13]
    if gx != 0.0 or gy != 0.0:        # the light's emission, linear over it: exact at the region's centroid
        cx, cy = region_centroid(shape, ax2, ay2, bx2, by2)
        K *= 1.0 + gx * cx + gy * cy
    inside = edge_side(px, py, pz, dx, dy, dz, ax, ay, az, bx, by, bz) == ref
    if ls.rows.shape[0]:
        count_beyond(ax2, ay2, bx2, by2, -1 if inside else 1, ls, s)
    return -K if inside else K
