"""Alpha mattes from Blender materials: the capture side of
``core/alpha.py``.

A material's alpha as Cycles sees it, read from its node tree (the Surface
input of the active Cycles Material Output, followed through reroutes):

* an Image Texture's Alpha (or Color, converted to a float as Cycles converts
  a colour -> float link: luminance with Rec.709 weights of the linear
  colour) linked to a Principled BSDF's Alpha (the glTF / FBX wiring);
* a constant Principled Alpha below 1 (a 1x1 matte);
* a Mix Shader of a Transparent BSDF and an opaque shader: alpha = the
  opaque shader's share (Factor weights the second Shader input), times the
  Transparent BSDF's colour (mean of RGB) for a grey one; the Factor a
  constant or an Image Texture (Alpha or Color);
* a Transparent BSDF alone (a constant matte).

Anything else with transparency (procedural alpha, math nodes, groups, other
set-ups) is treated as opaque with a one-line warning; so are unreadable
images (missing file, 0 x 0, UDIM / sequence / movie) and meshes that use a
matte but have no UV map. ``MatteCapture.opaque`` lists them for the plan.

UVs: an unlinked Vector uses the mesh's ``active_render`` UV map (checked in
bpy 5.0.1: Cycles renders with it, not with ``active``); a UV Map node names
its map; a Texture Coordinate node's UV output is the default map.
Extension MIRROR is captured exactly as REPEAT of the image mirrored into a
2w x 2h matte, with the triangles' UVs halved.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Dict, List, Optional, Tuple

import numpy as np

from ..core.alpha import CLIP, CLOSEST, EXTEND, LINEAR, REPEAT, AlphaMattes
from . import compat

log = logging.getLogger(__name__)

#: Rec.709 luminance of linear RGB: Cycles' colour -> float conversion
#: (``linear_rgb_to_gray`` with the default OCIO config's coefficients).
LUMA = np.array([0.2126, 0.7152, 0.0722], np.float32)
INTERPOLATION = {"Closest": CLOSEST, "Linear": LINEAR, "Cubic": LINEAR, "Smart": LINEAR}
EXTENSION = {"REPEAT": REPEAT, "EXTEND": EXTEND, "CLIP": CLIP, "MIRROR": REPEAT}


class Unreadable(Exception):
    """A material's transparency the capture cannot read (the reason)."""


@dataclass
class MatteSource:
    """A material's alpha: ``clip(bias + scale * x)`` with ``x`` the image
    node's output ``output`` ("Alpha" or "Color") or ``constant``."""

    bias: float
    scale: float
    constant: Optional[float] = None
    node: object = None             # the ShaderNodeTexImage
    output: str = "Alpha"
    uv_map: Optional[str] = None    # None: the mesh's default (active_render) UV map

    @property
    def image(self):
        return None if self.node is None else self.node.image

    def alpha_of(self, x):
        return np.clip(self.bias + self.scale * np.asarray(x, np.float32), 0.0, 1.0)


# --------------------------------------------------------------------------
# reading node trees
def _from(socket):
    """(node, output socket) linked into ``socket`` through reroutes, or None
    (unlinked, or only muted links: Cycles uses the default value)."""
    seen = 0
    while True:
        links = [lk for lk in socket.links if not lk.is_muted and lk.is_valid]
        if not links:
            return None
        node, out = links[0].from_node, links[0].from_socket
        if node.bl_idname != "NodeReroute":
            return node, out
        socket = node.inputs[0]
        seen += 1
        if seen > 1000:             # a reroute loop
            return None


def _tree_nodes(tree, depth: int = 0) -> List[object]:
    """Every node of ``tree``, nested node groups' nodes included."""
    out = []
    for n in tree.nodes:
        out.append(n)
        if n.bl_idname == "ShaderNodeGroup" and n.node_tree is not None and depth < 8:
            out.extend(_tree_nodes(n.node_tree, depth + 1))
    return out


def _upstream(socket) -> List[object]:
    """Every node feeding ``socket`` (node groups' own nodes included)."""
    out, stack, seen = [], [socket], set()
    while stack:
        s = stack.pop()
        for lk in s.links:
            if lk.is_muted:
                continue
            n = lk.from_node
            if n.as_pointer() in seen:
                continue
            seen.add(n.as_pointer())
            out.append(n)
            stack.extend(n.inputs)
            if n.bl_idname == "ShaderNodeGroup" and n.node_tree is not None:
                out.extend(_tree_nodes(n.node_tree))
    return out


def _is_transparent(node) -> bool:
    if node.bl_idname == "ShaderNodeBsdfTransparent":
        return True
    if node.bl_idname == "ShaderNodeBsdfPrincipled":
        a = node.inputs["Alpha"]
        return _from(a) is not None or float(a.default_value) < 1.0
    return False


def _has_transparency(socket) -> bool:
    return any(_is_transparent(n) for n in _upstream(socket))


def _what(node) -> str:
    return f"a {node.bl_label or node.bl_idname} node"


def _image_source(node, out, what: str) -> MatteSource:
    """The image texture ``node`` (output ``out``) feeding ``what``."""
    if node.bl_idname != "ShaderNodeTexImage":
        raise Unreadable(f"{what} comes from {_what(node)}")
    if out.name not in ("Alpha", "Color"):
        raise Unreadable(f"{what} comes from the image node's {out.name} output")
    if node.mute:
        raise Unreadable(f"{what} comes from a muted image node")
    if node.image is None:
        raise Unreadable(f"{what} comes from an image node without an image")
    if node.projection != "FLAT":
        raise Unreadable(f"{what}: image projection {node.projection} (only Flat is read)")
    uv_map = None
    vec = _from(node.inputs["Vector"])
    if vec is not None:
        vnode, vout = vec
        if vnode.bl_idname == "ShaderNodeUVMap":
            uv_map = vnode.uv_map or None
        elif not (vnode.bl_idname == "ShaderNodeTexCoord" and vout.name == "UV"):
            raise Unreadable(f"{what}: the image's Vector comes from {_what(vnode)} "
                             "(only UV maps are read)")
    return MatteSource(0.0, 1.0, node=node, output=out.name, uv_map=uv_map)


def _principled(bsdf) -> Optional[MatteSource]:
    a = bsdf.inputs["Alpha"]
    src = _from(a)
    if src is None:
        value = float(a.default_value)
        return None if value >= 1.0 else MatteSource(0.0, 1.0, constant=value)
    return _image_source(src[0], src[1], "the Principled BSDF's Alpha")


def _transparent_colour(node) -> float:
    c = node.inputs["Color"]
    if _from(c) is not None:
        raise Unreadable("the Transparent BSDF's Color is linked")
    return float(np.mean(np.asarray(c.default_value[:3], np.float64)))


def _mix(mix) -> Optional[MatteSource]:
    """Mix Shader: out = (1 - f) Shader_1 + f Shader_2 (inputs by position)."""
    fac, s1, s2 = mix.inputs[0], mix.inputs[1], mix.inputs[2]
    n1, n2 = _from(s1), _from(s2)
    t1 = n1 is not None and n1[0].bl_idname == "ShaderNodeBsdfTransparent"
    t2 = n2 is not None and n2[0].bl_idname == "ShaderNodeBsdfTransparent"
    if t1 == t2:
        if _has_transparency(s1) or _has_transparency(s2):
            raise Unreadable("a Mix Shader that is not a Transparent BSDF and an opaque shader")
        return None
    if _has_transparency(s2 if t1 else s1):
        raise Unreadable("a Mix Shader whose other shader is transparent too")
    c = _transparent_colour((n1 if t1 else n2)[0])
    # transmittance = c * (transparent share); alpha = 1 - transmittance
    # Transparent first: share = 1 - f -> alpha = (1 - c) + c f
    # Transparent second: share = f   -> alpha = 1 - c f
    bias, scale = (1.0 - c, c) if t1 else (1.0, -c)
    src = _from(fac)
    if src is None:
        f = float(np.clip(fac.default_value, 0.0, 1.0))
        value = float(np.clip(bias + scale * f, 0.0, 1.0))
        return None if value >= 1.0 else MatteSource(0.0, 1.0, constant=value)
    m = _image_source(src[0], src[1], "the Mix Shader's Factor")
    m.bias, m.scale = bias, scale
    return m


def read_material(mat) -> Optional[MatteSource]:
    """The material's alpha, None when it is opaque; raises Unreadable for
    transparency this capture cannot read."""
    nt = getattr(mat, "node_tree", None)
    if nt is None:
        return None
    out = nt.get_output_node("CYCLES")
    if out is None:
        return None
    surface = out.inputs["Surface"]
    src = _from(surface)
    if src is None:
        return None
    node = src[0]
    if node.mute:
        if _has_transparency(surface):
            raise Unreadable("its surface shader is muted")
        return None
    kind = node.bl_idname
    if kind == "ShaderNodeBsdfPrincipled":
        return _principled(node)
    if kind == "ShaderNodeMixShader":
        return _mix(node)
    if kind == "ShaderNodeBsdfTransparent":
        value = 1.0 - _transparent_colour(node)
        return None if value >= 1.0 else MatteSource(0.0, 1.0, constant=max(value, 0.0))
    if _has_transparency(surface):
        raise Unreadable(f"its transparency comes through {_what(node)}")
    return None


# --------------------------------------------------------------------------
# images
def _srgb_to_linear(c: np.ndarray) -> np.ndarray:
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4).astype(np.float32)


def image_values(node, output: str) -> np.ndarray:
    """float32[h, w] (row 0 = v 0) of the image node's ``output`` as Cycles
    reads it: Alpha, or Color -> float (linear luminance of the colour,
    premultiplied by alpha unless the node's Alpha output is linked, as
    Cycles' image node outputs it; within about 0.005 of Cycles for a byte
    image whose Alpha is linked too, where Cycles' 8-bit round trip is not
    modelled). Raises Unreadable for an image that
    cannot be read."""
    image = node.image
    if image.source not in ("FILE", "GENERATED"):
        raise Unreadable(f"image source {image.source} (only single images are read)")
    try:
        w, h = (int(v) for v in image.size)
        n = len(image.pixels) if w * h > 0 else 0
    except Exception:               # pragma: no cover - RNA refuses to load it
        w = h = n = 0
    if w * h <= 0 or n <= 0 or n % (w * h):
        raise Unreadable("cannot be read (missing file, empty or unsupported format)")
    buf = np.empty(n, np.float32)
    image.pixels.foreach_get(buf)
    px = np.nan_to_num(buf.reshape(h, w, n // (w * h)), nan=0.0, posinf=1.0, neginf=0.0)
    c = px.shape[-1]
    has_alpha = c == 4 and image.alpha_mode != "NONE"
    alpha = px[..., 3] if has_alpha else np.ones((h, w), np.float32)
    if output == "Alpha":
        return np.ascontiguousarray(alpha, np.float32)
    rgb = px[..., :3] if c >= 3 else np.repeat(px[..., :1], 3, axis=-1)
    space = image.colorspace_settings.name
    data = bool(getattr(image.colorspace_settings, "is_data", False)) or space == "Non-Color"
    if has_alpha and not data and image.alpha_mode != "CHANNEL_PACKED":
        # Cycles' Color output is premultiplied unless the node's Alpha is linked
        # (then divided by alpha), in the stored colour space: PREMUL images (and
        # float buffers in 5.0: compat) are stored premultiplied, byte STRAIGHT
        # ones are not and are premultiplied in 8 bits (checked against Cycles)
        stored_premultiplied = image.alpha_mode == "PREMUL" or (
            image.is_float and compat.float_pixels_premultiplied())
        alpha_linked = any(not lk.is_muted for lk in node.outputs["Alpha"].links)
        if not alpha_linked and not stored_premultiplied:
            rgb = rgb * alpha[..., None]
            if not image.is_float:
                rgb = np.round(rgb * 255.0) / 255.0
        elif alpha_linked and stored_premultiplied:
            rgb = np.divide(rgb, alpha[..., None], out=np.zeros_like(rgb), where=alpha[..., None] > 0)
    if space == "sRGB" and not image.is_float:
        rgb = _srgb_to_linear(rgb)
    return np.ascontiguousarray(rgb @ LUMA, np.float32)


# --------------------------------------------------------------------------
# the capture's state: one per capture_scene
class MatteCapture:
    """Mattes met while capturing one scene: each material read once, each
    image's texels captured once (instances and materials share them)."""

    def __init__(self, materials=()):
        self._by_material: Dict[int, int] = {}      # material pointer -> matte id (-1 opaque)
        self._blocks: Dict[tuple, Tuple[int, int, int]] = {}   # -> (offset, w, h)
        self._texels: List[np.ndarray] = []
        self._size = 0
        self.offset: List[int] = []
        self.width: List[int] = []
        self.height: List[int] = []
        self.interpolation: List[int] = []
        self.extension: List[int] = []
        self.mirror: List[bool] = []
        self.uv_map: List[Optional[str]] = []
        self.needs_uv: List[bool] = []
        self.names: List[str] = []                  # "material / image" (or "/ constant a")
        self.material: List[str] = []
        self.image: List[str] = []
        self.opaque: List[str] = []                 # "material: reason", for the plan
        self._warned = set()
        #: False when no material of ``materials`` (the depsgraph's) has any
        #: transparency: the capture then reads no material and no UV at all
        self.enabled = any(_maybe_transparent(m) for m in materials)

    # -- materials ---------------------------------------------------------
    def _treat_opaque(self, key, material: str, reason: str) -> None:
        if key in self._warned:
            return
        self._warned.add(key)
        log.warning("penumbra: material %r: %s; treated as opaque", material, reason)
        self.opaque.append(f"{material} ({reason})")

    def matte_of(self, mat) -> int:
        """The matte id of an (evaluated) material, -1 when opaque."""
        if mat is None:
            return -1
        key = mat.as_pointer()
        hit = self._by_material.get(key)
        if hit is not None:
            return hit
        name = mat.original.name_full if getattr(mat, "original", None) else mat.name_full
        mid = -1
        try:
            src = read_material(mat)
            if src is not None:
                mid = self._add(name, src)
        except Unreadable as exc:
            self._treat_opaque(("material", name), name, str(exc))
        except Exception as exc:    # pragma: no cover - a node tree RNA refuses to read
            self._treat_opaque(("material", name), name,
                               f"its node tree could not be read ({type(exc).__name__}: {exc})")
        self._by_material[key] = mid
        return mid

    def _add(self, name: str, src: MatteSource) -> int:
        if src.node is None:
            value = float(np.clip(src.constant, 0.0, 1.0))
            off, w, h = self._block(("constant", value), lambda: np.full((1, 1), value, np.float32))
            interp, ext, mirror, label = CLOSEST, REPEAT, False, f"constant {value:g}"
        else:
            node, image = src.node, src.image
            mirror = node.extension == "MIRROR"
            key = (image.as_pointer(), src.output, src.bias, src.scale, mirror,
                   image.alpha_mode, bool(node.outputs["Alpha"].links) if src.output == "Color" else None)

            def texels():
                try:
                    v = src.alpha_of(image_values(node, src.output))
                except Unreadable as exc:
                    raise Unreadable(f"image {image.name!r} {exc}")
                if mirror:                  # [v | mirrored v] over [same, flipped in v]
                    v = np.concatenate([v, v[:, ::-1]], 1)
                    v = np.concatenate([v, v[::-1]], 0)
                return v
            off, w, h = self._block(key, texels)
            interp = INTERPOLATION.get(node.interpolation, LINEAR)
            ext = EXTENSION[node.extension]
            label = image.name
        mid = len(self.offset)
        self.offset.append(off)
        self.width.append(w)
        self.height.append(h)
        self.interpolation.append(interp)
        self.extension.append(ext)
        self.mirror.append(mirror)
        self.uv_map.append(src.uv_map)
        self.needs_uv.append(src.node is not None)
        self.names.append(f"{name} / {label}")
        self.material.append(name)
        self.image.append(label)
        return mid

    def _block(self, key, make) -> Tuple[int, int, int]:
        hit = self._blocks.get(key)
        if hit is None:
            v = np.ascontiguousarray(make(), np.float32)
            hit = (self._size, int(v.shape[1]), int(v.shape[0]))
            self._texels.append(v.reshape(-1))
            self._size += v.size
            self._blocks[key] = hit
        return hit

    def object_lut(self, ob) -> Optional[np.ndarray]:
        """int32[slots] matte id per material slot of an evaluated object,
        or None when none of its materials has a matte."""
        if not self.enabled:
            return None
        mats = [slot.material for slot in ob.material_slots]
        if not mats:
            mats = list(getattr(ob.data, "materials", None) or [])
        lut = np.array([self.matte_of(m) for m in mats], np.int32)
        return lut if len(lut) and (lut >= 0).any() else None

    # -- triangles ---------------------------------------------------------
    def triangle_mattes(self, mesh, lut: np.ndarray, what: str) -> Tuple[np.ndarray, np.ndarray]:
        """(tri_matte int32[T], tri_uv float32[T,3,2]) of a triangulated mesh
        whose material slots map to mattes by ``lut``."""
        nt = len(mesh.loop_triangles)
        mi = np.empty(nt, np.int32)
        if nt:
            mesh.loop_triangles.foreach_get("material_index", mi)
        # Cycles clamps a material index past the last slot to the last slot
        tri_matte = lut[np.clip(mi, 0, len(lut) - 1)]
        tri_uv = np.zeros((nt, 3, 2), np.float32)
        used = np.unique(tri_matte[tri_matte >= 0])
        if not len(used):
            return tri_matte, tri_uv
        loops = np.empty(nt * 3, np.int32)
        mesh.loop_triangles.foreach_get("loops", loops)
        loops = loops.reshape(-1, 3)
        uv_cache: Dict[Optional[str], Optional[np.ndarray]] = {}
        for m in used:                      # per matte, not per triangle
            m = int(m)
            if not self.needs_uv[m]:
                continue
            sel = tri_matte == m
            name = self.uv_map[m]
            if name not in uv_cache:
                uv_cache[name] = _uv_loops(mesh, name)
            uv = uv_cache[name]
            if uv is None:
                missing = f"UV map {name!r}" if name else "UV map"
                self._treat_opaque(("uv", what, m), self.material[m],
                                   f"image {self.image[m]!r} on {what!r}, which has no {missing}")
                tri_matte[sel] = -1
                continue
            tri_uv[sel] = uv[loops[sel]]
        return tri_matte, tri_uv

    # -- the result --------------------------------------------------------
    def build(self, tri_matte: np.ndarray, tri_uv: np.ndarray) -> Optional[AlphaMattes]:
        """The scene's AlphaMattes, None when no triangle has a matte."""
        if not len(tri_matte) or not (tri_matte >= 0).any():
            return None
        mirror = np.array(self.mirror, bool)
        if mirror.any():                    # mirrored images are tiled 2 x 2: halve their UVs
            halve = np.zeros(len(tri_matte), bool)
            hit = tri_matte >= 0
            halve[hit] = mirror[tri_matte[hit]]
            tri_uv = tri_uv.copy()
            tri_uv[halve] *= 0.5
        return AlphaMattes(tri_matte=tri_matte, tri_uv=tri_uv,
                           texels=np.concatenate(self._texels) if self._texels else np.zeros(0, np.float32),
                           offset=self.offset, width=self.width, height=self.height,
                           interpolation=self.interpolation, extension=self.extension,
                           names=list(self.names))


def _uv_loops(mesh, name: Optional[str]) -> Optional[np.ndarray]:
    """float32[loops, 2] of the named UV map (None: the one Cycles renders
    with, ``active_render``), finite; None when the mesh has no such map."""
    layers = mesh.uv_layers
    if name:
        layer = layers.get(name)
    else:
        layer = next((l for l in layers if l.active_render), None) or layers.active
    if layer is None:
        return None
    uv = np.empty(len(mesh.loops) * 2, np.float32)
    if len(uv):
        layer.data.foreach_get("uv", uv)
    return np.nan_to_num(uv.reshape(-1, 2), nan=0.0, posinf=0.0, neginf=0.0)


def _maybe_transparent(mat) -> bool:
    """Cheap pre-check: does the material's tree hold a transparent shader
    (a Transparent BSDF, or a Principled BSDF with a linked or < 1 Alpha)?"""
    nt = getattr(mat, "node_tree", None)
    if nt is None:
        return False
    try:
        return any(_is_transparent(n) for n in _tree_nodes(nt))
    except Exception:               # pragma: no cover - a broken tree: read it in full later
        return True

