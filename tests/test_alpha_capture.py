"""Alpha mattes as the capture reads them (bridge/mattes.py):
every wiring, the texels and UVs per triangle, interpolation and extension,
images shared, bad input (one-line warning, opaque, never NaN), scenes
without mattes untouched, and the plan naming what was captured."""
import logging

import bpy
import numpy as np
import pytest

from penumbra.bridge import compat
from penumbra.bridge import mattes as mattes_mod
from penumbra.bridge.capture import capture_scene
from penumbra.bridge.mattes import LUMA
from penumbra.cli import main
from penumbra.core import alpha as A
from penumbra.core.planner import make_plan
from scenes import image_rgba, open_sample, sample_path

# a 4 x 2 matte: 8 distinct alpha values, row 0 at v = 0
W, H = 4, 2
ALPHA = np.array([[0.0, 0.25, 0.5, 1.0],
                  [0.75, 0.125, 1.0, 0.0]], np.float32)
RGB = np.array([0.9, 0.3, 0.1], np.float32)


def _image(name="matte", alpha=ALPHA, rgb=RGB):
    img = bpy.data.images.new(name, alpha.shape[1], alpha.shape[0], alpha=True, float_buffer=True)
    px = np.empty(alpha.shape + (4,), np.float32)
    px[..., :3] = rgb
    px[..., 3] = alpha
    img.pixels.foreach_set(px.ravel())
    img.alpha_mode = "STRAIGHT"
    return img


def _card(scene, name, material=None, uv=True, z=1.0, mesh=None):
    """A 2 x 2 quad at height z; UV = ((x + 1) / 2, (y + 1) / 2)."""
    if mesh is None:
        mesh = bpy.data.meshes.new(name)
        mesh.from_pydata([(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)], [], [[0, 1, 2, 3]])
        if uv:
            layer = mesh.uv_layers.new(name="UVMap")
            layer.data.foreach_set("uv", np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float32).ravel())
        if material is not None:
            mesh.materials.append(material)
    ob = bpy.data.objects.new(name, mesh)
    ob.location = (0, 0, z)
    scene.collection.objects.link(ob)
    return ob


def _principled(name, image=None, output="Alpha", interpolation="Closest", extension="REPEAT"):
    mat = bpy.data.materials.new(name)
    nt = mat.node_tree
    bsdf = nt.nodes["Principled BSDF"]
    if image is not None:
        tex = nt.nodes.new("ShaderNodeTexImage")
        tex.image = image
        tex.interpolation = interpolation
        tex.extension = extension
        reroute = nt.nodes.new("NodeReroute")       # the capture follows reroutes
        nt.links.new(tex.outputs[output], reroute.inputs[0])
        nt.links.new(reroute.outputs[0], bsdf.inputs["Alpha"])
    return mat


def _mix(name, image, transparent_first=True):
    mat = bpy.data.materials.new(name)
    nt = mat.node_tree
    bsdf, out = nt.nodes["Principled BSDF"], nt.nodes["Material Output"]
    clear = nt.nodes.new("ShaderNodeBsdfTransparent")
    mix = nt.nodes.new("ShaderNodeMixShader")
    tex = nt.nodes.new("ShaderNodeTexImage")
    tex.image = image
    nt.links.new(tex.outputs["Alpha"], mix.inputs[0])
    first, second = (clear, bsdf) if transparent_first else (bsdf, clear)
    nt.links.new(first.outputs[0], mix.inputs[1])
    nt.links.new(second.outputs[0], mix.inputs[2])
    nt.links.new(mix.outputs["Shader"], out.inputs["Surface"])
    return mat


def _texels(m: A.AlphaMattes, i: int) -> np.ndarray:
    o, w, h = int(m.offset[i]), int(m.width[i]), int(m.height[i])
    return m.texels[o:o + w * h].reshape(h, w)


def _card_tris(captured, name):
    oid = next(o.id for o in captured.objects if o.name == name)
    return np.flatnonzero(captured.tri_object == oid)


def _warnings(caplog):
    return [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]


# --------------------------------------------------------------------------
# texels and UVs
def test_texels_and_corner_uvs(factory_scene):
    _card(factory_scene, "Card", _principled("Leaf", _image()))
    m = capture_scene().alpha
    assert m is not None and m.count == 1 and m.names == ["Leaf / matte"]
    assert (m.width[0], m.height[0]) == (W, H)
    np.testing.assert_array_equal(_texels(m, 0), ALPHA)      # row 0 = v 0
    assert m.interpolation[0] == A.CLOSEST and m.extension[0] == A.REPEAT
    # tri_uv at each corner is the UV of that corner's vertex
    captured = capture_scene()
    tris = captured.triangles[_card_tris(captured, "Card")].astype(np.float64)
    uv = captured.alpha.tri_uv[_card_tris(captured, "Card")]
    np.testing.assert_allclose(uv, (tris[..., :2] + 1.0) / 2.0, atol=1e-6)
    assert (captured.alpha.tri_matte == 0).all()


def test_texel_at_a_points_uv_is_the_images_value(factory_scene):
    """A nearest lookup at a point of the card gives the image's pixel there."""
    _card(factory_scene, "Card", _principled("Leaf", _image()))
    captured = capture_scene()
    m = captured.alpha
    rng = np.random.default_rng(0)
    for _ in range(20):
        t = int(rng.integers(len(captured.triangles)))
        b = rng.dirichlet((1.0, 1.0, 1.0))
        p = b @ captured.triangles[t].astype(np.float64)
        uv = b @ m.tri_uv[t].astype(np.float64)
        x, y = int(np.floor(uv[0] * W)) % W, int(np.floor(uv[1] * H)) % H
        px, py = int(np.floor((p[0] + 1) / 2 * W)) % W, int(np.floor((p[1] + 1) / 2 * H)) % H
        assert (x, y) == (px, py)
        assert m.texels[m.offset[0] + y * W + x] == ALPHA[py, px]


@pytest.mark.parametrize("alpha_linked", [False, True])
def test_color_output_converts_as_cycles(factory_scene, alpha_linked):
    """Color -> float: Rec.709 luminance of the linear colour. In 5.0 a float
    buffer is stored premultiplied: Cycles outputs it as is, divided by alpha
    when the node's Alpha output is linked too; from 5.1 it is straight and
    premultiplied unless the Alpha output is linked (bridge/compat.py;
    tests/test_alpha_cycles.py checks both against Cycles)."""
    img = _image()
    assert img.is_float and img.colorspace_settings.name == "Linear Rec.709"
    mat = _principled("Grey", img, output="Color")
    if alpha_linked:
        nt = mat.node_tree
        nt.links.new(nt.nodes["Image Texture"].outputs["Alpha"], nt.nodes["Principled BSDF"].inputs["Roughness"])
    _card(factory_scene, "Card", mat)
    m = capture_scene().alpha
    luma = float(RGB @ LUMA)
    if compat.float_pixels_premultiplied():
        want = np.where(ALPHA > 0, np.minimum(luma / np.maximum(ALPHA, 1e-9), 1.0), 0.0) if alpha_linked else luma
    else:
        want = luma if alpha_linked else luma * ALPHA
    np.testing.assert_allclose(_texels(m, 0), np.broadcast_to(want, ALPHA.shape), atol=1e-6)


def test_constant_alpha_is_a_1x1_matte_without_uvs(factory_scene):
    mat = _principled("Veil")
    mat.node_tree.nodes["Principled BSDF"].inputs["Alpha"].default_value = 0.3
    _card(factory_scene, "Card", mat, uv=False)
    _card(factory_scene, "Opaque", _principled("Solid"), z=2.0)
    captured = capture_scene()
    m = captured.alpha
    assert m.count == 1 and (m.width[0], m.height[0]) == (1, 1)
    assert m.texels[m.offset[0]] == pytest.approx(0.3)
    assert m.names == ["Veil / constant 0.3"]
    assert (m.tri_matte[_card_tris(captured, "Card")] == 0).all()
    assert (m.tri_matte[_card_tris(captured, "Opaque")] == -1).all()


@pytest.mark.parametrize("transparent_first", [True, False])
def test_mix_shader_alpha_is_the_opaque_shares(factory_scene, transparent_first):
    """out = (1 - f) Shader_1 + f Shader_2: alpha = f with the Transparent
    BSDF first, 1 - f with it second."""
    _card(factory_scene, "Card", _mix("Mix", _image(), transparent_first))
    m = capture_scene().alpha
    want = ALPHA if transparent_first else 1.0 - ALPHA
    np.testing.assert_allclose(_texels(m, 0), want, atol=1e-7)


@pytest.mark.parametrize("interpolation, code", [("Closest", A.CLOSEST), ("Linear", A.LINEAR),
                                                 ("Cubic", A.LINEAR), ("Smart", A.LINEAR)])
@pytest.mark.parametrize("extension, ext_code", [("REPEAT", A.REPEAT), ("EXTEND", A.EXTEND),
                                                 ("CLIP", A.CLIP)])
def test_interpolation_and_extension(factory_scene, interpolation, code, extension, ext_code):
    _card(factory_scene, "Card", _principled("Leaf", _image(), interpolation=interpolation,
                                             extension=extension))
    m = capture_scene().alpha
    assert (m.interpolation[0], m.extension[0]) == (code, ext_code)


def test_mirror_is_a_mirrored_2x2_tile_with_half_uvs(factory_scene):
    """MIRROR at uv = REPEAT of [img | flipped] / [flipped in v] at uv / 2."""
    _card(factory_scene, "Card", _principled("Leaf", _image(), extension="MIRROR"))
    captured = capture_scene()
    m = captured.alpha
    assert m.extension[0] == A.REPEAT and (m.width[0], m.height[0]) == (2 * W, 2 * H)
    t = _texels(m, 0)
    np.testing.assert_array_equal(t[:H, :W], ALPHA)
    np.testing.assert_array_equal(t[:H, W:], ALPHA[:, ::-1])
    np.testing.assert_array_equal(t[H:, :], t[:H, :][::-1])
    tris = captured.triangles.astype(np.float64)
    np.testing.assert_allclose(m.tri_uv, (tris[..., :2] + 1.0) / 4.0, atol=1e-6)


def test_cycles_uv_map_is_active_render(factory_scene):
    """Cycles renders with the ``active_render`` UV map (checked in 5.0.1)."""
    ob = _card(factory_scene, "Card", _principled("Leaf", _image()))
    flipped = ob.data.uv_layers.new(name="Flipped")
    flipped.data.foreach_set("uv", np.array([[1, 0], [0, 0], [0, 1], [1, 1]], np.float32).ravel())
    flipped.active_render = True
    ob.data.uv_layers.active = ob.data.uv_layers["UVMap"]
    captured = capture_scene()
    tris = captured.triangles.astype(np.float64)
    np.testing.assert_allclose(captured.alpha.tri_uv[..., 0], (1.0 - tris[..., 0]) / 2.0, atol=1e-6)


def test_instances_share_one_captured_image(factory_scene):
    img = _image()
    leaf = _principled("Leaf", img)
    first = _card(factory_scene, "A", leaf)
    _card(factory_scene, "B", mesh=first.data, z=2.0)             # linked duplicate
    _card(factory_scene, "C", _mix("Mix", img), z=3.0)            # same image, another material
    captured = capture_scene()
    m = captured.alpha
    assert m.count == 2 and len(m.texels) == W * H                # one copy of the texels
    assert m.offset[0] == m.offset[1] == 0
    assert (m.tri_matte >= 0).all()


def test_collection_instances_carry_the_matte(factory_scene):
    coll = bpy.data.collections.new("Cards")
    factory_scene.collection.children.link(coll)
    card = _card(factory_scene, "Card", _principled("Leaf", _image()))
    factory_scene.collection.objects.unlink(card)
    coll.objects.link(card)
    for k in range(3):
        inst = bpy.data.objects.new(f"Inst{k}", None)
        inst.instance_type, inst.instance_collection = "COLLECTION", coll
        inst.location = (3.0 * (k + 1), 0.0, 0.0)
        factory_scene.collection.objects.link(inst)
    captured = capture_scene()
    m = captured.alpha
    assert len(captured.triangles) == 2 * 4 and m.count == 1 and len(m.texels) == W * H
    assert (m.tri_matte == 0).all()
    tris = captured.triangles.astype(np.float64)
    local_x = tris[..., 0] - np.round(tris.mean(axis=1)[:, None, 0] / 3.0) * 3.0
    np.testing.assert_allclose(m.tri_uv[..., 0], (local_x + 1.0) / 2.0, atol=1e-5)


def test_non_finite_triangles_drop_their_mattes_too(factory_scene):
    leaf = _principled("Leaf", _image())
    _card(factory_scene, "A", leaf)
    bad = _card(factory_scene, "B", _principled("Solid"), z=2.0)
    co = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [np.nan, 1, 0]], np.float32)
    bad.data.vertices.foreach_set("co", co.ravel())
    bad.data.update()
    captured = capture_scene()
    assert len(captured.triangles) == 3 and len(captured.alpha.tri_matte) == 3
    assert (captured.alpha.tri_matte[_card_tris(captured, "A")] == 0).all()


# --------------------------------------------------------------------------
# bad input: one line, opaque, never NaN
def _assert_one_line_opaque(caplog, captured, *names):
    lines = _warnings(caplog)
    assert len(lines) == 1 and "\n" not in lines[0], lines
    assert all(n in lines[0] for n in names) and "opaque" in lines[0]
    assert captured.alpha is None
    assert len(captured.alpha_opaque) == 1 and names[0] in captured.alpha_opaque[0]


def test_missing_image_file_is_opaque_with_one_warning(factory_scene, caplog, tmp_path):
    img = bpy.data.images.new("gone", 4, 4)
    img.source = "FILE"
    img.filepath = str(tmp_path / "gone.png")
    _card(factory_scene, "A", _principled("Leaf", img))
    _card(factory_scene, "B", mesh=bpy.data.objects["A"].data, z=2.0)   # warned once, not per user
    captured = capture_scene()
    _assert_one_line_opaque(caplog, captured, "Leaf", "gone")
    assert np.isfinite(captured.triangles).all()


def test_mesh_without_uvs_is_opaque_with_one_warning(factory_scene, caplog):
    _card(factory_scene, "A", _principled("Leaf", _image("leafimg")), uv=False)
    _assert_one_line_opaque(caplog, capture_scene(), "Leaf", "leafimg")


def test_non_finite_pixels_never_give_nan(factory_scene):
    alpha = ALPHA.copy()
    alpha[0, 0], alpha[1, 1] = np.nan, np.inf
    _card(factory_scene, "A", _principled("Leaf", _image(alpha=alpha)))
    t = capture_scene().alpha.texels
    assert np.isfinite(t).all() and t.min() >= 0.0 and t.max() <= 1.0


def _unreadable(kind):
    """A material whose transparency the capture does not read, and the
    node type its warning names."""
    mat = _principled(f"Unread_{kind}")
    nt = mat.node_tree
    bsdf, out = nt.nodes["Principled BSDF"], nt.nodes["Material Output"]
    if kind == "noise":
        nt.links.new(nt.nodes.new("ShaderNodeTexNoise").outputs["Fac"], bsdf.inputs["Alpha"])
        return mat, "Noise"
    if kind == "math":
        tex = nt.nodes.new("ShaderNodeTexImage")
        tex.image = _image()
        math_node = nt.nodes.new("ShaderNodeMath")
        nt.links.new(tex.outputs["Alpha"], math_node.inputs[0])
        nt.links.new(math_node.outputs[0], bsdf.inputs["Alpha"])
        return mat, "Math"
    group = bpy.data.node_groups.new("Leafy", "ShaderNodeTree")
    group.interface.new_socket("Shader", in_out="OUTPUT", socket_type="NodeSocketShader")
    inner = group.nodes.new("ShaderNodeBsdfPrincipled")
    inner.inputs["Alpha"].default_value = 0.2
    g_out = group.nodes.new("NodeGroupOutput")
    group.links.new(inner.outputs["BSDF"], g_out.inputs[0])
    node = nt.nodes.new("ShaderNodeGroup")
    node.node_tree = group
    nt.links.new(node.outputs[0], out.inputs["Surface"])
    return mat, "Group"


@pytest.mark.parametrize("kind", ["noise", "math", "group"])
def test_unreadable_transparency_is_opaque_and_named(factory_scene, caplog, kind):
    mat, node_type = _unreadable(kind)
    _card(factory_scene, "A", mat)
    captured = capture_scene()
    _assert_one_line_opaque(caplog, captured, mat.name, node_type)
    plan = make_plan(captured, ["embree"])
    assert any("treated as opaque" in n and mat.name in n for n in plan.notes)


# --------------------------------------------------------------------------
# scenes without mattes stay as they were
def test_scene_without_mattes_reads_no_material(factory_scene, monkeypatch, caplog):
    """No transparency anywhere: alpha is None and the capture reads neither
    materials nor UVs (so it is no slower)."""
    _card(factory_scene, "A", _principled("Solid", _image()))      # image on Base Color only
    nt = bpy.data.materials["Solid"].node_tree
    nt.links.new(nt.nodes["Image Texture"].outputs["Color"], nt.nodes["Principled BSDF"].inputs["Base Color"])
    for link in list(nt.links):
        if link.to_socket.name == "Alpha" or link.to_node.bl_idname == "NodeReroute":
            nt.links.remove(link)

    def boom(*a, **k):
        raise AssertionError("read a material in a scene without mattes")
    monkeypatch.setattr(mattes_mod, "read_material", boom)
    monkeypatch.setattr(mattes_mod.MatteCapture, "triangle_mattes", boom)
    captured = capture_scene()
    assert captured.alpha is None and captured.alpha_opaque == []
    assert not _warnings(caplog)
    assert not any("alpha" in n or "opaque" in n for n in make_plan(captured, ["embree"]).notes)


# --------------------------------------------------------------------------
# the sample scene and the plan
def test_leaf_cards_capture_every_wiring():
    open_sample("leaf_cards")
    captured = capture_scene(resolution=(32, 32))
    m = captured.alpha
    assert m.names == ["LeafMatte / leaf_matte", "LeafSoft / leaf_soft", "ChainLink / chain_link",
                       "Veil / constant 0.5", "MixLeaf / leaf_matte"]
    assert list(m.interpolation) == [A.CLOSEST, A.LINEAR, A.CLOSEST, A.CLOSEST, A.CLOSEST]
    assert m.offset[4] == m.offset[0]                 # the Mix Shader cards share the leaf image
    binary = _texels(m, 0)
    assert set(np.unique(binary)) == {0.0, 1.0}
    soft = _texels(m, 1)
    assert ((soft > 0) & (soft < 1)).mean() > 0.02
    np.testing.assert_array_equal(_texels(m, 2), image_rgba(bpy.data.images["chain_link"])[..., 3])
    fence = _card_tris(captured, "Fence")
    assert m.tri_uv[fence].max() == pytest.approx(12.0)           # tiled 12 x 6
    assert (captured.alpha.tri_matte[_card_tris(captured, "Ground")] == -1).all()
    assert np.isfinite(m.tri_uv).all() and np.isfinite(m.texels).all()


def test_plan_names_the_mattes(capsys):
    rc = main(["plan", sample_path("leaf_cards"), "--methods", "embree", "--resolution", "16x16"])
    assert rc == 0
    out = capsys.readouterr().out
    line = next(ln for ln in out.splitlines() if ln.startswith("note: alpha mattes: "))
    for name in ("LeafMatte / leaf_matte (128x128, Closest, Repeat)",
                 "LeafSoft / leaf_soft (128x128, Linear, Repeat)",
                 "ChainLink / chain_link (64x64, Closest, Repeat)",
                 "Veil / constant 0.5 (1x1, Closest, Repeat)", "MixLeaf / leaf_matte"):
        assert name in line
    assert "treated as opaque" not in out
