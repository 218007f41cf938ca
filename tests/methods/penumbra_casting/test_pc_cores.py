"""Closed solids in penumbra casting (``cores``): interior blockers inside
closed meshes, their disks, the solids' outward winding; leaf hexagons as
one blocker; and the casting with interior blockers, back-face culls and
hidden pairs against Embree's rays to the same light samples. No bpy."""
import os

import numpy as np
import pytest

import synthetic
from pc_helpers import assert_exact, one_object_scene, own_rays, run_pc
from penumbra.bench.scaling import bulge_split, uv_sphere_triangles
from penumbra.core.methods.penumbra_casting.blockers import coplanar_blockers
from penumbra.core.methods.penumbra_casting.cores import closed_solids, interior_blockers
from synthetic import area_light, quad, sun_light
from helpers import COMPILES_OUTSIDE_WARM_UP

_REGISTER = 'event.register("numba:compile", Compiles())\n'

LIGHT = dict(light_point=np.array([3.0, -2.0, 5.0]), light_dir=None,
             light_lo=np.array([2.5, -2.5, 5.0]), light_hi=np.array([3.5, -1.5, 5.0]))


def _sphere(n=4000, centre=(0.0, 0.0, 1.0), radius=1.0):
    return uv_sphere_triangles(n, radius, centre).astype(np.float64)


def test_interior_blockers_lie_inside_the_closed_sphere_and_are_convex():
    """A closed sphere of 40000 triangles: slice polygons strictly inside it,
    flat, perpendicular to the light's direction, their fans covering most of
    each slice's disk and never more."""
    polys, nv = interior_blockers(_sphere(40000), **LIGHT)          # 9 slices (one per 4096 triangles)
    assert len(polys) >= 2
    d = np.linalg.norm(polys - [0.0, 0.0, 1.0], axis=2)
    # inside the sphere, and inside its polygonal (inscribed) tessellation
    assert d.max() < 1.0 - 1e-5
    # slices perpendicular to the direction from the light to the centre
    n = np.array([0.0, 0.0, 1.0]) - LIGHT["light_point"]
    n /= np.linalg.norm(n)
    h = np.einsum("pkd,d->pk", polys - [0.0, 0.0, 1.0], n)
    assert np.ptp(h, axis=1).max() < 1e-9
    # the union of each slice's fan is about the slice's disk (its corners on a circle)
    area = {}
    for p, k, hp in zip(polys, nv, h[:, 0]):
        for j in range(1, k - 1):
            area[round(hp, 6)] = area.get(round(hp, 6), 0.0) + 0.5 * np.linalg.norm(np.cross(p[j] - p[0], p[j + 1] - p[0]))
    assert len(area) >= 8
    for hp, a in area.items():
        disk = np.pi * (1.0 - hp * hp)
        assert 0.9 * disk < a < disk


def test_solids_orientation_and_disks_inside_their_slices():
    """``closed_solids``: the winding sign of a closed sphere (flipped when
    its triangles are), nothing for an open one, and every disk inside its
    slice polygon (each disk's boundary points within the sphere)."""
    sph = _sphere(40000)
    s = closed_solids(sph, **LIGHT)
    assert (s.facing == 1).all() and (s.solid_of == 0).all()
    assert (closed_solids(sph[:, ::-1].copy(), **LIGHT).facing == -1).all()
    assert (closed_solids(sph[1:], **LIGHT).facing == 0).all()
    ok = s.disks[:, 7] > 0
    assert ok.sum() >= 8
    for dk in s.disks[ok]:
        nrm, c, r = dk[:3], dk[4:7], np.sqrt(dk[7])
        u = np.cross(nrm, [1.0, 0.0, 0.0]); u /= np.linalg.norm(u)
        assert abs(nrm @ c - dk[3]) < 1e-9
        assert np.linalg.norm(c + r * u - [0.0, 0.0, 1.0]) < 1.0


def test_no_interior_blockers_for_open_meshes_or_a_light_inside():
    """No polygon for a mesh with a hole or a solid whose box may hold the
    light; one fan per closed sphere; the sun is always outside."""
    sph = _sphere()
    assert len(interior_blockers(sph[1:], **LIGHT)[0]) == 0            # a hole: not closed
    inside = dict(LIGHT, light_lo=np.array([-0.2, -0.2, 0.8]), light_hi=np.array([0.2, 0.2, 1.2]))
    assert len(interior_blockers(sph, **inside)[0]) == 0               # the light may be in the solid
    two = np.concatenate([sph, _sphere(centre=(0.0, 0.0, 3.5))])
    assert len(interior_blockers(two, **LIGHT)[0]) >= 4                # one fan per closed sphere
    sun = interior_blockers(sph, None, np.array([0.3, 0.2, -1.0]), None, None)
    assert len(sun[0]) >= 2                                             # at infinity: always outside


def _leaf_fans(rng, n):
    """``n`` flat convex hexagonal leaves, each a fan of 4 triangles."""
    h, L = 0.2, 0.5
    leaf = np.array([[0, 0, 0], [-h, 0.3 * L, 0], [-0.8 * h, 0.65 * L, 0], [0, L, 0], [0.8 * h, 0.65 * L, 0],
                     [h, 0.3 * L, 0]])
    fan = leaf[[[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 4, 5]]]
    out = []
    for _ in range(n):
        rot, _ = np.linalg.qr(rng.normal(0, 1, (3, 3)))
        out.append(fan @ rot.T + rng.uniform([-2, -2, 0.8], [2, 2, 2.2]))
    return np.concatenate(out)


def test_a_leaf_hexagon_is_one_blocker_or_two_quads_at_four_corners():
    """A convex hexagonal leaf (a fan of 4 triangles) merges into one
    hexagon, or into two quads when polygons may have at most 4 corners;
    either way padded to MAXB corners."""
    leaves = _leaf_fans(np.random.default_rng(2), 30)
    polys, nv, poly_of = coplanar_blockers(leaves)
    assert len(polys) == 30 and (nv == 6).all()
    polys4, nv4, _ = coplanar_blockers(leaves, 4)
    assert len(polys4) == 60 and (nv4 == 4).all()
    assert polys4.shape[1] == polys.shape[1]                  # padded to MAXB: the same kernels


def _mixed_scene(light, res=48):
    """Ground, curved split leaves, hexagon leaves and a closed smooth sphere."""
    rng = np.random.default_rng(7)
    leaves = _leaf_fans(rng, 40)
    curved = bulge_split(_leaf_fans(rng, 10) + [0.0, 0.0, 0.3], 1, 0.15)
    sph = uv_sphere_triangles(3000, 0.7, (0.8, 0.5, 1.2))
    tris = np.concatenate([np.array(quad(-6, 6, -6, 6, 0.0)), leaves, curved, sph]).astype(np.float32)
    return one_object_scene(tris, light, res)


@pytest.mark.parametrize("light", [area_light(1.5, z=5.0), sun_light(0.1)], ids=["area", "sun"])
def test_hexagons_and_interior_blockers_block_exactly_embrees_rays(light):
    """Every relation the casting marks is a segment Embree finds blocked,
    with hexagons, interior blockers and back-face culls on (the defaults),
    and they change nothing against the paper's per-triangle casting beyond
    rays grazing an edge."""
    scene = _mixed_scene(light)
    fb, setup, V, stats = run_pc(scene)
    assert stats["interior_blockers"] >= 2
    # the sphere's triangles facing away from the light, and pairs hidden behind its slices
    assert stats["triangles_backface_culled"] > 0 and stats["hidden_pairs"] > 0 and stats["hidden_nodes"] > 0
    assert_exact(V, own_rays(fb, setup), setup.light.S)
    _, _, V_paper, st_paper = run_pc(scene, interior_blockers=False, coplanar_blockers=False, backface_cull=False)
    assert st_paper["interior_blockers"] == 0 and st_paper["blockers"] > stats["blockers"]
    assert st_paper["triangles_backface_culled"] == st_paper["hidden_pairs"] == 0
    assert_exact(V, V_paper, setup.light.S)


def test_a_concave_slice_gives_no_polygon():
    """A circular slice gives a convex fan; a star's spikes or a dent in the
    loop give none (the polygon would leave the slice)."""
    from penumbra.core.methods.penumbra_casting.cores import _convex_fan
    a = np.linspace(0, 2 * np.pi, 200, endpoint=False)
    normal = np.array([0.0, 0.0, 1.0])
    circle = np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], 1)
    fan = _convex_fan(circle, normal)
    assert fan is not None and (fan[1] >= 3).all()
    star = circle * (1.0 + 0.4 * (np.cos(5 * a) > 0.95))[:, None]       # five thin spikes
    dent = circle * (1.0 - 0.3 * np.exp(-((a - 1.0) / 0.2) ** 2))[:, None]   # one dent
    assert _convex_fan(star, normal) is None and _convex_fan(dent, normal) is None


@pytest.mark.parametrize("light", [area_light(1.0, z=4.5), sun_light(0.08)], ids=["area", "sun"])
def test_backface_cull_and_hidden_pairs_change_no_relation_on_a_smooth_sphere(light):
    """The closed sphere's back-facing triangles dropped and the (blocker,
    receiver) pairs hidden behind its slices skipped: the same relations as
    with every triangle tested, and as Embree's rays."""
    sph = uv_sphere_triangles(20000, 1.0, (0.3, 0.2, 1.0))
    tris = np.concatenate([np.array(quad(-5, 5, -5, 5, 0.0)), sph]).astype(np.float32)
    scene = one_object_scene(tris, light, 64, eye=(4.0, -5.0, 4.0))
    fb, setup, V, st = run_pc(scene)
    assert st["triangles_backface_culled"] > 0.3 * len(sph) and st["group_backface_culled"] > 0
    assert st["hidden_pairs"] + st["hidden_nodes"] > 0.3 * st["receiver_blocker_pairs"]
    _, _, V_all, st_all = run_pc(scene, backface_cull=False, hidden_behind_cores=False)
    assert st_all["hidden_pairs"] == st_all["hidden_nodes"] == st_all["triangles_backface_culled"] == 0
    assert_exact(V, V_all, setup.light.S, frac=0.0005)
    assert_exact(V, own_rays(fb, setup), setup.light.S)


def test_merge_on_the_solids_mesh_equals_the_merge_from_scratch():
    """``sub_mesh``: the merge of a subset of triangles on the vertex ids and
    adjacency built once for all of them is the merge built from the subset."""
    from penumbra.core.methods.penumbra_casting.blockers import sub_mesh
    rng = np.random.default_rng(3)
    tris = np.concatenate([_sphere(3000), _leaf_fans(rng, 20), np.array(quad(-3, 3, -3, 3, 0.0), float)])
    s = closed_solids(tris, **LIGHT)
    sel = np.flatnonzero(rng.random(len(tris)) < 0.7)
    a = coplanar_blockers(tris[sel])
    b = coplanar_blockers(tris[sel], mesh=sub_mesh(s.mesh, sel))
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x, y)


#: helpers' compile listener (compile events inside / outside the
#: warm-up), then a frame of a closed sphere
_CLOSED_SOLID_COMPILES = COMPILES_OUTSIDE_WARM_UP.split(_REGISTER)[0] + _REGISTER + r"""
from penumbra.bench.scaling import smooth_sphere_scene
from penumbra.core.frame import render_frame
render_frame(smooth_sphere_scene(2000, (16, 16)), ["penumbra_casting"], overrides={"samples": 4})
print(json.dumps({"inside": inside, "outside": outside}))
"""


def test_a_closed_solid_compiles_nothing_outside_the_warm_up(tmp_path):
    """The warm-up's scene (two quads) has no closed solid; on a fresh Numba
    cache the slicing kernels (``cores``) a real scene's closed mesh needs
    still compile inside the warm-up, not in the method's time."""
    import json
    import subprocess
    import sys
    env = dict(os.environ, PENUMBRA_NUMBA_CACHE_ROOT=str(tmp_path / "cache"))
    env.pop("NUMBA_CACHE_DIR", None)
    code = _CLOSED_SOLID_COMPILES.replace("{tests!r}", repr(os.path.dirname(os.path.abspath(synthetic.__file__))))
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert p.returncode == 0, p.stderr
    seen = json.loads(p.stdout.strip().splitlines()[-1])
    assert "_components" in seen["inside"] and "_slice_loop" in seen["inside"], seen["inside"]
    assert seen["outside"] == [], seen["outside"]
