"""Depth of field as Cycles' thin lens (``core/camera_samples.py``,
``pixel_rays.lens_ray_batch``, the filtered frame): lens rays against the
thin-lens geometry, the lens samples' distribution, and a defocused shadow
edge on a plane against its closed form."""
from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from penumbra.core import camera_effects, camera_samples, raycast, views
from penumbra.core.camera_samples import aperture_point, lens_points
from penumbra.core.filtered_frame import render_filtered
from penumbra.core.frame import render_frame
from penumbra.core.pixel_filter import PixelFilter
from synthetic import half_plane_scene, matte_layers_scene, persp_camera, sun_light, top_ortho_camera

LENS_MM = 35.0


def _defocused(scene, fstop=0.5, focus=0.5, blades=0, ortho=False):
    """``scene`` seen from (0, 0, 1) looking down through a thin lens."""
    if ortho:
        cam = top_ortho_camera(2.0, height=1.0)
        radius = 1.0 / (2.0 * fstop)
    else:
        cam = persp_camera((0, 0, 1.0), (0, 0, 0), lens=LENS_MM)
        radius = LENS_MM * 1e-3 / (2.0 * fstop)
    scene.camera = dataclasses.replace(cam, aperture_radius=radius, focus_distance=focus, aperture_blades=blades)
    return scene


def _edge_closed_form(scene, flt: PixelFilter) -> np.ndarray:
    """Per pixel row: the filtered irradiance ratio of a hard shadow edge
    along y = 0 on the ground z = 0 (lit at y > 0, a sun straight down: E0
    is the same everywhere, so the ratio is the lit share) seen through the
    thin lens: a ground point's pinhole image blurs into a disk of radius
    r = A |1 - D / f| on the ground (orthographic: A), whose lit share is
    the circular segment beyond y = 0; then the pixel filter along y."""
    cam = scene.camera
    W, H = scene.resolution
    xmin, xmax, ymin, ymax = views.camera_viewplane(cam, W, H)
    D = cam.world_from_camera[2, 3]
    ortho = cam.kind == "ORTHO"
    r = cam.aperture_radius * (1.0 if ortho else abs(1.0 - D / cam.focus_distance))
    d = np.linspace(-flt.radius, flt.radius, 4001)
    w = flt.profile(d)
    rows = np.arange(H)[:, None] + 0.5 + d[None, :]
    y = (ymax - rows / H * (ymax - ymin)) * (1.0 if ortho else D)
    t = np.clip(y / r, -1.0, 1.0)
    lit = 0.5 + (t * np.sqrt(1.0 - t * t) + np.arcsin(t)) / np.pi
    return (lit * w).sum(1) / w.sum()


@pytest.mark.parametrize("ortho", [False, True])
def test_a_defocused_shadow_edge_matches_the_thin_lens_closed_form(ortho):
    flt = PixelFilter("blackman-harris", 1.5, 4)
    scene = _defocused(half_plane_scene(sun_light(0.0), res=64), fstop=0.5 if not ortho else 2.0, ortho=ortho)
    res = render_filtered(scene, ["embree_irr"], pixel_filter=flt)
    V = res.lights[0].passes["embree_irr"]
    truth = _edge_closed_form(scene, flt)
    blurred = (truth > 0.02) & (truth < 0.98)
    assert blurred.sum() >= 4                       # the lens spreads the edge over several rows
    assert np.abs(V.mean(1) - truth).max() < 0.02   # 64 pixels a row: the lens noise averages out
    assert np.sqrt(np.mean((V - truth[:, None]) ** 2)) < 0.02
    eff = res.to_json()["camera_effects"]
    assert eff["sampled"] == "per sub-pixel receiver"
    assert eff["depth_of_field"]["aperture_radius"] == pytest.approx(scene.camera.aperture_radius)
    json.dumps(res.to_json())


def test_the_pinhole_pass_misses_the_defocus_the_lens_pass_has():
    flt = PixelFilter("blackman-harris", 1.5, 4)
    scene = _defocused(half_plane_scene(sun_light(0.0), res=64), fstop=0.3)
    truth = _edge_closed_form(scene, flt)
    lens = render_filtered(scene, ["embree_irr"], pixel_filter=flt).lights[0].passes["embree_irr"]
    pinhole = dataclasses.replace(scene, camera=dataclasses.replace(scene.camera, aperture_radius=0.0))
    sharp = render_filtered(pinhole, ["embree_irr"], pixel_filter=flt).lights[0].passes["embree_irr"]
    err_lens = np.sqrt(np.mean((lens - truth[:, None]) ** 2))
    err_sharp = np.sqrt(np.mean((sharp - truth[:, None]) ** 2))
    assert err_sharp > 4 * err_lens and err_sharp > 0.05


def test_pixel_centres_ignore_the_lens_and_say_so():
    scene = _defocused(half_plane_scene(sun_light(0.0), res=32))
    res = render_frame(scene, ["embree_irr"])
    assert res.to_json()["camera_effects"]["sampled"].startswith("no")
    pinhole = dataclasses.replace(scene, camera=dataclasses.replace(scene.camera, aperture_radius=0.0))
    ref = render_frame(pinhole, ["embree_irr"])
    assert np.array_equal(res.lights[0].passes["embree_irr"], ref.lights[0].passes["embree_irr"])
    assert "camera_effects" not in ref.to_json()


def test_lens_rays_meet_on_the_plane_in_focus_and_spread_elsewhere():
    for D in (0.5, 0.8):                              # the ground at the focus distance, then beyond it
        scene = _defocused(half_plane_scene(sun_light(0.0), res=16), fstop=0.5, focus=0.5)
        scene.camera = dataclasses.replace(scene.camera, world_from_camera=scene.camera.world_from_camera.copy())
        scene.camera.world_from_camera[2, 3] = D
        W, H = scene.resolution
        rows, cols = np.divmod(np.arange(W * H), W)
        lens = np.random.default_rng(1).uniform(-1, 1, (W * H, 2)) * scene.camera.aperture_radius
        g_lens = raycast.camera_gbuffer_at(scene, W, H, cols, rows, packed=True, lens=lens)
        g_pin = raycast.camera_gbuffer_at(scene, W, H, cols, rows, packed=True)
        P, Q = g_lens.position.reshape(-1, 3), g_pin.position.reshape(-1, 3)
        # camera-local x, y = world x, y here (looking down, +Y up): the ground point moves by L (1 - D/f)
        assert np.allclose(P[:, :2] - Q[:, :2], lens * (1.0 - D / 0.5), atol=1e-5)
        assert np.allclose(P[:, 2], 0.0, atol=1e-6)


def test_the_camera_sees_through_a_clear_matte_along_its_lens_ray():
    clear = np.zeros((2, 2), np.float32)
    with_card = matte_layers_scene(sun_light(0.0), [(0.3, clear, 0, 0)], res=16, camera_sees=True)
    bare = half_plane_scene(sun_light(0.0), res=16)
    out = []
    for scene in (with_card, bare):
        _defocused(scene, fstop=0.5, focus=0.5)
        W, H = scene.resolution
        rows, cols = np.divmod(np.arange(W * H), W)
        lens = lens_points(scene.camera, np.arange(W * H), W, 4)
        g = raycast.camera_gbuffer_at(scene, W, H, cols, rows, packed=True, lens=lens)
        out.append(g.position.reshape(-1, 3))
    pin = raycast.camera_gbuffer_at(bare, W, H, cols, rows, packed=True).position.reshape(-1, 3)
    assert np.abs(out[0] - out[1]).max() < 1e-3           # the pass-through's own precision (pinhole alike)
    assert np.abs(out[1] - pin).max() > 1e-2              # and the lens moved the points


def test_lens_samples_cover_the_aperture_uniformly_and_stratified_per_pixel():
    cam = dataclasses.replace(persp_camera((0, 0, 1.0), (0, 0, 0)), aperture_radius=2.0)
    grid, W, H = 4, 8, 8
    SW = grid * W
    L = lens_points(cam, np.arange(SW * grid * H), SW, grid, seed=3)
    r2 = (L ** 2).sum(1) / 4.0
    assert r2.max() <= 1.0 + 1e-12
    assert r2.mean() == pytest.approx(0.5, abs=0.02)               # uniform on the disk: E[r^2] = R^2 / 2
    # each pixel's 16 samples: one per lens stratum, so their mean is much nearer the centre
    # than 16 independent samples' (std R / sqrt(2 * 16) = 0.35 per axis)
    rows, cols = np.divmod(np.arange(SW * grid * H), SW)
    pixel = (rows // grid) * W + cols // grid
    means = np.array([L[pixel == p].mean(0) for p in range(W * H)])
    assert np.abs(means).max() < 0.35
    # the same sub-sample gets the same lens point whatever list holds it
    some = np.array([5, 77, 301, 1000])
    assert np.array_equal(lens_points(cam, some, SW, grid, seed=3), L[some])
    assert not np.array_equal(lens_points(cam, some, SW, grid, seed=4), L[some])


def test_a_bladed_aperture_stays_inside_its_polygon_and_the_ratio_squeezes_x():
    rng = np.random.default_rng(0)
    u, v = rng.random(4000), rng.random(4000)
    blades, rot = 5, 0.3
    pts = np.array([aperture_point(a, b, blades, rot, 1.0) for a, b in zip(u, v)])
    # inside the regular pentagon of circumradius 1 (corners at rot + odd multiples of pi / n):
    # within the apothem cos(pi / n) along every edge normal, rot + 2 k pi / n
    normals = rot + np.arange(blades) * 2 * math.pi / blades
    proj = pts @ np.stack([np.cos(normals), np.sin(normals)])
    assert proj.max() <= math.cos(math.pi / blades) + 1e-9
    assert np.linalg.norm(pts, axis=1).max() > 0.95                  # reaches the corners
    squeezed = np.array([aperture_point(a, b, 0, 0.0, 0.5) for a, b in zip(u, v)])
    disk = np.array([aperture_point(a, b, 0, 0.0, 1.0) for a, b in zip(u, v)])
    assert np.allclose(squeezed[:, 0], 0.5 * disk[:, 0]) and np.allclose(squeezed[:, 1], disk[:, 1])


def test_the_plan_line_names_the_lens():
    scene = half_plane_scene(sun_light(0.0), res=8)
    scene.camera = dataclasses.replace(persp_camera((0, 0, 1.0), (0, 0, 0)), aperture_radius=0.01,
                                       focus_distance=2.0)
    assert "lens radius 0.01" in camera_effects.effects_line(scene, True)
    assert "ignored" in camera_effects.effects_line(scene, False)
    scene.camera = dataclasses.replace(scene.camera, aperture_radius=0.0)
    assert camera_effects.effects_line(scene, True) is None
