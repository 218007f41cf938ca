"""Projections and Embree buffers against analytic geometry (no bpy)."""
import numpy as np
import pytest

from penumbra.core import raycast, views
from penumbra.core.kernels import face_project, pick_face
from penumbra.core.scene import Camera, ObjectInfo, Scene
from synthetic import area_light, quad, sphere_light, sun_light


def oblique_camera(**kw):
    """A camera at (1, -5, 2) looking along (0.3, 1, -0.4); ``kw`` as Camera's."""
    m = np.eye(4)
    m[:3, :3] = views.look_rotation(np.array([0.3, 1.0, -0.4]))
    m[:3, 3] = [1.0, -5.0, 2.0]
    return Camera(m, **kw)


@pytest.mark.parametrize("kw", [dict(), dict(kind="ORTHO", ortho_scale=3.0), dict(shift_x=0.2, shift_y=-0.1),
                                dict(sensor_fit="VERTICAL", lens=35.0), dict(pixel_aspect_x=2.0)])
def test_camera_rays_round_trip(kw):
    cam = oblique_camera(**kw)
    W, H = 40, 30
    org, d, tfar, axis = views.camera_rays(cam, W, H)
    pts = org + d * 3.7
    col, row, depth = views.world_to_camera_pixels(cam, W, H, pts)
    cc, rr = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    np.testing.assert_allclose(col, cc, atol=1e-9)
    np.testing.assert_allclose(row, rr, atol=1e-9)
    # depth along the axis: clip_start at the origin, growing with axis_scale
    np.testing.assert_allclose(depth, cam.clip_start + 3.7 * axis, rtol=1e-9)


def test_viewplane_matches_blender_formula():
    """36 mm sensor, 50 mm lens, 1920x1080, AUTO fit: horizontal half-width
    at unit distance is 18/50; shift 0.1 moves it by 0.1 * 36/50."""
    cam = oblique_camera(shift_x=0.1)
    xmin, xmax, ymin, ymax = views.camera_viewplane(cam, 1920, 1080)
    assert xmax - xmin == pytest.approx(36 / 50)
    assert ymax - ymin == pytest.approx(36 / 50 * 1080 / 1920)
    assert (xmin + xmax) / 2 == pytest.approx(0.1 * 36 / 50)


def test_face_projection_round_trip_and_numba_agrees():
    eye = np.array([0.5, -1.0, 3.0])
    rec = np.random.default_rng(0).uniform(-2, 2, (200, 3)) * [1, 1, 0]
    face = views.fit_perspective_face(eye, np.array([0.1, 0.0, -1.0]), rec, 64)
    org, d, scale = views.face_rays(face)
    pts = org + d * 2.5
    u, v, depth = views.project_to_face(face, pts)
    uu, vv = np.meshgrid(np.arange(face.width) + 0.5, np.arange(face.height) + 0.5)
    np.testing.assert_allclose(u, uu, atol=1e-9)
    np.testing.assert_allclose(v, vv, atol=1e-9)
    np.testing.assert_allclose(depth, 2.5 * scale, rtol=1e-12)
    fp = face.packed()
    for p in pts.reshape(-1, 3)[::97]:
        a = face_project(fp, *p)
        b = views.project_to_face(face, p)
        np.testing.assert_allclose(a, [float(x) for x in b], rtol=1e-12, atol=1e-12)
    # every receiver lands inside the fitted window
    u, v, depth = views.project_to_face(face, rec)
    assert (u >= 0).all() and (u < face.width).all() and (v >= 0).all() and (v < face.height).all()


def test_cube_faces_cover_every_receiver_once():
    eye = np.zeros(3)
    rec = np.random.default_rng(1).normal(size=(500, 3))
    faces = views.cube_faces(eye, rec, 16)
    assert len(faces) == 6
    packed = np.stack([f.packed() for f in faces])
    for p in rec:
        assert pick_face(packed, *p) >= 0


def test_point_light_uses_only_faces_that_see_receivers():
    rec = np.random.default_rng(2).uniform(-3, 3, (300, 3))
    rec[:, 2] = 0.0   # a ground plane below the light
    faces = views.light_view_faces(sphere_light(0.1, z=2.0), rec, (rec.min(0), rec.max(0)), 32)
    labels = {f.label for f in faces}
    assert "cube+Z" not in labels and "cube-Z" in labels


def test_depth_map_of_tilted_plane_matches_analytic_depth():
    """Plane z = 0.3 x through the origin seen from a light at (0,0,5) looking
    down: the ray along d hits it at t = 5 / (0.3 d_x - d_z); the map stores
    t times the cosine to the view axis."""
    tris = np.array([[[-10, -10, -3.0], [10, -10, 3.0], [10, 10, 3.0]],
                     [[-10, -10, -3.0], [10, 10, 3.0], [-10, 10, -3.0]]], np.float32)
    ts = raycast.TriangleScene(tris)
    lt = area_light(1.0, z=5.0)
    rec = np.array([[x, y, 0.3 * x] for x in (-3, 3) for y in (-3, 3)])
    faces = views.light_view_faces(lt, rec, (rec.min(0), rec.max(0)), 48)
    assert len(faces) == 1 and not faces[0].ortho
    lv = raycast.render_light_view(faces, ts, np.zeros(2, np.int32), lt.position)
    org, d, scale = views.face_rays(faces[0])
    t = 5.0 / (0.3 * d[..., 0] - d[..., 2])
    np.testing.assert_allclose(lv.depth[0], t * scale, rtol=2e-6)
    assert (lv.object_id[0] == 0).all()


def test_sun_view_is_orthographic_with_casters_in_front():
    tris = np.array(quad(-5, 5, -5, 5, 0.0), np.float32)
    ts = raycast.TriangleScene(tris)
    lt = sun_light(0.05)
    rec = np.array([[x, y, 0.0] for x in (-2, 2) for y in (-2, 2)])
    faces = views.light_view_faces(lt, rec, (tris.reshape(-1, 3).min(0), tris.reshape(-1, 3).max(0)), 32)
    assert len(faces) == 1 and faces[0].ortho
    lv = raycast.render_light_view(faces, ts, np.zeros(2, np.int32), lt.position)
    d = lv.depth[0]
    assert np.isfinite(d).all() and (d > 0).all()
    assert np.ptp(d) < 1e-4          # ground is perpendicular to the sun: constant depth


def test_gbuffer_of_a_plane():
    tris = np.array(quad(-5, 5, -5, 5, 0.0), np.float32)
    m = np.eye(4)
    m[:3, :3] = views.look_rotation(np.array([0, 0, -1.0]), np.array([0, 1.0, 0]))
    m[:3, 3] = [0, 0, 3.0]
    cam = Camera(m, lens=50.0, clip_start=0.1, clip_end=100.0)
    sc = Scene(tris, np.zeros(2, np.int32), [ObjectInfo("p", 0)], cam, [], (32, 24))
    g = raycast.camera_gbuffer(sc, 32, 24)
    assert g.hit.all()
    np.testing.assert_allclose(g.depth, 3.0, rtol=1e-6)
    np.testing.assert_allclose(g.position[..., 2], 0.0, atol=1e-6)
    np.testing.assert_allclose(g.normal.reshape(-1, 3), [[0, 0, 1]] * (32 * 24), atol=1e-6)
    # seen from below, the normal flips to face the camera
    m2 = m.copy()
    m2[:3, :3] = views.look_rotation(np.array([0, 0, 1.0]), np.array([0, 1.0, 0]))
    m2[:3, 3] = [0, 0, -3.0]
    sc.camera = Camera(m2, clip_start=0.1, clip_end=100.0)
    g2 = raycast.camera_gbuffer(sc, 32, 24)
    assert (g2.normal[..., 2] < -0.999).all()


def test_empty_geometry_misses_everything():
    ts = raycast.TriangleScene(np.zeros((0, 3, 3), np.float32))
    tri, t, u, v = ts.intersect(np.zeros((4, 3)), np.tile([0, 0, 1.0], (4, 1)))
    assert (tri == -1).all() and np.isinf(t).all()
    assert not ts.occluded(np.zeros((4, 3)), np.tile([0, 0, 1.0], (4, 1)), np.ones(4)).any()
