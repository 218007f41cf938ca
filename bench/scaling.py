"""Triangle-count scaling (``--part scaling``): ``embree`` and ``penumbra_casting`` side
by side at 10K, 100K and 1M triangles, and where penumbra casting's time goes
on foliage.

The 1M and 500K+ rows are the sample scenes ``dense_sphere`` (1,032,194
triangles) and ``dense_foliage`` (576,814), made by Subdivision Surface
modifiers so the .blend files stay small; the steps between are built here
from arrays (core ``Scene``):

* ``smooth_sphere_scene(n)``: the contact scene's shape (dense_sphere's
  layout): a smooth UV sphere of about ``n`` triangles resting on a ground
  plane (contact at its south pole), under a 1 m square area light, seen by a
  perspective camera.
* ``dense_foliage_scene(levels)``: the captured ``foliage`` sample with every
  leaf triangle split ``levels`` times (4^levels triangles each) and bulged
  off its plane by ``27 b0 b1 b2`` (barycentric; zero on the triangle's
  edges, so adjacent triangles stay watertight): curved leaves, no longer
  coplanar, at 50K-800K triangles.
"""
from __future__ import annotations

import math

import numpy as np

from ..core.scene import Camera, Light, ObjectInfo, Scene
from ..core.views import look_rotation


def _frame(pos, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = look_rotation(np.asarray(target, float) - np.asarray(pos, float), np.asarray(up, float))
    m[:3, 3] = pos
    return m


def uv_sphere_triangles(n_tris: int, radius: float = 1.0, centre=(0.0, 0.0, 1.0)) -> np.ndarray:
    """float32[T,3,3]: a closed UV sphere (shared vertices, one vertex per
    pole) of about ``n_tris`` triangles (segments = 2 x rings; quads split in
    two, fans at the poles)."""
    rings = max(3, int(round(math.sqrt(n_tris / 4.0))))
    seg = 2 * rings
    th = np.arange(1, rings) * (math.pi / rings)
    ph = np.arange(seg) * (2 * math.pi / seg)
    T, P = np.meshgrid(th, ph, indexing="ij")
    ring = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1).reshape(-1, 3)
    V = np.concatenate([[[0.0, 0.0, 1.0]], ring, [[0.0, 0.0, -1.0]]]) * radius + np.asarray(centre)
    V = V.astype(np.float32)
    j = np.arange(seg)
    jn = (j + 1) % seg
    row = lambda r: 1 + r * seg                                           # noqa: E731
    faces = [np.stack([np.zeros(seg, int), row(0) + j, row(0) + jn], 1)]
    for r in range(rings - 2):
        a, b, c, d = row(r) + j, row(r + 1) + j, row(r + 1) + jn, row(r) + jn
        faces += [np.stack([a, b, c], 1), np.stack([a, c, d], 1)]
    last = row(rings - 2)
    faces.append(np.stack([last + jn, last + j, np.full(seg, len(V) - 1)], 1))
    return V[np.concatenate(faces)]


def _ground(half: float) -> np.ndarray:
    a, b, c, d = [-half, -half, 0], [half, -half, 0], [half, half, 0], [-half, half, 0]
    return np.array([[a, b, c], [a, c, d]], np.float32)


def smooth_sphere_scene(n_tris: int, resolution=(1920, 1080)) -> Scene:
    """Ground, a smooth sphere of about ``n_tris`` triangles touching it, and a
    1 m square area light above and to the side (a soft contact shadow)."""
    sph = uv_sphere_triangles(n_tris)
    tris = np.concatenate([_ground(8.0), sph])
    ids = np.r_[np.zeros(2, np.int32), np.ones(len(sph), np.int32)]
    objs = [ObjectInfo("Ground", 0), ObjectInfo("Sphere", 1)]
    light = Light("AreaLight", "area", _frame((-2.5, -1.5, 4.5), (0.0, 0.0, 0.5)), blender_type="AREA",
                  shape="SQUARE", size=1.0, size_y=1.0)
    cam = Camera(_frame((5.0, -6.0, 4.0), (-0.8, 0.6, 0.4)), lens=35.0, clip_start=0.05, clip_end=100.0)
    sc = Scene(tris, ids, objs, cam, [light], tuple(resolution))
    sc.name = f"sphere_{len(tris) // 1000}K"
    return sc


def bulge_split(tris: np.ndarray, levels: int, height: float) -> np.ndarray:
    """Every triangle split ``levels`` times into 4 (midpoints), new vertices
    moved along its normal by ``height * edge * 27 b0 b1 b2`` (zero on the
    edges: neighbours keep sharing their edges exactly)."""
    n = 2 ** levels
    # barycentric lattice of the split: vertices (i, j) with i + j <= n
    ij = [(i, j) for i in range(n + 1) for j in range(n + 1 - i)]
    index = {p: k for k, p in enumerate(ij)}
    B = np.array([[1 - (i + j) / n, i / n, j / n] for i, j in ij])           # [K, 3]
    faces = []
    for i in range(n):
        for j in range(n - i):
            faces.append([index[(i, j)], index[(i + 1, j)], index[(i, j + 1)]])
            if i + j < n - 1:
                faces.append([index[(i + 1, j)], index[(i + 1, j + 1)], index[(i, j + 1)]])
    faces = np.array(faces)
    t = np.asarray(tris, np.float64)
    nrm = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    ln = np.linalg.norm(nrm, axis=1, keepdims=True)
    nrm = np.divide(nrm, ln, out=np.zeros_like(nrm), where=ln > 0)
    edge = np.linalg.norm(t[:, 1] - t[:, 0], axis=1)
    P = np.einsum("kc,tcd->tkd", B, t)                                        # [T, K, 3]
    bump = 27.0 * B[:, 0] * B[:, 1] * B[:, 2]                                 # [K]
    P += (height * edge)[:, None, None] * bump[None, :, None] * nrm[:, None, :]
    return P[:, faces].reshape(-1, 3, 3).astype(np.float32)


def dense_foliage_scene(base: Scene, levels: int) -> Scene:
    """The captured foliage ``base`` with every leaf triangle split and bulged
    (``bulge_split``, height 0.15 of an edge): curved leaves at 4^levels x
    the triangle count. Stems and ground are kept."""
    names = [o.name for o in base.objects]
    leaf_id = names.index("Leaves")
    is_leaf = base.tri_object == leaf_id
    leaves = bulge_split(base.triangles[is_leaf], levels, 0.15)
    tris = np.concatenate([base.triangles[~is_leaf], leaves])
    ids = np.r_[base.tri_object[~is_leaf], np.full(len(leaves), leaf_id, np.int32)]
    sc = Scene(tris, ids, base.objects, base.camera, base.lights, base.resolution)
    sc.name = f"foliage_{len(tris) // 1000}K"
    return sc


# --------------------------------------------------------------------------
# the tables
#: counters of penumbra_casting's stats shown as "where the time goes"
WHERE = ("blockers", "interior_blockers", "triangles_backface_culled", "blockers_per_leaf", "blockers_per_receiver",
         "hidden_pairs", "hidden_nodes", "group_volume_tests", "hard_volume_tests", "sample_tests_per_relation")
COLUMNS = ["scene", "triangles", "size", "samples", "embree_s", "penumbra_casting_s", "speedup", "rmse_pc_vs_embree",
           "phases"] + list(WHERE)
SPHERE_TRIANGLES = (10_000, 100_000)   # then the 1M sample scene dense_sphere
FOLIAGE_LEVELS = (0, 1, 2)             # 12.8K, 43K, 164K triangles; then dense_foliage (577K)
#: dense_foliage's samples at 1080p (at the other rows' 256 its casting would outlast the whole table)
DENSE_FOLIAGE_SAMPLES = 64


def _pair(name, scene, res, samples, repeats, rows):
    """embree and penumbra_casting on ``scene`` in the same run: one row."""
    from ..core.buffers import FrameBuffers
    from ..core.methods import producers
    from ..core.warmup import ensure_compiled
    from .harness import median_run
    reg = producers()
    fb = FrameBuffers(scene, *res)
    fb.gbuffer
    light = [lt for lt in scene.lights if lt.casts_shadow][0]
    out = {}
    for mid in ("embree", "penumbra_casting"):
        m = reg[mid]
        p = m.make_params({"samples": samples})
        ensure_compiled(m, light, p)
        out[mid] = median_run(lambda: m.run(fb, light, p), repeats)
    (te, re), (tp, rp) = out["embree"], out["penumbra_casting"]
    a = np.asarray(re.passes["embree"], np.float64)
    b = np.asarray(rp.passes["penumbra_casting"], np.float64)
    row = dict(scene=name, triangles=int(len(scene.triangles)), size=f"{res[0]}x{res[1]}", samples=samples,
               embree_s=te, penumbra_casting_s=tp, speedup=te / tp, rmse_pc_vs_embree=float(np.sqrt(np.mean((a - b) ** 2))),
               phases=", ".join(f"{k} {v:.2f}" for k, v in rp.time_s.items() if k != "total"))
    row.update({k: rp.stats.get(k, "") for k in WHERE})
    rows.append(row)
    print(row, flush=True)
    return row


def bench_scaling(repeats: int, quick: bool):
    """The scaling tables: cost against triangle count (smooth sphere 10K,
    100K and the 1M sample ``dense_sphere`` at 1080p, 64 samples; foliage
    split to 164K at 1080p, 256 samples, and the 577K sample
    ``dense_foliage``, ``DENSE_FOLIAGE_SAMPLES``) and the foliage sample at
    512x512 and 1920x1080 (256 samples), embree and penumbra_casting measured
    side by side, with where the casting's time goes (blockers per leaf node
    and per receiver, V_Gk tests, sample tests)."""
    from .harness import load_sample
    hd = (480, 270) if quick else (1920, 1080)
    rows = []
    for n in (SPHERE_TRIANGLES[:1] if quick else SPHERE_TRIANGLES):
        _pair("smooth sphere", smooth_sphere_scene(n, hd), hd, 64, repeats, rows)
    if not quick:
        _pair("dense_sphere", load_sample("dense_sphere", hd), hd, 64, repeats, rows)
    sq = (128, 128) if quick else (512, 512)
    _pair("foliage", load_sample("foliage", sq), sq, 256, repeats, rows)
    base = load_sample("foliage", hd)
    for lv in (FOLIAGE_LEVELS[:2] if quick else FOLIAGE_LEVELS):
        _pair("foliage" if lv == 0 else f"foliage split {lv}x", dense_foliage_scene(base, lv) if lv else base, hd,
              256, repeats, rows)
    dense = (96, 54) if quick else hd
    _pair("dense_foliage", load_sample("dense_foliage", dense), dense, DENSE_FOLIAGE_SAMPLES, repeats, rows)
    return rows
