"""Shared pieces of the single_sample tests: the method's run with checked
parameter names, the synthetic scenes several tests use, and measures of a
pass (penumbra width, the band along a hard edge)."""
import copy

import numpy as np

from helpers import buffers_of, run_method
from penumbra.core.methods import producer_of
from penumbra.core.scene import Camera, ObjectInfo, Scene
from penumbra.core.views import look_rotation
from synthetic import pixel_world_y, quad

HL = 4.0   # light height used by the synthetic scenes
PAPER = dict(blocker="nearest", surfaces="object", horizon=False)   # the paper: one ramp from the nearest blocker
FIELDS = frozenset(producer_of("single_sample").Params.__dataclass_fields__)


def run_ss(scene, fb=None, light=None, **params):
    """(V, MethodResult, buffers) of ``single_sample`` on ``scene`` (its
    first light unless ``light``); every name in ``params`` must be a field.
    The average pass (equation 2: the closed forms and the ``embree``
    reference of the tests) unless ``visibility`` is given."""
    assert set(params) <= FIELDS, set(params) - FIELDS
    params.setdefault("visibility", "average")
    fb = fb or buffers_of(scene)
    r = run_method("single_sample", fb, light or scene.lights[0], **params)
    return r.passes["single_sample"], r, fb


def with_light(scene, light):
    """``scene`` (a shallow copy) with ``light`` as its only light."""
    sc = copy.copy(scene)
    sc.lights = [light]
    return sc


def penumbra_width(scene, v):
    """Penumbra width (scene units) along y from the row means: twice the
    distance between their 1/4 and 3/4 crossings (exact for a linear ramp)."""
    rm = v.mean(axis=1).astype(np.float64)          # rows top (lit, y > 0) to bottom
    ys = pixel_world_y(scene, np.arange(v.shape[0]))
    assert rm[0] == 1.0 and rm[-1] == 0.0
    assert np.all(np.diff(rm) <= 1e-6)              # monotone across the edge
    # np.interp wants increasing x: walk from shadow to light
    y25 = np.interp(0.25, rm[::-1], ys[::-1])
    y75 = np.interp(0.75, rm[::-1], ys[::-1])
    return 2.0 * abs(y75 - y25)


def hard_edge_band(img):
    """Pixels within one pixel of a 0/1 transition of ``img``."""
    b = np.zeros(img.shape, bool)
    for ax in (0, 1):
        d = np.diff(img, axis=ax) != 0
        if ax == 0:
            b[1:] |= d
            b[:-1] |= d
        else:
            b[:, 1:] |= d
            b[:, :-1] |= d
    return b


def corner_box(x0, x1, y0, y1, z0, z1):
    """A closed axis-aligned box from its 8 corners: 12 triangles."""
    p = np.array([[x, y, z] for x in (x0, x1) for y in (y0, y1) for z in (z0, z1)], float)
    faces = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    return [[p[a], p[b], p[c]] for a, b, c, d in faces] + [[p[a], p[c], p[d]] for a, b, c, d in faces]


def box_scene(light, res=64):
    """Ground, a box floating above it and one standing on it (contact), and
    a perspective camera: occluders at several depths, contact shadows."""
    tris = quad(-8, 8, -8, 8, 0.0) + corner_box(-1, 0.5, -0.5, 0.8, 1.0, 1.6) + corner_box(1.2, 2.0, -1.5, -0.7, 0.0, 0.9)
    ids = [0, 0] + [1] * 12 + [2] * 12
    objs = [ObjectInfo("ground", 0), ObjectInfo("float", 1), ObjectInfo("stand", 2)]
    cam_m = np.eye(4)
    cam_m[:3, :3] = look_rotation(np.array([-0.2, 1.0, -0.9]))
    cam_m[:3, 3] = [1.5, -7.0, 6.0]
    cam = Camera(cam_m, lens=35.0, clip_start=0.01, clip_end=100.0)
    return Scene(np.array(tris, np.float32), np.array(ids), objs, cam, [light], (res, res))
