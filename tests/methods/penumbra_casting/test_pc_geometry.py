"""Plane geometry of penumbra casting (``geometry``) on random blockers
(triangles, convex quads and hexagons) and light polygons: every hard
shadow volume lies in the penumbra volume, both forms of the line-70 test
agree, and the hard volume is exactly the segment test."""
import numpy as np
import pytest

from penumbra.core.methods.penumbra_casting.geometry import (MAXB, MAXP, blocked_by_edges, hard_volume, in_hard_volume,
                                                             penumbra_volume, point_in_volume,
                                                             receiver_edge_functions, triangle_plane)


def _random_blocker(rng, nb):
    """A random triangle (nb = 3), or a random convex planar polygon (nb = 4,
    6: a quad, a leaf's hexagon): corners on an ellipse at sorted angles, in
    a randomly turned plane; returned as float64[MAXB, 3] with the last
    corner repeated."""
    if nb == 3:
        tri = rng.normal(0, 1, (3, 3))
    else:
        ang = np.sort(rng.uniform(0, 2 * np.pi, nb))
        while np.diff(np.concatenate([ang, [ang[0] + 2 * np.pi]])).max() > 0.9 * np.pi:
            ang = np.sort(rng.uniform(0, 2 * np.pi, nb))
        ab = rng.uniform(0.3, 1.5, 2)
        flat = np.stack([ab[0] * np.cos(ang), ab[1] * np.sin(ang), np.zeros(nb)], axis=1)
        rot, _ = np.linalg.qr(rng.normal(0, 1, (3, 3)))
        tri = flat @ rot.T + rng.normal(0, 0.5, 3)
    out = np.empty((MAXB, 3))
    out[:nb] = tri
    out[nb:] = tri[nb - 1]
    return out


def _segment_crosses(poly, nb, r, l, margin=1e-9):
    """Segment r -> l (l excluded, r excluded) meets the convex polygon: as a
    fan of triangles (Moller-Trumbore); None when it passes within ``margin``
    of an edge of the fan or of an end point (undecidable in floating point)."""
    hit = False
    for j in range(1, nb - 1):
        a, b, c = poly[0], poly[j], poly[j + 1]
        e1, e2 = b - a, c - a
        d = l - r
        p = np.cross(d, e2)
        det = e1 @ p
        s = r - a
        u = s @ p / det
        q = np.cross(s, e1)
        v = d @ q / det
        t = e2 @ q / det
        if min(abs(u), abs(v), abs(1 - u - v), abs(t), abs(1 - t)) <= margin:
            return None
        hit |= (u >= 0) and (v >= 0) and (u + v <= 1) and (0 < t < 1)
    return hit


@pytest.mark.parametrize("nb", [3, 4, 6])
def test_penumbra_volume_contains_every_hard_volume(nb):
    """Random blockers (triangles; convex quads, section 5), light polygons
    (finite and directional) and points: whenever a sample in the polygon
    blocks r (exact hard volume test), r is inside the penumbra volume (no
    slack), and both hard volume forms agree."""
    rng = np.random.default_rng(3 + nb)
    out = np.zeros((4, MAXP))
    hv = np.zeros((MAXB + 1, 4))
    ef = np.zeros((MAXB, 4))
    tn = np.zeros(4)
    DE = np.array([[0, 1], [1, 2], [2, 3], [3, 0]] + [[0, 0]] * 12, np.int64)
    hits = 0
    for trial in range(90):
        tri = _random_blocker(rng, nb) + [0, 0, 2.0]
        directional = trial % 3 == 0
        a, b = rng.uniform(0.1, 1.5, 2)
        corners = np.array([[-a, -b], [a, -b], [a, b], [-a, b]])
        DV = np.zeros((16, 4))
        if directional:
            DV[:4, :2] = corners * 0.3
            DV[:4, 2] = 1.0
        else:
            DV[:4, :2] = corners + rng.normal(0, 0.5, 2)
            DV[:4, 2] = 5.0
            DV[:4, 3] = 1.0
        k = penumbra_volume(tri, nb, DV, 4, DE, 4, 1e-12, out)
        assert k >= 0
        triangle_plane(tri, nb, tn)
        uv = rng.uniform(0, 1, (24, 2))
        for r in rng.normal(0, 2.5, (80, 3)):
            rho = receiver_edge_functions(tri, nb, tn, r[0], r[1], r[2], ef)
            inside = point_in_volume(out[None], 0, k, -1, r[0], r[1], r[2], 0.0)
            for u, v in uv:
                p = (DV[0] * (1 - u) * (1 - v) + DV[1] * u * (1 - v) + DV[2] * u * v + DV[3] * (1 - u) * v)
                blk = hard_volume(tri, nb, p[0], p[1], p[2], p[3], hv) and in_hard_volume(hv, nb, r[0], r[1], r[2])
                assert blk == blocked_by_edges(ef, rho, tn, p[0], p[1], p[2], p[3])
                if blk:
                    hits += 1
                    assert inside
    assert hits > 300


@pytest.mark.parametrize("nb", [3, 4, 6])
def test_hard_volume_is_the_segment_test(nb):
    """V_l holds r iff the segment from r to l crosses T (Moller-Trumbore on
    T, or on the two triangles of a convex quad)."""
    rng = np.random.default_rng(4 + nb)
    hv = np.zeros((MAXB + 1, 4))
    ef = np.zeros((MAXB, 4))
    tn = np.zeros(4)
    n_in = n_out = 0
    for _ in range(3000):
        tri = _random_blocker(rng, nb)
        r, l = rng.normal(0, 2, 3), rng.normal(0, 2, 3)
        ok = hard_volume(tri, nb, l[0], l[1], l[2], 1.0, hv) and in_hard_volume(hv, nb, *r)
        triangle_plane(tri, nb, tn)
        rho = receiver_edge_functions(tri, nb, tn, r[0], r[1], r[2], ef)
        assert ok == blocked_by_edges(ef, rho, tn, l[0], l[1], l[2], 1.0)
        mt = _segment_crosses(tri, nb, r, l)
        if mt is not None:
            assert ok == mt
            n_in += ok
            n_out += not ok
    assert n_in > 100 and n_out > 100
