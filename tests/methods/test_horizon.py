"""``core/methods/horizon.py`` (the share of a light above a receiver's
tangent plane, used by ``single_sample`` and ``irregular``): the Numba kernel
against the same closed forms vectorized in NumPy (``horizon_share_reference``
below), on random planes under every light kind, and ``scale_by_horizon``'s
in-place contract."""
import math

import numpy as np
import pytest

from penumbra.core.methods.horizon import SUN_RINGS, horizon_share, scale_by_horizon
from penumbra.core.scene import Light
from synthetic import light_matrix


# --------------------------------------------------------------------------
# the closed forms in NumPy, one light at a time over every point
def _disk_share(x):
    """Share of the unit disk where its coordinate along some axis exceeds x
    (the segment beyond the chord at x)."""
    x = np.clip(x, -1.0, 1.0)
    return (np.arccos(x) - x * np.sqrt(1.0 - x * x)) / np.pi


def _share_above(h, s):
    """Share of a unit disk mapped to h + s w (w its coordinate along one
    axis) where that is > 0: the light above a plane at signed height h whose
    tilt spreads it by s."""
    with np.errstate(divide="ignore", invalid="ignore"):
        x = np.where(s > 0.0, -h / np.where(s > 0.0, s, 1.0), np.where(h > 0.0, -np.inf, np.inf))
    return _disk_share(x)


def _square_share_above(h, A, B):
    """Share of (u, v) in [-1, 1]^2 with h + A u + B v > 0: 1 - G(-h), G the
    trapezoidal CDF of a U + b V (a >= b the larger / smaller of |A|, |B|)."""
    a = np.maximum(np.abs(A), np.abs(B))
    b = np.minimum(np.abs(A), np.abs(B))
    t = -h
    with np.errstate(divide="ignore", invalid="ignore"):
        lo = (t + a + b) ** 2 / (8.0 * a * b)
        mid = (t + a) / (2.0 * a)
        hi = 1.0 - (a + b - t) ** 2 / (8.0 * a * b)
    G = np.where(t <= -(a - b), lo, np.where(t <= a - b, mid, hi))
    G = np.where(t <= -(a + b), 0.0, np.where(t >= a + b, 1.0, G))
    G = np.where(a > 0.0, G, (t >= 0.0).astype(np.float64))        # a plane parallel to the light
    return 1.0 - np.nan_to_num(G, nan=0.0)


def horizon_share_reference(light, P: np.ndarray, Nrm: np.ndarray) -> np.ndarray:
    """``horizon_share`` in float64 NumPy. float64[n]: the share of the
    light (DESIGN.md's light domains) above each point's tangent plane
    (normal Nrm). Area lights: the rectangle's /
    ellipse's area (closed forms); sphere lights: the disk of radius r facing
    the point; suns: the cone's solid angle (``SUN_RINGS`` rings of equal
    solid angle, each cut exactly). Only points whose plane cuts the light
    are computed (1 / 0 for the others)."""
    P = np.asarray(P, np.float64)
    N = np.asarray(Nrm, np.float64)
    nn = np.einsum("ij,ij->i", N, N)
    if light.kind == "sun":
        h = N @ -np.asarray(light.direction, np.float64)
        m = np.sqrt(np.maximum(nn - h * h, 0.0))
        ca, sa = math.cos(light.sun_half_angle), math.sin(light.sun_half_angle)
        out = (h * ca - m * sa > 0.0).astype(np.float64)      # the whole cone above / not
        cut = np.flatnonzero((h * ca - m * sa <= 0.0) & (h * ca + m * sa > 0.0))
        cos_t = 1.0 - (np.arange(SUN_RINGS) + 0.5) / SUN_RINGS * (1.0 - ca)
        sin_t = np.sqrt(np.maximum(1.0 - cos_t * cos_t, 0.0))
        # per ring: the share of the circle's angle with cos_t h + sin_t m cos(phi) > 0
        with np.errstate(divide="ignore", invalid="ignore"):
            x = -(cos_t[None, :] * h[cut, None]) / (sin_t[None, :] * m[cut, None])
        x = np.where(np.isnan(x), np.where(h[cut, None] > 0.0, -1.0, 1.0), x)
        out[cut] = (np.arccos(np.clip(x, -1.0, 1.0)) / np.pi).mean(axis=1)
        return out
    d = np.asarray(light.position, np.float64) - P
    h = np.einsum("ij,ij->i", N, d)
    if light.kind == "sphere":
        dist2 = np.einsum("ij,ij->i", d, d)
        with np.errstate(divide="ignore", invalid="ignore"):
            along2 = np.where(dist2 > 0.0, h * h / dist2, 0.0)
        spread = light.radius * np.sqrt(np.maximum(nn - along2, 0.0))
    else:
        ax, ay, _ = light.axes
        hx, hy = light.half_size
        A = hx * (N @ ax)
        B = hy * (N @ ay)
        spread = np.hypot(A, B) if light.is_round else np.abs(A) + np.abs(B)
    out = (h > spread).astype(np.float64)
    cut = np.flatnonzero(np.abs(h) <= spread)
    if light.kind == "area" and not light.is_round:
        out[cut] = _square_share_above(h[cut], A[cut], B[cut])
    else:
        out[cut] = _share_above(h[cut], spread[cut])
    return out


# --------------------------------------------------------------------------
def _tilted(kind, rng, **kw):
    fwd = rng.normal(size=3)
    fwd[2] = -abs(fwd[2]) - 0.3                     # shining roughly down
    return Light("L", kind, light_matrix(rng.uniform(-1, 1, 3) + [0, 0, 3.0], fwd / np.linalg.norm(fwd)), **kw)


LIGHTS = {
    "square": lambda r: _tilted("area", r, blender_type="AREA", shape="SQUARE", size=2.0, size_y=2.0),
    "rectangle": lambda r: _tilted("area", r, blender_type="AREA", shape="RECTANGLE", size=3.0, size_y=0.7),
    "disk": lambda r: _tilted("area", r, blender_type="AREA", shape="DISK", size=2.0, size_y=2.0),
    "ellipse": lambda r: _tilted("area", r, blender_type="AREA", shape="ELLIPSE", size=3.0, size_y=1.0),
    "sphere": lambda r: _tilted("sphere", r, blender_type="POINT", radius=0.8),
    "sun": lambda r: _tilted("sun", r, blender_type="SUN", angle=0.3),
    "wide_sun": lambda r: _tilted("sun", r, blender_type="SUN", angle=2.5),
}


def _points(rng, light, n=20000):
    """Random points and planes, many of them cutting the light; a few hard
    ones: normals of zero and of odd lengths, planes through the light's
    centre, normals along the light's axes (a plane parallel to an area light)."""
    P = rng.uniform(-3, 3, (n, 3)) * [1, 1, 0.5]
    N = rng.normal(size=(n, 3)) * rng.uniform(0.2, 3.0, (n, 1))
    N[:10] = 0.0
    P[10:20] = light.position
    ax, ay, az = light.axes
    N[20:30] = az
    N[30:40] = -az
    N[40:50] = ax
    P[50:60] = light.position + 1e-9 * ax            # a hair off the light's centre
    return P, N


@pytest.mark.parametrize("name", sorted(LIGHTS))
@pytest.mark.parametrize("f32", [False, True])
def test_kernel_matches_the_numpy_closed_forms(name, f32):
    rng = np.random.default_rng(7)
    for _ in range(3):
        light = LIGHTS[name](rng)
        P, N = _points(rng, light)
        if f32:
            N = N.astype(np.float32)
        want = horizon_share_reference(light, P, N)
        got = horizon_share(light, P, N)
        assert got.dtype == np.float64 and got.shape == want.shape
        assert np.isfinite(want).all()
        cut = (want > 0.0) & (want < 1.0)
        assert cut.mean() > 0.05                     # the closed forms, not just 0 / 1, are compared
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
        assert ((got == 0.0) == (want == 0.0)).all() and ((got == 1.0) == (want == 1.0)).all()


@pytest.mark.parametrize("name", ["square", "disk", "sphere", "sun"])
def test_scale_by_horizon_multiplies_in_place_where_asked_and_v_is_positive(name):
    rng = np.random.default_rng(11)
    light = LIGHTS[name](rng)
    P, N = _points(rng, light, 5000)
    N = np.ascontiguousarray(N, np.float32)
    out = rng.uniform(0, 1, len(P))
    out[::7] = 0.0
    out[::11] = np.nan
    only = rng.uniform(size=len(P)) < 0.8
    before = out.copy()
    scale_by_horizon(light, P, N, only, out)
    share = horizon_share_reference(light, P, N)
    moved = only & (before > 0.0)
    np.testing.assert_allclose(out[moved], before[moved] * share[moved], rtol=1e-12, atol=1e-15)
    np.testing.assert_array_equal(out[~moved], before[~moved])     # NaN where it was NaN, 0 stays 0
    assert (share[moved] < 1.0).any()


def test_threads_do_not_change_the_result():
    rng = np.random.default_rng(5)
    light = LIGHTS["rectangle"](rng)
    P, N = _points(rng, light, 50000)
    one = horizon_share(light, P, N, threads=1)
    two = horizon_share(light, P, N, threads=2)
    np.testing.assert_array_equal(one, two)
    assert math.isclose(one.sum(), horizon_share_reference(light, P, N).sum(), rel_tol=1e-12)
