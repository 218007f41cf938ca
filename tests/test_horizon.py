"""``horizon`` (issue 17's share of the light above a receiver's tangent
plane): the Numba kernel against the NumPy closed forms it replaced
(``horizon_share_reference``), on random planes under every light kind, and
``scale_by_horizon``'s in-place contract."""
import math

import numpy as np
import pytest

from penumbra.core.methods.horizon import horizon_share, horizon_share_reference, scale_by_horizon
from penumbra.core.scene import Light
from synthetic import light_matrix


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
