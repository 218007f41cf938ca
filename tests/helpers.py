"""Helpers shared by the tests that need no bpy: the brute-force reference
on a frame's buffers, error measures and noise bounds, the invariants every
pass keeps, and a cancel token that cancels itself."""
from __future__ import annotations

import math
import os
import sys
from typing import Optional

import numpy as np

from penumbra.core.buffers import FrameBuffers
from penumbra.core.cancel import CancelToken
from penumbra.core.methods import producer_of
from penumbra.core.metrics import errors
from penumbra.core.scene import Light

#: the repository's root (the ``penumbra`` package)
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
#: the installed ``penumbra`` console script, beside this Python
PENUMBRA = os.path.join(os.path.dirname(sys.executable), "penumbra")


def buffers_of(scene, map_size: Optional[int] = None) -> FrameBuffers:
    """The frame's buffers at the scene's own resolution."""
    return FrameBuffers(scene, *scene.resolution, map_size)


def run_method(method_id: str, fb: FrameBuffers, light, **params):
    """``method_id``'s MethodResult on buffers ``fb`` for ``light``, its
    Params taken from ``params`` (unknown names ignored, as the CLI does)."""
    m = producer_of(method_id)
    return m.run(fb, light, m.make_params(params))


def run_declared(method, fb: FrameBuffers, light, **params):
    """``run_method`` on a view of ``fb`` that holds only the buffers the
    method declares (``needs``: touching another raises); ``method`` is an id
    or a Method. Returns (MethodResult, the view's billed phase times)."""
    m = producer_of(method) if isinstance(method, str) else method
    with fb.view(m.needs, m.id) as view:
        res = m.run(view, light, m.make_params(params))
    return res, view.phase_times()


def embree_pass(fb: FrameBuffers, light, samples: int = 256, seed: int = 0, pass_id: str = "embree") -> np.ndarray:
    """The brute-force reference pass (``embree``: average visibility;
    ``embree_irr``: the irradiance ratio) on buffers ``fb``."""
    return run_method("embree", fb, light, samples=samples, seed=seed).passes[pass_id]


def rmse(a, b, mask=None) -> float:
    """Root-mean-square difference over ``mask`` (all pixels by default), as
    the JSON's ``error.rmse``; 0 over an empty mask."""
    return errors(a, b, mask)["rmse"]


def in_range(v) -> bool:
    """A pass as every method must write it: float32, finite, in [0, 1]."""
    v = np.asarray(v)
    return v.dtype == np.float32 and bool(np.isfinite(v).all()) and float(v.min()) >= 0.0 and float(v.max()) <= 1.0


def mc_noise_bound(v, n_a: int, n_b: int) -> float:
    """The expected RMSE between two independent Monte Carlo estimates of
    the same per-pixel ratio V = sum_i w_i v_i / sum_i w_i (v_i = 0 or 1), of
    ``n_a`` and ``n_b`` light samples, over pixels whose V is ``v``:
    sqrt(mean(V (1 - V)) (1/n_a + 1/n_b)). One estimate of N samples has a
    standard deviation of at most about sqrt(V (1 - V) / N) (equal weights;
    numerator and denominator sharing their samples); stratified or Sobol
    samples only lower it."""
    v = np.asarray(v, np.float64)
    return math.sqrt(np.mean(v * (1 - v)) * (1.0 / n_a + 1.0 / n_b))


def fully_facing(g, light: Light) -> np.ndarray:
    """Pixels that see the whole light above their (geometric) tangent
    plane, with a margin of 0.02 in cosine: where a renderer shading with the
    smooth normal (Cycles) and one shading with the geometric normal agree."""
    P, n = g.position, g.normal.astype(np.float64)
    ok = g.hit.copy()
    if light.kind == "sphere":
        d = light.position - P
        dist = np.linalg.norm(d, axis=-1)
        sin_half = np.minimum(light.radius / dist, 1.0)
        return ok & (np.einsum("...i,...i->...", n, d) / dist > sin_half + 0.02)
    m = light.world_from_light
    c, ax, ay = light.position, m[:3, 0], m[:3, 1]
    hx, hy = 0.5 * light.size, 0.5 * light.size_y
    for sx in (-1, 1):
        for sy in (-1, 1):
            q = c + ax * sx * hx + ay * sy * hy
            dq = q - P
            ok &= np.einsum("...i,...i->...", n, dq) / np.linalg.norm(dq, axis=-1) > 0.02
    return ok


class CancelAfter(CancelToken):
    """Cancels itself once it has been checked ``n`` times (``checks``
    counts them): a cancel at a known point, without timing."""

    def __init__(self, n: int = 1):
        super().__init__()
        self.n, self.checks = n, 0

    def check(self):
        self.checks += 1
        if self.checks > self.n:
            self.cancel()
        super().check()


#: A script for ``python -c``: compiles with a listener that sorts each
#: Numba compilation by whether the warm-up (``core/warmup.py``) was running,
#: then renders a matte scene; prints {"inside": [...], "outside": [...]}
#: (kernel names). ``.format(tests=..., methods=[...], pixel_filter=...)``.
COMPILES_OUTSIDE_WARM_UP = r"""
import json, sys
sys.path.insert(0, {tests!r})
from numba.core import event
from penumbra.core import warmup
from penumbra.core.alpha import CLOSEST, REPEAT
from penumbra.core.filtered_frame import render_filtered
from penumbra.core.pixel_filter import parse
from synthetic import area_light, matte_layers_scene

inside, outside = [], []

def in_warm_up():
    # the warm-up holds warmup._lock while it runs (its worker threads see it taken)
    owned = getattr(warmup._lock, "_is_owned", None)      # an RLock: its owner may re-acquire it
    if owned is not None and owned():
        return True
    if warmup._lock.acquire(blocking=False):
        warmup._lock.release()
        return False
    return True

class Compiles(event.Listener):
    def on_start(self, ev):
        (inside if in_warm_up() else outside).append(ev.data["dispatcher"].py_func.__qualname__)
    def on_end(self, ev):
        pass

event.register("numba:compile", Compiles())
sc = matte_layers_scene(area_light(1.0), [(2.0, [[0.0, 1.0], [1.0, 0.0]], CLOSEST, REPEAT)], res=16,
                        camera_sees=True)
render_filtered(sc, {methods!r}, overrides={{"samples": 4}}, pixel_filter=parse({pixel_filter!r}))
print(json.dumps({{"inside": inside, "outside": outside}}))
"""


def polygon_form_factor(p, n, vertices) -> float:
    """The point-to-polygon form factor (Lambert): the irradiance at point
    ``p`` with normal ``n`` from a uniform Lambertian polygon ``vertices``
    (float[k, 3], in order) over pi times its radiance,
    (1 / 2 pi) sum_i beta_i (n . g_i), beta_i the angle edge i subtends at
    ``p`` and g_i the unit normal of the plane through ``p`` and the edge.
    The polygon must lie wholly above the point's tangent plane."""
    p, n = np.asarray(p, np.float64), np.asarray(n, np.float64)
    r = np.asarray(vertices, np.float64) - p
    r /= np.linalg.norm(r, axis=1)[:, None]
    total = 0.0
    for i in range(len(r)):
        a, b = r[i], r[(i + 1) % len(r)]
        c = np.cross(a, b)
        s = np.linalg.norm(c)
        if s > 0:
            total += np.arctan2(s, np.dot(a, b)) * np.dot(n, c / s)
    return abs(total) / (2.0 * np.pi)


def half_plane_irradiance_ratio(y: float, size: float = 1.0, light_z: float = 4.0, occluder_z: float = 2.0,
                                edge_y: float = 0.0) -> float:
    """The irradiance ratio (Agrawala et al. eq. 1 with / without V) at ground
    point (0, y, 0) of ``synthetic.half_plane_scene`` under
    ``synthetic.area_light(size, z=light_z)``: the light's part the point sees
    past the occluder's edge (light points with y_l >= y + (edge_y - y) z_l /
    z_o) is a rectangle; the ratio is its form factor over the whole light's."""
    h = 0.5 * size
    full = [(-h, -h, light_z), (h, -h, light_z), (h, h, light_z), (-h, h, light_z)]
    cut = y + (edge_y - y) * light_z / occluder_z
    lo = min(max(cut, -h), h)
    seen = [(-h, lo, light_z), (h, lo, light_z), (h, h, light_z), (-h, h, light_z)]
    f_all = polygon_form_factor((0, y, 0), (0, 0, 1), full)
    return polygon_form_factor((0, y, 0), (0, 0, 1), seen) / f_all if lo < h else 0.0


def placement(scale, angle_z: float, offset) -> np.ndarray:
    """A 4x4 world-from-object matrix: scale (sx, sy, sz), then a rotation
    by ``angle_z`` about Z, then the translation ``offset``."""
    c, s = np.cos(angle_z), np.sin(angle_z)
    m = np.eye(4)
    m[:3, :3] = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]) @ np.diag(scale)
    m[:3, 3] = offset
    return m


def leaf_cluster(rng, n: int, spread: float, centre, half: float):
    """``n`` square leaves of side 2 ``half`` at random orientations, their
    centres normal around ``centre`` with deviation ``spread``: (vertices
    float64[4n,3], faces int32[2n,3])."""
    c = rng.normal(size=(n, 3)) * spread + np.asarray(centre, float)
    a = rng.normal(size=(n, 3))
    a /= np.linalg.norm(a, axis=1)[:, None]
    b = np.cross(a, rng.normal(size=(n, 3)))
    b /= np.linalg.norm(b, axis=1)[:, None]
    verts = np.concatenate([c - half * a - half * b, c + half * a - half * b, c + half * a + half * b,
                            c - half * a + half * b])
    k = np.arange(n)
    faces = np.concatenate([np.stack([k, k + n, k + 2 * n], 1), np.stack([k, k + 2 * n, k + 3 * n], 1)])
    return verts, faces.astype(np.int32)


def instanced_grove(verts, leaves, ground_half: float, placements, light, camera, res: int, casts: bool = True):
    """A ground square of half side ``ground_half`` and one instance of the
    leaf cluster (``verts``, ``leaves``) per matrix of ``placements`` (one
    object each; ``casts``: they cast shadows), under ``light``, seen by
    ``camera`` at ``res`` x ``res``: (the scene kept as instances, the same
    scene flattened)."""
    from penumbra.core.scene import MeshInstances, ObjectInfo, Scene
    h = float(ground_half)
    ground = np.array([[-h, -h, 0], [h, -h, 0], [h, h, 0], [-h, h, 0]], np.float64)
    n = len(placements)
    objects = [ObjectInfo("ground", 0)] + [ObjectInfo(f"tree{i}", i + 1, casts_shadow=casts) for i in range(n)]
    instances = MeshInstances(vertices=[verts, ground], faces=[leaves, np.array([[0, 1, 2], [0, 2, 3]])],
                              mesh=[1] + [0] * n, object_id=np.arange(n + 1),
                              world_from_mesh=[np.eye(4)] + list(placements))
    lazy = Scene(None, None, objects, camera, [light], (res, res), instances=instances)
    tris, ids = instances.flatten()
    return lazy, Scene(tris, ids, objects, camera, [light], (res, res))
