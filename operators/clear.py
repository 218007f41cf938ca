"""Clear Penumbra data: Penumbra's images, its compositor nodes and its node
group, nothing else (the user's nodes, images and settings stay)."""
from __future__ import annotations

import bpy

from ..bridge import compat, compositor
from ..bridge.compositor import GROUP_NAME
from ..bridge.images import IMAGE_PREFIX     # pass images "Penumbra <layer> <pass>", "Penumbra Preview"


def penumbra_images():
    return [img for img in bpy.data.images if img.name.startswith(IMAGE_PREFIX) and img.library is None]


def penumbra_groups():
    return [g for g in bpy.data.node_groups
            if g.bl_idname == "CompositorNodeTree" and g.library is None
            and (g.name == GROUP_NAME or g.name.startswith(GROUP_NAME + ".") or g.get("penumbra"))]


def clear_penumbra_data():
    """Remove Penumbra's nodes (named ``Penumbra:...`` or its frame) from
    every compositor tree, then its node groups and images. Returns
    (nodes, groups, images) removed."""
    groups = penumbra_groups()
    group_ptrs = {g.as_pointer() for g in groups}
    n_nodes = 0
    for tree in bpy.data.node_groups:
        if tree.bl_idname != "CompositorNodeTree" or tree.as_pointer() in group_ptrs or tree.library:
            continue
        n_nodes += compositor.clear_nodes(tree)
        # group nodes using Penumbra's group, whatever their name
        for node in [n for n in tree.nodes if getattr(n, "node_tree", None) is not None
                     and n.node_tree.as_pointer() in group_ptrs]:
            tree.nodes.remove(node)
            n_nodes += 1
    for g in groups:
        bpy.data.node_groups.remove(g)
    for scene in bpy.data.scenes:
        compat.remove_penumbra_effect(scene)
    images = penumbra_images()
    for img in images:
        bpy.data.images.remove(img)
    return n_nodes, len(groups), len(images)


class PENUMBRA_OT_clear(bpy.types.Operator):
    """Remove Penumbra's images, compositor nodes and node group (nothing the
    user made)"""

    bl_idname = "penumbra.clear"
    bl_label = "Clear Penumbra Data"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        nodes, groups, images = clear_penumbra_data()
        if not (nodes or groups or images):
            self.report({"INFO"}, "Penumbra: nothing to clear")
        else:
            self.report({"INFO"}, f"Penumbra: removed {images} image(s), {nodes} compositor node(s) "
                                  f"and {groups} node group(s)")
        return {"FINISHED"}


classes = (PENUMBRA_OT_clear,)
