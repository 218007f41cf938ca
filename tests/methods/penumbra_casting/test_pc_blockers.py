"""Blocker polygons of penumbra casting (``blockers``): coplanar convex
triangle groups merged into one polygon (Laine & Aila 2005, section 5:
several blocker triangles processed at once) are exactly the union of their
triangles, and casting them changes no blocked relation except rays within
rounding of a removed inner edge; the coarse sort by area (section 3.3)."""
import numpy as np
import pytest

from pc_helpers import run_pc
from penumbra.core.methods.penumbra_casting import scene_blockers
from penumbra.core.methods.penumbra_casting.blockers import (MAXB, PLANE_ULPS, _unique_vertices, bucket_sort_by_area,
                                                             coplanar_blockers, pad_triangles)


def _area(tris):
    return 0.5 * np.linalg.norm(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]), axis=1)


def check_partition(tris, polys, nv, poly_of):
    """Every polygon: at most MAXB corners, planar within the tolerance,
    strictly convex, its area the sum of its triangles' areas, and every
    corner of those triangles on it (so, the triangles not overlapping, the
    polygon is their union)."""
    assert len(poly_of) == len(tris) and poly_of.min() >= 0 and poly_of.max() == len(polys) - 1
    assert ((nv >= 3) & (nv <= MAXB)).all()
    tri_area = _area(tris)
    for m in range(len(polys)):
        k = nv[m]
        P = polys[m, :k]
        assert (polys[m, k:] == P[-1]).all()                 # padding: the last corner
        mine = tris[poly_of == m]
        mag = max(np.abs(P).max(), np.abs(mine).max())
        tol = 2 * PLANE_ULPS * 2.0 ** -23 * mag
        c = P.mean(0)
        n = sum(np.cross(P[j] - c, P[(j + 1) % k] - c) for j in range(k))
        area = 0.5 * np.linalg.norm(n)
        n = n / np.linalg.norm(n)
        assert np.abs((mine.reshape(-1, 3) - c) @ n).max() <= tol
        for j in range(k):
            turn = np.cross(P[j] - P[j - 1], P[(j + 1) % k] - P[j]) @ n
            assert turn > 0.0, (m, j)
            # every triangle corner inside (or on) this edge
            e = P[(j + 1) % k] - P[j]
            side = np.cross(e, mine.reshape(-1, 3) - P[j]) @ n / np.linalg.norm(e)
            assert side.min() >= -tol
        assert area == pytest.approx(tri_area[poly_of == m].sum(), rel=1e-5)


def subdivided_plane(nx, ny, turn=0.0, offset=(0.0, 0.0, 0.0), dtype=np.float32):
    x, y = np.meshgrid(np.linspace(-1, 1, nx + 1), np.linspace(-0.5, 0.5, ny + 1), indexing="ij")
    V = np.stack([x, y, np.zeros_like(x)], -1)
    c, s = np.cos(turn), np.sin(turn)
    R = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]) @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    V = (V @ R.T + offset).astype(dtype).astype(np.float64)
    tris = []
    for i in range(nx):
        for j in range(ny):
            a, b, cc, d = V[i, j], V[i + 1, j], V[i + 1, j + 1], V[i, j + 1]
            tris += [[a, b, cc], [a, cc, d]] if (i + j) % 2 else [[a, b, d], [b, cc, d]]
    return np.array(tris)


def test_grids_bar_faces_become_rectangles():
    """GRIDS: 3 lattices of 2 x 16 bars, each a box of 4 long faces split in
    32 segments plus 2 end caps, and the ground quad: 3 * 32 * 6 + 1 = 577
    rectangles (the turned lattices' float32 corners included)."""
    from scenes import load_sample
    scene = load_sample("grids", (32, 32))
    tris = scene_blockers(scene)
    polys, nv, poly_of = coplanar_blockers(tris)
    assert len(tris) == 3 * 32 * (4 * 32 * 2 + 2 * 2) + 2
    assert len(polys) == 3 * 32 * 6 + 1
    assert (nv == 4).all()
    check_partition(tris, polys, nv, poly_of)


@pytest.mark.parametrize("turn", [0.0, 0.3, 1.1])
def test_subdivided_plane_merges_into_strips(turn):
    """An 8 x 3 grid of quads (alternating diagonals), turned and moved, in
    float32: each polygon grows across whole triangle edges only, so at best
    one strip per column or row; never a triangle left over."""
    tris = subdivided_plane(8, 3, turn, offset=(3.0, -2.0, 5.0))
    polys, nv, poly_of = coplanar_blockers(tris)
    check_partition(tris, polys, nv, poly_of)
    assert len(polys) <= 8 and (nv == 4).all()


def test_non_planar_and_concave_stay_apart():
    """A folded strip (two planes) and an L-shape (concave union): no polygon
    spans the fold, and the L's polygons are convex; a triangle fan of a
    regular hexagon merges into polygons of at most MAXB corners."""
    flat = subdivided_plane(4, 1)
    folded = flat.copy()
    right = folded[..., 0] > 0
    folded[..., 2] = np.where(right, folded[..., 0] * 0.01, 0.0)
    polys, nv, poly_of = coplanar_blockers(folded)
    check_partition(folded, polys, nv, poly_of)
    for m in range(len(polys)):
        xs = folded[poly_of == m][..., 0]
        assert xs.min() >= -1e-12 or xs.max() <= 1e-12
    # L: three unit squares
    sq = lambda x, y: [[[x, y, 0], [x + 1, y, 0], [x + 1, y + 1, 0]], [[x, y, 0], [x + 1, y + 1, 0], [x, y + 1, 0]]]
    L = np.array(sq(0, 0) + sq(1, 0) + sq(0, 1), float)
    polys, nv, poly_of = coplanar_blockers(L)
    check_partition(L, polys, nv, poly_of)
    assert len(polys) >= 2
    ang = np.arange(6) * np.pi / 3
    ring = np.stack([np.cos(ang), np.sin(ang), np.zeros(6)], 1)
    fan = np.array([[np.zeros(3), ring[j], ring[(j + 1) % 6]] for j in range(6)])
    polys, nv, poly_of = coplanar_blockers(fan)
    check_partition(fan, polys, nv, poly_of)
    assert len(polys) < 6


def test_degenerate_and_unshared_triangles_pass_through():
    """Zero-area triangles and isolated ones stay triangles, unchanged."""
    rng = np.random.default_rng(2)
    tris = rng.normal(0, 1, (20, 3, 3))
    tris[3, 2] = tris[3, 1]                       # zero area
    polys, nv, poly_of = coplanar_blockers(tris)
    assert (nv == 3).all() and len(polys) == 20
    ref, ref_nv = pad_triangles(tris)
    assert np.array_equal(polys[poly_of], ref) and np.array_equal(ref_nv, nv)


@pytest.mark.parametrize("name", ["grids", "sphere_plane", "torus_plane"])
def test_polygons_block_what_their_triangles_block(name):
    """The same receivers and light samples cast with and without merging:
    only relations within rounding of a removed inner edge may differ."""
    from scenes import load_sample
    scene = load_sample(name, (64, 64))
    out = {merged: run_pc(scene, samples=64, coplanar_blockers=merged)[2:] for merged in (True, False)}
    (Vm, sm), (Vt, st) = out[True], out[False]
    assert sm["blockers"] < st["blockers"]
    diff = np.abs(Vm - Vt) * 64
    assert diff.sum() <= 2, diff.sum()           # blocked relations that differ
    assert sm["nodes_visited"] < st["nodes_visited"]


def test_unique_vertices_is_numpy_unique():
    """The lexsort vertex identity gives np.unique(axis=0)'s vertices and
    ids exactly: 5000 corners on a 7^3 lattice (many repeats), -0.0 included."""
    rng = np.random.default_rng(7)
    V = rng.integers(-3, 4, (5000, 3)).astype(np.float32).astype(np.float64) * 0.25
    V[11, :] = [-0.0, 0.0, 0.25]
    V[12, :] = [0.0, -0.0, 0.25]
    P, inv = _unique_vertices(V)
    Pn, invn = np.unique(V, axis=0, return_inverse=True)
    assert np.array_equal(P, Pn) and np.array_equal(inv, invn.ravel())
    assert np.array_equal(P[inv], V)
    assert inv[11] == inv[12]


def test_coarse_sort_is_largest_first_by_bucket():
    """Triangles over five decades of size: the order holds each once, its
    log-area buckets ascend from the largest, and the first bucket's areas
    all exceed the others'."""
    rng = np.random.default_rng(6)
    s = 10.0 ** rng.uniform(-4, 1, 500)
    tris = rng.normal(0, 1, (500, 3, 3)) * s[:, None, None]
    order = bucket_sort_by_area(tris, np.full(len(tris), 3), 8)
    area = 0.5 * np.linalg.norm(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]), axis=1)
    la = np.log(area[order])
    b = np.minimum(7, ((la.max() - la) / (la.max() - la.min()) * 8).astype(int))
    assert sorted(order) == list(range(500))
    assert np.all(np.diff(b) >= 0)
    assert b[0] == 0 and b[-1] == 7            # coarse: buckets in order, stable inside one
    assert area[order[:np.sum(b == 0)]].min() > area[order[np.sum(b == 0):]].max()


def test_coarse_sort_takes_a_polygons_area_from_all_its_corners():
    """Blocker polygons (corners past ``nverts`` repeated, as the merge
    stores them) are bucketed by their whole area: regular triangles,
    squares and hexagons of circumradius r in any orientation, whose area
    is n sin(2 pi / n) r^2 / 2 (closed form)."""
    rng = np.random.default_rng(9)
    polys, nv, area = [], [], []
    for k in range(300):
        kind = k % 3
        n = (3, 4, 6)[kind]
        size = 10.0 ** rng.uniform(-3, 1)
        ang = np.arange(n) * 2 * np.pi / n
        pts = np.stack([np.cos(ang), np.sin(ang), np.zeros(n)], 1) * size
        R, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        pts = pts @ R.T + rng.normal(0, 5, 3)
        p = np.repeat(pts[-1:], MAXB, 0)
        p[:n] = pts
        polys.append(p)
        nv.append(n)
        area.append(0.5 * n * np.sin(2 * np.pi / n) * size ** 2)    # regular n-gon of circumradius size
    polys, nv, area = np.array(polys), np.array(nv, np.int64), np.array(area)
    order = bucket_sort_by_area(polys, nv, 8)
    la = np.log(area)
    b = np.minimum(7, ((la.max() - la) / (la.max() - la.min()) * 8).astype(int))
    assert sorted(order) == list(range(len(area)))
    assert np.all(np.diff(b[order]) >= 0)
    assert np.all(np.diff(order[b[order] == 3]) > 0)       # stable inside a bucket
