"""core/embree4.py: instanced scenes traced through the Embree library embreex
ships, against closed forms and against embreex on the flattened triangles."""
import numpy as np
import pytest

from helpers import leaf_cluster, placement
from penumbra.core import embree4

QUAD = np.array([[[-1, -1, 0], [1, -1, 0], [1, 1, 0]],
                 [[-1, -1, 0], [1, 1, 0], [-1, 1, 0]]], np.float32)


def _tilted(angle_x, offset):
    c, s = np.cos(angle_x), np.sin(angle_x)
    m = np.eye(4)
    m[:3, :3] = [[1, 0, 0], [0, c, -s], [0, s, c]]
    m[:3, 3] = offset
    return m

def test_closest_hit_matches_the_closed_form_per_instance():
    """Three instances of one quad, stacked along z: a ray down the z axis at
    (x, y) hits the highest quad that covers (x, y); its t, instance, and
    world normal (of a tilted quad: rotated) follow in closed form."""
    quad = embree4.Mesh(None, QUAD)
    xf = np.stack([placement((1, 1, 1), 0.0, (0, 0, 0)),
                   placement((0.5, 0.5, 1), 0.3, (0, 0, 2)),
                   _tilted(0.4, (3, 0, 1))])
    scene = embree4.InstancedScene([quad], [0, 0, 0], xf)
    org = np.array([[0, 0, 10], [0.9, 0.9, 10], [3, 0, 10], [5, 5, 10]], np.float32)
    dirs = np.tile(np.array([0, 0, -1], np.float32), (4, 1))
    t, inst, prim, u, v, ng = embree4.intersect(scene, org, dirs)
    assert inst.tolist() == [1, 0, 2, -1]
    np.testing.assert_allclose(t[:3], [8.0, 10.0, 9.0], rtol=1e-6)
    assert np.isinf(t[3]) and prim[3] == -1
    np.testing.assert_allclose(np.abs(ng[0]), [0, 0, 1], atol=1e-6)
    np.testing.assert_allclose(np.abs(ng[2]), [0, np.sin(0.4), np.cos(0.4)], atol=1e-6)
    assert (prim[:3] >= 0).all() and (prim[:3] < 2).all()

def test_tfar_and_tnear_bound_the_hits():
    quad = embree4.Mesh(None, QUAD)
    scene = embree4.InstancedScene([quad], [0, 0], [placement((1, 1, 1), 0, (0, 0, 0)),
                                                   placement((1, 1, 1), 0, (0, 0, 5))])
    org = np.zeros((3, 3), np.float32)
    org[:, 2] = 10
    dirs = np.tile(np.array([0, 0, -1], np.float32), (3, 1))
    t, inst, *_ = embree4.intersect(scene, org, dirs, tnear=[0, 6, 0], tfar=[np.inf, np.inf, 4])
    assert inst.tolist() == [1, 0, -1]
    assert embree4.occluded(scene, org, dirs, tnear=[0, 6, 0], tfar=[4.9, 9.9, 4.9]).tolist() == \
        [False, False, False]
    assert embree4.occluded(scene, org, dirs, tnear=[0, 6, 0], tfar=[5.1, 10.1, 5.1]).tolist() == \
        [True, True, True]

def test_degenerate_input_misses_cleanly():
    """An empty mesh, a mesh no instance uses, an instance of zero scale or a
    non-finite matrix: left out; a scene with nothing left misses every ray."""
    quad = embree4.Mesh(None, QUAD)
    empty = embree4.Mesh(None, np.zeros((0, 3, 3), np.float32))
    assert empty.handle == 0
    bad = np.eye(4)
    bad[0, 3] = np.nan
    scene = embree4.InstancedScene([quad, empty, quad], [1, 0, 0],
                                   [np.eye(4), placement((0, 0, 0), 0, (0, 0, 0)), bad])
    org = np.array([[0, 0, 1]], np.float32)
    dirs = np.array([[0, 0, -1]], np.float32)
    t, inst, *_ = embree4.intersect(scene, org, dirs)
    assert inst.tolist() == [-1] and np.isinf(t[0])
    assert not embree4.occluded(scene, org, dirs).any()
    none = embree4.InstancedScene([quad], np.zeros(0, int), np.zeros((0, 4, 4)))
    assert none.handle == 0
    assert embree4.intersect(none, org, dirs)[1].tolist() == [-1]


def test_agrees_with_embreex_on_the_flattened_scatter():
    """A scatter of 300 instances of a 400-leaf mesh: closest hits and
    occlusion agree with embreex tracing the same triangles flattened into
    world space (float32 rounding differs at shared edges and overlaps)."""
    from embreex import rtcore_scene as rtcs
    from embreex.mesh_construction import TriangleMesh

    rng = np.random.default_rng(3)
    verts, faces = leaf_cluster(rng, 400, 0.6, (0, 0, 2), 0.1)
    leaves = verts[faces].astype(np.float32)
    n = 300
    xf = np.stack([placement((s, s, s), ang, (x, y, 0)) for s, ang, x, y in
                   zip(0.7 + 0.6 * rng.random(n), 6.3 * rng.random(n), *(rng.random((2, n)) * 30 - 15))])
    scene = embree4.InstancedScene([embree4.Mesh(None, leaves)], np.zeros(n, int), xf)
    flat = (np.einsum("nij,tkj->ntki", xf[:, :3, :3], leaves.astype(np.float64))
            + xf[:, None, None, :3, 3]).reshape(-1, 3, 3).astype(np.float32)
    ref = rtcs.EmbreeScene()
    TriangleMesh(ref, flat)

    m = 20000
    org = np.column_stack([rng.random((m, 2)) * 30 - 15, np.full(m, 10.0)]).astype(np.float32)
    dirs = rng.normal(size=(m, 3)) * 0.2 + [0, 0, -1]
    dirs = (dirs / np.linalg.norm(dirs, axis=1)[:, None]).astype(np.float32)
    t, inst, prim, u, v, ng = embree4.intersect(scene, org, dirs)
    r = ref.run(org, dirs, output=1)
    hit_ref = r["primID"] >= 0
    assert hit_ref.mean() > 0.3
    assert np.mean(hit_ref != (inst >= 0)) < 1e-3
    both = hit_ref & (inst >= 0)
    close = np.abs(t[both] - r["tfar"][both]) <= 1e-4 * r["tfar"][both]
    assert close.mean() > 0.999
    same = (inst[both] * len(leaves) + prim[both]) == r["primID"][both]
    assert same.mean() > 0.999
    tri = flat[r["primID"][both]]
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    fn /= np.linalg.norm(fn, axis=1)[:, None]
    assert np.mean(np.abs(np.sum(fn * ng[both], axis=1)) > 0.9999) > 0.999

    tfar = np.full(m, 12.0, np.float32)
    occ = embree4.occluded(scene, org, dirs, tfar=tfar)
    occ_ref = ref.run(org, dirs, dists=tfar.copy(), query="OCCLUDED") != -1
    assert np.mean(occ != occ_ref) < 1e-3
    assert occ.mean() > 0.3

