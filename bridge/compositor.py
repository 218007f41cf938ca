"""Penumbra's compositor nodes (Blender 5.0 API, BLENDER_NOTES.md).

Every node Penumbra makes is named ``Penumbra:...``; a rebuild removes
exactly those and makes them anew, so it is idempotent and never touches a
node the user made. Two kinds live in the scene's compositing node group:

* ``build_side_by_side``: one Image node per stored pass image, in a frame
  named ``Penumbra`` (what Compute Passes shows);
* ``setup_compositor``: the "Penumbra" node group (a CompositorNodeTree in
  ``bpy.data.node_groups``) used through a group node, fed by its own Render
  Layers node, in a frame named ``Penumbra Compositor`` (node names
  ``Penumbra:~...``). Per light the group outputs the method's pass, the
  ray-traced reference of its V definition (``embree_irr`` for the
  irradiance ratio, ``embree`` for the average) and ``cycles``, the error
  |method - reference| in false colour (Map Range by the group's "Error
  Scale" input + Color Ramp; black = no error) and a "side by side" image:
  method | ray-traced reference over
  cycles | error, each at half size in a quadrant of the render's frame.
  Its sources are the stored pass images or the light's layer of a
  multilayer EXR written by ``penumbra render`` (Image node ``layer``).
  Per light the group also composites: its input "<layer>: unshadowed" is
  the light's own render with its shadow off, and its output
  "<layer>: shadowed" that render times the method's pass, the light's
  shadowed render (the pass is the irradiance ratio: unshadowed x V =
  shadowed). ``setup_compositor`` wires the input from the Render Layers
  node: the light's light group's Combined pass, or Diffuse Direct when the
  scene renders one light; else it is left for the user to connect.
  Sockets that stay the same keep their identifiers across rebuilds, so
  links to the group from the user's own nodes survive.
"""
from __future__ import annotations

from typing import Dict, Optional, Sequence

import bpy

from . import compat
from .images import pass_image_name

PREFIX = "Penumbra:"
FRAME_NAME = "Penumbra"


def compositor_tree(scene) -> bpy.types.NodeTree:
    """The compositor node group Penumbra's nodes go in (made when missing;
    per Blender line: ``bridge.compat.compositor_tree``)."""
    return compat.compositor_tree(scene, create=True)


def clear_nodes(tree) -> int:
    """Remove every node Penumbra made in ``tree`` (both kinds)."""
    ours = [n for n in tree.nodes if n.name.startswith(PREFIX) or n.name in (FRAME_NAME, SETUP_FRAME)]
    for n in ours:
        tree.nodes.remove(n)
    return len(ours)


def build_side_by_side(scene, layers: Dict[str, str], passes: Sequence[str]) -> bpy.types.NodeTree:
    """One row per light (``layers``: light name -> layer), one Image node per
    pass (e.g. ``pcf`` beside the ``embree`` reference), in the Penumbra frame."""
    tree = compositor_tree(scene)
    for n in [n for n in tree.nodes if (n.name.startswith(PREFIX) and not n.name.startswith(SETUP_PREFIX))
              or n.name == FRAME_NAME]:
        tree.nodes.remove(n)
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


# --------------------------------------------------------------------------
# the "Penumbra" node group: method | references | error | composite, per light
GROUP_NAME = "Penumbra"
GROUP_MARK = "penumbra"              # ID property marking Penumbra's own node group (clear.py too)
SETUP_PREFIX = PREFIX + "~"          # scene-tree nodes of the compositor setup
SETUP_FRAME = "Penumbra Compositor"
#: shown beside the method, in this order: the ray-traced reference of the
#: method's own V definition, then Cycles'
REFERENCES = {"irradiance": ("embree_irr", "cycles"), "average": ("embree", "cycles")}
ERROR_SCALE = 0.25                   # |error| shown at full colour by default
# false colour of |method - reference| / Error Scale: black = no error
ERROR_RAMP = ((0.0, (0.0, 0.0, 0.0, 1.0)), (0.3, (0.35, 0.0, 0.6, 1.0)),
              (0.65, (1.0, 0.35, 0.0, 1.0)), (1.0, (1.0, 1.0, 0.35, 1.0)))
# quadrants of the side-by-side image, as offsets in quarters of the render size
QUADRANTS = {"method": (-1, 1), "ray traced": (1, 1), "cycles": (-1, -1), "error": (1, -1)}


def socket_name(layer: str, what: str) -> str:
    """The group's output socket of ``what`` (a pass id, "error" or "side by
    side") for one light's layer."""
    return f"{layer}: {what}"


class SetupResult:
    """What :func:`setup_compositor` built."""

    def __init__(self, tree, group, node, lights, missing, error_refs, unwired=()):
        self.tree = tree              # the scene's compositing node group
        self.group = group            # the "Penumbra" node group
        self.node = node              # its group node in ``tree``
        self.lights = lights          # [(light name, layer, method)]
        self.missing = missing        # ["layer: pass"] with no source
        self.error_refs = error_refs  # layer -> reference the error compares with
        self.unwired = list(unwired)  # ["layer: unshadowed"] inputs left for the user to connect


def penumbra_group(create: bool = True):
    """Penumbra's compositor node group (marked with ``GROUP_MARK``; a
    CompositorNodeTree named "Penumbra" made before counts as ours too)."""
    for g in bpy.data.node_groups:
        if g.get(GROUP_MARK) and g.bl_idname == "CompositorNodeTree":
            return g
    g = bpy.data.node_groups.get(GROUP_NAME)
    if g is not None and g.bl_idname == "CompositorNodeTree":
        g[GROUP_MARK] = 1
        return g
    if not create:
        return None
    g = bpy.data.node_groups.new(GROUP_NAME, "CompositorNodeTree")
    g[GROUP_MARK] = 1
    g.description = ("Penumbra: per light, the method's shadow pass, the ray-traced and Cycles "
                     "references and the error, side by side")
    return g


def _ours(node, prefix: str = PREFIX) -> bool:
    return node.name.startswith(prefix)


def _new(tree, idname: str, name: str, label: str = "", location=(0.0, 0.0), parent=None):
    n = tree.nodes.new(idname)
    n.name = name
    if label:
        n.label = label
    n.location = location
    if parent is not None:
        n.parent = parent
    return n


def _group_spec(lights, vis) -> list:
    """(panel, name, in_out, socket type, description) of every interface
    socket, in order."""
    spec = [("", "Image", "INPUT", "NodeSocketColor",
             "The render: its size is the side-by-side canvas; passed through to Image"),
            ("", "Error Scale", "INPUT", "NodeSocketFloat",
             "Absolute error shown at full colour in the error image (smaller: more sensitive)"),
            ("", "Image", "OUTPUT", "NodeSocketColor", "The render, unchanged")]
    for _name, layer, method in lights:
        names = []
        for pid in [method, *REFERENCES[vis[layer]]]:
            if pid not in names:
                names.append(pid)
        for pid in names:
            what = "method" if pid == method else "reference"
            spec.append((layer, socket_name(layer, pid), "OUTPUT", "NodeSocketFloat",
                         f"{pid} shadow pass ({what}): 1 = lit, 0 = shadowed"))
        spec.append((layer, socket_name(layer, "unshadowed"), "INPUT", "NodeSocketColor",
                     "This light's render with its shadow off: its light group's Combined pass, or "
                     "Diffuse Direct when it is the only light"))
        spec.append((layer, socket_name(layer, "shadowed"), "OUTPUT", "NodeSocketColor",
                     f"unshadowed x {method}: this light's shadowed render"))
        spec.append((layer, socket_name(layer, "error"), "OUTPUT", "NodeSocketColor",
                     f"|{method} - reference| in false colour (black: no error)"))
        spec.append((layer, socket_name(layer, "side by side"), "OUTPUT", "NodeSocketColor",
                     f"{method} | {REFERENCES[vis[layer]][0]} over cycles | error, in the render's frame"))
    return spec


def _sync_interface(group, spec) -> None:
    """Make the group's interface ``spec`` while keeping every socket that
    is already right (so links to existing group nodes survive a rebuild)."""
    iface = group.interface
    want = {(p, n, io): t for p, n, io, t, _d in spec}
    panels_wanted = list(dict.fromkeys(p for p, *_ in spec if p))
    for item in list(iface.items_tree):
        if item.item_type != "SOCKET":
            continue
        key = (item.parent.name if item.parent else "", item.name, item.in_out)
        if want.get(key) != item.socket_type:
            iface.remove(item)
    have = {}
    for item in list(iface.items_tree):
        if item.item_type == "PANEL":
            if item.name not in panels_wanted or item.name in have:
                iface.remove(item)
            else:
                have[item.name] = item
    present = {(i.parent.name if i.parent else "", i.name, i.in_out)
               for i in iface.items_tree if i.item_type == "SOCKET"}
    for p, n, io, t, desc in spec:
        if (p, n, io) in present:
            continue
        kw = {}
        if p:
            if p not in have:
                have[p] = iface.new_panel(p)
            kw["parent"] = have[p]
        s = iface.new_socket(n, in_out=io, socket_type=t, **kw)
        s.description = desc
        if n == "Error Scale":
            s.default_value = ERROR_SCALE
            s.min_value = 1e-4
            s.max_value = 1.0


def _pass_sources(group, layer: str, pids, exr_image, x: float, y: float, frame):
    """pass id -> output socket of an Image node (stored pass images, or the
    light's layer of a multilayer EXR); a pass with no source is left out."""
    out = {}
    if exr_image is not None:
        n = _new(group, "CompositorNodeImage", f"{PREFIX}{layer}:exr", f"{layer} (EXR)", (x, y), frame)
        n.image = exr_image
        try:
            n.layer = layer
        except TypeError:            # the EXR has no such layer
            return out
        for pid in pids:
            s = n.outputs.get(pid)
            if s is not None and s.enabled:
                out[pid] = s
        return out
    for k, pid in enumerate(pids):
        img = bpy.data.images.get(pass_image_name(layer, pid))
        if img is None:
            continue
        n = _new(group, "CompositorNodeImage", f"{PREFIX}{layer}:{pid}", pid, (x, y - 230.0 * k), frame)
        n.image = img
        out[pid] = n.outputs["Image"]
    return out


def pass_visibility(method: str, layer: str, frame_visibility: str, written: Dict[str, Dict[str, str]]) -> str:
    """"average" or "irradiance": which V ``method``'s pass of ``layer`` is:
    as the EXR's header says (``written``: layer -> pass -> definition),
    else the definition the frame computed it in for a method that follows
    it (``frame_visibility``: the scene's setting), else the pass's own."""
    if method in written.get(layer, {}):
        return written[layer][method]
    from ..core import methods as registry
    if method in registry.pass_ids(external=False):
        m = registry.producer_of(method)
        return m.visibility(method, m.make_params({"visibility": frame_visibility}))
    return registry.visibility_of(method) if registry.is_external(method) else "irradiance"


def _written_visibility(exr_path: Optional[str]) -> Dict[str, Dict[str, str]]:
    """layer -> pass -> definition from a Penumbra EXR's header ({} without one)."""
    if not exr_path:
        return {}
    import json
    import OpenEXR
    with OpenEXR.File(bpy.path.abspath(exr_path), header_only=True) as f:
        raw = f.parts[0].header.get("penumbra/visibility")
    try:
        return json.loads(raw) if raw else {}
    except (TypeError, ValueError):
        return {}


def _error_reference(method: str, available, visibility: str) -> Optional[str]:
    """The reference of the method's own V definition when present
    (DESIGN.md: average -> embree, irradiance -> embree_irr), else the
    other references in order."""
    if visibility == "irradiance":
        order = ["embree_irr", "cycles", "embree"]
    else:
        order = ["embree", "cycles", "embree_irr"]
    return next((r for r in order if r != method and r in available), None)


def build_penumbra_group(lights, exr_path: Optional[str] = None, visibility: str = "irradiance"):
    """Rebuild the "Penumbra" node group for ``lights`` = [(light name,
    layer, method pass id)]. Sources: the stored pass images, or the layers
    of the multilayer EXR at ``exr_path``; ``visibility``: the definition the
    frame computed the methods in (an EXR's header says it itself).
    Returns (group, missing, refs)."""
    written = _written_visibility(exr_path)
    vis = {layer: pass_visibility(method, layer, visibility, written) for _n, layer, method in lights}
    group = penumbra_group()
    _sync_interface(group, _group_spec(lights, vis))
    for n in [n for n in group.nodes if _ours(n)]:
        group.nodes.remove(n)
    exr_image = None
    if exr_path:
        exr_image = bpy.data.images.load(bpy.path.abspath(exr_path), check_existing=True)
        exr_image.reload()
    L = group.links
    gin = _new(group, "NodeGroupInput", f"{PREFIX}Group Input", "", (-900.0, 300.0))
    gout = _new(group, "NodeGroupOutput", f"{PREFIX}Group Output", "", (2100.0, 300.0))
    L.new(gin.outputs["Image"], gout.inputs["Image"])
    # the canvas: the render's size, black; quarter / half sizes for the quadrants
    info = _new(group, "CompositorNodeImageInfo", f"{PREFIX}Canvas Info", "Render size", (-650.0, 520.0))
    L.new(gin.outputs["Image"], info.inputs["Image"])
    sep = _new(group, "ShaderNodeSeparateXYZ", f"{PREFIX}Canvas Size", "Width, height", (-450.0, 520.0))
    L.new(info.outputs["Dimensions"], sep.inputs["Vector"])
    size = {}
    for axis in ("X", "Y"):
        for f in (0.5, 0.25, -0.25):
            m = _new(group, "ShaderNodeMath", f"{PREFIX}{axis} x {f:g}", f"{axis} x {f:g}",
                     (-250.0, 620.0 - 60.0 * len(size)))
            m.operation = "MULTIPLY"
            m.inputs[1].default_value = f
            L.new(sep.outputs[axis], m.inputs[0])
            m.hide = True
            size[(axis, f)] = m.outputs[0]
    black = _new(group, "ShaderNodeMix", f"{PREFIX}Black Canvas", "Black canvas", (-250.0, 250.0))
    black.data_type = "RGBA"
    black.inputs["Factor"].default_value = 1.0
    L.new(gin.outputs["Image"], black.inputs[6])
    black.inputs[7].default_value = (0.0, 0.0, 0.0, 1.0)
    canvas = black.outputs[2]

    missing, refs = [], {}
    for row, (light_name, layer, method) in enumerate(lights):
        y = -400.0 * row
        frame = _new(group, "NodeFrame", f"{PREFIX}{layer}:frame", f"{light_name} ({method})", (0.0, y))
        pids = list(dict.fromkeys([method, *REFERENCES[vis[layer]]]))
        src = _pass_sources(group, layer, pids, exr_image, 0.0, y, frame)
        for pid in pids:
            if pid in src:
                L.new(src[pid], gout.inputs[socket_name(layer, pid)])
            else:
                missing.append(socket_name(layer, pid))
        # the composite: this light's unshadowed render x the method's pass
        if method in src:
            mul = _new(group, "ShaderNodeMix", f"{PREFIX}{layer}:shadowed", "unshadowed x pass",
                       (300.0, y + 160.0), frame)
            mul.data_type = "RGBA"
            mul.blend_type = "MULTIPLY"
            mul.inputs["Factor"].default_value = 1.0
            L.new(gin.outputs[socket_name(layer, "unshadowed")], mul.inputs[6])
            L.new(src[method], mul.inputs[7])
            L.new(mul.outputs[2], gout.inputs[socket_name(layer, "shadowed")])
        else:
            missing.append(socket_name(layer, "shadowed"))
        # error: |method - reference| -> Map Range (0..Error Scale) -> Color Ramp
        ref = _error_reference(method, src, vis[layer]) if method in src else None
        err = None
        if ref is not None:
            refs[layer] = ref
            sub = _new(group, "ShaderNodeMath", f"{PREFIX}{layer}:diff", f"{method} - {ref}",
                       (300.0, y), frame)
            sub.operation = "SUBTRACT"
            L.new(src[method], sub.inputs[0])
            L.new(src[ref], sub.inputs[1])
            ab = _new(group, "ShaderNodeMath", f"{PREFIX}{layer}:abs", "|error|", (480.0, y), frame)
            ab.operation = "ABSOLUTE"
            L.new(sub.outputs[0], ab.inputs[0])
            mr = _new(group, "ShaderNodeMapRange", f"{PREFIX}{layer}:scale", "/ Error Scale",
                      (660.0, y), frame)
            mr.clamp = True
            L.new(ab.outputs[0], mr.inputs["Value"])
            L.new(gin.outputs["Error Scale"], mr.inputs["From Max"])
            ramp = _new(group, "ShaderNodeValToRGB", f"{PREFIX}{layer}:false colour", "False colour",
                        (860.0, y), frame)
            cr = ramp.color_ramp
            while len(cr.elements) < len(ERROR_RAMP):
                cr.elements.new(0.5)
            for el, (pos, col) in zip(cr.elements, ERROR_RAMP):
                el.position = pos
                el.color = col
            L.new(mr.outputs["Result"], ramp.inputs["Factor"])
            err = ramp.outputs["Color"]
            L.new(err, gout.inputs[socket_name(layer, "error")])
        else:
            missing.append(socket_name(layer, "error"))
        # side by side: each image at half size in its quadrant of a black canvas
        quads = {"method": src.get(method), "ray traced": src.get(REFERENCES[vis[layer]][0]),
                 "cycles": src.get("cycles"), "error": err}
        prev = canvas
        for k, (role, sock) in enumerate(quads.items()):
            if sock is None:
                continue
            qx, qy = QUADRANTS[role]
            sc = _new(group, "CompositorNodeScale", f"{PREFIX}{layer}:{role} scale", f"{role}: half size",
                      (1150.0, y - 120.0 * k), frame)
            sc.inputs["Type"].default_value = "Absolute"
            L.new(size[("X", 0.5)], sc.inputs["X"])
            L.new(size[("Y", 0.5)], sc.inputs["Y"])
            L.new(sock, sc.inputs["Image"])
            tr = _new(group, "CompositorNodeTranslate", f"{PREFIX}{layer}:{role} move", f"{role}: quadrant",
                      (1350.0, y - 120.0 * k), frame)
            L.new(sc.outputs["Image"], tr.inputs["Image"])
            L.new(size[("X", 0.25 * qx)], tr.inputs["X"])
            L.new(size[("Y", 0.25 * qy)], tr.inputs["Y"])
            ao = _new(group, "CompositorNodeAlphaOver", f"{PREFIX}{layer}:{role} over", "",
                      (1550.0, y - 120.0 * k), frame)
            L.new(prev, ao.inputs["Background"])
            L.new(tr.outputs["Image"], ao.inputs["Foreground"])
            prev = ao.outputs["Image"]
        L.new(prev, gout.inputs[socket_name(layer, "side by side")])
    return group, missing, refs


def unshadowed_socket(scene, rl, light_name: str, n_lights: int):
    """The Render Layers output holding the light's own render: its light
    group's Combined pass (``Combined_<group>``) when the light has one in
    the node's view layer, else Diffuse Direct when the scene renders this
    light alone and the pass is on; None otherwise (the user connects it).
    Nothing of the user's render settings is changed."""
    ob = bpy.data.objects.get(light_name)
    layer = scene.view_layers.get(rl.layer) if rl.layer else None
    group = getattr(ob, "lightgroup", "") if ob is not None else ""
    names = []
    if group and layer is not None and group in {g.name for g in getattr(layer, "lightgroups", ())}:
        names.append(f"Combined_{group}")
    if n_lights == 1 and layer is not None and layer.use_pass_diffuse_direct:
        names.append("Diffuse Direct")
    rl.update()
    for name in names:
        sock = rl.outputs.get(name)
        if sock is not None and sock.enabled:
            return sock
    return None


def clear_setup(tree) -> int:
    """Remove the compositor setup's nodes from ``tree`` (not the group)."""
    ours = [n for n in tree.nodes if _ours(n, SETUP_PREFIX) or n.name == SETUP_FRAME]
    for n in ours:
        tree.nodes.remove(n)
    return len(ours)


def setup_compositor(scene, lights, exr_path: Optional[str] = None, view_layer: Optional[str] = None,
                     error_scale: float = ERROR_SCALE) -> SetupResult:
    """Build (or rebuild) the "Penumbra" group and use it in the scene's
    compositing node group: Penumbra's own Render Layers node feeds a group
    node; a Viewer shows the first light's side-by-side image. ``lights`` =
    [(light name, layer, method pass id)]. Only Penumbra's nodes (named
    ``Penumbra:...``, inside the "Penumbra Compositor" frame) are replaced;
    the user's nodes and links are left alone."""
    lights = [(str(a), str(b), str(c)) for a, b, c in lights]
    from . import settings
    group, missing, refs = build_penumbra_group(lights, exr_path, settings.visibility(scene))
    tree = compositor_tree(scene)
    clear_setup(tree)
    x0 = max((n.location.x for n in tree.nodes), default=0.0) + 400.0
    frame = _new(tree, "NodeFrame", SETUP_FRAME, "Penumbra: method | references | error", (x0, 0.0))
    rl = _new(tree, "CompositorNodeRLayers", f"{SETUP_PREFIX}Render Layers", "Render (Penumbra)",
              (x0, 0.0), frame)
    rl.scene = scene
    if view_layer:
        rl.layer = view_layer
    node = _new(tree, "CompositorNodeGroup", f"{SETUP_PREFIX}{GROUP_NAME}", GROUP_NAME,
                (x0 + 320.0, 0.0), frame)
    node.node_tree = group
    node.inputs["Error Scale"].default_value = float(error_scale)
    tree.links.new(compat.render_layers_socket(rl, "Image"), node.inputs["Image"])
    unwired = []
    for light_name, layer, _method in lights:
        sock = unshadowed_socket(scene, rl, light_name, len(lights))
        if sock is None:
            unwired.append(socket_name(layer, "unshadowed"))
        else:
            tree.links.new(sock, node.inputs[socket_name(layer, "unshadowed")])
    if lights:
        viewer = _new(tree, "CompositorNodeViewer", f"{SETUP_PREFIX}Viewer", "Penumbra side by side",
                      (x0 + 640.0, 0.0), frame)
        tree.links.new(node.outputs[socket_name(lights[0][1], "side by side")], viewer.inputs["Image"])
    return SetupResult(tree, group, node, lights, missing, refs, unwired)
