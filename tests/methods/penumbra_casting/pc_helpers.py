"""Helpers of the penumbra_casting tests: the casting on a scene's buffers,
Embree's rays to the very receiver points and light samples it used (their
average, or their irradiance ratio with the reference's weights), the
exactness check, and the scenes and lights several tests share."""
import numpy as np

from helpers import buffers_of
from penumbra.core import sampling
from penumbra.core.methods.base import PhaseTimer
from penumbra.core.methods.penumbra_casting import PenumbraCasting, cast, prepare, scene_blockers
from penumbra.core.scene import Camera, ObjectInfo, Scene
from penumbra.core.views import look_rotation
from synthetic import area_light, quad, sphere_light, sun_light

PC = PenumbraCasting()

LIGHTS = {
    "square": lambda: area_light(1.5, z=5.0),
    "rectangle": lambda: area_light(2.0, size_y=0.6, shape="RECTANGLE", z=5.0),
    "disk": lambda: area_light(1.5, shape="DISK", z=5.0),
    "ellipse": lambda: area_light(2.0, size_y=0.8, shape="ELLIPSE", z=5.0),
    "sphere": lambda: sphere_light(0.6, z=5.0),
    "spot": lambda: sphere_light(0.4, z=5.0, spot_size=1.2),
    "sun": lambda: sun_light(0.3),
}


def one_object_scene(tris, light, res, eye=(5.0, -6.0, 6.0)):
    """Triangles ``tris`` as one object, seen by a perspective camera (lens
    35) at ``eye`` looking at the origin, lit by ``light``."""
    m = np.eye(4)
    eye = np.asarray(eye, float)
    m[:3, :3] = look_rotation(-eye)
    m[:3, 3] = eye
    tris = np.asarray(tris, np.float32)
    return Scene(tris, np.zeros(len(tris), np.int32), [ObjectInfo("all", 0)], Camera(m, lens=35.0), [light],
                 (res, res))


def clutter_scene(light, res=48, n=60, seed=1):
    """Ground plane under random triangles, perspective camera (sees some sky)."""
    rng = np.random.default_rng(seed)
    tris = quad(-6, 6, -6, 6, 0.0)
    c = rng.uniform([-2.5, -2.5, 0.3], [2.5, 2.5, 2.5], (n, 3))
    for k in range(n):
        tris.append((c[k] + rng.normal(0, 0.35, (3, 3))).tolist())
    return one_object_scene(tris, light, res)


def run_pc(scene, light=None, **over):
    """(buffers, setup, V per receiver, stats) of the casting on ``scene``'s
    buffers with params ``over``; V is the average (each relation 1/S of it,
    as ``assert_exact`` counts) unless ``over`` sets ``visibility``."""
    fb = buffers_of(scene)
    light = light or scene.lights[0]
    p = PC.make_params({"visibility": "average", **over})
    setup = prepare(fb, light, p)
    V, stats = cast(setup, scene_blockers(scene), p, PhaseTimer())
    return fb, setup, V, stats


def _own_segments(setup):
    """Per relation (receiver-major): origin, unit direction, length and
    whether it is a sun's direction."""
    P = setup.sample_points(np.arange(len(setup.idx)))
    n, S, _ = P.shape
    o = np.repeat(setup.pts, S, axis=0)
    p = P.reshape(-1, 4)
    isdir = p[:, 3] == 0
    d = np.where(isdir[:, None], p[:, :3], p[:, :3] - o)
    dist = np.linalg.norm(d, axis=1)
    d = d / np.where(dist > 0, dist, 1.0)[:, None]
    return o, d, dist, isdir, (n, S)


def own_weights(setup):
    """float64[n, S]: the reference's irradiance weight of every relation
    the casting tests, written out here with NumPy: cos_r cos_l / d^2 from
    the receiver point (normal ``setup.N``), cos_l of an area light's -Z
    emission (clamped at 0), 1 for a sphere's disk; a sun's: cos_r."""
    o, d, dist, isdir, shape = _own_segments(setup)
    lp = setup.light.lp
    N = np.repeat(setup.N, shape[1], axis=0)
    cos_r = np.maximum((d * N).sum(1), 0.0)
    if lp[sampling.L_KIND] == 0.0:
        cos_l = np.maximum(d @ lp[sampling.L_AZ:sampling.L_AZ + 3], 0.0)
    else:
        cos_l = np.ones(len(d))
    w = np.where(isdir, cos_r, cos_r * cos_l / np.maximum(dist * dist, 1e-300))
    return w.reshape(shape)


def own_rays(fb, setup):
    """V from Embree shadow rays from the same receiver points to the same
    light samples the casting used (segments end 1e-6 short, as the
    reference's): their average, or with the setup's normals
    (``visibility="irradiance"``) their ratio with ``own_weights`` (the
    average where no weight is positive)."""
    o, d, dist, isdir, (n, S) = _own_segments(setup)
    tfar = np.where(isdir, 1e30, dist * (1 - 1e-6))
    occ = fb.shadow_scene.occluded(o.astype(np.float32), d.astype(np.float32), tfar.astype(np.float32))
    v = 1.0 - occ.reshape(n, S)
    if not len(setup.N):
        return v.mean(1)
    w = own_weights(setup)
    tot = w.sum(1)
    return np.where(tot > 0, (w * v).sum(1) / np.where(tot > 0, tot, 1.0), v.mean(1))


def relation_share(setup):
    """Per receiver the largest share of V one relation carries: 1/S for
    the average, max w_i / sum w_i for the irradiance ratio."""
    S = setup.light.S
    if not len(setup.N):
        return np.full(len(setup.idx), 1.0 / S)
    w = own_weights(setup)
    tot = w.sum(1)
    return np.where(tot > 0, w.max(1) / np.where(tot > 0, tot, 1.0), 1.0 / S)


def assert_exact(V, ref, S, frac=0.002, share=None):
    """Every blocked relation is a geometric fact: only rays grazing an edge
    within float32 rounding may differ (at most two per receiver, each
    ``share`` of V: 1/S by default)."""
    share = 1.0 / S if share is None else share
    diff = np.abs(V - ref)
    assert (diff > 1e-12).mean() <= frac, ((diff > 1e-12).sum(), len(V))
    assert (diff <= 2.0 * share + 1e-12).all(), diff.max()
