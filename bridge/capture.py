"""Scene capture: the one bpy -> numpy boundary (DESIGN.md, "Data model").

``capture_scene`` turns a Blender scene at one frame into a
:class:`penumbra.core.scene.Scene`: the evaluated triangles in world space
(modifiers, instances and parenting applied), one object id per triangle,
the camera with Blender's own parameters, and the lights.

Which geometry is "the scene" depends on the depsgraph it is read from:

* a **render** depsgraph is what Cycles renders: render subdivision levels,
  modifiers enabled for render, objects hidden in the viewport but not for
  render included, objects and collections hidden for render left out;
* a **viewport** depsgraph (``bpy.context.evaluated_depsgraph_get()``) is what
  the viewport shows. Capture filters it for render visibility (object
  ``hide_render``, collections excluded or hidden for render), but it cannot
  bring back objects the viewport does not evaluate (hidden in the viewport)
  and uses viewport modifier settings.

Blender has no Python constructor for a render depsgraph. ``mode="RENDER"``
gets one the way a render does: a tiny private render engine is registered for
the duration of one ``bpy.ops.render.render()`` call, reads the depsgraph it is
handed and draws nothing (about a millisecond, independent of resolution).
It runs the render handlers and leaves an empty "Render Result" behind, so
``mode="AUTO"`` uses it only in background mode (CLI, tests) and the viewport
depsgraph in an interactive session. Render handlers can recognise it with
:func:`is_capturing` (or ``scene.render.engine == CAPTURE_ENGINE_ID``).

Inside a render (a ``frame_change_post`` handler during rendering gets the
render depsgraph as its second argument) pass that depsgraph in.
"""
from __future__ import annotations

import logging
import math
import os
from typing import Dict, List, Optional, Tuple

import numpy as np

import bpy

from ..core.exr import DEPTH_PASS, VECTOR_PASS
from ..core.motion import ShutterMotion, frame_offsets
from ..core.scene import Camera, Light, MeshInstances, ObjectInfo, Scene, finite_triangles
from .mattes import MatteCapture

log = logging.getLogger(__name__)

#: Object types turned into triangles (via ``to_mesh()``).
MESH_TYPES = frozenset({"MESH", "CURVE", "SURFACE", "FONT", "META"})
#: bl_idname of the private render engine used for ``mode="RENDER"``.
CAPTURE_ENGINE_ID = "PENUMBRA_CAPTURE"
MODES = ("AUTO", "RENDER", "VIEWPORT")
MAX_MOTION_LEVEL = 4          # Cycles' motion_steps read up to this: at most 17 time steps

# persistent_id entries past the instance's depth are padded with INT_MAX.
_PID_PAD = 2147483647

_job: Optional[dict] = None


# --------------------------------------------------------------------------
# public API
def capture_scene(scene=None, depsgraph=None, frame=None, resolution=None, *,
                  mode: str = "AUTO") -> Scene:
    """Capture ``scene`` (default: the context scene) as a Penumbra Scene.

    ``depsgraph``: an evaluated depsgraph to read (e.g. the render depsgraph
    a render handler receives); when given, ``mode`` is ignored and its own
    mode decides whether render-visibility filtering is applied.
    ``frame``: ``scene.frame_set(frame)`` first (do not pass it with a
    depsgraph that belongs to a running render).
    With the render's motion blur on, ``Scene.motion`` holds what moves over
    the shutter (``_shutter_motion``: the depsgraph evaluated at each step's
    subframe, the frame set back after); a depsgraph handed in is read at
    its own frame only (a still frame).
    ``resolution``: ``(width, height)`` to use instead of the scene's render
    resolution (resolution_x/y * resolution_percentage / 100, as Blender
    rounds it).
    ``mode``: where the depsgraph comes from when none is given: "RENDER"
    (exactly what a render evaluates), "VIEWPORT" (the view layer's viewport
    depsgraph, filtered for render visibility) or "AUTO" (RENDER in
    background mode when no render job is running, else VIEWPORT).

    Raises ValueError for a panoramic camera, an unknown mode or a bad
    resolution. A scene without a camera gives ``Scene.camera = None``.
    """
    if mode not in MODES:
        raise ValueError(f"capture mode must be one of {', '.join(MODES)}, not {mode!r}")
    scene = scene if scene is not None else bpy.context.scene
    if resolution is not None:
        resolution = _check_resolution(resolution)
    else:
        _check_resolution(render_resolution(scene), "the scene's render resolution")
    if frame is not None:
        scene.frame_set(int(frame))
    if depsgraph is not None:
        return _capture_from_depsgraph(depsgraph, scene, resolution)
    if mode == "AUTO":
        mode = "RENDER" if (bpy.app.background and not _render_job_running()) else "VIEWPORT"
    view_layer = view_layer_of(scene)
    if mode == "RENDER":
        return _capture_with_render_depsgraph(scene, view_layer, resolution)
    if scene == bpy.context.scene and view_layer == bpy.context.view_layer:
        dg = bpy.context.evaluated_depsgraph_get()
    else:
        dg = view_layer.depsgraph
        dg.update()

    def set_time(frame, subframe):
        scene.frame_set(frame, subframe=subframe)
        dg.update()
    return _capture_from_depsgraph(dg, scene, resolution, set_time)


def render_resolution(scene) -> Tuple[int, int]:
    """The render size Blender uses: ``resolution * percentage // 100``
    (integer division, checked against a render in bpy 5.0.1), at least 1."""
    r = scene.render
    pct = int(r.resolution_percentage)
    return (max(1, int(r.resolution_x) * pct // 100),
            max(1, int(r.resolution_y) * pct // 100))


def is_capturing() -> bool:
    """True while ``capture_scene`` runs its private capture render (render
    handlers should then do nothing)."""
    return _job is not None


def blend_stem(scene=None) -> str:
    """The .blend file's stem, or the scene's name for an unsaved file."""
    path = bpy.data.filepath
    if path:
        return os.path.splitext(os.path.basename(path))[0]
    scene = scene if scene is not None else bpy.context.scene
    return scene.name


# --------------------------------------------------------------------------
# depsgraph sources
# Largest image side Penumbra computes (the CLI's --resolution limit): a
# 16384^2 G-buffer alone takes about 12 GB; Blender allows 65536^2.
MAX_SIDE = 16384


def _check_resolution(resolution, what="resolution") -> Tuple[int, int]:
    try:
        w, h = (int(v) for v in resolution)
    except (TypeError, ValueError):
        raise ValueError(f"{what} must be (width, height), got {resolution!r}") from None
    if w < 1 or h < 1:
        raise ValueError(f"{what} must be positive, got {w}x{h}")
    if w > MAX_SIDE or h > MAX_SIDE:
        raise ValueError(f"{what} {w}x{h} is too large: each side must be at most {MAX_SIDE}")
    return w, h


def _render_job_running() -> bool:
    try:
        return bool(bpy.app.is_job_running("RENDER"))
    except Exception:           # pragma: no cover - older API
        return False


def view_layer_of(scene):
    """The view layer a render of ``scene`` uses: the context's when
    ``scene`` is the context scene, else its first enabled one."""
    ctx_vl = getattr(bpy.context, "view_layer", None)
    if scene == bpy.context.scene and ctx_vl is not None:
        return ctx_vl
    for vl in scene.view_layers:
        if vl.use:
            return vl
    return scene.view_layers[0]


class PENUMBRA_RE_capture(bpy.types.RenderEngine):
    """Private engine: captures the render depsgraph it is handed, draws nothing."""

    bl_idname = CAPTURE_ENGINE_ID
    bl_label = "Penumbra Capture"
    bl_use_postprocess = False      # no compositor / sequencer pass after it
    bl_use_preview = False

    def render(self, depsgraph):
        job = _job
        if job is None or "result" in job or "error" in job:
            return
        try:
            job["result"] = _capture_from_depsgraph(depsgraph, job["scene"], job["resolution"],
                                                    lambda frame, subframe: self.frame_set(frame, subframe))
        except BaseException as exc:    # re-raised by the caller
            job["error"] = exc


def _capture_with_render_depsgraph(scene, view_layer, resolution) -> Scene:
    global _job
    if _job is not None:
        raise RuntimeError("capture_scene: a capture render is already running")
    if _render_job_running():
        raise RuntimeError("capture_scene: cannot capture a render depsgraph while a "
                           "render is running; pass the render's depsgraph instead")
    registered = bool(getattr(PENUMBRA_RE_capture, "is_registered", False))
    if not registered:
        bpy.utils.register_class(PENUMBRA_RE_capture)
    old_engine = scene.render.engine
    _job = {"scene": scene, "resolution": resolution}
    job = _job
    try:
        scene.render.engine = CAPTURE_ENGINE_ID
        bpy.ops.render.render(write_still=False, scene=scene.name, layer=view_layer.name)
    finally:
        _job = None
        scene.render.engine = old_engine
        if not registered:
            bpy.utils.unregister_class(PENUMBRA_RE_capture)
    if "error" in job:
        raise job["error"]
    if "result" not in job:
        raise RuntimeError(f"capture_scene: the capture render of scene {scene.name!r} "
                           f"(view layer {view_layer.name!r}) did not run")
    return job["result"]


# --------------------------------------------------------------------------
# render visibility (viewport depsgraphs only)
def _render_visible_objects(view_layer) -> set:
    """Pointers of original objects a render of ``view_layer`` includes:
    in a collection that is neither excluded nor hidden for render (nor any
    of its parents), and not ``hide_render`` themselves."""
    visible = set()

    def walk(lc):
        if lc.exclude or lc.collection.hide_render:
            return
        for ob in lc.collection.objects:
            if not ob.hide_render:
                visible.add(ob.as_pointer())
        for child in lc.children:
            walk(child)

    walk(view_layer.layer_collection)
    return visible


def _instance_render_visible(inst, visible: set) -> bool:
    """Viewport-depsgraph filter for one instance: its instancer must render,
    and objects instanced from a collection respect their ``hide_render``
    (object instances made by geometry nodes do not: checked in 5.0)."""
    parent = inst.parent
    if parent is None:
        return True
    porig = parent.original
    if porig.as_pointer() not in visible:
        return False
    if porig.instance_type == "COLLECTION" and inst.object.original.hide_render:
        return False
    return True


# --------------------------------------------------------------------------
# geometry
def _matrix(m) -> np.ndarray:
    return np.array(m, dtype=np.float64).reshape(4, 4)


def _orthonormal(m: np.ndarray, what: str = "object") -> Tuple[np.ndarray, np.ndarray]:
    """(rotation + translation 4x4, per-axis scale) of a 4x4 affine matrix.

    Local -Z (the view / emission direction) is kept exactly, Y is made
    orthogonal to it, X completes a right-handed frame (mirroring and shear
    are dropped)."""
    a = np.asarray(m, np.float64)[:3, :3]
    scale = np.linalg.norm(a, axis=0)
    z = a[:, 2] / (scale[2] if scale[2] > 0 else 1.0)
    y = a[:, 1] - np.dot(a[:, 1], z) * z
    ny = np.linalg.norm(y)
    if not np.isfinite(ny) or ny < 1e-12 or not np.isfinite(z).all() or np.linalg.norm(z) < 0.5:
        raise ValueError(f"{what}: degenerate transform (zero scale along local Y or Z)")
    y /= ny
    x = np.cross(y, z)
    out = np.eye(4)
    out[:3, 0], out[:3, 1], out[:3, 2] = x, y, z
    out[:3, 3] = np.asarray(m, np.float64)[:3, 3]
    return out, scale


def _mesh_arrays(mesh) -> Tuple[np.ndarray, np.ndarray]:
    """(vertices float64[V,3], triangle vertex indices int32[T,3]) of a Mesh."""
    nv = len(mesh.vertices)
    co = np.empty(nv * 3, np.float32)
    if nv:
        mesh.vertices.foreach_get("co", co)
    nt = len(mesh.loop_triangles)
    idx = np.empty(nt * 3, np.int32)
    if nt:
        mesh.loop_triangles.foreach_get("vertices", idx)
    return co.reshape(-1, 3).astype(np.float64), idx.reshape(-1, 3)


def _object_mesh_arrays(ob, mattes: Optional[MatteCapture] = None, lut=None):
    """Triangulated evaluated geometry of an evaluated object (local space):
    (vertices, triangles, alpha) with alpha = ``mattes.triangle_mattes`` of
    the mesh when ``lut`` (matte id per material slot) is given, else None."""
    empty = (np.zeros((0, 3)), np.zeros((0, 3), np.int32), None)
    try:
        mesh = ob.to_mesh()
    except RuntimeError:
        return empty
    try:
        if mesh is None:
            return empty
        co, idx = _mesh_arrays(mesh)
        alpha = mattes.triangle_mattes(mesh, lut, ob.name_full) if lut is not None else None
        return co, idx, alpha
    finally:
        ob.to_mesh_clear()


def _instance_name(inst) -> str:
    ob = inst.object
    if not inst.is_instance:
        return ob.name_full
    pid = [int(v) for v in inst.persistent_id]
    while pid and pid[-1] == _PID_PAD:
        pid.pop()
    parent = inst.parent.name_full if inst.parent is not None else ""
    return f"{parent}/{ob.name_full}#{'.'.join(str(v) for v in pid)}"


def _geometry_cache_key(ob):
    data = ob.data
    if data is None:
        return None
    if ob.type == "MESH":
        return ("MESH", data.as_pointer())
    return (ob.type, ob.original.as_pointer(), data.as_pointer())


# --------------------------------------------------------------------------
# camera and lights
def _capture_camera(scene, depsgraph) -> Optional[Camera]:
    cam_ob = scene.camera
    if cam_ob is None:
        return None
    try:
        cam_ev = cam_ob.evaluated_get(depsgraph)
    except Exception:               # not in this depsgraph (hidden in viewport)
        cam_ev = cam_ob
    data = cam_ev.data
    if cam_ob.type != "CAMERA" or data is None:
        raise ValueError(f"scene camera {cam_ob.name!r} is a {cam_ob.type}, not a camera")
    kind = data.type
    if kind not in ("PERSP", "ORTHO"):
        raise ValueError(f"camera {cam_ob.name!r} is {kind} (panoramic); Penumbra supports "
                         "perspective and orthographic cameras only")
    world, _ = _orthonormal(_matrix(cam_ev.matrix_world), f"camera {cam_ob.name!r}")
    r = scene.render
    return Camera(
        world_from_camera=world, kind=kind, lens=float(data.lens),
        sensor_width=float(data.sensor_width), sensor_height=float(data.sensor_height),
        sensor_fit=str(data.sensor_fit), ortho_scale=float(data.ortho_scale),
        shift_x=float(data.shift_x), shift_y=float(data.shift_y),
        clip_start=float(data.clip_start), clip_end=float(data.clip_end),
        pixel_aspect_x=float(r.pixel_aspect_x), pixel_aspect_y=float(r.pixel_aspect_y),
        **_thin_lens(data, kind, world))


def _thin_lens(data, kind: str, world: np.ndarray) -> dict:
    """The camera's depth of field as Cycles syncs it (``blender/camera.cpp``):
    lens radius lens / 1000 / (2 f-stop) (orthographic: 1 / (2 f-stop)),
    fewer than 3 blades a disk, the focus object's distance along the view
    axis (its bone's, with a subtarget); no DoF: a pinhole (``{}``)."""
    dof = getattr(data, "dof", None)
    if dof is None or not dof.use_dof:
        return {}
    fstop = max(float(dof.aperture_fstop), 1e-5)
    radius = 1.0 / (2.0 * fstop) if kind == "ORTHO" else float(data.lens) * 1e-3 / (2.0 * fstop)
    focus = float(dof.focus_distance)
    target = dof.focus_object
    if target is not None:
        at = _matrix(target.matrix_world)
        bone = target.pose.bones.get(dof.focus_subtarget) if target.pose and dof.focus_subtarget else None
        if bone is not None:
            at = at @ _matrix(bone.matrix)
        focus = abs(float(np.dot(world[:3, 2], world[:3, 3] - at[:3, 3])))
    return dict(aperture_radius=radius, focus_distance=max(focus, 1e-5),
                aperture_blades=int(dof.aperture_blades) if int(dof.aperture_blades) >= 3 else 0,
                aperture_rotation=float(dof.aperture_rotation), aperture_ratio=float(dof.aperture_ratio))


def core_light(name: str, light, matrix_world) -> Light:
    """Blender light data + its world matrix -> ``core.scene.Light``: the one
    place Blender's light types map to Penumbra's kinds (object scale folded
    into the size)."""
    world, scale = _orthonormal(_matrix(matrix_world), f"light {name!r}")
    t = light.type
    common = dict(name=name, world_from_light=world, blender_type=t,
                  color=tuple(float(c) for c in light.color), energy=float(light.energy),
                  casts_shadow=bool(light.use_shadow))
    if t == "AREA":
        shape = str(light.shape)
        sx, sy = float(scale[0]), float(scale[1])
        size = float(light.size) * sx
        size_y = float(light.size_y if shape in ("RECTANGLE", "ELLIPSE") else light.size) * sy
        # non-uniform object scale stretches a square / disk (Cycles scales the axes)
        if shape == "SQUARE" and not np.isclose(size, size_y, rtol=1e-6, atol=0.0):
            shape = "RECTANGLE"
        elif shape == "DISK" and not np.isclose(size, size_y, rtol=1e-6, atol=0.0):
            shape = "ELLIPSE"
        return Light(kind="area", shape=shape, size=size, size_y=size_y, **common)
    if t == "POINT":
        return Light(kind="sphere", radius=float(light.shadow_soft_size), spot_size=float(np.pi),
                     **common)
    if t == "SPOT":
        return Light(kind="sphere", radius=float(light.shadow_soft_size),
                     spot_size=float(light.spot_size), spot_blend=float(light.spot_blend),
                     **common)
    if t == "SUN":
        return Light(kind="sun", angle=float(light.angle), **common)
    raise ValueError(f"light {name!r}: unsupported light type {t!r}")


def light_kind_size(light) -> Tuple[str, float]:
    """(kind, extent) of a captured ``core.scene.Light`` or of Blender light
    data (mapped by :func:`core_light` without the object's scale: ``auto``
    only tells zero from non-zero sizes)."""
    if not isinstance(light, Light):
        if getattr(light, "type", "") not in ("AREA", "POINT", "SPOT", "SUN"):
            raise ValueError(f"not a light: {light!r}")
        light = core_light(light.name, light, np.eye(4))
    return light.kind, float(light.extent)


def object_named(name: str):
    """The object whose ``name`` or ``name_full`` (linked data) is ``name``."""
    ob = bpy.data.objects.get(name)
    if ob is None:
        ob = next((o for o in bpy.data.objects if o.name_full == name), None)
    return ob


def light_object(captured_name: str):
    """The Blender light object of a captured light (instances are named
    ``parent/object#id``: their source object), or None when there is none."""
    ob = object_named(captured_name)
    if ob is None and "/" in captured_name:
        ob = object_named(captured_name.split("/", 1)[1].rsplit("#", 1)[0])
    if ob is None or ob.type != "LIGHT":
        return None
    return ob


# --------------------------------------------------------------------------
# the capture proper
def _capture_from_depsgraph(depsgraph, scene, resolution, set_time=None) -> Scene:
    """The Scene in ``depsgraph``; with motion blur on and ``set_time``
    (``(frame, subframe)`` -> the depsgraph evaluated then) its motion over
    the shutter too (``_shutter_motion``)."""
    filter_render = depsgraph.mode != "RENDER"
    visible = _render_visible_objects(depsgraph.view_layer) if filter_render else None

    meshes = _Meshes()
    pieces: List[tuple] = []        # (object name, mesh index, world_from_mesh)
    infos: Dict[str, dict] = {}
    lights: List[Light] = []
    mattes = MatteCapture(i for i in depsgraph.ids if isinstance(i, bpy.types.Material))

    for inst in depsgraph.object_instances:
        _capture_instance(inst, filter_render, visible, meshes, pieces, infos, lights, mattes)
    captured = _assemble(scene, depsgraph, resolution, meshes, pieces, infos, lights, mattes)
    captured.motion = _shutter_motion(scene, depsgraph, pieces, captured, set_time)
    captured.frame_motion = _frame_motion(scene, depsgraph, pieces, captured, set_time)
    vl = depsgraph.view_layer
    captured.data_passes = tuple(p for p, on in ((DEPTH_PASS, getattr(vl, "use_pass_z", False)),
                                                 (VECTOR_PASS, getattr(vl, "use_pass_vector", False))) if on)
    return captured


def _shutter_motion(scene, depsgraph, pieces, captured: Scene, set_time) -> Optional[ShutterMotion]:
    """What moves over the shutter when the scene renders with motion blur,
    as Cycles syncs it (``core/motion.py``): Cycles' time steps over the
    shutter (``_motion_over``). None: no motion blur, no ``set_time``, or
    nothing moves."""
    r = scene.render
    if set_time is None or not r.use_motion_blur:
        return None
    obs = [ob for ob in scene.objects if ob.type in MESH_TYPES]
    level = max([_cycles(ob, "motion_steps", 1) for ob in obs] + [1])
    steps = (2 << (min(int(level), MAX_MOTION_LEVEL) - 1)) + 1
    shutter, position = float(r.motion_blur_shutter), str(r.motion_blur_position)
    return _motion_over(scene, depsgraph, pieces, captured, set_time, frame_offsets(steps, shutter, position),
                        shutter, position)


def _frame_motion(scene, depsgraph, pieces, captured: Scene, set_time) -> Optional[ShutterMotion]:
    """The placements at the previous and the next frame, for the Vector
    pass (``core/data_passes.py``): a ``ShutterMotion`` over frames -1, 0,
    +1, when the view layer's Vector pass is on (None otherwise, or when
    nothing moves)."""
    if set_time is None or not getattr(depsgraph.view_layer, "use_pass_vector", False):
        return None
    return _motion_over(scene, depsgraph, pieces, captured, set_time, np.array([-1.0, 0.0, 1.0]), 2.0, "CENTER")


def _motion_over(scene, depsgraph, pieces, captured: Scene, set_time, offsets: np.ndarray, shutter: float,
                 position: str) -> Optional[ShutterMotion]:
    """The captured objects' and the camera's placements at the frame plus
    each of ``offsets`` (frames; the depsgraph evaluated there by
    ``set_time``, the frame set back after), reading only placements, as
    deltas from the frame's (an object with Cycles' motion blur off stands
    still). None when nothing moves."""
    frame_of = {}                    # object id -> (name, its placement at the frame)
    ids = {o.name: o.id for o in captured.objects}
    for name, _mesh, m in pieces:
        frame_of.setdefault(ids[name], (name, m))
    order = sorted(frame_of)
    row = {frame_of[i][0]: j for j, i in enumerate(order)}
    steps = len(offsets)
    still = np.array([frame_of[i][1] for i in order]).reshape(-1, 4, 4)
    at = np.broadcast_to(still, (steps, len(order), 4, 4)).copy()
    cam = captured.camera
    cams = np.broadcast_to(cam.world_from_camera, (steps, 4, 4)).copy() if cam is not None else None
    frame, sub = int(scene.frame_current), float(scene.frame_subframe)
    try:
        for k, off in enumerate(offsets):
            if off == 0.0:
                continue
            t = frame + sub + float(off)
            set_time(int(math.floor(t)), float(t - math.floor(t)))
            for inst in depsgraph.object_instances:
                ob = inst.object
                if ob.type not in MESH_TYPES or not inst.show_self:
                    continue
                j = row.get(_instance_name(inst))
                if j is not None and _moves(inst):
                    at[k, j] = _matrix(inst.matrix_world)
            if cams is not None and _cycles(scene.camera, "use_motion_blur", True):
                cams[k] = _capture_camera(scene, depsgraph).world_from_camera
    finally:
        set_time(frame, sub)
    with np.errstate(all="ignore"):          # a zero-scale placement: pinv keeps it finite
        delta = np.einsum("kmij,mjl->kmil", at, np.linalg.pinv(still)) if len(order) else at
    delta[..., 3, :] = (0.0, 0.0, 0.0, 1.0)
    moving = np.isfinite(delta).all(axis=(0, 2, 3)) & (np.abs(delta - np.eye(4)).max(axis=(0, 2, 3)) > 1e-7)
    cam_delta = None
    if cams is not None:
        cam_delta = cams @ np.linalg.inv(cam.world_from_camera)
        if np.abs(cam_delta - np.eye(4)).max() <= 1e-7:
            cam_delta = None
    if not moving.any() and cam_delta is None:
        return None
    return ShutterMotion(np.array(order, np.int32)[moving], delta[:, moving], cam_delta, shutter, position)


def _cycles(ob, attr: str, default):
    """Object ``ob``'s Cycles setting ``attr`` (``default`` without Cycles)."""
    settings = getattr(ob, "cycles", None)
    return getattr(settings, attr, default) if settings is not None else default


def _moves(inst) -> bool:
    """Cycles blurs this instance's motion: its object's motion blur is on,
    and its instancer's too."""
    if not _cycles(inst.object, "use_motion_blur", True):
        return False
    return inst.parent is None or bool(_cycles(inst.parent, "use_motion_blur", True))


class _Meshes:
    """The unique evaluated meshes of a capture: an instance's mesh is read
    once per geometry (``_geometry_cache_key``, with the object's matte
    lookup), an object that is not an instance gets a mesh of its own.
    Triangles with a non-finite vertex are dropped from their mesh."""

    def __init__(self):
        self.index: Dict[tuple, int] = {}
        self.vertices: List[np.ndarray] = []
        self.faces: List[np.ndarray] = []
        self.alpha: List[Optional[tuple]] = []
        self.dropped = 0

    def of(self, ob, key, mattes: MatteCapture, lut) -> int:
        """The mesh index of evaluated object ``ob`` (-1: no surface)."""
        if key is not None and key in self.index:
            return self.index[key]
        co, idx, alpha = _object_mesh_arrays(ob, mattes, lut)
        if len(idx):
            ok = np.isfinite(co[idx].reshape(len(idx), 9)).all(axis=1)
            if not ok.all():
                self.dropped += int((~ok).sum())
                idx = idx[ok]
                if alpha is not None:
                    alpha = (alpha[0][ok], alpha[1][ok])
        m = -1
        if len(idx):
            m = len(self.faces)
            self.vertices.append(co)
            self.faces.append(idx)
            self.alpha.append(alpha)
        if key is not None:
            self.index[key] = m
        return m


def _capture_instance(inst, filter_render, visible, meshes, pieces, infos, lights, mattes):
    """Add one depsgraph object instance to the capture lists."""
    ob = inst.object
    otype = ob.type
    if otype not in MESH_TYPES and otype != "LIGHT":
        return
    if filter_render:
        if inst.is_instance:
            if not _instance_render_visible(inst, visible):
                return
        elif ob.original.as_pointer() not in visible:
            return
    name = _instance_name(inst)
    if otype == "LIGHT":
        lights.append(core_light(name, ob.data, inst.matrix_world))
        return
    if not inst.show_self:
        return                      # an instancer that does not render itself
    lut = mattes.object_lut(ob)     # None unless one of its materials has a matte
    key = _geometry_cache_key(ob) if inst.is_instance else None
    if key is not None and lut is not None:
        key = key + (lut.tobytes(),)
    mesh = meshes.of(ob, key, mattes, lut)
    if mesh < 0:
        return                      # no surface (an instancer, an empty curve): no object id
    m = _matrix(inst.matrix_world)
    casts = bool(ob.visible_shadow)
    cam_vis = bool(ob.visible_camera)
    if inst.is_instance and inst.parent is not None:
        # Cycles ANDs an instance's ray visibility with its instancer's
        casts = casts and bool(inst.parent.visible_shadow)
        cam_vis = cam_vis and bool(inst.parent.visible_camera)
    if name in infos:               # same name twice: merge (deterministic order)
        infos[name]["casts_shadow"] &= casts
    else:
        infos[name] = dict(casts_shadow=casts, visible_camera=cam_vis,
                           pass_index=int(ob.pass_index))
    pieces.append((name, mesh, m))


def _assemble(scene, depsgraph, resolution, meshes: _Meshes, pieces, infos, lights, mattes) -> Scene:
    names = sorted(infos)
    ids = {n: i for i, n in enumerate(names)}
    objects = [ObjectInfo(name=n, id=ids[n], **infos[n]) for n in names]
    instances = MeshInstances(
        vertices=meshes.vertices, faces=meshes.faces,
        mesh=np.array([p[1] for p in pieces], np.int32),
        world_from_mesh=np.array([p[2] for p in pieces], np.float64).reshape(-1, 4, 4),
        object_id=np.array([ids[p[0]] for p in pieces], np.int32))
    mesh_alpha = meshes.alpha
    alpha = None
    if not instances.shares_meshes or any(a is not None for a in mesh_alpha):
        triangles, tri_object = instances.flattened()
        alpha = _assemble_mattes(instances, mesh_alpha, mattes)
        dropped = meshes.dropped
        if len(triangles):              # finite_triangles cannot reshape an empty array
            if alpha is None:
                triangles, tri_object, more = finite_triangles(triangles, tri_object)
            else:                       # the kept triangles' indices filter the mattes too
                triangles, kept, more = finite_triangles(triangles, np.arange(len(triangles)))
                tri_object = tri_object[kept]
                alpha = alpha.subset(kept)
            dropped += more
        if dropped:
            log.warning("capture: dropped %d triangle(s) with non-finite vertices", dropped)
    else:                               # instanced: flattened when a method asks (Scene.triangles)
        triangles = tri_object = None
        if meshes.dropped:
            log.warning("capture: dropped %d triangle(s) with non-finite vertices", meshes.dropped)
    lights.sort(key=lambda lt: lt.name)

    captured = Scene(
        triangles=triangles, tri_object=tri_object, objects=objects,
        camera=_capture_camera(scene, depsgraph), lights=lights,
        resolution=resolution if resolution is not None else render_resolution(scene),
        frame=int(scene.frame_current), name=blend_stem(scene), alpha=alpha,
        alpha_opaque=list(mattes.opaque), instances=instances)
    return captured


def _assemble_mattes(instances: MeshInstances, mesh_alpha: List[Optional[tuple]],
                     mattes: MatteCapture):
    """AlphaMattes over the flattened triangles (``MeshInstances.flatten``'s
    order), or None when no instanced mesh has a matte (the scene is then
    captured without mattes)."""
    order = instances.order()
    used = [instances.mesh[i] for i in order]
    if all(mesh_alpha[m] is None for m in used):
        return None
    faces = instances.faces
    tri_matte = np.concatenate([mesh_alpha[m][0] if mesh_alpha[m] is not None
                                else np.full(len(faces[m]), -1, np.int32) for m in used])
    tri_uv = np.concatenate([mesh_alpha[m][1] if mesh_alpha[m] is not None
                             else np.zeros((len(faces[m]), 3, 2), np.float32) for m in used])
    return mattes.build(tri_matte, tri_uv)
