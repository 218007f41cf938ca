"""Penumbra's data model: what a captured frame holds (DESIGN.md, "Data model").

Everything here is plain NumPy; the one bpy -> numpy boundary
(``bridge/capture.py``) fills these dataclasses, tests build them by hand.

Conventions
-----------
* World space is Blender's (right-handed, Z up), in scene units.
* Matrices are float64 4x4, column vectors: ``p_world = M @ p_local``.
* Images are indexed ``[row, column]`` with row 0 at the *top* (EXR order);
  pixel centres sit at ``(column + 0.5, row + 0.5)``.
"""
from __future__ import annotations

import copy
import logging
import math
import os
from dataclasses import dataclass, field
from typing import List, NamedTuple, Optional, Tuple

import numpy as np

from .alpha import AlphaMattes
from .motion import ShutterMotion

log = logging.getLogger(__name__)

LIGHT_KINDS = ("area", "sphere", "sun")
#: ``Light.kind_code``: a kind's index in LIGHT_KINDS, the code Numba kernels branch on
KIND_AREA, KIND_SPHERE, KIND_SUN = 0, 1, 2
AREA_SHAPES = ("SQUARE", "RECTANGLE", "DISK", "ELLIPSE")
#: a sun's angle is clamped below a hemisphere where its spread per unit
#: distance, tan(angle / 2), must stay finite (``Light.sun_spread``)
SUN_MAX_SPREAD_ANGLE = math.radians(179.0)


@dataclass
class ObjectInfo:
    """One renderable object instance; ``id`` is its index in ``Scene.objects``."""

    name: str
    id: int
    casts_shadow: bool = True      # Cycles ray visibility `visible_shadow`
    visible_camera: bool = True    # Cycles ray visibility `visible_camera`
    pass_index: int = 0


@dataclass
class Camera:
    """The scene camera, with Blender's own parameters (see ``views.camera_viewplane``)."""

    world_from_camera: np.ndarray          # 4x4; camera looks along its local -Z, +Y up
    kind: str = "PERSP"                    # PERSP | ORTHO
    lens: float = 50.0                     # focal length, mm
    sensor_width: float = 36.0             # mm
    sensor_height: float = 24.0            # mm
    sensor_fit: str = "AUTO"               # AUTO | HORIZONTAL | VERTICAL
    ortho_scale: float = 6.0
    shift_x: float = 0.0
    shift_y: float = 0.0
    clip_start: float = 0.1
    clip_end: float = 1000.0
    pixel_aspect_x: float = 1.0
    pixel_aspect_y: float = 1.0
    # depth of field, as Cycles' thin lens (``core/camera_samples.py``); 0: a pinhole
    aperture_radius: float = 0.0           # lens radius in scene units (Cycles' aperturesize)
    focus_distance: float = 10.0           # distance of the plane in focus along the view axis
    aperture_blades: int = 0               # polygonal aperture with this many sides (< 3: a disk)
    aperture_rotation: float = 0.0         # the polygon's rotation, radians
    aperture_ratio: float = 1.0            # anamorphic squeeze: the lens x axis divided by it

    @property
    def has_depth_of_field(self) -> bool:
        return self.aperture_radius > 0.0

    @property
    def position(self) -> np.ndarray:
        return np.asarray(self.world_from_camera, np.float64)[:3, 3].copy()

    @property
    def forward(self) -> np.ndarray:
        m = np.asarray(self.world_from_camera, np.float64)
        f = -m[:3, 2]
        return f / np.linalg.norm(f)


@dataclass
class Light:
    """A light as DESIGN.md's light domains define it.

    ``world_from_light`` is orthonormal (rotation + translation): object scale
    is folded into ``size``/``size_y`` at capture. The light shines along its
    local -Z (area, spot, sun).

    kind:
      * ``area``   - uniform over ``shape`` (SQUARE, RECTANGLE, DISK, ELLIPSE) of
        ``size`` x ``size_y`` in the local XY plane; one-sided, emits along -Z.
      * ``sphere`` - point or spot light of ``radius`` (a disk of that radius
        through the centre, facing the shaded point); radius 0 = hard shadows.
        ``spot_size`` (full cone angle, radians) < pi makes it a spot.
      * ``sun``    - directions uniform in the cone of full angle ``angle``
        around the local -Z.

    Each kind answers for itself what the methods need of it (pbrt-v4's
    light interface): ``axes``, ``half_size``, ``is_round``,
    ``bounding_radius`` / ``box()`` of the emitting shape, the sun's cone
    (``sun_half_angle``, ``sun_cos_max``, ``sun_spread``), the spot's cone
    (``spot_half_angle``, ``spot_cos``), ``is_zero_size`` and ``kind_code``.
    """

    name: str
    kind: str
    world_from_light: np.ndarray
    blender_type: str = ""                 # POINT | SPOT | AREA | SUN
    shape: str = "SQUARE"
    size: float = 0.0
    size_y: float = 0.0
    radius: float = 0.0
    spot_size: float = np.pi               # full cone angle; pi = no cone
    spot_blend: float = 0.0
    angle: float = 0.0                     # sun angular diameter, radians
    color: Tuple[float, float, float] = (1.0, 1.0, 1.0)
    energy: float = 1.0
    casts_shadow: bool = True

    def __post_init__(self):
        if self.kind not in LIGHT_KINDS:
            raise ValueError(f"light {self.name!r}: unknown kind {self.kind!r}")
        if self.kind == "area" and self.shape not in AREA_SHAPES:
            raise ValueError(f"light {self.name!r}: unknown area shape {self.shape!r}")
        if self.kind == "area" and self.shape in ("SQUARE", "DISK"):
            self.size_y = self.size
        self.world_from_light = np.asarray(self.world_from_light, np.float64)

    @property
    def position(self) -> np.ndarray:
        return self.world_from_light[:3, 3].copy()

    @property
    def direction(self) -> np.ndarray:
        """Unit direction the light shines along (its local -Z)."""
        d = -self.world_from_light[:3, 2]
        return d / np.linalg.norm(d)

    @property
    def kind_code(self) -> int:
        """KIND_AREA | KIND_SPHERE | KIND_SUN: the kind as kernels see it."""
        return LIGHT_KINDS.index(self.kind)

    @property
    def axes(self) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The light's local X, Y, Z axes in world space, unit length (an area
        light's sides run along X and Y; it emits along -Z)."""
        m = self.world_from_light
        return tuple(m[:3, k] / np.linalg.norm(m[:3, k]) for k in range(3))

    @property
    def half_size(self) -> Tuple[float, float]:
        """An area light's half extents along its local X and Y."""
        return 0.5 * self.size, 0.5 * self.size_y

    @property
    def is_round(self) -> bool:
        """An area light whose shape is a disk or an ellipse (else a rectangle)."""
        return self.kind == "area" and self.shape in ("DISK", "ELLIPSE")

    @property
    def bounding_radius(self) -> float:
        """Radius of the ball around ``position`` that holds every emitting
        point: an area light's half diagonal (a disk's or an ellipse's too:
        that of the rectangle around it), a sphere light's radius. A sun has
        no position: ``inf``."""
        if self.kind == "area":
            return float(0.5 * np.hypot(self.size, self.size_y))
        if self.kind == "sphere":
            return float(self.radius)
        return math.inf

    def box(self) -> Tuple[np.ndarray, np.ndarray]:
        """(lo, hi): the axis-aligned box around the emitting points (a box
        around the ball of ``bounding_radius``). Not for a sun."""
        if self.kind == "sun":
            raise ValueError(f"light {self.name!r}: a sun has no box")
        c, r = self.position, self.bounding_radius
        return c - r, c + r

    @property
    def sun_half_angle(self) -> float:
        """Half-angle of a sun's cone of directions, at most a hemisphere."""
        return 0.5 * min(self.angle, math.pi)

    @property
    def sun_cos_max(self) -> float:
        """Cosine of ``sun_half_angle``: the cap directions are sampled in."""
        return math.cos(self.sun_half_angle)

    @property
    def sun_spread(self) -> float:
        """tan of a sun's half-angle, the angle clamped at SUN_MAX_SPREAD_ANGLE:
        how far its penumbra widens per unit distance from the blocker (finite)."""
        half = 0.5 * min(self.angle, SUN_MAX_SPREAD_ANGLE)
        return math.tan(half) if half > 0 else 0.0

    @property
    def is_spot(self) -> bool:
        return self.kind == "sphere" and self.spot_size < np.pi - 1e-6

    @property
    def spot_half_angle(self) -> float:
        """Half-angle of a spot's cone (pi / 2 for a light without one)."""
        return 0.5 * min(self.spot_size, math.pi)

    @property
    def spot_cos(self) -> float:
        """Cosine of ``spot_half_angle``: points with a smaller cosine to the
        axis are outside the cone."""
        return math.cos(self.spot_half_angle)

    @property
    def extent(self) -> float:
        """Characteristic size: the light's diameter (area: its larger side),
        or for a sun its angular diameter in radians."""
        if self.kind == "area":
            return float(max(self.size, self.size_y))
        if self.kind == "sphere":
            return 2.0 * float(self.radius)
        return float(self.angle)

    @property
    def is_zero_size(self) -> bool:
        """A light of size zero casts hard shadows only (DESIGN.md)."""
        return self.extent <= 0.0


class InstanceGeometry(NamedTuple):
    """``MeshInstances`` packed for kernels: per instance its mesh, world
    matrix, object id and first triangle in the flattened soup; the meshes'
    vertices and faces concatenated, each mesh from its start."""
    mesh: np.ndarray             # int32[I]
    world_from_mesh: np.ndarray  # float64[I,4,4]
    object_id: np.ndarray        # int32[I]
    triangle_offset: np.ndarray  # int64[I]
    vertices: np.ndarray         # float64[V,3], every mesh's
    vertex_start: np.ndarray     # int64[M]
    faces: np.ndarray            # int32[F,3], every mesh's (indices within its mesh)
    face_start: np.ndarray       # int64[M]


#: bytes a frame holds per flattened triangle, at the least (measured on a
#: scatter of 2,000 trees: ``penumbra plan`` peaks at 2.35 GB for 9.6 M)
BYTES_PER_FLATTENED_TRIANGLE = 200


class GeometryTooLarge(ValueError):
    """The scene's flattened triangles cannot fit in memory (one line; the
    CLI exits 2)."""


def physical_memory() -> Optional[int]:
    """This machine's memory in bytes (None where the OS does not say)."""
    try:
        return int(os.sysconf("SC_PHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
    except (AttributeError, OSError, ValueError):
        return None


@dataclass
class MeshInstances:
    """The captured geometry as Blender holds it: each unique evaluated mesh
    once, in its own space, and per instance the mesh, its placement and its
    object. ``flatten`` gives the world-space triangle soup ``Scene.triangles``
    is made of (instance by instance in object-id order, each instance's
    triangles in its mesh's order).

    A scene with no instancing has one instance per object, of a mesh of its
    own; an instancer's N instances of one mesh share that mesh.
    """

    vertices: List[np.ndarray]       # float64[V,3] per mesh, mesh space
    faces: List[np.ndarray]          # int32[F,3] per mesh: vertex indices
    mesh: np.ndarray                 # int32[I]: the mesh of each instance
    world_from_mesh: np.ndarray      # float64[I,4,4]
    object_id: np.ndarray            # int32[I]: index into Scene.objects

    def __post_init__(self):
        self.mesh = np.asarray(self.mesh, np.int32).reshape(-1)
        self.object_id = np.asarray(self.object_id, np.int32).reshape(-1)
        self.world_from_mesh = np.asarray(self.world_from_mesh, np.float64).reshape(-1, 4, 4)
        if not (len(self.mesh) == len(self.object_id) == len(self.world_from_mesh)):
            raise ValueError("instances need one mesh, matrix and object id each")
        if len(self.vertices) != len(self.faces):
            raise ValueError("each mesh needs its vertices and its faces")

    @property
    def count(self) -> int:
        """Instances."""
        return len(self.mesh)

    def mesh_triangles(self) -> np.ndarray:
        """int64[M]: triangles per mesh."""
        return np.array([len(f) for f in self.faces], np.int64)

    def instance_triangles(self) -> np.ndarray:
        """int64[I]: triangles per instance (its mesh's)."""
        return self.mesh_triangles()[self.mesh] if self.count else np.zeros(0, np.int64)

    @property
    def unique_triangles(self) -> int:
        """Triangles of the meshes instances use, each mesh counted once."""
        used = np.unique(self.mesh)
        return int(self.mesh_triangles()[used].sum()) if len(used) else 0

    @property
    def instanced_triangles(self) -> int:
        """Triangles of every instance: the size of the flattened soup."""
        return int(self.instance_triangles().sum())

    @property
    def shares_meshes(self) -> bool:
        """Whether some mesh is placed more than once (the scene instances)."""
        return bool(len(self.mesh)) and len(np.unique(self.mesh)) < len(self.mesh)

    def flattened(self) -> Tuple[np.ndarray, np.ndarray]:
        """``flatten``, refused in one line (``GeometryTooLarge``) when the
        soup cannot fit in this machine's memory: before allocating it
        (``BYTES_PER_FLATTENED_TRIANGLE``) or when the allocation fails."""
        self.check_fits(self.instanced_triangles, "them")
        try:
            with np.errstate(invalid="ignore", over="ignore"):   # non-finite placements: finite_triangles
                return self.flatten()
        except MemoryError:
            raise GeometryTooLarge(self._too_large("there is not enough memory to hold them")) from None

    def check_fits(self, triangles: int, what: str) -> None:
        """Refuse (``GeometryTooLarge``) to flatten ``triangles`` (``what``
        they are, for the message) when they cannot fit in this machine's
        memory (``BYTES_PER_FLATTENED_TRIANGLE`` each)."""
        memory = physical_memory()
        need = int(triangles) * BYTES_PER_FLATTENED_TRIANGLE
        if memory is not None and need > memory:
            raise GeometryTooLarge(self._too_large(
                f"needs at least {need / 2**30:.0f} GB for {what}, more than this machine's "
                f"{memory / 2**30:.0f} GB"))

    def _too_large(self, why: str) -> str:
        return (f"the scene places {self.instanced_triangles:,} triangles ({self.count:,} instances of "
                f"{self.unique_triangles:,} unique triangles); Penumbra flattens instances into "
                f"world-space triangles for this and {why}")

    def order(self) -> np.ndarray:
        """int64[I]: the instances in flattening order (by object id, stable)."""
        return np.argsort(self.object_id, kind="stable")

    def flatten(self, selected: Optional[np.ndarray] = None) -> Tuple[np.ndarray, np.ndarray]:
        """(float32[T,3,3] world-space triangles, int32[T] object ids) of
        every instance (or of the ``selected`` ones, bool per instance), in
        ``order``: each mesh's vertices placed in float64, rounded to float32
        (``placed``), then gathered into triangles. A selected instance's
        triangles are bit for bit those of the whole soup."""
        order = self.order()
        if selected is not None:
            order = order[np.asarray(selected, bool)[order]]
        tris, ids = [], []
        for i in order:
            faces = self.faces[self.mesh[i]]
            tris.append(self.placed(i)[faces])
            ids.append(np.full(len(faces), self.object_id[i], np.int32))
        if not tris:
            return np.zeros((0, 3, 3), np.float32), np.zeros(0, np.int32)
        return np.concatenate(tris), np.concatenate(ids)

    def placed(self, i: int) -> np.ndarray:
        """float32[V,3]: instance i's mesh vertices in world space."""
        m = self.world_from_mesh[i]
        return (self.vertices[self.mesh[i]] @ m[:3, :3].T + m[:3, 3]).astype(np.float32)

    def triangle_offsets(self) -> np.ndarray:
        """int64[I]: the index in ``flatten``'s soup of each instance's first
        triangle (a hit on instance i, triangle p of its mesh, is soup
        triangle ``offsets[i] + p``)."""
        counts = self.instance_triangles()
        order = self.order()
        starts = np.zeros(self.count, np.int64)
        starts[order] = np.concatenate([[0], np.cumsum(counts[order])[:-1]]) if self.count else []
        return starts

    def packed(self) -> InstanceGeometry:
        """The instances and meshes as one ``InstanceGeometry``."""
        def starts(arrays):
            sizes = np.array([len(a) for a in arrays], np.int64)
            return np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64) if len(sizes) else sizes
        verts = np.concatenate(self.vertices) if self.vertices else np.zeros((0, 3))
        faces = np.concatenate(self.faces) if self.faces else np.zeros((0, 3), np.int32)
        return InstanceGeometry(
            np.ascontiguousarray(self.mesh, np.int32), np.ascontiguousarray(self.world_from_mesh, np.float64),
            np.ascontiguousarray(self.object_id, np.int32), self.triangle_offsets(),
            np.ascontiguousarray(verts, np.float64), starts(self.vertices),
            np.ascontiguousarray(faces, np.int32), starts(self.faces))

    def instance_boxes(self) -> np.ndarray:
        """float64[I,2,3]: each instance's world box (lo, hi), from its mesh's
        box corners placed by its matrix: it holds every triangle of the
        instance (it is larger than their own box when rotated)."""
        boxes = np.zeros((self.count, 2, 3), np.float64)
        for m, (verts, faces) in enumerate(zip(self.vertices, self.faces)):
            which = np.nonzero(self.mesh == m)[0]
            if not len(which) or not len(faces):
                continue
            used = verts[np.unique(faces)]
            lo, hi = used.min(0), used.max(0)
            corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                                for z in (lo[2], hi[2])])
            xf = self.world_from_mesh[which]
            world = np.einsum("nij,kj->nki", xf[:, :3, :3], corners) + xf[:, None, :3, 3]
            boxes[which, 0] = world.min(1)
            boxes[which, 1] = world.max(1)
        return boxes


@dataclass
class ExpandedInstances:
    """Some instances of a scene kept as instances, flattened: ``scene`` is
    a flattened Scene (same objects, camera, lights) of their triangles, in
    the whole soup's order restricted to them (``MeshInstances.flatten``).
    ``local_ids`` maps the whole soup's triangle ids (a G-buffer's) to this
    soup's."""

    scene: "Scene"
    selected: np.ndarray         # bool[I]: the instances expanded
    soup_start: np.ndarray       # int64[I]: each instance's first triangle in the whole soup
    start: np.ndarray            # int64[I]: its first triangle here, -1 when not expanded
    instance_count: int          # instances of the scene
    soup_triangles: int          # triangles of the whole soup
    soup_order: np.ndarray       # int64: the instances with triangles, by ``soup_start``
    expanded: dict               # ``expansion_counts`` of ``selected``

    def counts(self) -> dict:
        """What was expanded, against the whole scene (``expansion_counts``)."""
        return dict(self.expanded)

    def local_ids(self, soup_ids: np.ndarray) -> np.ndarray:
        """int64 like ``soup_ids``: each triangle id of the whole soup (-1:
        none) as an id of this soup, -1 where its instance was not expanded."""
        t = np.asarray(soup_ids, np.int64)
        if not len(self.soup_order):
            return np.full(t.shape, -1, np.int64)
        at = np.searchsorted(self.soup_start[self.soup_order], t, side="right") - 1
        k = self.soup_order[np.maximum(at, 0)]
        ok = (t >= 0) & (t < self.soup_triangles) & (self.start[k] >= 0)
        return np.where(ok, self.start[k] + t - self.soup_start[k], -1)


def expandable(instances: MeshInstances, selected: np.ndarray) -> np.ndarray:
    """bool per instance: ``selected`` less the instances whose box is not
    finite (the whole soup drops their triangles too)."""
    return np.asarray(selected, bool) & np.isfinite(instances.instance_boxes()).all(axis=(1, 2))


def expansion_counts(scene: "Scene", selected: np.ndarray) -> dict:
    """What expanding the ``selected`` instances of ``scene`` (bool per
    instance, ``expandable``) gives, against the whole scene: ``instances``
    of ``of_instances``, ``triangles`` of ``of_triangles``, and
    ``shadow_triangles`` (those of instances whose object casts shadows)."""
    per = scene.instances.instance_triangles()
    casts = scene.instance_flag("casts_shadow")
    return {"instances": int(selected.sum()), "of_instances": int(len(per)),
            "triangles": int(per[selected].sum()), "of_triangles": int(per.sum()),
            "shadow_triangles": int(per[selected & casts].sum())}


def expand_instances(scene: "Scene", selected: np.ndarray) -> ExpandedInstances:
    """The ``selected`` instances (bool per instance) of ``scene`` (kept as
    instances) as an ``ExpandedInstances`` (``expandable`` ones only)."""
    ins = scene.instances
    selected = expandable(ins, selected)
    per = ins.instance_triangles()
    ins.check_fits(int(per[selected].sum()), f"the {int(selected.sum()):,} instance(s) that can shadow a "
                                            f"visible receiver")
    try:
        with np.errstate(invalid="ignore", over="ignore"):
            tris, ids = ins.flatten(selected)
    except MemoryError:
        raise GeometryTooLarge(ins._too_large("there is not enough memory to hold them")) from None
    counts = np.where(selected, per, 0)
    order = ins.order()
    start = np.full(ins.count, -1, np.int64)
    start[order] = np.concatenate([[0], np.cumsum(counts[order])[:-1]]) if ins.count else []
    start[~selected] = -1
    flat = Scene(tris, ids, scene.objects, scene.camera, scene.lights, scene.resolution, scene.frame, scene.name,
                 motion=scene.motion)
    return ExpandedInstances(flat, selected, ins.triangle_offsets(), start, ins.count, int(per.sum()),
                             order[per[order] > 0], expansion_counts(scene, selected))


@dataclass
class Scene:
    """One captured frame: triangle soup plus camera and lights."""

    triangles: Optional[np.ndarray]        # float32[T,3,3], world space (None: ``instances.flatten()`` on first use)
    tri_object: Optional[np.ndarray]       # int32[T], index into objects
    objects: List[ObjectInfo]
    camera: Optional[Camera]
    lights: List[Light]
    resolution: Tuple[int, int] = (512, 512)   # (width, height) after percentage
    frame: int = 1
    name: str = "scene"
    alpha: Optional[AlphaMattes] = None    # core/alpha.py; None: every surface is opaque
    #: materials whose transparency the capture could not read, treated as
    #: opaque ("material: why"; the plan's notes, ``planner.alpha_notes``)
    alpha_opaque: List[str] = field(default_factory=list)
    #: how the triangles were placed (``MeshInstances``); None for a scene
    #: built from triangles alone (every object its own mesh)
    instances: Optional[MeshInstances] = None
    #: what moves over the shutter (``core/motion.py``); None: a still frame
    motion: Optional[ShutterMotion] = None
    #: the Z and vector passes to write beside the shadow passes
    #: (``core/data_passes.py``: "Depth", "Vector"; the view layer's switches)
    data_passes: Tuple[str, ...] = ()
    #: placements at the previous and the next frame, for the Vector pass
    #: (a ``ShutterMotion`` over frames -1, 0, +1); None: nothing moves
    frame_motion: Optional[ShutterMotion] = None

    def __post_init__(self):
        if self.triangles is None:
            if self.instances is None or self.alpha is not None or self.tri_object is not None:
                raise ValueError("a scene without triangles needs its instances (and no mattes)")
            del self.triangles, self.tri_object       # flattened on first use: __getattr__
            return
        tris = np.asarray(self.triangles, np.float32).reshape(-1, 3, 3)
        ids = np.asarray(self.tri_object, np.int32).reshape(-1)
        if len(ids) != len(tris):
            raise ValueError("tri_object must have one id per triangle")
        self.triangles = np.ascontiguousarray(tris)
        self.tri_object = np.ascontiguousarray(ids)
        if self.alpha is not None and len(self.alpha.tri_matte) != len(tris):
            raise ValueError("alpha mattes must have one entry per triangle")

    def __getattr__(self, name: str):
        # a scene captured as instances flattens its triangles when first asked for them
        if name in ("triangles", "tri_object") and self.__dict__.get("instances") is not None:
            tris, ids = self.__dict__["instances"].flattened()
            tris, ids, dropped = finite_triangles(tris, ids) if len(tris) else (tris, ids, 0)
            if dropped:
                log.warning("dropped %d triangle(s) with non-finite vertices", dropped)
            self.__dict__["triangles"] = np.ascontiguousarray(tris)
            self.__dict__["tri_object"] = np.ascontiguousarray(ids)
            return self.__dict__[name]
        raise AttributeError(name)

    @property
    def is_flattened(self) -> bool:
        """Whether the world-space triangle soup exists (a scene built from
        triangles, or one whose instances were flattened on demand)."""
        return "triangles" in self.__dict__

    def at_resolution(self, width: int, height: int) -> "Scene":
        """The same scene rendered at ``width`` x ``height`` (shares every
        array; does not flatten instances)."""
        other = copy.copy(self)
        other.resolution = (int(width), int(height))
        return other

    # -- derived masks -------------------------------------------------
    def _object_flags(self, attr: str) -> np.ndarray:
        """bool per object id: its ``attr`` (casts_shadow, visible_camera)."""
        return np.array([getattr(o, attr) for o in self.objects] or [True], bool)

    def _object_flag(self, attr: str) -> np.ndarray:
        if len(self.tri_object) == 0:
            return np.zeros(0, bool)
        return self._object_flags(attr)[self.tri_object]

    def instance_flag(self, attr: str) -> np.ndarray:
        """bool per instance (``instances``): its object's ``attr``
        (casts_shadow, visible_camera)."""
        return self._object_flags(attr)[self.instances.object_id]

    def casts_any_shadow(self) -> bool:
        """Whether some triangle casts shadows (on the instances while a
        scene captured as instances is not flattened)."""
        if self.is_flattened:
            return bool(self.tri_casts_shadow.any())
        ins = self.instances
        return bool(ins.count) and bool((self.instance_flag("casts_shadow") & (ins.instance_triangles() > 0)).any())

    @property
    def tri_casts_shadow(self) -> np.ndarray:
        return self._object_flag("casts_shadow")

    @property
    def tri_visible_camera(self) -> np.ndarray:
        return self._object_flag("visible_camera")

    def bounds(self) -> Tuple[np.ndarray, np.ndarray]:
        """Axis-aligned bounds of all triangles (finite ones); of the
        instances' boxes (``MeshInstances.instance_boxes``) while a scene
        captured as instances is not flattened."""
        if not self.is_flattened:
            boxes = self.instances.instance_boxes()
            ok = np.isfinite(boxes).all(axis=(1, 2))
            if not ok.any():
                return np.zeros(3), np.zeros(3)
            return boxes[ok, 0].min(0), boxes[ok, 1].max(0)
        if len(self.triangles) == 0:
            return np.zeros(3), np.zeros(3)
        v = self.triangles.reshape(-1, 3).astype(np.float64)
        return v.min(axis=0), v.max(axis=0)

    def extent(self) -> float:
        """The largest side of ``bounds`` (1 when empty or not finite)."""
        lo, hi = self.bounds()
        e = float(np.max(hi - lo))
        return e if e > 0 and np.isfinite(e) else 1.0

    def geometry_counts(self) -> Tuple[int, int, int]:
        """(instances, unique triangles, instanced triangles): what a
        two-level ray caster holds against what the flattened soup holds."""
        if self.instances is None:
            return len(np.unique(self.tri_object)), len(self.triangles), len(self.triangles)
        i = self.instances
        return i.count, i.unique_triangles, i.instanced_triangles

    def light(self, name: str) -> Light:
        for lt in self.lights:
            if lt.name == name:
                return lt
        raise KeyError(name)


def finite_triangles(triangles: np.ndarray, tri_object: np.ndarray):
    """Drop triangles with non-finite vertices; returns (triangles, ids, dropped)."""
    triangles = np.asarray(triangles).reshape(-1, 3, 3)
    ok = np.isfinite(triangles.reshape(len(triangles), 9)).all(axis=1)
    return triangles[ok], tri_object[ok], int((~ok).sum())


@dataclass
class GBuffer:
    """Camera view at pixel centres (DESIGN.md "GBuffer").

    ``depth`` is the distance along the camera's view axis (Cycles' Depth pass
    convention), +inf where nothing is hit. ``normal`` is the geometric normal
    flipped to face the camera (the side that is seen). ``position`` is
    computed from barycentrics on the float32 triangle, float64.

    A packed G-buffer (``pixel`` given; ``pixel_filter``'s sub-pixel
    receivers) holds a list of N pixels of a larger view as shape (1, N):
    ``pixel[k]`` is entry k's flat index (row * width + col) in that view.
    """

    position: np.ndarray      # float64[H,W,3]
    normal: np.ndarray        # float32[H,W,3], unit, facing the camera
    depth: np.ndarray         # float32[H,W]
    object_id: np.ndarray     # int32[H,W], -1 where empty
    triangle_id: np.ndarray   # int32[H,W], -1 where empty
    hit: np.ndarray           # bool[H,W]
    pixel: Optional[np.ndarray] = None   # int64[N]: a packed G-buffer's pixels (None: dense)
    time: Optional[np.ndarray] = None    # float32[H,W]: each entry's shutter time (None: the frame's)
    #: bool[H,W]: the entries that stand for the whole shutter (receivers a
    #: still camera sees on still objects, in a filtered frame of moving
    #: ones): a method that traces time draws each of their shadow rays' own
    #: (``camera_samples.ray_times``) instead of the entry's ``time``; None: none
    over_shutter: Optional[np.ndarray] = None

    @property
    def shape(self) -> Tuple[int, int]:
        return self.depth.shape

    def hit_points(self):
        """(flat pixel ids int64, positions float64[n,3], normals float64[n,3])
        of the pixels that see a surface, contiguous, for the kernels."""
        idx = np.flatnonzero(self.hit.reshape(-1)).astype(np.int64)
        P = np.ascontiguousarray(self.position.reshape(-1, 3)[idx], np.float64)
        N = np.ascontiguousarray(self.normal.reshape(-1, 3)[idx], np.float64)
        return idx, P, N

    def times(self, idx: np.ndarray) -> Optional[np.ndarray]:
        """float32 shutter times of entries ``idx`` (None: all at the frame)."""
        return None if self.time is None else np.ascontiguousarray(self.time.reshape(-1)[idx], np.float32)

    def spread(self, idx: np.ndarray) -> Optional[np.ndarray]:
        """bool: which of entries ``idx`` stand for the whole shutter
        (``over_shutter``; None: none does)."""
        return None if self.over_shutter is None else np.ascontiguousarray(self.over_shutter.reshape(-1)[idx], bool)

    def seed_ids(self, idx: np.ndarray) -> np.ndarray:
        """The pixel ids that seed entries ``idx``' per-pixel samples: their
        flat index in the view (a packed G-buffer's ``pixel``), so a
        sub-pixel receiver draws the same samples whichever list holds it."""
        idx = np.asarray(idx, np.int64)
        return idx if self.pixel is None else np.ascontiguousarray(self.pixel[idx], np.int64)


@dataclass
class ViewFace:
    """One projection of a light view (perspective, orthographic or a cube face).

    View space looks along -Z. ``bounds`` = (left, right, bottom, top): at unit
    distance for perspective (tangent space), in scene units for orthographic.
    Pixel (row, col) covers u in [col, col+1), v in [row, row+1) with
    u = (x' - left) / (right - left) * width, v = (top - y') / (top - bottom) * height,
    where x' = x/-z (perspective) or x (orthographic).
    Depth stored in a map is ``-z`` in view space: the distance along the view
    axis from the light centre (perspective) or from the view plane through
    the view origin (orthographic).
    """

    view_from_world: np.ndarray   # 4x4 float64
    ortho: bool
    bounds: Tuple[float, float, float, float]
    width: int
    height: int
    label: str = ""

    def packed(self) -> np.ndarray:
        """float64[24] for Numba kernels: 16 matrix, ortho, l, r, b, t, w, h, 0."""
        out = np.zeros(24, np.float64)
        out[:16] = np.asarray(self.view_from_world, np.float64).reshape(16)
        out[16] = 1.0 if self.ortho else 0.0
        out[17:21] = self.bounds
        out[21] = self.width
        out[22] = self.height
        return out


@dataclass
class LightView:
    """Depth + object-ID maps of one light from one eye point (DESIGN.md "LightView").

    ``faces`` share one resolution so the maps stack: ``depth[f]`` is face f.
    ``eye`` is where the rays start (light centre, or a light sample).
    """

    faces: List[ViewFace]
    depth: np.ndarray            # float32[F,h,w], +inf where empty
    object_id: np.ndarray        # int32[F,h,w], -1 where empty
    eye: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def packed_faces(self) -> np.ndarray:
        return np.stack([f.packed() for f in self.faces]) if self.faces else np.zeros((0, 24))
