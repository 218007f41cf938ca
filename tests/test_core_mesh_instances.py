"""core/scene.py MeshInstances: the captured instancing, flattened and counted."""
import numpy as np
import pytest

from helpers import placement
from penumbra.core.scene import MeshInstances



def test_mesh_instances_flatten_and_count():
    """``MeshInstances``: two meshes, three instances; the soup is each
    instance's mesh placed by its matrix, in object-id order, and the counts
    tell the shared triangles from the placed ones."""
    tri = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float64)
    quad = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], np.float64)
    ins = MeshInstances(vertices=[tri, quad], faces=[np.array([[0, 1, 2]]), np.array([[0, 1, 2], [0, 2, 3]])],
                        mesh=[1, 0, 1], object_id=[2, 0, 1],
                        world_from_mesh=[placement((2, 2, 2), 0, (0, 0, 1)), np.eye(4),
                                         placement((1, 1, 1), np.pi / 2, (5, 0, 0))])
    assert (ins.count, ins.unique_triangles, ins.instanced_triangles) == (3, 3, 5)
    tris, ids = ins.flatten()
    assert ids.tolist() == [0, 1, 1, 2, 2]
    np.testing.assert_allclose(tris[0], tri, atol=1e-7)
    np.testing.assert_allclose(tris[1], [[5, 0, 0], [5, 1, 0], [4, 1, 0]], atol=1e-6)
    np.testing.assert_allclose(tris[4], [[0, 0, 1], [2, 2, 1], [0, 2, 1]], atol=1e-6)
    with pytest.raises(ValueError):
        MeshInstances(vertices=[tri], faces=[np.array([[0, 1, 2]])], mesh=[0, 0], object_id=[0],
                      world_from_mesh=[np.eye(4)] * 2)
