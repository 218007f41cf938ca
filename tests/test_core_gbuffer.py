"""The fused primary-ray kernels (core/pixel_rays.py) against plain NumPy
formulas of the same buffers (views.camera_rays / views.face_rays and the
hit post-processing), bit for bit; the G-buffer's invariants; the reach and
whole-light masks (no bpy)."""
import numpy as np
import pytest

from penumbra.core import raycast, views
from penumbra.core.scene import Camera, GBuffer
from synthetic import area_light, box, grid_quad, make_scene, quad, sphere_light, stress_cases, sun_light


def numpy_gbuffer(scene, width, height, tri_scene):
    """The G-buffer from views.camera_rays, one intersect call and NumPy
    post-processing: the formula the fused kernels must match to the bit."""
    cam = scene.camera
    org, d, tfar, _ = views.camera_rays(cam, width, height)
    n = width * height
    tri, t, u, v = tri_scene.intersect(org.reshape(n, 3), d.reshape(n, 3), tfar.reshape(n))
    hit = tri >= 0
    pos = np.zeros((n, 3), np.float64)
    nrm = np.zeros((n, 3), np.float32)
    T = scene.triangles[tri[hit]].astype(np.float64)
    uu, vv = u[hit][:, None], v[hit][:, None]
    pos[hit] = (1.0 - uu - vv) * T[:, 0] + uu * T[:, 1] + vv * T[:, 2]
    ng = np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0])
    ln = np.linalg.norm(ng, axis=1, keepdims=True)
    ng = np.where(ln > 0, ng / np.where(ln > 0, ln, 1.0), 0.0)
    flip = np.einsum("ij,ij->i", ng, d.reshape(n, 3)[hit]) > 0
    ng[flip] *= -1.0
    nrm[hit] = ng.astype(np.float32)
    depth = np.full(n, np.inf, np.float32)
    depth[hit] = ((pos[hit] - cam.position) @ cam.forward).astype(np.float32)
    obj = np.full(n, -1, np.int32)
    obj[hit] = scene.tri_object[tri[hit]]
    return GBuffer(pos.reshape(height, width, 3), nrm.reshape(height, width, 3), depth.reshape(height, width),
                   obj.reshape(height, width), tri.reshape(height, width), hit.reshape(height, width))


def numpy_face(face, tri_scene, tri_object):
    """A light-view face's depth and ids from views.face_rays and one
    intersect call."""
    org, d, scale = views.face_rays(face)
    n = face.width * face.height
    tri, t, _, _ = tri_scene.intersect(org.reshape(n, 3), d.reshape(n, 3))
    hit = tri >= 0
    depth = np.full(n, np.inf, np.float32)
    depth[hit] = (t[hit] * scale.reshape(n)[hit]).astype(np.float32)
    ids = np.full(n, -1, np.int32)
    ids[hit] = tri_object[tri[hit]]
    return depth.reshape(face.height, face.width), ids.reshape(face.height, face.width)


def cluttered_scene(camera, lights=(area_light(),)):
    """A tessellated ground, a tilted quad and boxes (front and back faces
    seen, edges and gaps): every branch of the post-processing."""
    tris = grid_quad(-3, 3, -3, 3, 0.0, 7, 5)
    ids = [0] * len(tris)
    tilt = np.array(quad(-1, 1, -1, 1, 0.0), float)
    tilt[..., 2] = 0.8 + 0.3 * tilt[..., 0] + 0.1 * tilt[..., 1]
    for t in box(0.5, 1.5, -1.2, -0.4, 0.0, 1.1) + box(-1.8, -1.0, 0.6, 1.4, 0.2, 0.9) + tilt.tolist():
        tris.append(t)
        ids.append(1)
    return make_scene(tris, ids, list(lights), camera=camera)


def look_camera(eye, target, **kw):
    m = np.eye(4)
    eye = np.asarray(eye, float)
    m[:3, :3] = views.look_rotation(np.asarray(target, float) - eye)
    m[:3, 3] = eye
    return Camera(m, **kw)


CAMERAS = {
    "persp": dict(),
    "persp_wide": dict(lens=18.0),
    "ortho": dict(kind="ORTHO", ortho_scale=5.0),
    "ortho_shift": dict(kind="ORTHO", ortho_scale=4.0, shift_x=0.15, shift_y=-0.2),
    "shift": dict(shift_x=0.2, shift_y=-0.1),
    "fit_vertical": dict(sensor_fit="VERTICAL", lens=35.0),
    "fit_horizontal": dict(sensor_fit="HORIZONTAL", lens=28.0),
    "pixel_aspect": dict(pixel_aspect_x=2.0),
    "clipped": dict(clip_start=3.0, clip_end=6.5),
}


@pytest.mark.parametrize("name", sorted(CAMERAS))
@pytest.mark.parametrize("size", [(61, 37), (24, 40)])
def test_gbuffer_equals_the_numpy_formula(name, size):
    cam = look_camera([2.5, -4.0, 3.0], [0.0, 0.0, 0.3], **CAMERAS[name])
    scene = cluttered_scene(cam)
    W, H = size
    ts = raycast.TriangleScene.from_scene(scene, scene.tri_visible_camera)
    want = numpy_gbuffer(scene, W, H, ts)
    for threads in (1, 2):
        got = raycast.camera_gbuffer(scene, W, H, ts, threads=threads)
        assert got.hit.any() and not got.hit.all()
        for k in ("position", "normal", "depth", "object_id", "triangle_id", "hit"):
            a, b = getattr(got, k), getattr(want, k)
            assert a.dtype == b.dtype and a.shape == b.shape, k
            assert np.array_equal(a, b), k


def test_gbuffer_bands_cover_every_row(monkeypatch):
    """Bands of a few rows (one ragged at the end) give the same buffer."""
    cam = look_camera([2.5, -4.0, 3.0], [0.0, 0.0, 0.3])
    scene = cluttered_scene(cam)
    ts = raycast.TriangleScene.from_scene(scene, scene.tri_visible_camera)
    whole = raycast.camera_gbuffer(scene, 50, 33, ts, threads=1)
    monkeypatch.setattr(raycast, "BAND_RAYS", 50 * 4)
    banded = raycast.camera_gbuffer(scene, 50, 33, ts, threads=2)
    for k in ("position", "normal", "depth", "object_id", "triangle_id", "hit"):
        assert np.array_equal(getattr(whole, k), getattr(banded, k)), k


@pytest.mark.parametrize("name", ["persp", "ortho", "shift", "clipped"])
def test_gbuffer_invariants(name):
    """Position on the hit triangle's plane, unit normal facing the camera,
    depth = distance along the view axis, ids of the hit triangle."""
    cam = look_camera([2.5, -4.0, 3.0], [0.0, 0.0, 0.3], **CAMERAS[name])
    scene = cluttered_scene(cam)
    g = raycast.camera_gbuffer(scene, 64, 48)
    assert g.hit.sum() > 100
    tri = g.triangle_id[g.hit]
    P = g.position[g.hit]
    T = scene.triangles[tri].astype(np.float64)
    ng = np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0])
    ng /= np.linalg.norm(ng, axis=1, keepdims=True)
    assert np.abs(np.einsum("ij,ij->i", P - T[:, 0], ng)).max() < 1e-5
    N = g.normal[g.hit].astype(np.float64)
    np.testing.assert_allclose(np.linalg.norm(N, axis=1), 1.0, atol=1e-6)
    np.testing.assert_allclose(np.abs(np.einsum("ij,ij->i", N, ng)), 1.0, atol=1e-6)
    if cam.kind == "ORTHO":
        view = np.broadcast_to(cam.forward, P.shape)
    else:
        view = P - cam.position
    assert (np.einsum("ij,ij->i", N, view) <= 0).all()
    np.testing.assert_allclose(g.depth[g.hit], (P - cam.position) @ cam.forward, rtol=1e-6, atol=1e-6)
    assert (g.depth[g.hit] >= cam.clip_start * (1 - 1e-6)).all()
    assert (g.depth[g.hit] <= cam.clip_end * (1 + 1e-6)).all()
    assert np.array_equal(g.object_id[g.hit], scene.tri_object[tri])
    assert (g.triangle_id[~g.hit] == -1).all() and (g.object_id[~g.hit] == -1).all()
    assert np.isinf(g.depth[~g.hit]).all() and (g.position[~g.hit] == 0).all() and (g.normal[~g.hit] == 0).all()
    # the camera-invisible objects are not in the G-buffer
    hidden = make_scene(scene.triangles, scene.tri_object, scene.lights, camera=cam, camera_sees=[True, False])
    g2 = raycast.camera_gbuffer(hidden, 64, 48)
    assert (g2.object_id[g2.hit] == 0).all()


@pytest.mark.parametrize("light", [area_light(z=4.0), sphere_light(0.3, z=2.5), sun_light(0.1)],
                         ids=["area", "point_cube", "sun_ortho"])
def test_light_view_equals_the_numpy_formula(light):
    cam = look_camera([2.5, -4.0, 3.0], [0.0, 0.0, 0.3])
    scene = cluttered_scene(cam, [light])
    g = raycast.camera_gbuffer(scene, 48, 36)
    faces = views.light_view_faces(light, g.position[g.hit], scene.bounds(), 53)
    assert faces
    ts = raycast.TriangleScene.from_scene(scene, scene.tri_casts_shadow)
    lv = raycast.render_light_view(faces, ts, scene.tri_object, light.position)
    for k, f in enumerate(faces):
        depth, ids = numpy_face(f, ts, scene.tri_object)
        assert np.array_equal(lv.depth[k], depth) and np.array_equal(lv.object_id[k], ids)
    assert np.isfinite(lv.depth).any()


def test_empty_bvh_gives_an_empty_gbuffer():
    cam = look_camera([2.5, -4.0, 3.0], [0.0, 0.0, 0.3])
    scene = cluttered_scene(cam)
    g = raycast.camera_gbuffer(scene, 20, 10, raycast.TriangleScene(np.zeros((0, 3, 3), np.float32)))
    assert not g.hit.any() and np.isinf(g.depth).all() and (g.object_id == -1).all()
    assert g.position.dtype == np.float64 and (g.position == 0).all()


def numpy_reach_mask(g, light):
    """``metrics.reach_mask`` as a NumPy formula."""
    import math
    P, n, ok, c = g.position, g.normal.astype(np.float64), g.hit.copy(), light.position
    if light.kind == "sun":
        return ok & ((n @ -light.direction) > -math.sin(light.sun_half_angle))
    d = c - P
    dist = np.linalg.norm(d, axis=-1)
    dist = np.where(dist > 0, dist, 1e-300)
    if light.kind == "sphere":
        ok &= np.einsum("...i,...i->...", n, d) / dist > -np.minimum(light.radius / dist, 1.0)
        if light.is_spot:
            ok &= -(np.einsum("...i,...i->...", d, light.direction)) / dist >= light.spot_cos
        return ok
    m = light.world_from_light
    ax, ay, az = m[:3, 0], m[:3, 1], m[:3, 2]
    ok &= ((P - c) @ (-az)) > 0
    hx, hy = light.half_size
    if light.is_round:
        pts = [c + ax * hx * math.cos(a) + ay * hy * math.sin(a)
               for a in np.linspace(0, 2 * np.pi, 16, endpoint=False)]
    else:
        pts = [c + ax * sx * hx + ay * sy * hy for sx in (-1, 1) for sy in (-1, 1)]
    above = np.zeros(ok.shape, bool)
    for q in pts + [c]:
        above |= np.einsum("...i,...i->...", n, q - P) > 0
    return ok & above


@pytest.mark.parametrize("case", sorted(stress_cases()))
def test_reach_mask_kernel_equals_the_numpy_formula(case):
    """The reach mask (which pixels a light can illuminate at all) of the
    Numba kernel is the NumPy formula's, pixel for pixel, for every light
    kind and area shape of the stress suite, and it is a subset of the hits."""
    from penumbra.core.metrics import reach_mask
    scene = stress_cases(res=40)[case]
    W, H = scene.resolution
    g = raycast.camera_gbuffer(scene, W, H)
    for light in scene.lights:
        m = reach_mask(g, light)
        assert m.dtype == np.bool_ and m.shape == (H, W) and not (m & ~g.hit).any()
        np.testing.assert_array_equal(m, numpy_reach_mask(g, light))


@pytest.mark.parametrize("make, whole", [(lambda: area_light(8.0, z=4.0), False),
                                         (lambda: area_light(1.0, z=4.0), True),
                                         (lambda: area_light(8.0, shape="DISK", z=4.0), False),
                                         (lambda: sphere_light(3.5, z=4.0), False),
                                         (lambda: sphere_light(0.3, z=4.0), True),
                                         (lambda: sun_light(1.2), False), (lambda: sun_light(0.2), True)])
def test_whole_light_mask_on_a_tilted_plane(make, whole):
    """``metrics.whole_light_mask``: on a lone plane
    tilted 60 degrees, a light whose part lies below every point's tangent
    plane (an 8-unit area light 4 above it, a 3.5 sphere, a 69-degree sun)
    leaves no pixel in the mask; a small one above keeps every pixel; the
    mask lies inside ``reach_mask`` and where it holds the closed-form share
    of the light above the plane (``horizon.horizon_share``) is 1."""
    from penumbra.core.metrics import reach_mask, whole_light_mask
    from penumbra.core.methods.horizon import horizon_share
    from synthetic import lone_tilted_plane
    light = make()
    scene = lone_tilted_plane(60.0, light, res=16)
    g = raycast.camera_gbuffer(scene, 16, 16)
    m = whole_light_mask(g, light)
    assert g.hit.all() and m.dtype == np.bool_ and m.shape == (16, 16)
    assert m.all() if whole else not m.any()
    assert not (m & ~reach_mask(g, light)).any()
    share = horizon_share(light, g.position.reshape(-1, 3), g.normal.reshape(-1, 3)).reshape(16, 16)
    assert (share[m] == 1.0).all() and (share[~m] < 1.0).all()
