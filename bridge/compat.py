"""Everything that differs between the Blender lines Penumbra supports
(5.0, 5.1, 5.2 LTS, 5.3): the rest of the add-on calls these and never
branches on the version itself.

- The compositor. 5.0 - 5.2: one node group per scene,
  ``Scene.compositing_node_group``. 5.3: a stack of effects,
  ``Scene.compositor_effects`` (each with a ``node_group``; an effect's Group
  Input "Image" is the previous effect's result, the first one's the render),
  and reading ``compositing_node_group`` raises a DeprecationWarning (it gives
  the active effect's group). On 5.3 Penumbra's nodes live in its own effect,
  "Penumbra", appended to the stack with a pass-through group, so the user's
  effects, their groups and the stack's result are left as they are.
- Render Layers sockets. 5.0: the node has every pass socket, disabled ones
  unavailable until the node updates. 5.1+: only the enabled passes' sockets
  exist. Either way: enable the pass on the view layer, ``node.update()``,
  then look the socket up by name.
- Float images with straight alpha. 5.0: ``Image.pixels`` of a float buffer
  is what Cycles treats as premultiplied (its Image Texture's Color output
  is those values as they are). 5.2, 5.3: they are straight, and Cycles
  premultiplies them like a byte image. Checked by rendering in 5.0.1, 5.2.3
  and 5.3.0; 5.1 not checked (taken as 5.2).
"""
from __future__ import annotations

from typing import List, Optional

import bpy

EFFECT_NAME = "Penumbra"                 # Penumbra's compositor effect (5.3+)
EFFECT_TREE_NAME = "Effect (Penumbra)"   # its node group
EFFECT_TREE_TAG = "penumbra_effect"      # ID property marking that group
TREE_NAME = "Compositor"                 # the scene group Penumbra makes when there is none (5.0 - 5.2)


def float_pixels_premultiplied() -> bool:
    """Whether a STRAIGHT float image's ``pixels`` are premultiplied as
    Cycles reads them (5.0; not from 5.1 on: module docstring)."""
    return tuple(bpy.app.version) < (5, 1, 0)


def has_compositor_effects() -> bool:
    """Blender 5.3+: the compositor is a stack of effects."""
    return "compositor_effects" in bpy.types.Scene.bl_rna.properties


def _new_tree(name: str, pass_through_input: bool):
    tree = bpy.data.node_groups.new(name, "CompositorNodeTree")
    tree.interface.new_socket("Image", in_out="OUTPUT", socket_type="NodeSocketColor")
    if pass_through_input:      # 5.3 effect: the stack's image in, unchanged out
        tree.interface.new_socket("Image", in_out="INPUT", socket_type="NodeSocketColor")
        src = tree.nodes.new("NodeGroupInput")
    else:                       # 5.0 - 5.2 scene group: the render in, unchanged out
        src = tree.nodes.new("CompositorNodeRLayers")
    out = tree.nodes.new("NodeGroupOutput")
    out.location = (400, 0)
    tree.links.new(src.outputs["Image"], out.inputs["Image"])
    return tree


def penumbra_effect(scene):
    """5.3+: Penumbra's own compositor effect, or None (always None before 5.3)."""
    if not has_compositor_effects():
        return None
    return next((e for e in scene.compositor_effects if e.name == EFFECT_NAME), None)


def compositor_tree(scene, create: bool = True):
    """The compositor node group Penumbra puts its nodes in, or None when
    there is none and ``create`` is False.

    5.0 - 5.2: the scene's ``compositing_node_group``; a new one passing the
    render through (Render Layers -> Group Output) when it has none.
    5.3+: the group of Penumbra's own effect; a new effect at the end of the
    stack with a pass-through group (Group Input -> Group Output) when there
    is none; the stack's active effect stays the one the user had."""
    if not has_compositor_effects():
        tree = scene.compositing_node_group
        if tree is None and create:
            tree = _new_tree(TREE_NAME, pass_through_input=False)
            scene.compositing_node_group = tree
        return tree
    effect = penumbra_effect(scene)
    if effect is None:
        if not create:
            return None
        effects = scene.compositor_effects
        active = effects.active
        effect = effects.new(EFFECT_NAME)
        if active is not None:
            effects.active = active
    if effect.node_group is None and create:
        tree = _new_tree(EFFECT_TREE_NAME, pass_through_input=True)
        tree[EFFECT_TREE_TAG] = True
        effect.node_group = tree
    return effect.node_group


def set_compositor_tree(scene, tree) -> None:
    """Make ``tree`` the scene's own compositor (what a user does in the
    Compositor editor). 5.0 - 5.2: ``compositing_node_group``. 5.3+: the
    group of a new effect "Scene Effect" (the name Blender gives it)."""
    if not has_compositor_effects():
        scene.compositing_node_group = tree
        return
    scene.compositor_effects.new("Scene Effect").node_group = tree


#: Nodes besides Render Layers that read the render at the top of a tree the
#: compositor runs: 5.3+ an effect's Group Input (the stack's image); none before.
RENDER_INPUT_NODES = ("NodeGroupInput",) if has_compositor_effects() else ()


def render_trees(scene) -> List:
    """The node groups the compositor runs when the scene renders, in order.
    5.0 - 5.2: the scene group (if any). 5.3+: each render-enabled effect's."""
    if not has_compositor_effects():
        tree = scene.compositing_node_group
        return [] if tree is None else [tree]
    return [e.node_group for e in scene.compositor_effects
            if e.enable_for_render and e.node_group is not None]


def remove_penumbra_effect(scene) -> bool:
    """5.3+: remove Penumbra's effect (and its group) when its group holds
    nothing but the pass-through nodes; True when it was removed."""
    effect = penumbra_effect(scene)
    if effect is None:
        return False
    tree = effect.node_group
    if tree is not None and any(n.bl_idname not in ("NodeGroupInput", "NodeGroupOutput") for n in tree.nodes):
        return False
    scene.compositor_effects.remove(effect)
    if tree is not None and tree.get(EFFECT_TREE_TAG) and tree.users == 0:
        bpy.data.node_groups.remove(tree)
    return True


def render_layers_socket(node, name: str, pass_flag: Optional[str] = None):
    """The output ``name`` of a Render Layers node, looked up by name.

    ``pass_flag`` (e.g. ``"use_pass_z"`` for "Depth") is switched on in the
    node's view layer first, then the node updated: 5.1+ only make sockets for
    enabled passes, 5.0 marks the others unavailable. KeyError when there is
    no such (enabled) socket."""
    if pass_flag is not None:
        scene = node.scene or bpy.context.scene
        layer = scene.view_layers[node.layer]
        if not getattr(layer, pass_flag):
            setattr(layer, pass_flag, True)
        node.update()
    sock = node.outputs.get(name)
    if sock is None or not sock.enabled:
        raise KeyError(f"Render Layers node {node.name!r} has no {name!r} output"
                       + ("" if pass_flag else " (enable its pass)"))
    return sock
