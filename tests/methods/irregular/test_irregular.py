"""Soft irregular shadow mapping (Johnson et al. 2009), method ``irregular``.

Closed forms (equation 3 and the rectangle kernel against numeric
integration, the half-plane penumbra), one occluding triangle against a
numerically integrated light, the sample scenes against ``embree`` at 256
samples, the zero-size light against Embree's rays to the light centre, the
C = 0 identity of equation 4 against an exact layer count, the sampled
overlap C of equation 5 (closed forms of overlapping strips, foliage-like
scenes against embree, the paper's C = 0 kept bit for bit), the overdraw
reductions against brute force, and the hard cases of DESIGN.md: the average
pass (equation 2); the irradiance pass against ``embree_irr``.
"""
import dataclasses
import math

import numpy as np
import pytest
from numba import njit

from penumbra.core.buffers import FrameBuffers
from penumbra.core.methods.irregular.geom import (SHAPE_DISK, SHAPE_SQUARE, clip_and_occlude_2d,
                                             minor_segment_area, rect_segment_area, region_centroid)
from penumbra.core.methods.irregular.mesh import mesh_adjacency
from penumbra.core.methods.irregular import IrregularParams, soft_irregular
from penumbra.core.scene import Camera, Light, ObjectInfo, Scene
from penumbra.core.views import look_rotation
from helpers import buffers_of, embree_pass, in_range, run_method
from synthetic import (area_light, half_plane_scene, light_matrix, make_scene, quad, sphere_light,
                       sun_light, top_ortho_camera)

MODES = ("centre", "light")
REF_SAMPLES = 256
# a 256-sample reference cannot resolve differences below half a sample
REF_RESOLUTION = 0.5 / REF_SAMPLES


def run(scene, light=None, **over):
    """``irregular``'s MethodResult on the scene's own buffers, and the
    buffers: the average pass (equation 2, as ``reference``) unless
    ``visibility`` is given."""
    fb = buffers_of(scene)
    over.setdefault("visibility", "average")
    return run_method("irregular", fb, light or scene.lights[0], **over), fb


def reference(fb, light, samples=REF_SAMPLES):
    return embree_pass(fb, light, samples)


def dilate(mask, r):
    out = mask.copy()
    for dy in range(-r, r + 1):
        for dx in range(-r, r + 1):
            out |= np.roll(np.roll(mask, dy, 0), dx, 1)
    return out


# --------------------------------------------------------------------------
# equation 3 and the rectangle kernel
def _numeric_region(shape, ax, ay, bx, by, n=1601, centroid=False):
    """Area fraction of the light shape inside the wedge AOB and beyond the
    line AB, by midpoint integration on an n x n grid (``centroid``: the
    region's centroid)."""
    h = 2.0 / n
    c = -1.0 + h * (np.arange(n) + 0.5)
    X, Y = np.meshgrid(c, c)
    inside = (X * X + Y * Y <= 1.0) if shape == SHAPE_DISK else np.ones_like(X, bool)
    cab = ax * by - ay * bx
    s = 1.0 if cab >= 0 else -1.0
    wedge = (s * (ax * Y - ay * X) >= 0) & (s * (X * by - Y * bx) >= 0)
    ex, ey = bx - ax, by - ay
    side_o = np.sign(ex * (0 - ay) - ey * (0 - ax))
    beyond = np.sign(ex * (Y - ay) - ey * (X - ax)) == -side_o
    total = math.pi if shape == SHAPE_DISK else 4.0
    region = inside & wedge & beyond
    if centroid:
        return X[region].mean(), Y[region].mean()
    return region.sum() * h * h / total


@pytest.mark.parametrize("d", [0.0, 0.1, 0.35, 0.6, 0.9, 0.99])
def test_equation3_full_chord_is_the_minor_circular_segment(d):
    w = math.sqrt(1 - d * d)
    theta = 2 * math.acos(d)
    exact = (theta - math.sin(theta)) / (2 * math.pi)
    assert minor_segment_area(-w, d, w, d) == pytest.approx(exact, abs=1e-12)
    assert minor_segment_area(w, d, -w, d) == pytest.approx(exact, abs=1e-12)   # orientation-free
    # and the same chord reached by clipping a long line
    assert clip_and_occlude_2d(SHAPE_DISK, -5.0, d, 7.0, d) == pytest.approx(exact, abs=1e-12)
    if d > 0:
        assert _numeric_region(SHAPE_DISK, -5.0, d, 7.0, d) == pytest.approx(exact, abs=2e-3)


def test_equation3_against_numeric_integration_of_a_clipped_disk():
    """Segments with endpoints inside, outside, one of each, rotated: equation
    3 (with clipping) equals the integrated area of the disk inside the wedge
    and beyond the segment."""
    rng = np.random.default_rng(3)
    for _ in range(24):
        a = rng.uniform(-1.4, 1.4, 2)
        b = rng.uniform(-1.4, 1.4, 2)
        got = clip_and_occlude_2d(SHAPE_DISK, a[0], a[1], b[0], b[1])
        want = _numeric_region(SHAPE_DISK, a[0], a[1], b[0], b[1])
        assert got == pytest.approx(want, abs=2.5e-3), (a, b)


def test_rectangle_kernel_against_numeric_integration():
    rng = np.random.default_rng(4)
    for _ in range(24):
        a = rng.uniform(-1.6, 1.6, 2)
        b = rng.uniform(-1.6, 1.6, 2)
        got = clip_and_occlude_2d(SHAPE_SQUARE, a[0], a[1], b[0], b[1])
        want = _numeric_region(SHAPE_SQUARE, a[0], a[1], b[0], b[1])
        assert got == pytest.approx(want, abs=2.5e-3), (a, b)
    # a full chord at height d cuts off (1 - d) / 2 of the square
    for d in (0.0, 0.3, 0.8):
        assert rect_segment_area(-1.0, d, 1.0, d) == pytest.approx((1 - d) / 2, abs=1e-12)


@pytest.mark.parametrize("shape", [SHAPE_DISK, SHAPE_SQUARE])
def test_region_centroid_against_numeric_integration(shape):
    """The centroid of the region a clipped segment's term measures (the
    irradiance pass weighs the term by the light's emission there) against
    the integrated one, for segments inside the light and reaching its
    border."""
    rng = np.random.default_rng(8 + shape)
    checked = 0
    for _ in range(40):
        a, b = rng.uniform(-1.0, 1.0, 2), rng.uniform(-1.0, 1.0, 2)
        if shape == SHAPE_DISK:
            a, b = a / max(1.0, np.hypot(*a)), b / max(1.0, np.hypot(*b))
        if _numeric_region(shape, a[0], a[1], b[0], b[1], n=801) < 0.01:
            continue                      # too small for the grid
        got = region_centroid(shape, a[0], a[1], b[0], b[1])
        want = _numeric_region(shape, a[0], a[1], b[0], b[1], n=801, centroid=True)
        assert np.allclose(got, want, atol=6e-3), (a, b, got, want)
        checked += 1
    assert checked > 15


@pytest.mark.parametrize("shape", [SHAPE_DISK, SHAPE_SQUARE])
def test_edge_terms_compose_to_the_covered_area(shape):
    """Section 2.3-2.4 in 2D: [centre inside] + sum of the signed edge terms
    (+ outside the edge, - inside) is the covered fraction of the light."""
    rng = np.random.default_rng(5 + shape)
    n = 1201
    h = 2.0 / n
    c = -1.0 + h * (np.arange(n) + 0.5)
    X, Y = np.meshgrid(c, c)
    light = (X * X + Y * Y <= 1.0) if shape == SHAPE_DISK else np.ones_like(X, bool)
    for _ in range(12):
        v = rng.uniform(-1.5, 1.5, (3, 2))
        area2 = (v[1, 0] - v[0, 0]) * (v[2, 1] - v[0, 1]) - (v[1, 1] - v[0, 1]) * (v[2, 0] - v[0, 0])
        if abs(area2) < 0.05:
            continue
        sgn = np.sign(area2)
        inside_all = np.ones_like(X, bool)
        total = 0.0
        centre_in = True
        for k in range(3):
            a, b = v[k], v[(k + 1) % 3]
            e = sgn * ((b[0] - a[0]) * (Y - a[1]) - (b[1] - a[1]) * (X - a[0]))
            inside_all &= e >= 0
            o_in = sgn * ((b[0] - a[0]) * (0 - a[1]) - (b[1] - a[1]) * (0 - a[0])) >= 0
            centre_in &= bool(o_in)
            K = clip_and_occlude_2d(shape, a[0], a[1], b[0], b[1])
            total += -K if o_in else K
        total += 1.0 if centre_in else 0.0
        want = (light & inside_all).sum() * h * h / (math.pi if shape == SHAPE_DISK else 4.0)
        assert total == pytest.approx(want, abs=3e-3)


# --------------------------------------------------------------------------
# one occluding triangle, whole pipeline, against a numerically integrated light
def _light_points(light, p, n=160):
    """n*n stratified points on the light's domain as seen from p (world)."""
    u = (np.arange(n) + 0.5) / n
    U, Vv = np.meshgrid(u, u)
    U, Vv = U.ravel(), Vv.ravel()
    m = light.world_from_light
    if light.kind == "area":
        x, y = 2 * U - 1, 2 * Vv - 1
        if light.shape in ("DISK", "ELLIPSE"):
            keep = x * x + y * y <= 1
            x, y = x[keep], y[keep]
        x, y = x * light.size / 2, y * light.size_y / 2
        return light.position + np.outer(x, m[:3, 0]) + np.outer(y, m[:3, 1]), False
    if light.kind == "sphere":
        w = light.position - p
        w /= np.linalg.norm(w)
        e1 = np.cross(w, [1.0, 0, 0] if abs(w[0]) < 0.9 else [0, 1.0, 0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(w, e1)
        x, y = 2 * U - 1, 2 * Vv - 1
        keep = x * x + y * y <= 1
        r = light.radius
        return light.position + np.outer(x[keep] * r, e1) + np.outer(y[keep] * r, e2), False
    # sun: uniform in the cone (solid angle)
    half = light.angle / 2
    cos_t = 1 - U * (1 - math.cos(half))
    sin_t = np.sqrt(1 - cos_t ** 2)
    phi = 2 * math.pi * Vv
    return (np.outer(sin_t * np.cos(phi), m[:3, 0]) + np.outer(sin_t * np.sin(phi), m[:3, 1])
            + np.outer(cos_t, m[:3, 2])), True


def _blocked_fraction(tri, p, pts, directional, w=None):
    """Fraction of the segments p -> pts (or rays along pts) crossing ``tri``
    (of their weights ``w``)."""
    a, b, c = tri
    d = pts if directional else pts - p
    e1, e2 = b - a, c - a
    hvec = np.cross(d, e2)
    det = hvec @ e1
    f = 1.0 / det
    s = p - a
    u = f * (hvec @ s)
    q = np.cross(s, e1)
    v = f * (d @ q)
    t = f * (q @ e2)
    hit = (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)
    if not directional:
        hit &= t < 1
    return hit.mean() if w is None else float((hit * w).sum() / w.sum())


LIGHTS_1TRI = {
    "square": lambda: area_light(1.0, z=4.0),
    "rectangle": lambda: area_light(1.6, 0.6, shape="RECTANGLE", z=4.0),
    "disk": lambda: area_light(1.2, shape="DISK", z=4.0),
    "ellipse": lambda: area_light(1.4, 0.5, shape="ELLIPSE", z=4.0),
    "sphere": lambda: sphere_light(0.6, z=4.0),
    "sun": lambda: sun_light(math.radians(12.0)),
}


def _emission(light, p, pts, directional):
    """The light's emission towards p from each of ``pts``: an area light's
    cos_l / d^2 (one-sided, along its -Z), a sphere's facing disk 1 / d^2, a
    sun's 1 (its points are uniform in solid angle)."""
    if directional:
        return np.ones(len(pts))
    d = pts - p
    d2 = np.einsum("ij,ij->i", d, d)
    if light.kind == "sphere":
        return 1.0 / d2
    return np.maximum(d @ light.axes[2], 0.0) / d2 ** 1.5


@pytest.mark.parametrize("visibility", ["average", "irradiance"])
@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("kind", sorted(LIGHTS_1TRI))
def test_single_triangle_matches_integrated_light(kind, mode, visibility):
    """A tilted triangle over receivers on z = 0: V equals the numerically
    integrated visible fraction (the projection of each edge from the
    receiver is exact, so only the integration grid limits the agreement).
    visibility="irradiance": the fraction of the light's emission towards
    the receiver (cos_l / d^2), taken as linear over the light (each term at
    its region's centroid): an area light's within 0.007 of the integrated
    one, which the average fraction misses by more than 0.02."""
    light = LIGHTS_1TRI[kind]()
    tri = np.array([[-0.7, -0.5, 1.6], [0.9, -0.2, 2.3], [0.1, 0.8, 1.9]])
    xs = np.linspace(-1.8, 1.8, 10)
    P = np.array([[x, y, 0.0] for x in xs for y in xs])
    Nrm = np.tile([0.0, 0.0, 1.0], (len(P), 1))
    V, U, pen, _ = soft_irregular(P, Nrm, tri[None].astype(np.float32), np.zeros(1, np.int32), light,
                                  IrregularParams(silhouette_from=mode, visibility=visibility), scale=10.0)
    tri32 = tri.astype(np.float32).astype(np.float64)
    want = np.empty(len(P))
    for i, p in enumerate(P):
        pts, directional = _light_points(light, p)
        w = np.ones(len(pts)) if visibility == "average" else _emission(light, p, pts, directional)
        want[i] = 1.0 - _blocked_fraction(tri32, p, pts, directional, w)
    assert np.all(np.isfinite(V))
    tol = 4e-3 if kind == "sun" else 2.5e-3     # sun: gnomonic disk vs uniform cone
    if visibility == "irradiance" and light.kind == "area":
        tol = 7e-3
        V_avg = soft_irregular(P, Nrm, tri[None].astype(np.float32), np.zeros(1, np.int32), light,
                               IrregularParams(silhouette_from=mode, visibility="average"), scale=10.0)[0]
        assert np.abs(V_avg - want).max() > 0.02
    assert np.abs(V - want).max() < tol
    assert ((want > 0.02) & (want < 0.98)).sum() >= 5          # the test sees penumbrae


# --------------------------------------------------------------------------
# closed forms of the half-plane (tests/synthetic.py)
def _edge_threshold(fb):
    """Receivers are the G-buffer points moved off the ground by
    ``offset_origin`` (height h): from (y, h) the occluder edge (height 2,
    light at 4) covers the light's y < -2 y / (2 - h)."""
    from penumbra.core.sampling import offset_points
    g = fb.gbuffer
    P = offset_points(g.position.reshape(-1, 3).astype(np.float64), g.normal.reshape(-1, 3).astype(np.float64),
                      fb.scale, False)
    y, h = P[:, 1], P[:, 2]
    return (-2.0 * y / (2.0 - h)).reshape(g.shape)


@pytest.mark.parametrize("mode", MODES)
def test_half_plane_square_light_is_exact(mode):
    a = 1.0
    scene = half_plane_scene(area_light(size=a, z=4.0), res=64, occluder_z=2.0)
    r, fb = run(scene, silhouette_from=mode)
    v = r.passes["irregular"]
    expect = np.clip((a / 2 - _edge_threshold(fb)) / a, 0, 1)
    assert np.abs(v - expect).max() < 1e-6
    assert ((v > 0.05) & (v < 0.95)).sum() > 300


@pytest.mark.parametrize("mode", MODES)
def test_half_plane_disk_and_rectangle_lights_are_exact(mode):
    R = 0.5
    scene = half_plane_scene(area_light(size=2 * R, shape="DISK", z=4.0), res=64)
    r, fb = run(scene, silhouette_from=mode)
    d = np.clip(_edge_threshold(fb) / R, -1, 1)
    expect = (np.arccos(d) - d * np.sqrt(1 - d * d)) / np.pi
    assert np.abs(r.passes["irregular"] - expect).max() < 1e-6
    # a 3 x 1 rectangle across the edge behaves like its 1-wide extent
    scene = half_plane_scene(area_light(size=3.0, size_y=1.0, shape="RECTANGLE", z=4.0), res=64)
    r, fb = run(scene, silhouette_from=mode)
    expect = np.clip(0.5 - _edge_threshold(fb), 0, 1)
    assert np.abs(r.passes["irregular"] - expect).max() < 1e-6


def test_rectangle_as_equal_area_disk_approximation_error():
    """``rect_kernel=False`` uses the disk kernel on the equal-area ellipse
    (an approximation, section 2.3): against the square's closed form the
    error stays below 0.05, the exact kernel below 1e-5."""
    a = 1.0
    scene = half_plane_scene(area_light(size=a, z=4.0), res=64)
    r, fb = run(scene, rect_kernel=False)
    expect = np.clip((a / 2 - _edge_threshold(fb)) / a, 0, 1)
    err = np.abs(r.passes["irregular"] - expect).max()
    assert 0.01 < err < 0.05


# --------------------------------------------------------------------------
# the sample scenes against the ray-traced reference
@pytest.fixture(scope="module")
def samples():
    from scenes import load_sample
    out = {}
    for name in ("grids", "sphere_plane", "torus_plane"):
        sc = load_sample(name, (96, 96))
        fb = FrameBuffers(sc, 96, 96)
        light = sc.lights[0]
        out[name] = (sc, fb, light, reference(fb, light))
    return out


def _irregular(fb, light, **over):
    """The average pass unless ``visibility`` is given (``run``)."""
    over.setdefault("visibility", "average")
    return run_method("irregular", fb, light, **over).passes["irregular"]


@pytest.mark.parametrize("name", ["grids", "sphere_plane", "torus_plane"])
def test_lit_and_umbra_match_the_reference(samples, name):
    """Where the reference is exactly 0 or 1 and no pixel of its penumbra is
    adjacent, V matches it (to the reference's own resolution, half a sample).
    ``light`` mode: everywhere; the paper's ``centre`` mode: on the planes,
    while receivers on an occluder next to its own silhouette from the
    centre follow section 5.1 (single point of projection)."""
    sc, fb, light, ref = samples[name]
    g = fb.gbuffer
    pen = g.hit & (ref > 0) & (ref < 1)
    away = g.hit & ~dilate(pen, 1) & ((ref == 0) | (ref == 1))
    planes = np.isin(g.object_id, [o.id for o in sc.objects if o.name in ("Ground", "Plane")])
    assert away.sum() > 400 and ((ref == 0) & away).sum() >= 10 and ((ref == 1) & away).sum() > 20
    for mode, where in (("light", away), ("centre", away & planes)):
        v = _irregular(fb, light, silhouette_from=mode)
        assert in_range(v)
        assert np.abs(v - ref)[where].max() <= REF_RESOLUTION, mode


@pytest.mark.parametrize("name", ["grids", "sphere_plane", "torus_plane"])
def test_penumbra_error_is_bounded(samples, name):
    """Equation 4 with C = 0 (section 5.2) over-counts overlapping occluders,
    so with layers counted from each receiver (``light`` mode) V never
    exceeds the truth: V - ref stays within the reference's noise (< 0.05)
    everywhere. One occluder without overlap (sphere, torus): |V - ref| is
    noise too. GRIDS (three crossing lattices): the over-count makes the
    penumbrae darker on average, never brighter. The paper's ``centre``
    mode adds the single-point-of-projection error (5.1) at occluders' own
    terminators, within the bounds below. The sampled C of equation 5
    (default) removes GRIDS' over-count: no mean bias left and a far smaller
    RMSE in both modes; the others unchanged."""
    sc, fb, light, ref = samples[name]
    hit = fb.gbuffer.hit
    v = _irregular(fb, light, silhouette_from="light", overlap="zero")
    d = (v - ref)[hit]
    assert d.max() < 0.05
    rmse = float(np.sqrt(np.mean(d * d)))
    pen = ((ref > 0) & (ref < 1))[hit]
    if name == "grids":
        assert d[pen].mean() < -0.05 and rmse < 0.16
    else:
        assert np.abs(d).max() < 0.05 and rmse < 0.003
    vc = _irregular(fb, light, overlap="zero")
    dc = (vc - ref)[hit]
    assert float(np.sqrt(np.mean(dc * dc))) < {"grids": 0.16, "sphere_plane": 0.01,
                                               "torus_plane": 0.015}[name]
    for mode, bound in (("light", {"grids": 0.025, "sphere_plane": 0.003, "torus_plane": 0.003}),
                        ("centre", {"grids": 0.04, "sphere_plane": 0.01, "torus_plane": 0.015})):
        ds = (_irregular(fb, light, silhouette_from=mode) - ref)[hit]
        assert float(np.sqrt(np.mean(ds * ds))) < bound[name] and abs(ds[pen].mean()) < 0.02


@pytest.mark.parametrize("name", ["grids", "sphere_plane", "torus_plane"])
def test_zero_size_light_is_the_exact_hard_shadow(samples, name):
    """A light of size zero: V equals Embree's single ray to the light centre
    (same offset origins) at every receiver."""
    sc, _, light, _ = samples[name]
    lt0 = dataclasses.replace(light, size=0.0, size_y=0.0, radius=0.0)
    sc0 = dataclasses.replace(sc, lights=[lt0])
    fb = FrameBuffers(sc0, 96, 96)
    hard = reference(fb, lt0, samples=1)
    assert ((hard == 0) & fb.gbuffer.hit).sum() > 100
    for mode in MODES:
        v = _irregular(fb, lt0, silhouette_from=mode)
        np.testing.assert_array_equal(v, hard)


@pytest.mark.parametrize("name", ["grids", "torus_plane"])
def test_overdraw_reductions_change_nothing(samples, name):
    """Section 2.5's per-bin quad width and wedge test, and the quads
    themselves, only skip receivers whose term is exactly 0: every switch
    gives the bits of the brute force (every edge at every receiver).
    (GRIDS at 48 px: the brute force is quadratic.)"""
    if name == "grids":
        from scenes import load_sample
        sc = load_sample(name, (48, 48))
        fb, light = FrameBuffers(sc, 48, 48), sc.lights[0]
    else:
        sc, fb, light, _ = samples[name]
    for mode in MODES:
        bf = _irregular(fb, light, silhouette_from=mode, brute_force=True)
        for refine in (False, True):
            for wedge in (False, True):
                v = _irregular(fb, light, silhouette_from=mode, bin_refine=refine, wedge_test=wedge)
                np.testing.assert_array_equal(v, bf)


def test_silhouettes_are_not_needed_for_correctness(samples):
    """Section 2.1: with every edge instead of the silhouettes the result is
    the same (interior edges cancel); without adjacency every triangle is its
    own occluder, front and back faces of closed meshes both count: with
    C = 0 V can only get darker, with the sampled C the two layers unite
    (up to the samples' estimate of their overlap)."""
    sc, fb, light, _ = samples["sphere_plane"]
    for mode in MODES:
        v = _irregular(fb, light, silhouette_from=mode)
        every = _irregular(fb, light, silhouette_from=mode, silhouettes=False)
        assert np.abs(v - every).max() < 1e-9
        v0 = _irregular(fb, light, silhouette_from=mode, overlap="zero")
        noadj = _irregular(fb, light, silhouette_from=mode, adjacency=False, overlap="zero")
        assert (noadj <= v0 + 1e-9).all() and (noadj < v0 - 0.1).any()
        noadj = _irregular(fb, light, silhouette_from=mode, adjacency=False)
        assert np.abs(noadj - v).max() < 0.05 and np.abs(noadj - v).mean() < 0.002


# --------------------------------------------------------------------------
# equation 4 with C = 0: the sum is the expected number of occluder layers
def _box(x0, x1, y0, y1, z0, z1):
    """12 outward-wound triangles of an axis-aligned box."""
    c = np.array([[x, y, z] for z in (z0, z1) for y in (y0, y1) for x in (x0, x1)], float)
    quads = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]
    return [[c[a], c[b], c[d]] for a, b, d, _ in quads] + [[c[a], c[d], c[e]] for a, _, d, e in quads]


@njit(cache=True)
def _entries(P, L, tri, closed_tri):
    """Per (point, light point): entries into closed solids (outward normal
    facing the point) plus crossings of open surfaces along the segment."""
    out = np.zeros((P.shape[0], L.shape[1]))
    for i in range(P.shape[0]):
        for j in range(L.shape[1]):
            px, py, pz = P[i, 0], P[i, 1], P[i, 2]
            dx, dy, dz = L[i, j, 0] - px, L[i, j, 1] - py, L[i, j, 2] - pz
            cnt = 0.0
            for t in range(tri.shape[0]):
                ax, ay, az = tri[t, 0, 0], tri[t, 0, 1], tri[t, 0, 2]
                e1x, e1y, e1z = tri[t, 1, 0] - ax, tri[t, 1, 1] - ay, tri[t, 1, 2] - az
                e2x, e2y, e2z = tri[t, 2, 0] - ax, tri[t, 2, 1] - ay, tri[t, 2, 2] - az
                hx, hy, hz = dy * e2z - dz * e2y, dz * e2x - dx * e2z, dx * e2y - dy * e2x
                det = hx * e1x + hy * e1y + hz * e1z
                if det == 0.0:
                    continue
                f = 1.0 / det
                sx, sy, sz = px - ax, py - ay, pz - az
                u = f * (hx * sx + hy * sy + hz * sz)
                qx, qy, qz = sy * e1z - sz * e1y, sz * e1x - sx * e1z, sx * e1y - sy * e1x
                v = f * (dx * qx + dy * qy + dz * qz)
                tt = f * (qx * e2x + qy * e2y + qz * e2z)
                if u < 0 or v < 0 or u + v > 1 or tt <= 0 or tt >= 1:
                    continue
                if closed_tri[t]:
                    nx, ny, nz = e1y * e2z - e1z * e2y, e1z * e2x - e1x * e2z, e1x * e2y - e1y * e2x
                    if nx * dx + ny * dy + nz * dz < 0.0:
                        cnt += 1.0
                else:
                    cnt += 1.0
            out[i, j] = cnt
    return out


def test_unclamped_sum_is_the_expected_layer_count():
    """Two overlapping boxes and a floating plate over a ground, square
    light: umbra + penumbra (before the clamp of equation 4) equals the mean
    number of occluder layers between each receiver and the light, counted
    exactly with every triangle; where occluders overlap it exceeds the
    occluded fraction (the paper's C = 0)."""
    tris = _box(-0.9, 0.3, -0.6, 0.4, 1.0, 1.5) + _box(-0.2, 0.8, -0.3, 0.7, 1.8, 2.2)
    nbox = len(tris)
    tris += quad(0.2, 1.2, -1.0, -0.2, 2.6)
    T = np.array(tris, np.float32)
    obj = np.array([0] * 12 + [1] * 12 + [2] * 2, np.int32)
    light = area_light(1.2, z=4.0)
    xs = np.linspace(-1.6, 1.6, 17)
    P = np.array([[x, y, 0.0] for x in xs for y in xs])
    Nrm = np.tile([0.0, 0.0, 1.0], (len(P), 1))
    V, U, pen, stats = soft_irregular(P, Nrm, T, obj, light, IrregularParams(silhouette_from="light", overlap="zero",
                                                                              visibility="average"), scale=10.0)
    assert stats["closed_components"] == 2
    n = 128
    u = (np.arange(n) + 0.5) / n
    X, Y = np.meshgrid(u, u)
    lp = np.stack([(2 * X.ravel() - 1) * 0.6, (2 * Y.ravel() - 1) * 0.6, np.full(n * n, 4.0)], -1)
    L = np.broadcast_to(lp, (len(P), n * n, 3)).copy()
    closed_tri = np.arange(len(T)) < nbox
    layers = _entries(P, L, T.astype(np.float64), closed_tri).mean(1)
    occ = U + pen
    assert np.abs(occ - layers).max() < 0.01          # the integration grid's resolution
    assert (layers > 1.2).any() and ((occ > 0.05) & (occ < 0.95)).sum() > 20
    blocked = (_entries(P, L, T.astype(np.float64), closed_tri) > 0).mean(1)
    assert np.abs(V - (1 - np.minimum(layers, 1))).max() < 0.01
    assert (V < 1 - blocked - 0.05).any()            # the over-count of overlaps
    # equation 5's C from the 8 x 8 light samples: the same sums, V near the
    # exact union (the error is the samples' estimate of the overlap only)
    V2, U2, pen2, _ = soft_irregular(P, Nrm, T, obj, light, IrregularParams(silhouette_from="light",
                                                                            visibility="average"), scale=10.0)
    assert np.array_equal(U2, U) and np.array_equal(pen2, pen)
    assert np.abs(V2 - (1 - blocked)).max() < 0.07
    assert np.abs(V2 - (1 - blocked)).mean() < 0.25 * np.abs(V - (1 - blocked)).mean()


# --------------------------------------------------------------------------
# adjacency
def test_adjacency_closed_open_and_per_object():
    cube = np.array(_box(0, 1, 0, 1, 0, 1), np.float32)
    plane = np.array(quad(-1, 1, -1, 1, 0.0), np.float32)
    tris = np.concatenate([cube, cube + np.float32(1.0), plane])     # second cube touches the first
    obj = np.array([0] * 12 + [1] * 12 + [2] * 2, np.int32)
    tri_edge, count, t0, t1, d0, d1, root, closed = mesh_adjacency(tris, obj)
    assert len(np.unique(root[:12])) == 1 and len(np.unique(root[12:24])) == 1
    assert root[0] != root[12] and root[24] == root[25] and root[24] != root[0]
    assert closed[root[0]] and closed[root[12]] and not closed[root[24]]
    assert (count == 2).sum() == 18 * 2 + 1 and (count == 1).sum() == 4
    # one object holding both cubes: a shared vertex, still two closed solids
    tri_edge, count, *_, root, closed = mesh_adjacency(tris[:24], np.zeros(24, np.int32))
    assert root[0] != root[12] and closed[root[0]] and closed[root[12]]


# --------------------------------------------------------------------------
# hard cases (DESIGN.md "Numerical robustness")
def _scene(tris, ids, objs, light, cam=None, res=40):
    cam = cam or top_ortho_camera(3.0, height=3.0)
    return Scene(np.array(tris, np.float32).reshape(-1, 3, 3), np.array(ids, np.int32), objs, cam,
                 [light], (res, res))


def _objs(n, camera=None):
    camera = camera or [True] * n
    return [ObjectInfo(f"o{i}", i, visible_camera=camera[i]) for i in range(n)]


def _persp_camera(pos, target, lens=35.0, clip_start=1e-3, clip_end=1e4):
    m = np.eye(4)
    m[:3, :3] = look_rotation(np.asarray(target, float) - np.asarray(pos, float), np.array([0, 0, 1.0]))
    m[:3, 3] = pos
    return Camera(m, lens=lens, clip_start=clip_start, clip_end=clip_end)


def _hard_cases():
    ground = quad(-10, 10, -10, 10, 0.0)
    occl = quad(-10, 10, -10, 0.0, 2.0)
    cases = {}
    cases["grazing_sun"] = _scene(ground + occl, [0, 0, 1, 1], _objs(2, [True, False]),
                                  Light("s", "sun", light_matrix((0, 0, 5), (1.0, 0.0, -1e-3)), angle=0.05))
    cases["grazing_area"] = _scene(ground + occl, [0, 0, 1, 1], _objs(2, [True, False]),
                                   Light("a", "area", light_matrix((9.0, 0, 0.05), (-1.0, 0.0, -0.02)),
                                         size=0.5, size_y=0.5))
    cases["contact_box"] = _scene(ground + _box(-0.5, 0.5, -0.5, 0.5, 0.0, 1.0), [0, 0] + [1] * 12,
                                  _objs(2), area_light(1.0, z=4.0))
    cases["coplanar"] = _scene(ground + quad(-1, 1, -1, 1, 0.0) + occl, [0, 0, 1, 1, 2, 2],
                               _objs(3, [True, True, False]), area_light(1.0, z=4.0))
    cases["occluder_behind_light"] = _scene(ground + quad(-10, 10, -10, 0, 6.0), [0, 0, 1, 1],
                                            _objs(2, [True, False]), area_light(1.0, z=4.0))
    cases["light_inside_box"] = _scene(ground + _box(-1, 1, -1, 1, 0.5, 2.5), [0, 0] + [1] * 12,
                                       _objs(2, [True, False]), sphere_light(0.3, z=1.5))
    cases["camera_inside_box"] = _scene(_box(-2, 2, -2, 2, -1, 3), [0] * 12, _objs(1),
                                        sphere_light(0.3, z=6.0),
                                        cam=_persp_camera((0.0, 0.0, 1.0), (0.3, 0.2, -1.0)))
    cases["far_near_1e6"] = _scene(quad(-1e4, 1e4, -1e4, 1e4, 0.0) + quad(-1e-2, 1e-2, -1e-2, 1e-2, 1e-3),
                                   [0, 0, 1, 1], _objs(2), sphere_light(1e-3, z=2e-3),
                                   cam=_persp_camera((0, -5e-3, 2e-3), (0, 1e3, 0), clip_start=1e-5,
                                                     clip_end=1e5))
    degenerate = [[[0, 0, 1], [1, 1, 1], [2, 2, 1]], [[0, 0, 1.5], [0, 0, 1.5], [1, 0, 1.5]],
                  [[0.3, 0.3, 1.0], [0.3 + 1e-6, 0.3, 1.0], [0.3, 0.3 + 1e-6, 1.0]]]
    cases["degenerate_subpixel"] = _scene(ground + occl + degenerate, [0, 0, 1, 1, 2, 2, 2],
                                          _objs(3, [True, False, True]), area_light(1.0, z=4.0))
    cases["no_casters"] = Scene(np.array(ground, np.float32), np.zeros(2, np.int32),
                                [ObjectInfo("g", 0, casts_shadow=False)], top_ortho_camera(3.0),
                                [area_light(1.0)], (40, 40))
    cases["nothing_visible"] = _scene(occl, [0, 0], _objs(1, [False]), area_light(1.0, z=4.0))
    cases["huge_light"] = _scene(ground + occl, [0, 0, 1, 1], _objs(2, [True, False]),
                                 area_light(200.0, z=4.0))
    cases["huge_sphere_light"] = _scene(ground + occl, [0, 0, 1, 1], _objs(2, [True, False]),
                                        sphere_light(3.5, z=4.0))
    cases["point_light_all_around"] = _scene(ground + _box(-0.3, 0.3, -0.3, 0.3, 0.2, 0.8), [0, 0] + [1] * 12,
                                             _objs(2), sphere_light(0.2, z=1.2),
                                             cam=_persp_camera((4.0, -3.0, 3.0), (0, 0, 0.5)))
    return cases


HARD = _hard_cases()


@pytest.mark.parametrize("name", ["point_light_all_around", "grazing_sun", "grazing_area",
                                  "huge_sphere_light", "contact_box", "light_inside_box"])
def test_quads_are_conservative_on_every_kind_of_face(name):
    """Cube faces (point light all around), the sun's orthographic face,
    quads covering whole faces (a light wider than its distance to the
    occluder), grazing light: binned quads give the brute force's bits."""
    scene = HARD[name]
    for mode in MODES:
        bf = run(scene, silhouette_from=mode, brute_force=True)[0].passes["irregular"]
        r, _ = run(scene, silhouette_from=mode)
        np.testing.assert_array_equal(r.passes["irregular"], bf)
    if name == "point_light_all_around":
        assert len(r.stats["grid_faces"]) >= 3
    if name == "huge_sphere_light":
        assert r.stats["quads_whole_face"] > 0


def test_point_light_with_cube_faces_matches_the_reference():
    """A sphere light close above a box, seen from the side: the receivers
    spread over several cube faces; one closed occluder, so ``light`` mode
    agrees with the reference to its noise."""
    scene = HARD["point_light_all_around"]
    r, fb = run(scene, silhouette_from="light")
    ref = reference(fb, scene.lights[0])
    hit = fb.gbuffer.hit
    d = (r.passes["irregular"] - ref)[hit]
    assert ((ref > 0.05) & (ref < 0.95))[hit].sum() > 50
    assert np.abs(d).max() < 0.06 and float(np.sqrt(np.mean(d * d))) < 0.01


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("name", sorted(HARD))
def test_hard_cases_are_finite_and_in_range(name, mode):
    scene = HARD[name]
    r, fb = run(scene, silhouette_from=mode)
    v = r.passes["irregular"]
    assert v.shape == (40, 40) and in_range(v)
    assert (v[~fb.gbuffer.hit] == 1.0).all()
    if name in ("no_casters", "nothing_visible", "occluder_behind_light"):
        assert (v == 1.0).all()


@pytest.mark.parametrize("mode", MODES)
def test_light_inside_a_closed_box_shadows_everything_outside(mode):
    """A sphere light inside a closed box (floor included) above the ground:
    every ground point is outside the box, so V = 0 everywhere, as the
    reference says; the grid uses cube faces around the light."""
    scene = HARD["light_inside_box"]
    r, fb = run(scene, silhouette_from=mode)
    v = r.passes["irregular"]
    hit = fb.gbuffer.hit
    assert hit.sum() > 1000 and (v[hit] == 0.0).all()
    assert (reference(fb, scene.lights[0], samples=16)[hit] == 0.0).all()


@pytest.mark.parametrize("factor", [1e-3, 1e4])
def test_scene_scale_does_not_change_the_result(factor):
    base = half_plane_scene(area_light(1.0, z=4.0), res=48)
    v0 = run(base)[0].passes["irregular"]
    lt = base.lights[0]
    m = lt.world_from_light.copy()
    m[:3, 3] *= factor
    light = dataclasses.replace(lt, world_from_light=m, size=lt.size * factor, size_y=lt.size_y * factor)
    cm = base.camera.world_from_camera.copy()
    cm[:3, 3] *= factor
    cam = dataclasses.replace(base.camera, world_from_camera=cm, ortho_scale=base.camera.ortho_scale * factor,
                              clip_start=base.camera.clip_start * factor, clip_end=base.camera.clip_end * factor)
    scaled = dataclasses.replace(base, triangles=base.triangles * np.float32(factor), camera=cam, lights=[light])
    v1 = run(scaled)[0].passes["irregular"]
    assert np.abs(v1 - v0).max() < 1e-3


# --------------------------------------------------------------------------
# occluder overlap: equation 5's C from the depth complexity at light samples
LINE = np.array([[x, 0.0, 0.0] for x in np.linspace(-0.5, 0.5, 11)])
SCALE = 10.0


def _receiver_height():
    """The height ``offset_origin`` lifts the ground points of LINE to."""
    from penumbra.core.sampling import offset_points
    P = offset_points(LINE, np.tile([0.0, 0.0, 1.0], (len(LINE), 1)), SCALE, False)
    assert np.ptp(P[:, 2]) == 0.0 and (P[:, 1] == 0.0).all()
    return float(P[0, 2])


def _strips(bands, z, zl=4.0):
    """Long strips (x in [-10, 10]) at height z whose images from the
    receivers of LINE on the light plane z = zl cover the light-y ``bands``."""
    h = _receiver_height()
    tris = []
    for y0, y1 in bands:
        tris += quad(-10.0, 10.0, y0 * (z - h) / (zl - h), y1 * (z - h) / (zl - h), z)
    return tris


def _on_the_line(tris, light, **over):
    """V at the ground points LINE (x, 0, 0), x in [-0.5, 0.5], under open strips."""
    T = np.array(tris, np.float32).reshape(-1, 3, 3)
    P = LINE
    Nrm = np.tile([0.0, 0.0, 1.0], (len(P), 1))
    over.setdefault("visibility", "average")
    V, U, pen, _ = soft_irregular(P, Nrm, T, np.arange(len(T)) // 2, light, IrregularParams(**over),
                                  scale=SCALE)
    return V, U, pen


# light-y bands of a unit square light (half side 0.5), on cell boundaries of
# the light samples for every overlap_samples divisible by 4
HALF_A = [(-0.6, -0.25), (0.25, 0.6)]       # half the light, not its centre
HALF_B = [(-0.25, 0.25)]                    # the other half
QUARTER = [(0.25, 0.6)]


@pytest.mark.parametrize("mode", MODES)
def test_two_occluders_over_the_same_half_unite(mode):
    """Two occluders at heights 1 and 2 covering the same half of the light:
    V = 0.5 (the paper's C = 0 adds them: V = 0); over disjoint halves V = 0
    in both; one alone V = 0.5 in both."""
    light = area_light(1.0, z=4.0)
    same = _strips(HALF_A, 1.0) + _strips(HALF_A, 2.0)
    V, _, _ = _on_the_line(same, light, silhouette_from=mode)
    assert np.abs(V - 0.5).max() < 1e-6
    V, _, _ = _on_the_line(same, light, silhouette_from=mode, overlap="zero")
    assert np.abs(V).max() < 1e-6
    for over in ("sampled", "zero"):
        V, _, _ = _on_the_line(_strips(HALF_A, 1.0) + _strips(HALF_B, 2.0), light, silhouette_from=mode,
                               overlap=over)
        assert np.abs(V).max() < 1e-6
        V, _, _ = _on_the_line(_strips(HALF_B, 2.0), light, silhouette_from=mode, overlap=over)
        assert np.abs(V - 0.5).max() < 1e-6


def test_three_layers_over_a_quarter_and_the_umbra_stay_exact():
    """Three strips over the same quarter of the light: V = 0.75 (C = 0:
    0.25); under a full cover plus that quarter the umbra stays exactly 0."""
    light = area_light(1.0, z=4.0)
    tris = _strips(QUARTER, 1.0) + _strips(QUARTER, 1.5) + _strips(QUARTER, 2.0)
    V, _, _ = _on_the_line(tris, light)
    assert np.abs(V - 0.75).max() < 1e-6
    V, _, _ = _on_the_line(tris, light, overlap="zero")
    assert np.abs(V - 0.25).max() < 1e-6
    V, U, _ = _on_the_line(tris + _strips([(-0.6, 0.6)], 3.0), light)
    assert (U >= 1).all() and np.abs(V).max() < 1e-6
    V, U, _ = _on_the_line(_strips([(-0.6, 0.6)], 3.0) + _strips([(-0.6, 0.6)], 2.0), light)
    assert (U == 2).all() and (V == 0.0).all()


def _leaves(rng, n, centre, spread, size):
    """n small randomly oriented single-sided triangles (leaves) around centre."""
    c = np.asarray(centre, float) + rng.uniform(-1, 1, (n, 3)) * spread
    tris = []
    for k in range(n):
        a, b = rng.normal(size=3), rng.normal(size=3)
        a /= np.linalg.norm(a)
        b -= a * (a @ b)
        b /= np.linalg.norm(b)
        tris.append([c[k] - size * a, c[k] + size * a, c[k] + 1.5 * size * b])
    return tris


FOLIAGE_LIGHTS = {"square": lambda: area_light(1.2, z=3.0), "disk": lambda: area_light(1.2, shape="DISK", z=3.0),
                  "rectangle": lambda: area_light(1.5, size_y=0.8, shape="RECTANGLE", z=3.0),
                  "point": lambda: sphere_light(0.5, z=3.0), "sun": lambda: sun_light(0.35)}


@pytest.fixture(scope="module")
def foliage_like():
    rng = np.random.default_rng(17)
    tris = quad(-4, 4, -4, 4, 0.0) + _leaves(rng, 400, (0.0, 0.0, 1.3), (0.8, 0.8, 0.5), 0.09)
    ids = [0, 0] + [1] * 400
    out = {}
    for name, mk in FOLIAGE_LIGHTS.items():
        light = mk()
        sc = make_scene(tris, ids, [light], res=48, camera=top_ortho_camera(2.0, height=0.5))
        fb = FrameBuffers(sc, 48, 48)
        out[name] = (fb, light, reference(fb, light, 1024))
    return out


@pytest.mark.parametrize("kind", sorted(FOLIAGE_LIGHTS))
def test_foliage_like_overlap_against_embree(foliage_like, kind):
    """400 small leaves over a ground, every light kind: with the sampled C
    the error against a 1024-sample reference is the reference's noise, far
    below the paper's C = 0, which over-darkens (mean signed error < 0)."""
    fb, light, ref = foliage_like[kind]
    v = _irregular(fb, light)
    v0 = _irregular(fb, light, overlap="zero")
    pen = (ref > 0.02) & (ref < 0.98)
    assert pen.sum() > 500
    e, e0 = (v - ref)[pen], (v0 - ref)[pen]
    rmse, rmse0 = np.sqrt(np.mean(e * e)), np.sqrt(np.mean(e0 * e0))
    assert rmse < 0.04 and rmse < 0.4 * rmse0
    assert e0.mean() < -0.05 and abs(e.mean()) < 0.015


@pytest.mark.parametrize("name", ["grids", "sphere_plane", "torus_plane"])
def test_paper_overlap_switch_keeps_equation_4(samples, name):
    """``overlap="zero"`` is the paper's equation 4 bit for bit: the sampled
    C leaves the umbra count and the penumbra sum untouched and only
    subtracts C >= 0 before the clamp (never darker than C = 0)."""
    sc, fb, light, ref = samples[name]
    g = fb.gbuffer
    idx, P, Nrm = g.hit_points()
    tris, tobj = fb.shadow_triangles
    V0, U0, pen0, _ = soft_irregular(P, Nrm, tris, tobj, light, IrregularParams(overlap="zero", visibility="average"),
                                     fb.scale, bounds=sc.bounds())
    V, U, pen, st = soft_irregular(P, Nrm, tris, tobj, light, IrregularParams(visibility="average"), fb.scale,
                                   bounds=sc.bounds())
    assert np.array_equal(U, U0) and np.array_equal(pen, pen0) and st["overlap_samples"] > 40
    assert np.array_equal(V0, (1.0 - np.clip(U0 + pen0, 0.0, 1.0)).astype(np.float32))
    assert (V >= V0).all()
    assert np.array_equal(_irregular(fb, light, overlap="zero").ravel()[idx], V0)


def test_overlap_switch_rejects_unknown_values():
    with pytest.raises(ValueError, match="overlap"):
        _on_the_line(_strips(HALF_A, 1.0), area_light(1.0, z=4.0), overlap="average")


def test_horizon_switch_bounds_v_by_the_light_above_the_plane():
    """``horizon`` (off by default): a lone plane tilted 60 degrees
    under an 8 x 8 square light 4 above the origin hides the light beyond a
    line that is the same for every point on it: V = (4 + 4 cot 60) / 8 =
    0.789 (the reference agrees: its rays into the plane hit it). With the
    switch V is at most that share (here exactly it: nothing else casts);
    the default is the paper's and unchanged by it. The irradiance ratio is
    1 (the light the plane hides lies below it: cos_r = 0), and so is the
    irradiance pass, with the switch or without."""
    from synthetic import lone_tilted_plane
    t = math.radians(60.0)
    scene = lone_tilted_plane(60.0, area_light(size=8.0, z=4.0), res=24)
    exact = (4.0 + 4.0 / math.tan(t)) / 8.0
    on, fb = run(scene, horizon=True)
    off, _ = run(scene)
    ref = reference(fb, scene.lights[0])
    hit = fb.gbuffer.hit
    assert hit.all() and abs(ref[hit].mean() - exact) < 0.01
    v_on, v_off = on.passes["irregular"][hit], off.passes["irregular"][hit]
    assert (v_on <= v_off + 1e-7).all()
    np.testing.assert_allclose(v_on, np.minimum(v_off, exact), atol=1e-5)
    assert np.abs(v_on - ref[hit]).mean() < 0.01
    assert np.abs(v_off - ref[hit]).mean() > 0.05, v_off.mean()     # the paper's misses it here
    ref_irr = embree_pass(fb, scene.lights[0], REF_SAMPLES, pass_id="embree_irr")
    assert (ref_irr[hit] > 0.999).all()
    for over in ({}, {"horizon": True}):
        assert (run(scene, visibility="irradiance", **over)[0].passes["irregular"][hit] == 1.0).all()


@pytest.mark.parametrize("name", ["grids", "sphere_plane", "torus_plane"])
def test_irradiance_pass_against_the_irradiance_reference(samples, name):
    """visibility="irradiance": equation 5's V over the share of the light
    above the receiver's plane (its own surface hides the rest, which weighs
    nothing in the ratio) against ``embree_irr`` where the light reaches:
    at the occluders' own terminators the average pass is far from the
    ratio, the irradiance pass close to it."""
    sc, fb, light, _ = samples[name]
    reach = fb.reach(light)
    ref = embree_pass(fb, light, REF_SAMPLES, pass_id="embree_irr")

    def rmse(v):
        return float(np.sqrt(np.mean((v - ref)[reach] ** 2)))
    e_irr = rmse(_irregular(fb, light, visibility="irradiance"))
    e_avg = rmse(_irregular(fb, light))
    bound, miss = {"grids": (0.05, 0.06), "sphere_plane": (0.005, 0.02), "torus_plane": (0.005, 0.02)}[name]
    assert e_irr < bound and e_avg > miss, (e_irr, e_avg)
