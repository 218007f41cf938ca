"""Surface labels finer than object ids: the connected pieces of each
object's mesh (triangles sharing a vertex position). A shrub's leaves are one
object but thousands of pieces; the map methods' "same surface" tests
(``layered``'s gradient and footprint neighbours, ``single_sample``'s id
test) use these so that two leaves side by side in a map are not one
surface."""
from __future__ import annotations

import numpy as np

from .irregular.mesh import mesh_adjacency


def mesh_pieces(scene) -> np.ndarray:
    """int32 per triangle: the lowest triangle index of its connected piece
    (within its object: touching objects stay apart)."""
    if len(scene.triangles) == 0:
        return np.zeros(0, np.int32)
    root = mesh_adjacency(scene.triangles, scene.tri_object)[6]
    return np.ascontiguousarray(root, np.int32)
