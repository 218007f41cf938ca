"""bpy scenes for the tests and the bench: the bundled sample scenes (opened,
or captured as core Scenes), small scenes built for one check, and what the
tests read back from bpy (an image's pixels, what a panel draws, the render
settings).

Loading a .blend needs bpy (``bridge/capture.py`` is the one boundary);
each capture is cached per (name, resolution) for the whole test run.
"""
from __future__ import annotations

import functools
import os

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SAMPLES = os.path.join(ROOT, "sample_blends")

#: Every scene ``sample_blends/make_samples.py`` builds (its ``SCENES``).
SAMPLE_NAMES = ("grids", "sphere_plane", "torus_plane", "foliage", "sun_pillars", "leaf_cards", "dense_sphere",
                "dense_foliage")


def sample_path(name: str) -> str:
    return os.path.join(SAMPLES, f"{name}.blend")


def open_sample(name: str, resolution=None):
    """Open ``sample_blends/<name>.blend`` in bpy; returns its scene, set to
    render at ``resolution`` (W, H) at 100 % when given."""
    import bpy
    bpy.ops.wm.open_mainfile(filepath=sample_path(name), load_ui=False)
    scene = bpy.context.scene
    if resolution is not None:
        scene.render.resolution_x, scene.render.resolution_y = resolution
        scene.render.resolution_percentage = 100
    return scene


@functools.lru_cache(maxsize=16)
def load_sample(name: str, resolution=(128, 128)):
    """Capture ``sample_blends/<name>.blend`` at ``resolution`` (W, H)."""
    from penumbra.bridge.capture import capture_scene
    sc = capture_scene(open_sample(name), resolution=tuple(resolution))
    sc.name = name
    return sc


def tiny_cycles_scene(width: int, height: int, world_color=None):
    """A factory-empty bpy scene for compositor checks: Cycles at 1 sample,
    no denoising, ``width`` x ``height`` at 100 %, one camera (and a world of
    ``world_color`` when given). The compositor evaluates headless only in a
    render with ``write_still``, so these tests render this."""
    import bpy
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.samples = 1
    scene.cycles.use_denoising = False
    scene.render.resolution_x, scene.render.resolution_y = width, height
    scene.render.resolution_percentage = 100
    if world_color is not None:
        scene.world = bpy.data.worlds.new("World")
        scene.world.color = world_color
    cam = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    scene.collection.objects.link(cam)
    scene.camera = cam
    return scene


#: meshes a user's file may hold that the capture must survive (vertices, faces)
BAD_MESHES = {
    "nan_vertices": ([(float("nan"), 0, 1), (1, 0, 1), (0, 1, 1), (0.5, 0.5, 1)], [(0, 1, 2), (1, 3, 2)]),
    "inf_vertices": ([(float("inf"), 0, 1), (1, -float("inf"), 1), (0, 1, 1)], [(0, 1, 2)]),
    "huge_vertices": ([(3e38, 0, 1), (-3e38, 0, 1), (0, 3e38, 1)], [(0, 1, 2)]),
    "empty_mesh": ([], []),
    "vertices_only": ([(0, 0, 1), (1, 0, 1)], []),
    "degenerate_faces": ([(0, 0, 1), (0, 0, 1), (0, 0, 1), (1, 1, 1), (2, 2, 1)], [(0, 1, 2), (0, 3, 4)]),
}


def save_plane_blend(path, camera_at=(0, 0, 6), mesh_data=None, resolution=None) -> str:
    """A factory-empty file with a 4 x 4 plane, an area light 3 above it, a
    camera at ``camera_at`` (None: no camera), and a mesh object "bad" built
    from ``mesh_data`` (vertices, faces) when given; saved to ``path``."""
    import bpy
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.mesh.primitive_plane_add(size=4)
    bpy.ops.object.light_add(type="AREA", location=(0, 0, 3))
    if camera_at is not None:
        bpy.ops.object.camera_add(location=camera_at)
        bpy.context.scene.camera = bpy.context.object
    if mesh_data is not None:
        verts, faces = mesh_data
        me = bpy.data.meshes.new("bad")
        me.from_pydata(verts, [], faces)
        ob = bpy.data.objects.new("bad", me)
        bpy.context.scene.collection.objects.link(ob)
    if resolution is not None:
        r = bpy.context.scene.render
        r.resolution_x, r.resolution_y = resolution
        r.resolution_percentage = 100
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    return str(path)


def image_rgba(img) -> np.ndarray:
    """A bpy image's pixels as float32[h, w, 4], row 0 at the bottom (as
    Blender stores them)."""
    w, h = img.size
    px = np.empty(w * h * 4, np.float32)
    img.pixels.foreach_get(px)
    return px.reshape(h, w, 4)


class RecordingLayout:
    """A stand-in for a panel's ``layout`` that records what the panel
    draws: ``props`` ((data, property name)), ``operators`` (idnames) and
    ``labels`` (texts); its rows and columns are itself."""

    use_property_split = use_property_decorate = active = enabled = True

    def __init__(self):
        self.props, self.operators, self.labels = [], [], []

    def prop(self, data, name, **kw):
        self.props.append((data, name))

    def operator(self, idname, **kw):
        self.operators.append(idname)
        return type("Props", (), {})()

    def label(self, text="", **kw):
        self.labels.append(text)

    def row(self, **kw):
        return self

    column = row


def draw_panel(panel_cls, context) -> RecordingLayout:
    """Draw the add-on panel ``panel_cls`` for ``context`` (any object with
    the attributes the panel reads: ``scene``, ``light``) into a
    RecordingLayout; returns it."""
    layout = RecordingLayout()
    panel_cls.draw(type("Panel", (), {"layout": layout})(), context)
    return layout


def render_state(scene) -> dict:
    """Everything a reference render touches, as plain values: equal before
    and after means the render left the scene as it found it."""
    import bpy
    from penumbra.bridge import compat
    r, c = scene.render, scene.cycles
    snap = {
        "engine": r.engine, "res": (r.resolution_x, r.resolution_y, r.resolution_percentage),
        "filepath": r.filepath, "file_format": r.image_settings.file_format,
        "media_type": r.image_settings.media_type, "color_depth": r.image_settings.color_depth,
        "use_compositing": r.use_compositing, "use_sequencer": r.use_sequencer,
        "use_border": r.use_border, "world": scene.world.name if scene.world else None,
        "camera_dof": scene.camera.data.dof.use_dof if scene.camera else None,
        "materials": sorted(m.name for m in bpy.data.materials),
        "compositor trees": [t.name for t in compat.render_trees(scene)],
        "penumbra.render_passes": getattr(getattr(scene, "penumbra", None), "render_passes", None),
    }
    for k in ("samples", "seed", "use_animated_seed", "use_adaptive_sampling", "use_denoising",
              "pixel_filter_type", "filter_width", "max_bounces", "diffuse_bounces",
              "glossy_bounces", "transmission_bounces", "transparent_max_bounces",
              "direct_light_sampling_type", "light_sampling_threshold", "use_layer_samples"):
        v = getattr(c, k)
        snap[f"cycles.{k}"] = round(v, 6) if isinstance(v, float) else v
    for vl in scene.view_layers:
        snap[f"vl.{vl.name}"] = (getattr(vl.material_override, "name", None),
                                 vl.use_pass_diffuse_direct, vl.samples)
    for ob in scene.objects:
        if ob.type == "LIGHT":
            snap[f"light.{ob.name}"] = (ob.data.use_shadow, ob.hide_render, round(ob.data.energy, 6))
    return snap


def linear_keys(ob, path: str, values, frames) -> None:
    """Keyframes of ``ob.<path>`` at ``frames``, interpolated linearly."""
    from bpy_extras import anim_utils
    for v, f in zip(values, frames):
        setattr(ob, path, v)
        ob.keyframe_insert(path, frame=f)
    ad = ob.animation_data
    for fc in anim_utils.action_get_channelbag_for_slot(ad.action, ad.action_slot).fcurves:
        for kp in fc.keyframe_points:
            kp.interpolation = "LINEAR"


def sliding_box_scene(scene, res=(48, 48)):
    """In the empty ``scene``: a ground, a unit box at height 1 sliding from
    x = -2 to 2 between frames 1 and 3 (linear keys), a sun tilted so the
    shadow falls towards the camera, a camera above looking down; Cycles
    with Blackman-Harris 1.5 px, the render's motion blur on (shutter 0.5,
    centred), at frame 2."""
    import bpy
    bpy.ops.mesh.primitive_plane_add(size=12.0)
    bpy.ops.mesh.primitive_cube_add(size=1.0, location=(0.0, 0.0, 1.0))
    box = bpy.context.active_object
    box.name = "Box"
    linear_keys(box, "location", [(-2.0, 0, 1.0), (2.0, 0, 1.0)], [1, 3])   # 2 per frame: 1 over the shutter
    sun = bpy.data.objects.new("Sun", bpy.data.lights.new("Sun", "SUN"))
    sun.data.angle, sun.data.energy = 0.02, 3.0
    sun.rotation_euler = (-0.6, 0.0, 0.0)
    scene.collection.objects.link(sun)
    cam = bpy.data.objects.new("Cam", bpy.data.cameras.new("Cam"))
    cam.data.lens = 35.0
    cam.location = (0, -1.0, 6.0)
    scene.collection.objects.link(cam)
    scene.camera = cam
    scene.render.engine = "CYCLES"
    scene.cycles.pixel_filter_type = "BLACKMAN_HARRIS"
    scene.cycles.filter_width = 1.5
    scene.render.resolution_x, scene.render.resolution_y = res
    scene.render.resolution_percentage = 100
    scene.render.use_motion_blur = True
    scene.render.motion_blur_shutter = 0.5
    scene.frame_set(2)
    return scene
