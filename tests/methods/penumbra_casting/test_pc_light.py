"""The light side of penumbra casting (``light``): samples in groups of 32
on a jittered grid, and bounding polygons / volumes Delta_Gk and Delta_L that
bound every sample of every set (section 3.4), for every light kind."""
import numpy as np
import pytest

from helpers import buffers_of
from pc_helpers import LIGHTS, PC, clutter_scene
from penumbra.core import sampling
from penumbra.core.methods.penumbra_casting import prepare
from penumbra.core.methods.penumbra_casting.light import MODE_SPHERE, group_layout


def test_groups_of_32_on_a_jittered_grid():
    """256 samples: a 16 x 16 grid in 8 groups of 32 (the paper's setting);
    1024 samples: 32 groups; every stratum has one bit."""
    nx, ny, G, bit2s, g_start, blocks = group_layout(256, 32)
    assert (nx, ny, G) == (16, 16, 8)
    assert np.all(np.diff(g_start) == 32) and sorted(bit2s) == list(range(256))
    nx, ny, G, bit2s, g_start, blocks = group_layout(1024, 32)
    assert G == 32 and g_start[-1] == 1024


def _local2(points, centre, ax, ay, az, directional):
    d = points - (0 if directional else centre)
    if directional:
        return np.stack([d @ ax / (d @ az), d @ ay / (d @ az)], -1)
    return np.stack([d @ ax, d @ ay], -1)


def _inside_convex(poly, q, tol):
    """q (m,2) inside the convex polygon (k,2), either orientation."""
    k = len(poly)
    if k < 3:
        return np.ones(len(q), bool)
    s = np.zeros((len(q), k))
    for i in range(k):
        a, b = poly[i], poly[(i + 1) % k]
        s[:, i] = (b[0] - a[0]) * (q[:, 1] - a[1]) - (b[1] - a[1]) * (q[:, 0] - a[0])
    area2 = sum(poly[i, 0] * poly[(i + 1) % k, 1] - poly[(i + 1) % k, 0] * poly[i, 1] for i in range(k))
    return np.all(s * np.sign(area2) >= -tol, axis=1)


@pytest.mark.parametrize("kind", ["square", "rectangle", "disk", "ellipse", "sun", "sphere"])
@pytest.mark.parametrize("shared", [False, True])
def test_group_polygons_bound_every_sample_of_every_set(kind, shared):
    """Section 3.4: Delta_Gk bounds the group's samples in all sample sets
    (here every receiver's samples), and Delta_L bounds them all."""
    light = LIGHTS[kind]()
    scene = clutter_scene(light, res=24)
    fb = buffers_of(scene)
    setup = prepare(fb, light, PC.make_params({"samples": 256, "shared_samples_with_reference": shared}))
    L = setup.light
    P = setup.sample_points(np.arange(len(setup.idx)))
    m = light.world_from_light
    ax, ay, az = m[:3, 0], m[:3, 1], m[:3, 2]
    c = light.position
    if light.kind == "sphere":
        if L.mode == MODE_SPHERE:
            e1, e2 = (np.array(v) for v in sampling.orthonormal_basis(*L.w0))
            frame = np.stack([e1, e2, L.w0])
        else:
            frame = np.eye(3)
        for g in range(L.G):
            loc = (P[:, L.g_start[g]:L.g_start[g + 1], :3] - c) @ frame.T
            box = (L.DVg[g, :L.nvg[g], :3] - c) @ frame.T
            assert (loc >= box.min(0) - 1e-9).all() and (loc <= box.max(0) + 1e-9).all()
        return
    directional = light.kind == "sun"
    full = _local2(L.DVL[:L.nvl, :3], c, ax, ay, az, directional)
    allq = _local2(P[..., :3].reshape(-1, 3), c, ax, ay, az, directional)
    assert _inside_convex(full, allq, 1e-9).all()
    for g in range(L.G):
        poly = _local2(L.DVg[g, :L.nvg[g], :3], c, ax, ay, az, directional)
        q = _local2(P[:, L.g_start[g]:L.g_start[g + 1], :3].reshape(-1, 3), c, ax, ay, az, directional)
        assert _inside_convex(poly, q, 1e-9).all(), g
