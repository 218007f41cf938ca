"""The ``cycles`` reference: the irradiance ratio V as Cycles renders it.

Per light, two Cycles renders of the scene's camera view, each with only that
light on, every surface a white diffuse (``view_layer.material_override``):

    V = Diffuse Direct with the light's shadow / Diffuse Direct with
        ``light.use_shadow = False``

(DESIGN.md "What V means": the irradiance ratio, compared with ``embree_irr``).
Both renders use the same seed, so they trace the same light samples and the
ratio's noise is that of a ratio estimator with ``samples`` light samples per
pixel, like ``embree_irr``'s. Settings (BLENDER_NOTES.md, "A Cycles shadow
reference that lines up"): GAUSSIAN pixel filter of width 0.01 px (one ray
through each pixel centre, as Penumbra's pixel-centre G-buffer) or, for a
filtered pass (``core/pixel_filter.py``), the pass's own filter
(``cycles_filter``), every bounce count 0, next
event estimation only, no adaptive sampling, no denoising, no light-sampling
threshold, no clamping, no time limit; the world is removed for the render
(it would light the scene too) and so are the other lights (``hide_render``).

Alpha mattes: an override replaces every material, so a scene
whose materials hold a matte (``bridge/mattes.py`` reads them as the capture
does) is rendered without ``material_override``: every material slot gets the
white diffuse instead, except those with a matte, which get a white copy that
keeps the matte (Mix Shader of a Transparent BSDF and the white diffuse, by
the same image node, interpolation, extension and UV map, or the constant),
and ``transparent_max_bounces`` is 64 (at 0 alpha cards cast solid shadows;
BLENDER_NOTES "Alpha mattes"). Checked in bpy 5.0.1. Materials the capture
treats as opaque are white and opaque here too. Scenes without mattes render
with the override and no transparent bounces.

The renders go to a temporary folder as multilayer EXR (the "Render Result"
image has no pixels in background mode; checked in bpy 5.0.1) and the Diffuse
Direct pass is read back with OpenEXR (Blender writes one part per pass).
Everything changed on the scene is put back afterwards, error or not, and
nothing is ever saved to the .blend. The compositor, the sequencer and
Penumbra's own "passes in every render" setting are off for these renders;
render handlers can also recognise them with :func:`is_rendering`.
"""
from __future__ import annotations

import glob
import logging
import os
import shutil
import tempfile
import time
from typing import Callable, Dict, List, Tuple

import numpy as np

import bpy

from ..core.methods.base import MethodResult
from .capture import object_named, view_layer_of
from .mattes import MatteSource, Unreadable, read_material

log = logging.getLogger(__name__)

PASS_ID = "cycles"
FILTER = {"type": "GAUSSIAN", "width_px": 0.01}


def cycles_filter(pixel_filter=None) -> dict:
    """Cycles' ``pixel_filter_type`` / ``filter_width`` for a core PixelFilter
    (None or ``none``: ``FILTER``, rays through pixel centres). EEVEE's radial
    Gaussian (sigma 0.284 R) becomes Cycles' Gaussian of the same sigma
    (sigma = width / 4)."""
    if pixel_filter is None or pixel_filter.is_none:
        return dict(FILTER)
    kind, w = pixel_filter.kind, float(pixel_filter.width)
    if kind == "box":
        return {"type": "BOX", "width_px": 1.0}
    if kind == "eevee":
        from ..core.pixel_filter import EEVEE_SIGMA
        return {"type": "GAUSSIAN", "width_px": 4.0 * EEVEE_SIGMA * w}
    return {"type": {"gaussian": "GAUSSIAN", "blackman-harris": "BLACKMAN_HARRIS"}[kind], "width_px": w}


WHITE_MATERIAL = "Penumbra White Diffuse (temporary)"
DIFFUSE_DIRECT = "Diffuse Direct"
WHITE_MATTE_MATERIAL = "Penumbra White Matte (temporary)"
#: transparent bounces for a scene with mattes: alpha cards crossed per ray
TRANSPARENT_BOUNCES = 64

_rendering = 0


def is_rendering() -> bool:
    """True while a Cycles reference render runs (render handlers should then
    do nothing: these renders are Penumbra's own, not the user's)."""
    return _rendering > 0


class CyclesReferenceError(ValueError):
    """A clear one-line reason the reference cannot be rendered."""


# --------------------------------------------------------------------------
# scene changes that are always undone
class _Changes:
    """Attribute changes remembered with their old values, undone in reverse
    order (each one on its own: one failure does not stop the others)."""

    def __init__(self):
        self._undo: List[Tuple[object, str, object]] = []
        self._seen = set()

    def set(self, owner, attr: str, value) -> None:
        key = (owner.as_pointer() if hasattr(owner, "as_pointer") else id(owner), type(owner).__name__, attr)
        if key not in self._seen:
            self._seen.add(key)
            self._undo.append((owner, attr, getattr(owner, attr)))
        if getattr(owner, attr) != value:
            setattr(owner, attr, value)

    def remember(self, owner, *attrs: str) -> None:
        """Record current values without changing them (settings that change
        one another, e.g. the image format and its colour depth)."""
        for attr in attrs:
            if hasattr(owner, attr):
                self.set(owner, attr, getattr(owner, attr))

    def set_if(self, owner, attr: str, value) -> None:
        """``set`` when ``owner`` has ``attr`` (settings that come and go
        between Blender versions)."""
        if owner is not None and hasattr(owner, attr):
            self.set(owner, attr, value)

    def restore(self) -> List[str]:
        """Put every value back. Some settings depend on others (an 8-bit
        colour depth is refused while the format is still EXR and silently
        becomes 16), so passes repeat until nothing changes."""
        failed: Dict[str, str] = {}
        for _ in range(4):
            changed = False
            failed.clear()
            for owner, attr, old in reversed(self._undo):
                try:
                    if getattr(owner, attr) != old:
                        setattr(owner, attr, old)
                        changed = True
                except Exception as exc:       # report, keep restoring the rest
                    failed[attr] = f"{attr}: {exc}"
            if not changed:
                break
        for owner, attr, old in self._undo:
            try:
                if getattr(owner, attr) != old:
                    failed.setdefault(attr, f"{attr} stays {getattr(owner, attr)!r}, not {old!r}")
            except Exception as exc:           # pragma: no cover - the owner is gone
                failed.setdefault(attr, f"{attr}: {exc}")
        for msg in failed.values():
            log.warning("Penumbra: could not restore %s", msg)
        self._undo.clear()
        self._seen.clear()
        return list(failed.values())


# --------------------------------------------------------------------------
# helpers
def find_light_object(name: str):
    """The light object a captured light's ``name`` names (``name_full``)."""
    ob = object_named(name)
    if ob is None:
        if "#" in name:
            raise CyclesReferenceError(
                f"light {name!r} is an instance (collection / geometry instancing); the Cycles "
                "reference needs a light object of its own")
        raise CyclesReferenceError(f"no light object named {name!r}")
    if ob.type != "LIGHT":
        raise CyclesReferenceError(f"{name!r} is a {ob.type}, not a light")
    return ob


def _white_material():
    mat = bpy.data.materials.new(WHITE_MATERIAL)
    nt = mat.node_tree
    for n in list(nt.nodes):
        nt.nodes.remove(n)
    bsdf = nt.nodes.new("ShaderNodeBsdfDiffuse")
    bsdf.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    bsdf.inputs["Roughness"].default_value = 0.0
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    nt.links.new(bsdf.outputs["BSDF"], out.inputs["Surface"])
    mat.diffuse_color = (1.0, 1.0, 1.0, 1.0)
    return mat


def _white_matte_material(src: MatteSource):
    """White diffuse with the matte of ``src``: Mix Shader(Factor = alpha,
    Transparent BSDF, white Diffuse BSDF), alpha = clamp(bias + scale x) with
    x the image node's output (a colour -> float link converts as in the
    original) or the constant."""
    mat = _white_material()
    mat.name = WHITE_MATTE_MATERIAL
    nt = mat.node_tree
    bsdf = next(n for n in nt.nodes if n.bl_idname == "ShaderNodeBsdfDiffuse")
    out = next(n for n in nt.nodes if n.bl_idname == "ShaderNodeOutputMaterial")
    clear = nt.nodes.new("ShaderNodeBsdfTransparent")
    clear.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    mix = nt.nodes.new("ShaderNodeMixShader")
    nt.links.new(clear.outputs["BSDF"], mix.inputs[1])
    nt.links.new(bsdf.outputs["BSDF"], mix.inputs[2])
    nt.links.new(mix.outputs["Shader"], out.inputs["Surface"])
    if src.node is None:
        mix.inputs[0].default_value = float(src.alpha_of(src.constant))
        return mat
    tex = nt.nodes.new("ShaderNodeTexImage")
    tex.image = src.node.image
    tex.interpolation = src.node.interpolation
    tex.extension = src.node.extension
    if src.uv_map:
        uv = nt.nodes.new("ShaderNodeUVMap")
        uv.uv_map = src.uv_map
        nt.links.new(uv.outputs["UV"], tex.inputs["Vector"])
    affine = nt.nodes.new("ShaderNodeMath")
    affine.operation = "MULTIPLY_ADD"
    affine.use_clamp = True
    affine.inputs[1].default_value = float(src.scale)
    affine.inputs[2].default_value = float(src.bias)
    nt.links.new(tex.outputs[src.output], affine.inputs[0])
    nt.links.new(affine.outputs["Value"], mix.inputs[0])
    if src.output == "Color" and any(not lk.is_muted for lk in src.node.outputs["Alpha"].links):
        # Cycles divides the Color output by alpha when the node's Alpha output is
        # linked (checked in 5.0.1): link it here too, through min(value, alpha + 1),
        # which keeps the value (<= 1) and cannot be constant-folded away
        plus_one = nt.nodes.new("ShaderNodeMath")
        plus_one.operation = "ADD"
        plus_one.inputs[1].default_value = 1.0
        keep = nt.nodes.new("ShaderNodeMath")
        keep.operation = "MINIMUM"
        nt.links.new(tex.outputs["Alpha"], plus_one.inputs[0])
        nt.links.new(affine.outputs["Value"], keep.inputs[0])
        nt.links.new(plus_one.outputs["Value"], keep.inputs[1])
        nt.links.new(keep.outputs["Value"], mix.inputs[0])
    return mat


def _matte_swaps(white) -> Tuple[List[tuple], List[object]]:
    """([(material slot, replacement)], [matte copies made]) for every
    object's material slots when some material holds a matte; ([], []) when
    none does (the view layer's override is used then)."""
    copies: Dict[int, object] = {}
    swaps = []
    seen = set()
    for ob in bpy.data.objects:
        for i, slot in enumerate(ob.material_slots):
            m = slot.material
            # a slot linked to the data is the mesh's: linked duplicates share it (swap it once,
            # or restoring would put the replacement back)
            owner = ob.data if slot.link == "DATA" else ob
            if m is None or (owner.as_pointer(), slot.link, i) in seen:
                continue
            seen.add((owner.as_pointer(), slot.link, i))
            key = m.as_pointer()
            if key not in copies:
                try:
                    src = read_material(m)
                except Unreadable:
                    src = None
                copies[key] = _white_matte_material(src) if src is not None else None
            swaps.append((slot, copies[key] or white))
    made = [c for c in copies.values() if c is not None]
    return (swaps, made) if made else ([], [])


def read_diffuse_direct(path: str, view_layer: str) -> np.ndarray:
    """float32[H,W,3] Diffuse Direct (row 0 at the top) from a Cycles multilayer
    EXR, walking its parts (Blender writes one part per pass)."""
    import OpenEXR
    want = {f"{view_layer}.{DIFFUSE_DIRECT}.{c}": i for i, c in enumerate("RGB")}
    found: Dict[int, np.ndarray] = {}
    with OpenEXR.File(path, separate_channels=True) as f:
        for part in f.parts:
            for name, ch in part.channels.items():
                if name in want:
                    found[want[name]] = np.asarray(ch.pixels, np.float32)
        if len(found) != 3:     # a single-layer file names channels without the layer
            for part in f.parts:
                for name, ch in part.channels.items():
                    for k, c in enumerate("RGB"):
                        if k not in found and name.endswith(f"{DIFFUSE_DIRECT}.{c}"):
                            found[k] = np.asarray(ch.pixels, np.float32)
    if len(found) != 3:
        raise CyclesReferenceError(f"{os.path.basename(path)} holds no {DIFFUSE_DIRECT} pass")
    return np.stack([found[0], found[1], found[2]], axis=-1)


def shadow_ratio(shadowed: np.ndarray, unshadowed: np.ndarray) -> np.ndarray:
    """V = sum_c shadowed / sum_c unshadowed over the colour channels; 0
    where the unshadowed sum is not positive; finite, clamped to [0, 1]."""
    s = np.asarray(shadowed, np.float64)
    u = np.asarray(unshadowed, np.float64)
    if s.ndim == 3:
        s = s.sum(axis=-1)
        u = u.sum(axis=-1)
    s = np.nan_to_num(s, nan=0.0, posinf=0.0, neginf=0.0)
    u = np.nan_to_num(u, nan=0.0, posinf=0.0, neginf=0.0)
    ok = u > 0.0
    v = np.zeros(u.shape, np.float64)
    np.divide(s, u, out=v, where=ok)
    return np.clip(v, 0.0, 1.0).astype(np.float32)


def _configure(ch: _Changes, scene, view_layer, resolution, samples, seed, out_base, material,
               filter_: dict = FILTER):
    """Every setting of the reference render, remembered in ``ch``."""
    r = scene.render
    c = scene.cycles
    ch.set(r, "engine", "CYCLES")
    W, H = resolution
    ch.set(r, "resolution_x", int(W))
    ch.set(r, "resolution_y", int(H))
    ch.set(r, "resolution_percentage", 100)
    for attr, value in (("use_border", False), ("use_crop_to_border", False),
                        ("use_compositing", False),
                        ("use_sequencer", False), ("use_freestyle", False),
                        ("film_transparent", False), ("use_file_extension", True),
                        ("use_overwrite", True), ("use_placeholder", False),
                        ("use_single_layer", False)):
        ch.set_if(r, attr, value)
    ch.set(r, "filepath", out_base)
    im = r.image_settings
    ch.remember(im, "media_type", "file_format", "color_depth", "exr_codec", "color_mode",
                "color_management")
    # order matters (BLENDER_NOTES.md): media type first, it switches the format
    ch.set_if(im, "media_type", "MULTI_LAYER_IMAGE")
    ch.set(im, "file_format", "OPEN_EXR_MULTILAYER")
    ch.set(im, "color_depth", "32")
    ch.set(im, "exr_codec", "ZIP")
    # Cycles: the pass's pixel filter, direct light only, plain Monte Carlo
    for attr, value in (("samples", int(samples)), ("seed", int(seed)),
                        ("use_animated_seed", False), ("use_adaptive_sampling", False),
                        ("use_denoising", False), ("pixel_filter_type", filter_["type"]),
                        ("filter_width", float(filter_["width_px"])), ("max_bounces", 0), ("diffuse_bounces", 0),
                        ("glossy_bounces", 0), ("transmission_bounces", 0),
                        ("volume_bounces", 0), ("transparent_max_bounces", 0),
                        ("direct_light_sampling_type", "NEXT_EVENT_ESTIMATION"),
                        ("light_sampling_threshold", 0.0), ("sample_clamp_direct", 0.0),
                        ("sample_clamp_indirect", 0.0), ("time_limit", 0.0),
                        ("use_sample_subset", False), ("sample_offset", 0),
                        ("use_layer_samples", "IGNORE"), ("use_guiding", False),
                        ("caustics_reflective", False), ("caustics_refractive", False)):
        ch.set_if(c, attr, value)
    ch.set(scene, "world", None)            # the world would light the scene too
    ss = getattr(scene, "penumbra", None)
    if ss is not None:                      # Penumbra's own render handlers stay out of it
        ch.set_if(ss, "render_passes", False)
    ch.set(view_layer, "use", True)
    ch.set(view_layer, "material_override", material)
    ch.set(view_layer, "use_pass_diffuse_direct", True)
    ch.set_if(view_layer, "samples", 0)


def _render_once(scene, view_layer, folder: str) -> Tuple[np.ndarray, float]:
    for p in glob.glob(os.path.join(folder, "*")):
        os.unlink(p)
    t0 = time.perf_counter()
    bpy.ops.render.render(write_still=True, layer=view_layer.name, scene=scene.name)
    dt = time.perf_counter() - t0
    files = sorted(glob.glob(os.path.join(folder, "*.exr")))
    if not files:
        raise CyclesReferenceError("the Cycles render wrote no EXR")
    return read_diffuse_direct(files[0], view_layer.name), dt


def render_light_reference(scene, light_name: str, resolution, samples: int = 64, seed: int = 0,
                           view_layer=None, pixel_filter=None) -> Tuple[np.ndarray, Dict[str, float]]:
    """V (float32[H,W], row 0 at the top) for one light and the two render
    times, rendered with ``pixel_filter`` (``cycles_filter``); the scene is
    left exactly as it was, error or not."""
    global _rendering
    W, H = (int(v) for v in resolution)
    if W < 1 or H < 1:
        raise CyclesReferenceError(f"resolution must be positive, got {W}x{H}")
    if samples < 1:
        raise CyclesReferenceError(f"samples must be at least 1, got {samples}")
    if scene.camera is None:
        raise CyclesReferenceError("the scene has no camera")
    light_ob = find_light_object(light_name)
    view_layer = view_layer or view_layer_of(scene)
    folder = tempfile.mkdtemp(prefix="penumbra_cycles_")
    ch = _Changes()
    material = None
    made: List[object] = []
    _rendering += 1
    try:
        material = _white_material()
        swaps, made = _matte_swaps(material)
        _configure(ch, scene, view_layer, (W, H), samples, seed, os.path.join(folder, "ref"),
                   None if swaps else material, cycles_filter(pixel_filter))
        if swaps:                           # mattes: per-slot white materials, no override
            ch.set(scene.cycles, "transparent_max_bounces", TRANSPARENT_BOUNCES)
            for slot, replacement in swaps:
                ch.set(slot, "material", replacement)
        for ob in scene.objects:            # one light at a time
            if ob.type == "LIGHT" and ob != light_ob:
                ch.set(ob, "hide_render", True)
        ch.set(light_ob, "hide_render", False)
        ch.set(light_ob.data, "use_shadow", True)
        shadowed, t_sh = _render_once(scene, view_layer, folder)
        ch.set(light_ob.data, "use_shadow", False)
        unshadowed, t_un = _render_once(scene, view_layer, folder)
    finally:
        _rendering -= 1
        failed = ch.restore()
        for m in ([material] if material is not None else []) + made:
            try:
                bpy.data.materials.remove(m)
            except Exception as exc:        # pragma: no cover - nothing holds it
                failed.append(f"material: {exc}")
        shutil.rmtree(folder, ignore_errors=True)
    if failed:
        raise CyclesReferenceError("could not restore the scene: " + "; ".join(failed))
    if shadowed.shape[:2] != (H, W):
        raise CyclesReferenceError(f"Cycles rendered {shadowed.shape[1]}x{shadowed.shape[0]}, "
                                   f"expected {W}x{H}")
    return shadow_ratio(shadowed, unshadowed), {"render_shadowed": t_sh, "render_unshadowed": t_un}


def reference_params(samples: int, seed: int, pixel_filter=None) -> dict:
    return {"samples": int(samples), "seed": int(seed),
            "filter": cycles_filter(pixel_filter), "bounces": 0,
            "light_sampling": "NEXT_EVENT_ESTIMATION", "material_override": "white diffuse",
            "blender": bpy.app.version_string}


def make_cycles_producer(bpy_scene, resolution, samples: int = 64, seed: int = 0,
                         view_layer=None, pixel_filter=None) -> Callable:
    """``producer(light) -> MethodResult`` for ``core.frame.render_frame(...,
    external={"cycles": producer})``: ``light`` is a core Light whose ``name``
    is the Blender light object's name. ``resolution`` is (W, H) and must be
    the captured scene's, so the pixel grids line up."""
    W, H = (int(v) for v in resolution)
    samples = int(samples)
    seed = int(seed)

    def producer(light) -> MethodResult:
        v, times = render_light_reference(bpy_scene, light.name, (W, H), samples, seed, view_layer,
                                          pixel_filter)
        return MethodResult(passes={PASS_ID: v}, time_s=times,
                            stats={"resolution": [W, H]},
                            params=reference_params(samples, seed, pixel_filter))
    return producer
