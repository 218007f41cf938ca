"""Methods that need world-space triangles, on a scene kept as instances,
expand only the instances that can shadow a visible receiver
(``FrameBuffers.expansion``): their passes are the flattened scene's, the
frame record and the plan say how much was expanded, and a scene that is
not kept as instances builds the same buffers as before."""
import numpy as np
import pytest

from helpers import instanced_grove, leaf_cluster, placement
from penumbra.core.buffers import EXPAND_PHASE, FrameBuffers
from penumbra.core.frame import render_frame
from penumbra.core.planner import plan_frame
from penumbra.core.scene import Light
from synthetic import light_matrix, persp_camera

NEAR, FAR, LEAVES = 10, 8, 60


def _grove_and_far_trees(res=40):
    """A 32 x 32 ground, NEAR instances of one leaf cluster under an area
    light in the middle and FAR more at the ground's corners, out of the
    camera's view and of the light's reach of what it sees; the scene kept
    as instances and the same scene flattened."""
    rng = np.random.default_rng(7)
    verts, leaves = leaf_cluster(rng, LEAVES, 0.25, (0, 0, 0.9), 0.08)
    near = [placement((s, s, s), a, (x, y, 0)) for s, a, x, y in
            zip(0.8 + 0.4 * rng.random(NEAR), 6.3 * rng.random(NEAR), *(rng.random((2, NEAR)) * 2.4 - 1.2))]
    corners = [(sx * 13.0 + dx, sy * 13.0, 0) for sx in (-1, 1) for sy in (-1, 1) for dx in (0.0, 1.5)]
    far = [placement((1, 1, 1), 0.0, c) for c in corners]
    light = Light("Area", "area", light_matrix((0.4, -0.3, 3.5), (-0.4, 0.3, -3.5)), blender_type="AREA",
                  shape="SQUARE", size=1.0)
    cam = persp_camera((1.0, -2.5, 6.5), (0, 0, 0.3), lens=35.0)
    return instanced_grove(verts, leaves, 16.0, near + far, light, cam, res)


def test_only_the_instances_that_can_shadow_a_visible_receiver_are_expanded():
    """The far trees are left out; every G-buffer triangle maps onto the
    same triangle of the expansion, bit for bit; the scene stays instances."""
    lazy, flat = _grove_and_far_trees()
    fb = FrameBuffers(lazy, *lazy.resolution)
    counts = fb.expansion_counts()
    tree = 2 * LEAVES
    assert counts == {"instances": 1 + NEAR, "of_instances": 1 + NEAR + FAR, "triangles": 2 + NEAR * tree,
                      "of_triangles": 2 + (NEAR + FAR) * tree, "shadow_triangles": 2 + NEAR * tree}
    e = fb.expansion
    assert e.counts() == counts and len(e.scene.triangles) == counts["triangles"]
    g = fb.gbuffer
    seen = g.triangle_id[g.hit]
    local = e.local_ids(seen)
    assert (local >= 0).all() and len(np.unique(g.object_id[g.hit])) > 3
    np.testing.assert_array_equal(e.scene.triangles[local], flat.triangles[seen])
    np.testing.assert_array_equal(e.scene.tri_object[local], flat.tri_object[seen])
    far_ids = np.arange(2 + NEAR * tree, 2 + (NEAR + FAR) * tree)   # soup order: by object id
    assert (flat.tri_object[far_ids] > NEAR).all()
    assert (e.local_ids(far_ids) == -1).all() and e.local_ids(np.array([-1]))[0] == -1
    assert not lazy.is_flattened


@pytest.mark.parametrize("method", ["penumbra_casting", "irregular"])
def test_a_world_triangle_method_on_expanded_instances_gives_the_flattened_pass(method):
    lazy, flat = _grove_and_far_trees()
    a = render_frame(lazy, [method], overrides={"samples": 32})
    b = render_frame(flat, [method], overrides={"samples": 32})
    va, vb = a.lights[0].passes[method], b.lights[0].passes[method]
    assert va.min() < 0.3 and (va < 0.99).mean() > 0.05       # the grove shadows the ground
    assert np.abs(va - vb).max() < 1e-3
    rec = a.lights[0].record[method]
    assert rec["expanded"]["triangles"] == 2 + NEAR * 2 * LEAVES < rec["expanded"]["of_triangles"]
    assert rec["expanded"]["instances"] == 1 + NEAR and EXPAND_PHASE in rec["time_s"]
    assert "expanded" not in b.lights[0].record[method] and EXPAND_PHASE not in b.lights[0].record[method]["time_s"]
    assert not lazy.is_flattened


def test_mesh_pieces_of_expanded_instances_label_the_receivers_as_the_flattened_scene():
    """single_sample's mesh surfaces: the receivers' pieces come through the
    expansion (``triangle_pieces``); the pass is the flattened scene's."""
    lazy, flat = _grove_and_far_trees()
    opts = {"method_overrides": {"single_sample": {"surfaces": "mesh"}}}
    va = render_frame(lazy, ["single_sample"], **opts).lights[0].passes["single_sample"]
    vb = render_frame(flat, ["single_sample"], **opts).lights[0].passes["single_sample"]
    assert va.min() < 0.5 and np.abs(va - vb).max() < 1e-3
    fb = FrameBuffers(lazy, *lazy.resolution)
    g = fb.gbuffer
    pieces = fb.triangle_pieces(g.triangle_id)
    assert ((pieces >= 0) == g.hit).all() and not lazy.is_flattened


def test_the_plan_says_what_a_world_triangle_method_expands():
    lazy, flat = _grove_and_far_trees()
    plan, _ = plan_frame(lazy, ["penumbra_casting", "pcf"], buffers=FrameBuffers(lazy, *lazy.resolution))
    (lp,) = plan.lights
    assert lp.expanded["instances"] == 1 + NEAR and lp.expanded["of_instances"] == 1 + NEAR + FAR
    assert any(d.startswith(f"penumbra_casting expands {1 + NEAR} of {1 + NEAR + FAR} instances")
               for d in lp.decisions), lp.decisions
    assert plan.to_json()["lights"][0]["expanded"] == lp.expanded
    only_pcf, _ = plan_frame(lazy, ["pcf"], buffers=FrameBuffers(lazy, *lazy.resolution))
    assert only_pcf.lights[0].expanded is None and "expanded" not in only_pcf.to_json()["lights"][0]
    flat_plan, _ = plan_frame(flat, ["penumbra_casting"], buffers=FrameBuffers(flat, *flat.resolution))
    assert "expanded" not in flat_plan.to_json()["lights"][0]
    assert not any("expand" in d for d in flat_plan.lights[0].decisions)


def test_a_flattened_scene_builds_its_triangle_buffers_from_its_own_triangles():
    """Nothing is expanded on a scene that is not kept as instances: the
    triangle buffers are the captured ones, and the ledger has no expansion."""
    _, flat = _grove_and_far_trees()
    fb = FrameBuffers(flat, *flat.resolution)
    assert fb.expansion is None and fb.expansion_counts() is None
    tris, ids = fb.shadow_triangles
    np.testing.assert_array_equal(tris, flat.triangles)
    np.testing.assert_array_equal(ids, flat.tri_object)
    g = fb.gbuffer
    t = g.triangle_id.reshape(-1)
    np.testing.assert_array_equal(fb.triangle_pieces(t), np.where(t >= 0, fb.mesh_pieces[np.maximum(t, 0)], -1))
    assert fb.shadow_scene.count == len(flat.triangles)
    assert "expand_instances" not in fb.build_times


def test_auto_counts_what_the_world_triangle_methods_expand(monkeypatch):
    """When the whole soup would not fit in memory but the instances that
    can shadow a visible receiver do, ``auto`` may pick a method that needs
    world-space triangles; its shape counts the instances and the expansion."""
    from penumbra.core import scene as core_scene
    from penumbra.core.auto_choice import scene_shape

    lazy, _ = _grove_and_far_trees()
    light = lazy.lights[0]
    fb = FrameBuffers(lazy, *lazy.resolution)
    counts = fb.expansion_counts()
    per_triangle = core_scene.BYTES_PER_FLATTENED_TRIANGLE
    monkeypatch.setattr(core_scene, "physical_memory",
                        lambda: per_triangle * (counts["of_triangles"] + counts["triangles"]) // 2)
    whole = scene_shape(lazy, light)
    culled = scene_shape(lazy, light, counts["shadow_triangles"])
    assert whole.instanced_only and not culled.instanced_only
    assert culled.instances == 1 + NEAR + FAR and culled.triangles == counts["of_triangles"]
    assert culled.triangles_for("penumbra_casting") == counts["shadow_triangles"] < culled.triangles
    assert culled.triangles_for("pcf") == culled.triangles
    assert f"{1 + NEAR + FAR} instances" in culled.describe()
    plan, _ = plan_frame(lazy, ["auto"], buffers=fb)
    assert str(counts["shadow_triangles"]) in plan.lights[0].auto["reason"].replace(",", "")
