"""Penumbra's compositor nodes (Blender 5.0 API, BLENDER_NOTES.md).

Every node Penumbra makes is named ``Penumbra:...`` and sits inside one frame
node named ``Penumbra``; a rebuild removes exactly those and makes them anew,
so it is idempotent and never touches a node the user made.
"""
from __future__ import annotations

from typing import Dict, Sequence

import bpy

PREFIX = "Penumbra:"
FRAME_NAME = "Penumbra"


def pass_image_name(layer: str, pass_id: str) -> str:
    return f"Penumbra {layer} {pass_id}"


def store_pass_image(layer: str, pass_id: str, v) -> bpy.types.Image:
    """A float Blender image holding pass ``v`` (float32[H,W], row 0 at the
    top) as grey; updated in place when it already exists with that size."""
    import numpy as np
    h, w = v.shape
    name = pass_image_name(layer, pass_id)
    img = bpy.data.images.get(name)
    if img is not None and tuple(img.size) != (w, h):
        bpy.data.images.remove(img)
        img = None
    if img is None:
        img = bpy.data.images.new(name, w, h, alpha=False, float_buffer=True)
    rgba = np.empty((h, w, 4), np.float32)
    g = np.asarray(v, np.float32)[::-1]          # Blender rows go bottom-up
    rgba[..., 0] = g
    rgba[..., 1] = g
    rgba[..., 2] = g
    rgba[..., 3] = 1.0
    img.pixels.foreach_set(rgba.ravel())
    img.update()
    return img


def compositor_tree(scene) -> bpy.types.NodeTree:
    """The scene's compositing node group; when it has none, a new one that
    passes the render through (Render Layers -> Group Output)."""
    tree = scene.compositing_node_group
    if tree is None:
        tree = bpy.data.node_groups.new("Compositor", "CompositorNodeTree")
        tree.interface.new_socket("Image", in_out="OUTPUT", socket_type="NodeSocketColor")
        rl = tree.nodes.new("CompositorNodeRLayers")
        out = tree.nodes.new("NodeGroupOutput")
        out.location = (400, 0)
        tree.links.new(rl.outputs["Image"], out.inputs["Image"])
        scene.compositing_node_group = tree
    return tree


def clear_nodes(tree) -> int:
    ours = [n for n in tree.nodes if n.name.startswith(PREFIX) or n.name == FRAME_NAME]
    for n in ours:
        tree.nodes.remove(n)
    return len(ours)


def build_side_by_side(scene, layers: Dict[str, str], passes: Sequence[str]) -> bpy.types.NodeTree:
    """One row per light (``layers``: light name -> layer), one Image node per
    pass (e.g. ``pcf`` beside the ``embree`` reference), in the Penumbra frame."""
    tree = compositor_tree(scene)
    clear_nodes(tree)
    frame = tree.nodes.new("NodeFrame")
    frame.name = FRAME_NAME
    frame.label = "Penumbra shadow passes"
    x0 = max((n.location.x for n in tree.nodes if n is not frame), default=0.0) + 400.0
    for row, (light_name, layer) in enumerate(layers.items()):
        for col, pid in enumerate(passes):
            img = bpy.data.images.get(pass_image_name(layer, pid))
            if img is None:
                continue
            node = tree.nodes.new("CompositorNodeImage")
            node.name = f"{PREFIX}{layer}:{pid}"
            node.label = f"{light_name}: {pid}"
            node.image = img
            node.location = (x0 + 260.0 * col, -320.0 * row)
            node.parent = frame
    return tree
