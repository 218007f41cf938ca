"""Scenes built in code (no bpy) for the core tests."""
from __future__ import annotations

import math

import numpy as np

from penumbra.core.scene import Camera, Light, ObjectInfo, Scene
from penumbra.core.views import look_rotation


def quad(x0, x1, y0, y1, z):
    a, b, c, d = [x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z]
    return [[a, b, c], [a, c, d]]


def light_matrix(pos, forward=(0, 0, -1.0)):
    m = np.eye(4)
    m[:3, :3] = look_rotation(np.asarray(forward, float), np.array([0, 1.0, 0]))
    m[:3, 3] = pos
    return m


def top_ortho_camera(half=2.0, height=1.0, center=(0.0, 0.0)):
    """Orthographic camera looking straight down at z=0, +Y up in the image."""
    m = light_matrix((center[0], center[1], height))
    return Camera(m, kind="ORTHO", ortho_scale=2 * half, clip_start=1e-3, clip_end=100.0)


def half_plane_scene(light: Light, res=64, occluder_z=2.0, edge_y=0.0, half=2.0, ground=10.0):
    """Ground z=0, an opaque plane at ``occluder_z`` covering y < edge_y, and an
    orthographic camera between them looking down at the ground."""
    tris = quad(-ground, ground, -ground, ground, 0.0) + quad(-ground, ground, -ground, edge_y, occluder_z)
    ids = [0, 0, 1, 1]
    objs = [ObjectInfo("ground", 0, casts_shadow=True), ObjectInfo("occluder", 1, visible_camera=False)]
    cam = top_ortho_camera(half, height=min(1.0, occluder_z * 0.5))
    return Scene(np.array(tris, np.float32), np.array(ids), objs, cam, [light], (res, res))


def area_light(size=1.0, size_y=None, shape="SQUARE", z=4.0, name="Area"):
    return Light(name, "area", light_matrix((0, 0, z)), blender_type="AREA", shape=shape,
                 size=size, size_y=size if size_y is None else size_y)


def sphere_light(radius=0.5, z=4.0, name="Point", spot_size=np.pi):
    return Light(name, "sphere", light_matrix((0, 0, z)), blender_type="SPOT" if spot_size < np.pi else "POINT",
                 radius=radius, spot_size=spot_size)


def sun_light(angle=0.1, name="Sun"):
    return Light(name, "sun", light_matrix((0, 0, 10.0)), blender_type="SUN", angle=angle)


def pixel_world_y(scene: Scene, row):
    """World y of a pixel row's centre for ``top_ortho_camera``."""
    W, H = scene.resolution
    half = scene.camera.ortho_scale / 2
    return half - (row + 0.5) / H * 2 * half


# --------------------------------------------------------------------------
# stress-suite builders: DESIGN.md's "Numerical robustness" hard cases
def box(x0, x1, y0, y1, z0, z1):
    """A closed axis-aligned box: 12 triangles."""
    t = quad(x0, x1, y0, y1, z0) + quad(x0, x1, y0, y1, z1)
    v = [[x0, y0], [x1, y0], [x1, y1], [x0, y1]]
    for k in range(4):
        (ax, ay), (bx, by) = v[k], v[(k + 1) % 4]
        A, B, C, D = [ax, ay, z0], [bx, by, z0], [bx, by, z1], [ax, ay, z1]
        t += [[A, B, C], [A, C, D]]
    return t


def grid_quad(x0, x1, y0, y1, z, nx, ny):
    """The rectangle [x0,x1] x [y0,y1] at height z tessellated into nx x ny cells
    (2 nx ny triangles): a surface made of many small triangles."""
    xs = np.linspace(x0, x1, nx + 1)
    ys = np.linspace(y0, y1, ny + 1)
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    a = np.stack([X[:-1, :-1], Y[:-1, :-1]], -1).reshape(-1, 2)
    b = np.stack([X[1:, :-1], Y[1:, :-1]], -1).reshape(-1, 2)
    c = np.stack([X[1:, 1:], Y[1:, 1:]], -1).reshape(-1, 2)
    d = np.stack([X[:-1, 1:], Y[:-1, 1:]], -1).reshape(-1, 2)
    zz = np.full((len(a), 1), float(z))
    a, b, c, d = (np.concatenate([p, zz], 1) for p in (a, b, c, d))
    return np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)]).tolist()


def persp_camera(eye, target, lens=35.0, clip_start=1e-3, clip_end=100.0):
    """A perspective camera at ``eye`` looking at ``target``."""
    eye = np.asarray(eye, float)
    m = light_matrix(eye, np.asarray(target, float) - eye)
    return Camera(m, kind="PERSP", lens=lens, clip_start=clip_start, clip_end=clip_end)


def make_scene(tris, ids, lights, res=48, camera=None, names=("ground", "occluder"), camera_sees=None):
    """A Scene from triangle lists; object k is ``names[k]``. ``camera_sees``
    (bool per object, default all) sets ``visible_camera``."""
    sees = camera_sees or [True] * len(names)
    objs = [ObjectInfo(n, i, visible_camera=sees[i]) for i, n in enumerate(names)]
    tris = np.asarray(tris, np.float32).reshape(-1, 3, 3)
    return Scene(tris, np.asarray(ids, np.int32), objs, camera or top_ortho_camera(2.0),
                 list(lights), (res, res))


def sun_pillars_scene(res=64, width=0.06, height=1.2, spacing=0.6, count=3, elevation_deg=20.0,
                      angle_deg=4.0, ground=20.0):
    """The sun_pillars sample scene in small: ``count`` thin square pillars (``width``
    wide, ``height`` tall, ``spacing`` apart along y at x = 0) on a wide ground,
    a sun of ``angle_deg`` from -X at ``elevation_deg`` (shadows
    height / tan(elevation) long towards +X), a perspective camera seeing the
    ground far beyond the shadows (so the receivers span many metres)."""
    ys = (np.arange(count) - 0.5 * (count - 1)) * spacing
    h = 0.5 * width
    tris = quad(-ground, ground, -ground, ground, 0.0)
    for y in ys:
        tris += box(-h, h, y - h, y + h, 0.0, height)
    ids = [0, 0] + [1] * (len(tris) - 2)
    el = math.radians(elevation_deg)
    fwd = (math.cos(el), 0.0, -math.sin(el))
    sun = Light("Sun", "sun", light_matrix((-10.0, 0.0, 10.0 * math.tan(el)), fwd), blender_type="SUN",
                angle=math.radians(angle_deg))
    cam = persp_camera((3.0, -2.5, 2.5), (2.5, 0.0, 0.0), lens=24.0)
    return make_scene(tris, ids, [sun], res, cam, names=("ground", "pillars"))


def scaled_scene(scene: Scene, s: float) -> Scene:
    """The whole scene (geometry, camera, lights, clip range) scaled by ``s``
    about the origin: every V is unchanged."""
    cam = scene.camera
    cm = np.array(cam.world_from_camera, float)
    cm[:3, 3] *= s
    cam2 = Camera(cm, kind=cam.kind, lens=cam.lens, ortho_scale=cam.ortho_scale * s,
                  clip_start=cam.clip_start * s, clip_end=cam.clip_end * s)
    lights = []
    for lt in scene.lights:
        lm = np.array(lt.world_from_light, float)
        lm[:3, 3] *= s
        lights.append(Light(lt.name, lt.kind, lm, blender_type=lt.blender_type, shape=lt.shape,
                            size=lt.size * s, size_y=lt.size_y * s, radius=lt.radius * s,
                            spot_size=lt.spot_size, angle=lt.angle))
    return Scene((scene.triangles.astype(np.float64) * s).astype(np.float32), scene.tri_object,
                 scene.objects, cam2, lights, scene.resolution, name=scene.name)


def stress_cases(res=48):
    """DESIGN.md's hard cases as (name, Scene); every scene has one light."""
    g = quad(-10, 10, -10, 10, 0.0)
    cases = {}
    # light 2 degrees above the horizon, a box on the ground: long grazing shadows
    cases["grazing_area"] = make_scene(
        g + box(-0.5, 0.5, -0.5, 0.5, 0.0, 0.5), [0, 0] + [1] * 12,
        [Light("A", "area", light_matrix((10, 0, 0.35), (-1, 0, -0.035)), shape="SQUARE", size=1.0)], res)
    cases["grazing_sun"] = make_scene(
        g + box(-0.5, 0.5, -0.5, 0.5, 0.0, 0.5), [0, 0] + [1] * 12,
        [Light("S", "sun", light_matrix((0, 0, 5), (-1, 0, -0.035)), angle=0.05)], res)
    # a box standing on the ground: receiver touches its occluder
    cases["contact"] = make_scene(g + box(-0.5, 0.5, -0.5, 0.5, 0.0, 1.0), [0, 0] + [1] * 12,
                                  [area_light(1.0)], res)
    # an occluder lying in the receiver's plane (shadows nothing), plus a real one above
    cases["coplanar"] = make_scene(g + quad(-1, 1, -1, 1, 0.0) + quad(-10, 10, -10, 0.0, 2.0),
                                   [0, 0, 1, 1, 2, 2], [area_light(1.0)], res,
                                   names=("ground", "coplanar", "occluder"), camera_sees=[True, True, False])
    # an occluder above a sphere light: behind it, shadows nothing
    cases["behind_light"] = make_scene(g + quad(-3, 3, -3, 3, 6.0), [0, 0, 1, 1], [sphere_light(0.3)], res)
    # a closed box around the light: everything the camera sees is in shadow
    cases["light_in_box"] = make_scene(g + box(-1, 1, -1, 1, 3.0, 5.0), [0, 0] + [1] * 12,
                                       [area_light(1.0)], res)
    # the camera inside a closed box lit from outside: every visible point in shadow
    cases["camera_inside"] = make_scene(g + box(-1, 1, -1, 1, 0.0, 1.0), [0, 0] + [1] * 12,
                                        [area_light(1.0)], res,
                                        camera=persp_camera((0.3, -0.2, 0.5), (0, 0.2, 0.0), lens=16.0))
    cases["scale_1e-3"] = scaled_scene(half_plane_scene(area_light(1.0), res=res), 1e-3)
    cases["scale_1e4"] = scaled_scene(half_plane_scene(area_light(1.0), res=res), 1e4)
    # near clip 1e-3, far clip 1e3; geometry from 1e-2 to 1e3 away in the light's view too
    cases["near_far_1e6"] = make_scene(
        quad(-1e3, 1e3, -1e3, 1e3, 0.0) + quad(-1.0, 1.0, -1.0, 0.0, 0.5), [0, 0, 1, 1],
        [sphere_light(0.1, z=1.0)], res,
        camera=persp_camera((0.0, -1.5, 1.2), (0.0, 0.0, 0.0), clip_start=1e-3, clip_end=1e3))
    # degenerate (zero-area, collinear) triangles and an occluder made of
    # sub-pixel triangles (cells of 1/16 unit; a pixel is 1/12 unit)
    degenerate = [[[0, 0, 1], [0, 0, 1], [0, 0, 1]], [[0, 0, 1], [1, 1, 1], [2, 2, 1]],
                  [[-1, -1, 1.5], [-1, -1, 1.5], [1, 1, 1.5]], [[0, 0, 2], [0, 0, 2], [0, 0, 2]]]
    fine = grid_quad(-3.0, 3.0, -3.0, 0.0, 2.0, 96, 48)
    rest = quad(-10, 10, -10, -3.0, 2.0) + quad(-10, -3.0, -3.0, 0.0, 2.0) + quad(3.0, 10, -3.0, 0.0, 2.0)
    cases["degenerate_subpixel"] = make_scene(
        g + degenerate + fine + rest, [0, 0] + [1] * (len(degenerate) + len(fine) + len(rest)),
        [area_light(1.0)], res, camera_sees=[True, False])
    # sub-pixel triangles scattered as dust between light and ground
    rng = np.random.default_rng(7)
    c = rng.uniform([-2, -2, 1.0], [2, 2, 3.0], (400, 1, 3))
    dust = (c + rng.normal(0, 0.01, (400, 3, 3))).tolist()
    cases["subpixel_dust"] = make_scene(g + dust, [0, 0] + [1] * 400, [area_light(1.0)], res,
                                        camera_sees=[True, False])
    # the light's view holds no receiver: a spot cone aimed away from all the camera sees
    spot = Light("Spot", "sphere", light_matrix((0, 0, 4.0), (0, 1.0, 0.0)), blender_type="SPOT",
                 radius=0.2, spot_size=0.5)
    cases["empty_light_view"] = half_plane_scene(spot, res=res)
    cases["camera_sees_nothing"] = make_scene(g + quad(-10, 10, -10, 0, 2.0), [0, 0, 1, 1], [area_light(1.0)],
                                              res, camera=persp_camera((0, 0, 1.0), (0, 0, 5.0)))
    cases["huge_area_light"] = half_plane_scene(area_light(50.0), res=res)
    cases["huge_sphere_light"] = half_plane_scene(sphere_light(3.5), res=res)
    cases["huge_sun"] = half_plane_scene(sun_light(2.5), res=res)
    # every light type and area shape on the half-plane scene
    cases["square"] = half_plane_scene(area_light(1.0), res=res)
    cases["rectangle"] = half_plane_scene(area_light(1.5, 0.5, "RECTANGLE"), res=res)
    cases["disk"] = half_plane_scene(area_light(1.2, shape="DISK"), res=res)
    cases["ellipse"] = half_plane_scene(area_light(1.5, 0.6, "ELLIPSE"), res=res)
    cases["point_radius"] = half_plane_scene(sphere_light(0.5), res=res)
    cases["spot_radius"] = half_plane_scene(sphere_light(0.4, spot_size=2.0), res=res)
    cases["sun"] = half_plane_scene(sun_light(0.3), res=res)
    # a line light: a rectangle with one side 0 (not a light of size zero)
    cases["line_light"] = half_plane_scene(area_light(0.0, 1.2, "RECTANGLE"), res=res)
    return cases


def zero_size_cases(res=48):
    """Lights of size zero (hard shadows) of every type, on the half-plane scene
    and on a box standing on the ground."""
    lights = {"area": area_light(0.0), "point": sphere_light(0.0), "spot": sphere_light(0.0, spot_size=2.0),
              "sun": Light("Sun", "sun", light_matrix((0, 0, 10.0), (0.3, 0.2, -1.0)), blender_type="SUN",
                           angle=0.0)}
    out = {}
    for k, lt in lights.items():
        out[f"half_plane_{k}"] = half_plane_scene(lt, res=res)
    out["box_point"] = make_scene(quad(-10, 10, -10, 10, 0.0) + box(-0.6, 0.4, -0.5, 0.5, 0.0, 0.8),
                                  [0, 0] + [1] * 12, [sphere_light(0.0, z=2.5)], res)
    return out


# --------------------------------------------------------------------------
# alpha-matte occluders
def planar_uv(tris, lo, hi):
    """float32[T,3,2]: UVs mapping the xy square [lo, hi]^2 onto [0, 1]^2."""
    xy = np.asarray(tris, np.float64)[..., :2]
    return ((xy - lo) / (hi - lo)).astype(np.float32)


def matte_layers_scene(light, layers, res=48, camera=None, camera_sees=False, ground=10.0):
    """Ground z=0 and one quad over [-ground, ground]^2 per layer (z, texels
    float[h, w] with row 0 at v = 0, interpolation, extension), each with its
    own matte and planar UVs (u along x, v along y over the quad). By default
    the camera (``top_ortho_camera``, at z=1) sees the ground only."""
    from penumbra.core.alpha import AlphaMattes
    tris = quad(-ground, ground, -ground, ground, 0.0)
    ids, matte = [0, 0], [-1, -1]
    texels, offset, width, height, interp, ext = [], [], [], [], [], []
    for k, (z, tex, ip, ex) in enumerate(layers):
        tex = np.asarray(tex, np.float32).reshape(np.shape(tex)[0], -1)
        tris += quad(-ground, ground, -ground, ground, z)
        ids += [k + 1, k + 1]
        matte += [k, k]
        offset.append(sum(len(t) for t in texels))
        texels.append(tex.reshape(-1))
        height.append(tex.shape[0])
        width.append(tex.shape[1])
        interp.append(ip)
        ext.append(ex)
    tris = np.asarray(tris, np.float32)
    uv = planar_uv(tris, -ground, ground)
    uv[np.asarray(matte) < 0] = 0.0
    objs = [ObjectInfo("ground", 0)] + [ObjectInfo(f"card{k}", k + 1, visible_camera=camera_sees)
                                        for k in range(len(layers))]
    mattes = AlphaMattes(matte, uv, np.concatenate(texels) if texels else np.zeros(0), offset, width,
                         height, interp, ext, [f"card{k} / matte" for k in range(len(layers))])
    return Scene(tris, np.asarray(ids, np.int32), objs, camera or top_ortho_camera(2.0),
                 [light], (res, res), alpha=mattes)


def leaf_cloud_scene(n_leaves=150, res=48, seed=17, leaf=(0.2, 0.11), light_size=(1.5, 0.8)):
    """Foliage-like (``sample_blends/foliage.blend`` in small): a
    ground plane and ``n_leaves`` small single-sided quads (2 triangles each),
    randomly oriented, filling a box around (0, 0, 1.2); all leaves are ONE
    object. A rectangular area light of about the cloud's size above, a
    perspective camera seeing the leaves and their shadow on the ground."""
    rng = np.random.default_rng(seed)
    half = np.array([leaf[0] / 2, leaf[1] / 2])
    corners = np.array([[-half[0], -half[1], 0], [half[0], -half[1], 0],
                        [half[0], half[1], 0], [-half[0], half[1], 0]])
    q = rng.standard_normal((n_leaves, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    rot = np.stack([np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
                    np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
                    np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1)], 1)
    centres = rng.uniform([-0.6, -0.4, 0.95], [0.6, 0.4, 1.45], (n_leaves, 3))
    v = np.einsum("nij,vj->nvi", rot, corners) + centres[:, None, :]
    leaves = np.concatenate([v[:, [0, 1, 2]], v[:, [0, 2, 3]]], axis=0)
    tris = np.concatenate([np.asarray(quad(-6, 6, -6, 6, 0.0)), leaves])
    ids = [0, 0] + [1] * len(leaves)
    light = Light("Area", "area", light_matrix((0.6, -0.3, 3.6), (-0.6, 0.3, -2.4)), blender_type="AREA",
                  shape="RECTANGLE", size=light_size[0], size_y=light_size[1])
    cam = persp_camera((1.8, -2.6, 2.0), (-0.3, 0.3, 0.5), lens=30.0)
    return make_scene(tris, ids, [light], res, camera=cam, names=("ground", "leaves"))


def lone_tilted_plane(tilt_deg, light, res=64, size=3.0, view=0.5):
    """A 2 size x 2 size plane through the origin tilted by ``tilt_deg``
    about x, alone under the light, seen from above by an orthographic camera
    over [-view, view]^2 (by default its middle only, edges out of view:
    where an open surface ends, seen from the light, the paper's splat leaves
    its border texels partly covered)."""
    t = math.radians(tilt_deg)
    c, s = math.cos(t), math.sin(t)
    tris = np.array(quad(-size, size, -size, size, 0.0), np.float64)
    y, z = tris[..., 1].copy(), tris[..., 2].copy()
    tris[..., 1], tris[..., 2] = c * y - s * z, s * y + c * z
    cam = top_ortho_camera(half=view, height=3.0)
    return Scene(tris.astype(np.float32), np.zeros(2, np.int32), [ObjectInfo("tilted", 0)], cam, [light],
                 (res, res))
