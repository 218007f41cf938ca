"""Scene capture (bridge/capture.py): the bpy -> numpy boundary.

These tests build small scenes with bpy and check that the captured
``penumbra.core.scene.Scene`` holds exactly what Blender would render.
"""
import math
import os

import bpy
import bmesh
import numpy as np
import pytest
from mathutils import Matrix

from penumbra.core import views
from penumbra.core.scene import Scene
from penumbra.bridge.capture import (
    CAPTURE_ENGINE_ID, capture_scene, is_capturing, render_resolution)
from scenes import linear_keys

# cube of side 2 centred at the origin: 8 vertices, 12 triangles
CUBE_CORNERS = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)


# --------------------------------------------------------------------------
# scene building helpers
def _cube(scene, name, collection=None, size=2.0):
    me = bpy.data.meshes.new(name)
    bm = bmesh.new()
    bmesh.ops.create_cube(bm, size=size)
    bm.to_mesh(me)
    bm.free()
    ob = bpy.data.objects.new(name, me)
    (collection or scene.collection).objects.link(ob)
    return ob


def _light(scene, name, kind, **props):
    data = bpy.data.lights.new(name, kind)
    for k, v in props.items():
        setattr(data, k, v)
    ob = bpy.data.objects.new(name, data)
    scene.collection.objects.link(ob)
    return ob


def _camera(scene, name="Cam", **props):
    data = bpy.data.cameras.new(name)
    for k, v in props.items():
        setattr(data, k, v)
    ob = bpy.data.objects.new(name, data)
    scene.collection.objects.link(ob)
    scene.camera = ob
    return ob


def _obj(captured: Scene, name):
    matches = [o for o in captured.objects if o.name == name]
    assert len(matches) == 1, (name, [o.name for o in captured.objects])
    return matches[0]


def _tris_of(captured: Scene, name):
    return captured.triangles[captured.tri_object == _obj(captured, name).id]


def _unique_points(tris, decimals=4):
    return np.unique(np.round(tris.reshape(-1, 3).astype(np.float64), decimals), axis=0)


def _same_point_sets(a, b, decimals=4):
    a = _unique_points(np.asarray(a), decimals)
    b = _unique_points(np.asarray(b), decimals)
    return a.shape == b.shape and np.allclose(a, b, atol=2 * 10.0 ** -decimals)


# --------------------------------------------------------------------------
# lights
AREA_CASES = [
    # shape, size, size_y, object scale, expected (shape, size, size_y)
    ("SQUARE", 0.5, 9.0, (2.0, 2.0, 1.0), ("SQUARE", 1.0, 1.0)),
    ("SQUARE", 0.5, 9.0, (2.0, 3.0, 1.0), ("RECTANGLE", 1.0, 1.5)),
    ("RECTANGLE", 0.5, 0.25, (2.0, 3.0, 5.0), ("RECTANGLE", 1.0, 0.75)),
    ("DISK", 0.8, 9.0, (1.5, 1.5, 1.0), ("DISK", 1.2, 1.2)),
    ("DISK", 0.8, 9.0, (1.0, 0.5, 1.0), ("ELLIPSE", 0.8, 0.4)),
    ("ELLIPSE", 0.4, 1.2, (0.5, 2.0, 1.0), ("ELLIPSE", 0.2, 2.4)),
]


@pytest.mark.parametrize("shape,size,size_y,scale,expected", AREA_CASES)
def test_area_light_shapes_scaled_by_object(factory_scene, shape, size, size_y, scale, expected):
    ob = _light(factory_scene, "Area", "AREA", shape=shape, size=size, size_y=size_y,
                color=(0.25, 0.5, 1.0), energy=123.0, use_shadow=False)
    ob.location = (1.0, -2.0, 3.0)
    ob.rotation_euler = (0.3, -0.4, 1.1)
    ob.scale = scale
    lt, = capture_scene().lights
    assert lt.name == "Area" and lt.kind == "area" and lt.blender_type == "AREA"
    assert lt.shape == expected[0]
    assert lt.size == pytest.approx(expected[1], rel=1e-6)
    assert lt.size_y == pytest.approx(expected[2], rel=1e-6)
    assert lt.color == pytest.approx((0.25, 0.5, 1.0))
    assert lt.energy == pytest.approx(123.0)
    assert lt.casts_shadow is False
    # orthonormal, same position and axes as the object
    m = lt.world_from_light
    assert np.allclose(m[:3, :3].T @ m[:3, :3], np.eye(3), atol=1e-9)
    assert np.linalg.det(m[:3, :3]) == pytest.approx(1.0)
    assert np.allclose(lt.position, (1.0, -2.0, 3.0))
    rot = np.array(ob.rotation_euler.to_matrix())
    assert np.allclose(m[:3, :3], rot, atol=1e-6)
    assert np.allclose(lt.direction, -rot[:, 2], atol=1e-6)


def test_point_spot_sun_parameters(factory_scene):
    _light(factory_scene, "Point", "POINT", shadow_soft_size=0.35, energy=50.0,
           color=(1.0, 0.5, 0.25))
    spot = _light(factory_scene, "Spot", "SPOT", shadow_soft_size=0.2,
                  spot_size=math.radians(40.0), spot_blend=0.3, energy=800.0, use_shadow=True)
    spot.location = (0.0, 0.0, 5.0)
    sun = _light(factory_scene, "Sun", "SUN", angle=math.radians(4.0), energy=3.0,
                 use_shadow=False)
    sun.rotation_euler = (0.5, 0.0, 0.25)
    captured = capture_scene()
    assert [lt.name for lt in captured.lights] == ["Point", "Spot", "Sun"]
    point = captured.light("Point")
    assert point.kind == "sphere" and point.blender_type == "POINT"
    assert point.radius == pytest.approx(0.35)
    assert point.spot_size == pytest.approx(math.pi) and not point.is_spot
    assert point.energy == pytest.approx(50.0)
    assert point.color == pytest.approx((1.0, 0.5, 0.25))
    assert point.casts_shadow is True
    sp = captured.light("Spot")
    assert sp.kind == "sphere" and sp.blender_type == "SPOT" and sp.is_spot
    assert sp.radius == pytest.approx(0.2)
    assert sp.spot_size == pytest.approx(math.radians(40.0))
    assert sp.spot_blend == pytest.approx(0.3)
    assert np.allclose(sp.position, (0, 0, 5)) and np.allclose(sp.direction, (0, 0, -1))
    sn = captured.light("Sun")
    assert sn.kind == "sun" and sn.blender_type == "SUN"
    assert sn.angle == pytest.approx(math.radians(4.0))
    assert sn.casts_shadow is False
    rot = np.array(sun.rotation_euler.to_matrix())
    assert np.allclose(sn.direction, -rot[:, 2], atol=1e-6)


def test_point_light_scale_removed(factory_scene):
    ob = _light(factory_scene, "P", "POINT", shadow_soft_size=0.5)
    ob.scale = (3.0, 3.0, 3.0)
    lt, = capture_scene().lights
    assert lt.radius == pytest.approx(0.5)
    assert np.allclose(lt.world_from_light, np.eye(4))


def test_hidden_light_dropped(factory_scene):
    _light(factory_scene, "Shown", "POINT")
    _light(factory_scene, "Hidden", "POINT").hide_render = True
    for mode in ("RENDER", "VIEWPORT"):
        assert [lt.name for lt in capture_scene(mode=mode).lights] == ["Shown"]


# --------------------------------------------------------------------------
# geometry
def test_transformed_array_modifier_object(factory_scene):
    parent = bpy.data.objects.new("Rig", None)
    factory_scene.collection.objects.link(parent)
    parent.location = (1.0, 2.0, 3.0)
    parent.rotation_euler = (0.0, 0.0, math.radians(90.0))
    ob = _cube(factory_scene, "Bars")
    ob.parent = parent
    ob.location = (0.5, 0.0, 0.0)
    ob.scale = (0.5, 0.5, 2.0)
    arr = ob.modifiers.new("Array", "ARRAY")
    arr.count = 3
    arr.use_relative_offset = True
    arr.relative_offset_displace = (1.0, 0.0, 0.0)
    arr.use_merge_vertices = False
    captured = capture_scene()
    tris = _tris_of(captured, "Bars")
    assert tris.shape == (36, 3, 3) and tris.dtype == np.float32
    assert captured.triangles.shape == (36, 3, 3) and captured.tri_object.dtype == np.int32
    # expected: three cubes side by side in local X, then child, then parent transform
    local = np.concatenate([CUBE_CORNERS + (2.0 * k, 0, 0) for k in range(3)])
    m = np.array(parent.matrix_world) @ np.array(ob.matrix_parent_inverse) @ np.array(
        Matrix.LocRotScale(ob.location, ob.rotation_euler, ob.scale))
    world = local @ m[:3, :3].T + m[:3, 3]
    assert np.allclose(m, np.array(ob.matrix_world), atol=1e-6)
    assert _same_point_sets(tris, world)
    # every triangle is a real (non-degenerate) triangle of the cubes
    area = np.linalg.norm(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]), axis=1)
    assert (area > 1e-3).all()


def test_render_vs_viewport_modifier_levels(factory_scene):
    ob = _cube(factory_scene, "Sub")
    mod = ob.modifiers.new("Subsurf", "SUBSURF")
    mod.levels = 1
    mod.render_levels = 2
    assert len(capture_scene(mode="RENDER").triangles) == 12 * 16
    assert len(capture_scene(mode="VIEWPORT").triangles) == 12 * 4


def test_curve_and_text_objects_are_triangulated(factory_scene):
    font = bpy.data.curves.new("Txt", "FONT")
    font.body = "Hi"
    ob = bpy.data.objects.new("Txt", font)
    factory_scene.collection.objects.link(ob)
    ob.location = (0.0, 0.0, 4.0)
    captured = capture_scene()
    tris = _tris_of(captured, "Txt")
    assert len(tris) > 10
    assert np.allclose(tris[..., 2], 4.0, atol=1e-5)


def test_collection_instances_get_distinct_ids(factory_scene):
    src = bpy.data.collections.new("Src")
    factory_scene.collection.children.link(src)
    _cube(factory_scene, "A", src)
    b = _cube(factory_scene, "B", src)
    b.location = (5.0, 0.0, 0.0)
    hidden = _cube(factory_scene, "C", src)
    hidden.hide_render = True
    bpy.context.view_layer.layer_collection.children["Src"].exclude = True
    for k, y in enumerate((0.0, 10.0)):
        inst = bpy.data.objects.new(f"Inst{k}", None)
        inst.instance_type = "COLLECTION"
        inst.instance_collection = src
        inst.location = (0.0, y, 0.0)
        factory_scene.collection.objects.link(inst)
    for mode in ("RENDER", "VIEWPORT"):
        captured = capture_scene(mode=mode)
        names = [o.name for o in captured.objects]
        assert names == sorted(names)
        assert names == ["Inst0/A#0", "Inst0/B#1", "Inst1/A#0", "Inst1/B#1"], mode
        assert [o.id for o in captured.objects] == [0, 1, 2, 3]
        assert sorted(np.unique(captured.tri_object)) == [0, 1, 2, 3]
        for name, offset in (("Inst0/A#0", (0, 0, 0)), ("Inst0/B#1", (5, 0, 0)),
                             ("Inst1/A#0", (0, 10, 0)), ("Inst1/B#1", (5, 10, 0))):
            assert _same_point_sets(_tris_of(captured, name), CUBE_CORNERS + offset), name


def test_instanced_lights_and_nested_instances(factory_scene):
    inner = bpy.data.collections.new("Inner")
    factory_scene.collection.children.link(inner)
    _cube(factory_scene, "Box", inner, size=1.0)
    lamp = _light(factory_scene, "Lamp", "POINT", shadow_soft_size=0.1)
    factory_scene.collection.objects.unlink(lamp)
    inner.objects.link(lamp)
    lamp.location = (0.0, 0.0, 2.0)
    outer = bpy.data.collections.new("Outer")
    factory_scene.collection.children.link(outer)
    mid = bpy.data.objects.new("Mid", None)
    mid.instance_type = "COLLECTION"
    mid.instance_collection = inner
    mid.location = (3.0, 0.0, 0.0)
    outer.objects.link(mid)
    for name in ("Inner", "Outer"):
        bpy.context.view_layer.layer_collection.children[name].exclude = True
    top = bpy.data.objects.new("Top", None)
    top.instance_type = "COLLECTION"
    top.instance_collection = outer
    top.location = (0.0, 10.0, 0.0)
    factory_scene.collection.objects.link(top)
    for mode in ("RENDER", "VIEWPORT"):
        captured = capture_scene(mode=mode)
        assert len(captured.objects) == 1 and len(captured.lights) == 1, mode
        box = captured.objects[0]
        assert box.name.startswith("Top/Box#") and box.name.count(".") == 1
        assert _same_point_sets(captured.triangles, 0.5 * CUBE_CORNERS + (3, 10, 0))
        lt = captured.lights[0]
        assert lt.name.startswith("Top/Lamp#") and lt.radius == pytest.approx(0.1)
        assert np.allclose(lt.position, (3.0, 10.0, 2.0))


def test_capture_other_scene(factory_scene):
    other = bpy.data.scenes.new("Other")
    _cube(other, "OtherCube").location = (0, 0, 7)
    _cube(factory_scene, "MainCube")
    other.render.resolution_x, other.render.resolution_y = 100, 80
    for mode in ("RENDER", "VIEWPORT"):
        captured = capture_scene(other, mode=mode)
        assert [o.name for o in captured.objects] == ["OtherCube"], mode
        assert captured.resolution == (100, 80)
        assert np.allclose(captured.triangles[..., 2].mean(), 7.0)


def test_vertex_dupli_instances(factory_scene):
    me = bpy.data.meshes.new("Spots")
    me.from_pydata([(0, 0, 0), (4, 0, 0), (0, 4, 0), (4, 4, 0)], [], [(0, 1, 3, 2)])
    emitter = bpy.data.objects.new("Emitter", me)
    factory_scene.collection.objects.link(emitter)
    emitter.instance_type = "VERTS"
    emitter.show_instancer_for_render = False
    child = _cube(factory_scene, "Child", size=1.0)
    child.parent = emitter
    captured = capture_scene()
    names = [o.name for o in captured.objects]
    assert names == [f"Emitter/Child#{k}" for k in range(4)]
    assert len(captured.triangles) == 4 * 12            # emitter's own quad not rendered
    centres = sorted(tuple(np.round(_tris_of(captured, n).reshape(-1, 3).mean(0), 4))
                     for n in names)
    assert centres == sorted([(0.0, 0.0, 0.0), (4.0, 0.0, 0.0), (0.0, 4.0, 0.0), (4.0, 4.0, 0.0)])


def _instance_on_points_tree():
    ng = bpy.data.node_groups.new("Scatter", "GeometryNodeTree")
    ng.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    ng.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    gin = ng.nodes.new("NodeGroupInput")
    gout = ng.nodes.new("NodeGroupOutput")
    iop = ng.nodes.new("GeometryNodeInstanceOnPoints")
    ico = ng.nodes.new("GeometryNodeMeshIcoSphere")
    ico.inputs["Radius"].default_value = 0.25
    ico.inputs["Subdivisions"].default_value = 1
    ng.links.new(gin.outputs[0], iop.inputs["Points"])
    ng.links.new(ico.outputs["Mesh"], iop.inputs["Instance"])
    ng.links.new(iop.outputs[0], gout.inputs[0])
    return ng


def test_geometry_nodes_instances(factory_scene):
    ob = _cube(factory_scene, "Scatter")          # 8 points -> 8 icospheres
    ob.location = (0.0, 0.0, 10.0)
    ob.modifiers.new("GN", "NODES").node_group = _instance_on_points_tree()
    captured = capture_scene()
    names = [o.name for o in captured.objects]
    # the modifier leaves the object itself no surface: only the 8 instances
    inst = [n for n in names if n.startswith("Scatter/")]
    assert len(inst) == 8 and len(set(inst)) == 8 and len(names) == 8
    assert len(captured.triangles) == 8 * 20
    centres = np.array([_tris_of(captured, n).reshape(-1, 3).mean(0) for n in inst])
    assert _same_point_sets(centres, CUBE_CORNERS + (0, 0, 10), decimals=3)
    for n in inst:
        r = np.linalg.norm(_tris_of(captured, n).reshape(-1, 3) - _tris_of(captured, n).reshape(-1, 3).mean(0), axis=1)
        assert np.allclose(r, 0.25, atol=1e-4)


def test_instances_share_one_mesh(factory_scene):
    """Instances keep their instancing: the 8 icospheres of an Instance on
    Points modifier and two collection instances of one cube are read as one
    mesh each, placed 10 times; the flattened soup is those placements."""
    ob = _cube(factory_scene, "Scatter")
    ob.location = (0.0, 0.0, 10.0)
    ob.modifiers.new("GN", "NODES").node_group = _instance_on_points_tree()
    src = bpy.data.collections.new("Src")
    factory_scene.collection.children.link(src)
    _cube(factory_scene, "A", src)
    bpy.context.view_layer.layer_collection.children["Src"].exclude = True
    for k in range(2):
        inst = bpy.data.objects.new(f"Inst{k}", None)
        inst.instance_type = "COLLECTION"
        inst.instance_collection = src
        inst.location = (0.0, 5.0 * k, 0.0)
        inst.scale = (1.0 + k, 1.0, 1.0)
        factory_scene.collection.objects.link(inst)
    _cube(factory_scene, "Plain").location = (20.0, 0.0, 0.0)
    for mode in ("RENDER", "VIEWPORT"):
        captured = capture_scene(mode=mode)
        ins = captured.instances
        assert ins.count == 11 and len(ins.faces) == 3, mode
        assert sorted(len(f) for f in ins.faces) == [12, 12, 20]
        assert captured.geometry_counts() == (11, 44, 2 * 12 + 8 * 20 + 12)
        tris, ids = ins.flatten()
        assert np.array_equal(tris, captured.triangles) and np.array_equal(ids, captured.tri_object)
        names = [o.name for o in captured.objects]
        assert sorted(names[i] for i in ins.object_id) == sorted(names)
        wide = ins.world_from_mesh[ins.object_id == names.index("Inst1/A#0")][0]
        assert np.allclose(wide[:3, 3], (0, 5, 0)) and np.allclose(np.diag(wide)[:3], (2, 1, 1))


def test_ids_deterministic(factory_scene):
    for name in ("Zeta", "alpha", "Beta", "Gamma"):
        _cube(factory_scene, name).location = (len(name), 0, 0)
    a = capture_scene()
    b = capture_scene(mode="VIEWPORT")
    assert [o.name for o in a.objects] == sorted(["Zeta", "alpha", "Beta", "Gamma"])
    assert [(o.name, o.id) for o in a.objects] == [(o.name, o.id) for o in b.objects]
    assert np.array_equal(a.triangles, b.triangles)
    assert np.array_equal(a.tri_object, b.tri_object)
    assert (np.diff(a.tri_object) >= 0).all()


def test_ray_visibility_and_pass_index(factory_scene):
    caster = _cube(factory_scene, "Caster")
    no_shadow = _cube(factory_scene, "NoShadow")
    no_shadow.visible_shadow = False
    no_shadow.pass_index = 7
    no_cam = _cube(factory_scene, "NoCam")
    no_cam.visible_camera = False
    captured = capture_scene()
    assert _obj(captured, "Caster").casts_shadow and _obj(captured, "Caster").visible_camera
    assert _obj(captured, "NoShadow").casts_shadow is False
    assert _obj(captured, "NoShadow").visible_camera is True
    assert _obj(captured, "NoShadow").pass_index == 7
    assert _obj(captured, "NoCam").visible_camera is False
    assert _obj(captured, "NoCam").casts_shadow is True
    mask = captured.tri_casts_shadow
    assert mask.sum() == 24 and not mask[captured.tri_object == _obj(captured, "NoShadow").id].any()


def test_instance_inherits_instancer_shadow_visibility(factory_scene):
    src = bpy.data.collections.new("Src")
    factory_scene.collection.children.link(src)
    _cube(factory_scene, "A", src)
    bpy.context.view_layer.layer_collection.children["Src"].exclude = True
    inst = bpy.data.objects.new("Inst", None)
    inst.instance_type = "COLLECTION"
    inst.instance_collection = src
    inst.visible_shadow = False
    factory_scene.collection.objects.link(inst)
    captured = capture_scene()
    assert _obj(captured, "Inst/A#0").casts_shadow is False


def test_hidden_for_render_dropped(factory_scene):
    _cube(factory_scene, "Shown")
    _cube(factory_scene, "HiddenRender").hide_render = True
    viewport_hidden = _cube(factory_scene, "HiddenViewport")
    viewport_hidden.hide_viewport = True
    col = bpy.data.collections.new("NoRender")
    factory_scene.collection.children.link(col)
    _cube(factory_scene, "InNoRender", col)
    col.hide_render = True
    excl = bpy.data.collections.new("Excluded")
    factory_scene.collection.children.link(excl)
    _cube(factory_scene, "InExcluded", excl)
    bpy.context.view_layer.layer_collection.children["Excluded"].exclude = True
    render = capture_scene(mode="RENDER")
    assert [o.name for o in render.objects] == ["HiddenViewport", "Shown"]
    assert len(render.triangles) == 24
    # a viewport depsgraph is filtered for render visibility too (but cannot
    # evaluate what the viewport hides)
    viewport = capture_scene(mode="VIEWPORT")
    assert [o.name for o in viewport.objects] == ["Shown"]


def test_nan_vertices_dropped(factory_scene):
    ob = _cube(factory_scene, "Broken")
    co = np.empty(len(ob.data.vertices) * 3, np.float32)
    ob.data.vertices.foreach_get("co", co)
    co[0] = np.nan                   # vertex 0 is used by several triangles
    co[5] = np.inf
    ob.data.vertices.foreach_set("co", co)
    ob.data.update()
    _cube(factory_scene, "Fine").location = (5, 0, 0)
    for mode in ("RENDER", "VIEWPORT"):
        captured = capture_scene(mode=mode)
        assert np.isfinite(captured.triangles).all()
        assert len(_tris_of(captured, "Fine")) == 12
        n_broken = int((captured.tri_object == _obj(captured, "Broken").id).sum())
        assert 0 <= n_broken < 12


def test_empty_scene(factory_scene):
    captured = capture_scene()
    assert captured.triangles.shape == (0, 3, 3)
    assert captured.tri_object.shape == (0,)
    assert captured.objects == [] and captured.lights == [] and captured.camera is None


def test_frame_resolution_and_name(factory_scene):
    ob = _cube(factory_scene, "Mover")
    ob.location = (0, 0, 0)
    ob.keyframe_insert("location", frame=1)
    ob.location = (10, 0, 0)
    ob.keyframe_insert("location", frame=11)
    # two auto-clamped Bezier keys: symmetric, so frame 6 is exactly half way
    factory_scene.render.resolution_x = 1001
    factory_scene.render.resolution_y = 333
    factory_scene.render.resolution_percentage = 50
    captured = capture_scene(frame=6)
    assert captured.frame == 6 and factory_scene.frame_current == 6
    assert np.allclose(_tris_of(captured, "Mover").reshape(-1, 3).mean(0), (5, 0, 0), atol=1e-5)
    assert captured.resolution == (500, 166) == render_resolution(factory_scene)
    assert captured.name == factory_scene.name         # unsaved file
    assert capture_scene(resolution=(64, 48)).resolution == (64, 48)
    with pytest.raises(ValueError):
        capture_scene(resolution=(0, 10))
    with pytest.raises(ValueError):
        capture_scene(mode="BOGUS")


def test_capture_render_leaves_scene_untouched(factory_scene):
    factory_scene.render.engine = "CYCLES"
    _cube(factory_scene, "A")
    capture_scene(mode="RENDER")
    assert factory_scene.render.engine == "CYCLES"
    assert not is_capturing()
    assert CAPTURE_ENGINE_ID not in {getattr(e, "bl_idname", None)
                                     for e in bpy.types.RenderEngine.__subclasses__()
                                     if getattr(e, "is_registered", False)}


def test_error_inside_capture_render_propagates(factory_scene):
    cam = _camera(factory_scene)
    cam.data.type = "PANO"
    for mode in ("RENDER", "VIEWPORT"):
        with pytest.raises(ValueError, match="panoramic"):
            capture_scene(mode=mode)
    assert not is_capturing()


# --------------------------------------------------------------------------
# camera
def test_no_camera(factory_scene):
    _cube(factory_scene, "A")
    captured = capture_scene()
    assert captured.camera is None
    assert len(captured.triangles) == 12


CAMERA_CASES = [
    # kind, sensor_fit, res_x, res_y, percentage, shift, pixel aspect
    ("PERSP", "AUTO", 640, 480, 50, (0.0, 0.0), (1, 1)),
    ("PERSP", "AUTO", 300, 500, 100, (0.1, -0.2), (1, 1)),
    ("PERSP", "HORIZONTAL", 320, 480, 75, (0.05, 0.1), (1, 1)),
    ("PERSP", "VERTICAL", 640, 360, 100, (-0.15, 0.05), (1, 1)),
    ("PERSP", "VERTICAL", 1001, 667, 37, (0.0, 0.3), (1, 1)),
    ("PERSP", "AUTO", 400, 300, 100, (0.1, 0.0), (2, 1)),
    ("ORTHO", "AUTO", 640, 480, 100, (0.0, 0.0), (1, 1)),
    ("ORTHO", "HORIZONTAL", 200, 400, 50, (0.2, -0.1), (1, 1)),
    ("ORTHO", "VERTICAL", 500, 250, 100, (-0.1, 0.25), (1, 2)),
]


@pytest.mark.parametrize("kind,fit,rx,ry,pct,shift,aspect", CAMERA_CASES)
def test_camera_matches_blender_view_frame(factory_scene, kind, fit, rx, ry, pct, shift, aspect):
    sc = factory_scene
    sc.render.resolution_x, sc.render.resolution_y = rx, ry
    sc.render.resolution_percentage = pct
    sc.render.pixel_aspect_x, sc.render.pixel_aspect_y = aspect
    cam_ob = _camera(sc, type=kind, lens=35.0, sensor_width=32.0, sensor_height=20.0,
                     sensor_fit=fit, ortho_scale=7.5, shift_x=shift[0], shift_y=shift[1],
                     clip_start=0.25, clip_end=300.0)
    cam_ob.location = (3.0, -7.0, 2.5)
    cam_ob.rotation_euler = (1.2, 0.1, 0.4)
    captured = capture_scene()
    cam = captured.camera
    W, H = captured.resolution
    assert (W, H) == (rx * pct // 100, ry * pct // 100)
    assert cam.kind == kind and cam.sensor_fit == fit
    assert cam.lens == pytest.approx(35.0) and cam.ortho_scale == pytest.approx(7.5)
    assert (cam.sensor_width, cam.sensor_height) == pytest.approx((32.0, 20.0))
    assert (cam.shift_x, cam.shift_y) == pytest.approx(shift)
    assert (cam.clip_start, cam.clip_end) == pytest.approx((0.25, 300.0))
    assert (cam.pixel_aspect_x, cam.pixel_aspect_y) == pytest.approx(aspect)
    assert np.allclose(cam.world_from_camera, np.array(cam_ob.matrix_world), atol=1e-6)

    # Blender's own frame corners (camera local space) -> world -> pixels
    local = np.array([tuple(v) for v in cam_ob.data.view_frame(scene=sc)], float)
    world = local @ cam.world_from_camera[:3, :3].T + cam.world_from_camera[:3, 3]
    col, row, depth = views.world_to_camera_pixels(cam, W, H, world)
    assert (depth > 0).all()
    corners = sorted(zip(np.round(col, 6), np.round(row, 6)))
    expected = sorted([(0, 0), (W, 0), (0, H), (W, H)])
    half_pixel = 0.5
    for (c, r), (ec, er) in zip(corners, expected):
        assert abs(c - ec) < half_pixel and abs(r - er) < half_pixel, (corners, expected)

    # the ray through the top-left pixel centre passes half a pixel inside
    # the frame's top-left corner
    org, d, tfar, axis = views.camera_rays(cam, W, H)
    tl = int(np.argmin(col + row))
    tl_world = world[tl]
    cam_inv = np.linalg.inv(cam.world_from_camera)
    p_corner = cam_inv[:3, :3] @ tl_world + cam_inv[:3, 3]
    o = cam_inv[:3, :3] @ org[0, 0] + cam_inv[:3, 3]
    dd = cam_inv[:3, :3] @ d[0, 0]
    t = (p_corner[2] - o[2]) / dd[2]                 # same view depth as the corner
    p_ray = o + t * dd
    frame_w = abs(local[:, 0].max() - local[:, 0].min())
    frame_h = abs(local[:, 1].max() - local[:, 1].min())
    off_px = ((p_ray[0] - p_corner[0]) / (frame_w / W), (p_corner[1] - p_ray[1]) / (frame_h / H))
    # view_frame uses the nominal resolution, a render the rounded one
    # (resolution * percentage // 100): exact when that keeps the aspect ratio
    tol = 1e-3 if W * ry == H * rx else half_pixel
    assert off_px == pytest.approx((0.5, 0.5), abs=tol)
    # and the bottom-right pixel centre ray projects to (W-0.5, H-0.5)
    far = org[-1, -1] + d[-1, -1] * 5.0
    c2, r2, _ = views.world_to_camera_pixels(cam, W, H, far[None])
    assert c2[0] == pytest.approx(W - 0.5, abs=1e-6) and r2[0] == pytest.approx(H - 0.5, abs=1e-6)


def test_camera_scale_removed(factory_scene):
    cam_ob = _camera(factory_scene)
    cam_ob.location = (1, 2, 3)
    cam_ob.rotation_euler = (0.7, 0.0, -0.3)
    cam_ob.scale = (2.0, 3.0, 0.5)
    cam = capture_scene().camera
    m = cam.world_from_camera
    assert np.allclose(m[:3, :3].T @ m[:3, :3], np.eye(3), atol=1e-9)
    assert np.allclose(m[:3, :3], np.array(cam_ob.rotation_euler.to_matrix()), atol=1e-6)
    assert np.allclose(cam.position, (1, 2, 3))


@pytest.mark.parametrize("kind", ["PERSP", "ORTHO"])
def test_depth_of_field_is_cycles_thin_lens(factory_scene, kind):
    cam_ob = _camera(factory_scene, type=kind, lens=85.0)
    cam_ob.location = (0, -4, 1)
    cam_ob.rotation_euler = (math.radians(80), 0, 0)
    assert capture_scene().camera.aperture_radius == 0.0          # DoF off: a pinhole
    dof = cam_ob.data.dof
    dof.use_dof, dof.aperture_fstop, dof.focus_distance = True, 1.4, 3.5
    dof.aperture_blades, dof.aperture_rotation, dof.aperture_ratio = 6, 0.25, 1.5
    cam = capture_scene().camera
    radius = 1.0 / (2 * 1.4) if kind == "ORTHO" else 85.0e-3 / (2 * 1.4)
    assert cam.aperture_radius == pytest.approx(radius)
    assert cam.focus_distance == pytest.approx(3.5)
    assert (cam.aperture_blades, cam.aperture_rotation, cam.aperture_ratio) == (6, pytest.approx(0.25), 1.5)
    dof.aperture_blades = 2                                         # fewer than 3 blades: Cycles' disk
    target = bpy.data.objects.new("Target", None)
    factory_scene.collection.objects.link(target)
    target.location = (0.7, 2.0, 0.3)                               # 6 m ahead along the view axis, off it
    dof.focus_object = target
    cam = capture_scene().camera
    axis = np.array(cam_ob.matrix_world.to_3x3().col[2])
    expect = abs(float(np.dot(axis, np.array(cam_ob.location) - np.array(target.location))))
    assert cam.aperture_blades == 0 and cam.focus_distance == pytest.approx(expect, rel=1e-6)
    assert expect != pytest.approx(3.5)


def test_motion_over_the_shutter_is_blenders_own_evaluation(factory_scene):
    sc = factory_scene
    cam = _camera(sc)
    cam.location = (0, 0, 8)
    mover, still = _cube(sc, "Mover"), _cube(sc, "Still")
    still.location = (4, 0, 0)
    linear_keys(mover, "location", [(0, 0, 0), (2, 1, 0)], [1, 3])
    mover.keyframe_insert("rotation_euler", frame=1)
    sc.frame_set(2)
    assert capture_scene().motion is None                    # motion blur off: a still frame
    sc.render.use_motion_blur = True
    sc.render.motion_blur_shutter = 0.5
    captured = capture_scene()
    assert (sc.frame_current, sc.frame_subframe) == (2, 0.0)   # the frame is set back
    motion = captured.motion
    assert motion.steps == 3 and motion.camera is None
    assert [captured.objects[i].name for i in motion.objects] == ["Mover"]
    frame_m = np.array(mover.matrix_world)
    for k, off in enumerate((-0.25, 0.0, 0.25)):
        sc.frame_set(1 if off < 0 else 2, subframe=(1.75 if off < 0 else 2 + off) % 1)
        expect = np.array(mover.matrix_world) @ np.linalg.inv(frame_m)
        assert np.allclose(motion.delta[k, 0], expect, atol=1e-6)
    assert np.allclose(motion.delta[:, 0, :3, 3], [[-0.25, -0.125, 0], [0, 0, 0], [0.25, 0.125, 0]], atol=1e-6)
    sc.frame_set(2)
    viewport = capture_scene(mode="VIEWPORT").motion             # the same steps from the viewport depsgraph
    assert np.allclose(viewport.delta, motion.delta) and (sc.frame_current, sc.frame_subframe) == (2, 0.0)
    mover.cycles.use_motion_blur = False                     # Cycles' per-object switch
    assert capture_scene().motion is None
    mover.cycles.use_motion_blur = True
    mover.cycles.motion_steps = 2                             # Cycles: (2 << (2 - 1)) + 1 = 5 steps
    sc.render.motion_blur_position = "START"
    linear_keys(cam, "location", [(0, 0, 8), (0, 2, 8)], [2, 4])
    motion = capture_scene().motion
    assert motion.steps == 5 and motion.position == "START"
    assert np.allclose(motion.delta[:, 0, 0, 3], np.linspace(0.0, 0.5, 5), atol=1e-6)
    assert np.allclose(motion.camera[:, 1, 3], np.linspace(0.0, 0.5, 5), atol=1e-6)


# --------------------------------------------------------------------------
# during a render
def test_capture_from_render_handler_depsgraph(factory_scene):
    """During a real render, frame_change_post gets the render depsgraph."""
    sc = factory_scene
    ob = _cube(sc, "Sub")
    mod = ob.modifiers.new("Subsurf", "SUBSURF")
    mod.levels, mod.render_levels = 0, 1
    _camera(sc).location = (0, -10, 0)
    sc.render.engine = "CYCLES"
    sc.cycles.samples = 1
    sc.render.resolution_x = sc.render.resolution_y = 8
    got = []

    def handler(scene, depsgraph):
        if depsgraph is not None and depsgraph.mode == "RENDER":
            got.append(capture_scene(scene, depsgraph=depsgraph))

    bpy.app.handlers.frame_change_post.append(handler)
    try:
        bpy.ops.render.render()
    finally:
        bpy.app.handlers.frame_change_post.remove(handler)
    assert got, "frame_change_post did not run with a render depsgraph"
    assert len(got[0].triangles) == 12 * 4 and got[0].camera is not None
    # the viewport depsgraph passed explicitly is filtered but not re-evaluated
    viewport = capture_scene(depsgraph=bpy.context.evaluated_depsgraph_get())
    assert len(viewport.triangles) == 12


def _scatter_file(path, scale=1.0):
    """A .blend: 8 icosphere instances (Instance on Points, instance scale
    ``scale``) above a ground quad, an instancer whose instance is an empty
    mesh, a sun and a camera looking down."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    ob = _cube(scene, "Scatter")
    ob.location = (0.0, 0.0, 2.0)
    tree = _instance_on_points_tree()
    tree.nodes["Instance on Points"].inputs["Scale"].default_value = (scale, scale, scale)
    ob.modifiers.new("GN", "NODES").node_group = tree
    empty_src = bpy.data.objects.new("Nothing", bpy.data.meshes.new("Nothing"))
    scene.collection.objects.link(empty_src)
    empty_src.hide_render = True
    holder = _cube(scene, "EmptyScatter")
    holder.instance_type = "VERTS"
    holder.show_instancer_for_render = False
    empty_src.parent = holder
    me = bpy.data.meshes.new("Ground")
    me.from_pydata([(-4, -4, 0), (4, -4, 0), (4, 4, 0), (-4, 4, 0)], [], [(0, 1, 2, 3)])
    scene.collection.objects.link(bpy.data.objects.new("Ground", me))
    _light(scene, "Sun", "SUN", angle=math.radians(5))
    cam = bpy.data.objects.new("Cam", bpy.data.cameras.new("Cam"))
    cam.location = (0.0, 0.0, 12.0)
    scene.collection.objects.link(cam)
    scene.camera = cam
    scene.render.resolution_x = scene.render.resolution_y = 24
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    return str(path)


@pytest.mark.parametrize("scale", [0.0, 1.0])
def test_degenerate_instances_render_clean_passes(tmp_path, scale):
    """Instances of zero scale and an instancer whose mesh is empty: the
    capture keeps what has a surface, and every pass is finite in [0, 1]."""
    from penumbra.cli import main
    from penumbra.core import exr
    blend = _scatter_file(tmp_path / "scatter.blend", scale)
    captured = capture_scene()
    assert captured.instances.count == 9                    # 8 icospheres and the ground
    assert np.isfinite(captured.triangles).all()
    out = tmp_path / "out"
    assert main(["render", blend, "--out", str(out), "--methods", "pcf,embree_irr", "--samples", "4",
                 "--no-previews", "--quiet"]) == 0
    layers = exr.read_multilayer(str(out / "scatter.0001.exr"))
    for name in ("pcf", "embree_irr"):
        v = layers["Sun"][name]
        assert np.isfinite(v).all() and v.min() >= 0.0 and v.max() <= 1.0
    shadowed = (layers["Sun"]["embree_irr"] < 0.5).mean()
    assert (shadowed > 0.0) == (scale > 0.0)


def test_a_scene_too_large_to_flatten_is_refused_in_one_line(tmp_path, monkeypatch, capsys):
    """A scatter whose flattened triangles cannot fit in memory: the capture
    keeps it as instances, and flattening it, or expanding the instances
    penumbra_casting needs as world-space blockers, is refused before
    allocating (the CLI: one line, exit 2); a MemoryError while flattening
    says the same."""
    from penumbra.cli import main
    from penumbra.core import scene as core_scene
    from penumbra.core.scene import GeometryTooLarge, MeshInstances
    blend = _scatter_file(tmp_path / "scatter.blend")
    monkeypatch.setattr(core_scene, "physical_memory", lambda: 1000)
    captured = capture_scene()
    assert not captured.is_flattened
    with pytest.raises(GeometryTooLarge, match="places 162 triangles .9 instances of 22 unique"):
        captured.triangles
    capsys.readouterr()
    assert main(["render", blend, "--out", str(tmp_path / "o"), "--methods", "penumbra_casting", "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "needs at least 0 GB" in err[0] and "penumbra: error:" in err[0]
    assert not (tmp_path / "o").exists() or not os.listdir(tmp_path / "o")
    monkeypatch.setattr(core_scene, "physical_memory", lambda: None)

    def no_memory(self):
        raise MemoryError()
    monkeypatch.setattr(MeshInstances, "flatten", no_memory)
    with pytest.raises(GeometryTooLarge, match="not enough memory to hold them"):
        capture_scene().triangles
