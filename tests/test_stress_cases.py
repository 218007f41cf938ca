"""The stress suite: DESIGN.md's hard cases ("Numerical robustness")
through every registered method.

Each case is a scene built in code (``synthetic.stress_cases``), run once per
method on buffers shared per case. Every method's raw pass (before
``render_frame`` clips it) must be float32 of the image's shape, finite and in
[0, 1]. The methods that claim to converge to the physical answer must stay
within a per-case RMSE bound of ``embree`` (256 stratified shadow rays per
pixel) over the pixels the light can reach (``metrics.reach_mask``; elsewhere V
has no meaning). A light of size zero gives the hard shadow for every method.

Bounds (RMSE over the reach mask). Both the method (64 samples) and the
reference (256 samples) are Monte Carlo estimates with stratified samples; in
a penumbra pixel an unstratified estimate of N samples has standard deviation
at most 0.5 / sqrt(N) (0.0625 at 64, 0.031 at 256), stratification lowers it,
and lit / umbra pixels have none, so the pure noise part of the RMSE over a
scene whose penumbra covers a fraction f of the pixels is below
sqrt(f) * 0.07. The half-plane scenes have f about 1/4: noise < 0.035.
``NOISE`` = 0.04 is that bound; ``BIAS`` adds what each method's documented
approximation costs (LDI texel splatting for ``layered``, the depth images'
sampling for ``depth_raytrace``, the additive edge occlusion of
``irregular``), measured here and kept with margin, per case, where a case
departs from the method's ordinary error.
"""
from __future__ import annotations

import functools

import numpy as np
import pytest

from penumbra.core import methods as registry
from penumbra.core.buffers import FrameBuffers
from penumbra.core.metrics import reach_mask
from helpers import embree_pass, in_range, rmse, run_declared
from synthetic import leaf_cloud_scene, stress_cases, sun_pillars_scene, zero_size_cases

RES = 48
SAMPLES = 64          # every method's light samples
REF_SAMPLES = 256     # the reference's
# two sample scenes in small (tests/synthetic.py): foliage (150 small
# randomly oriented single-sided leaves of one object under an area light of
# the cloud's size) and sun_pillars (thin pillars under a 4-degree sun)
CASES = dict(stress_cases(RES), foliage=leaf_cloud_scene(res=RES), sun_pillars=sun_pillars_scene(RES))
ZERO = zero_size_cases(RES)
METHODS = list(registry.producers())
PHYSICAL = ("layered", "depth_raytrace", "penumbra_casting", "irregular")

NOISE = 0.04
# per-method error of the approximation on ordinary scenes (the half-plane
# scenes of each method's own tests): layered splats each sample into LDI
# texels (about one texel of shadow-edge shift: ~0.03), depth_raytrace traces
# depth images (~0.02), penumbra_casting is exact per sample (0), irregular's
# penumbra is analytic but adds edge occlusions of separate objects (0.01)
BASE = {"layered": 0.03, "depth_raytrace": 0.02, "penumbra_casting": 0.0, "irregular": 0.01}
# cases where a method's own documented approximation costs more, with why
EXTRA = {
    # irregular computes silhouettes from the light's centre (Johnson et al.
    # 2.1) and sums the occlusion of overlapping silhouette edges additively,
    # clamped: a box's faces overlap in the penumbra next to its base
    ("contact", "irregular"): 0.08,
    ("contact", "layered"): 0.04,
    # a 2-degree light sees the ground edge-on: every depth image from the
    # light has a handful of texels across the whole receiver (Agrawala et
    # al. 6.1, "Sampling"); the paper gives no bound, the methods' own tests
    # set from the methods' own tests; irregular's light-space grid degenerates
    ("grazing_area", "depth_raytrace"): 0.10,
    # irregular: silhouettes from the light's centre (Johnson et al. 2.1):
    # seen from 10 units at 2 degrees, the box's silhouette from the centre
    # and from the light's ends differ by whole faces
    ("grazing_area", "irregular"): 0.18,
    # a light 50x its height above the occluder: its corners see the
    # occluder's edge at grazing angles, depth images leak there
    ("huge_area_light", "depth_raytrace"): 0.22,
    ("huge_sphere_light", "depth_raytrace"): 0.05,
    # layered's sphere-light samples fill the ball whose projection along
    # every direction is the facing disk, exact up to the perspective of a
    # point at distance d: O((r / d)^2) (the layered package's docstring); here
    # r / d = 3.5 / 4, so no small bound follows: measured, kept with margin
    ("huge_sphere_light", "layered"): 0.08,
    # a sun of 143 degrees: the cone's rim directions are grazing
    ("huge_sun", "depth_raytrace"): 0.16,
    ("huge_sun", "irregular"): 0.11,
    # layered's LDI sees the ground from 2 degrees (the area light's samples)
    # or from down to 0.6 degrees (the sun cone's rim): a texel of ground
    # spans 1 / tan(angle) = 29 to 100 texel widths in depth. Its plane-depth
    # comparison holds up to MAX_SLOPE = 30 (88 degrees); past that it falls
    # back to the paper's raw epsilon test and the ground shadows itself (too
    # dark). Not derived: measured, kept with margin (steep ground keeps the
    # paper's 4-neighbour splat and nearest-pixel display).
    ("grazing_area", "layered"): 0.13,
    ("grazing_sun", "layered"): 0.32,
    # at 48 px a leaf is about two texels of the light's maps and the gaps
    # between leaves one or less. layered's footprint splat does not fill
    # thin gaps as the paper's 4-neighbour splat does (Agrawala et al. 4),
    # but leaves of two texels still lose or gain a texel; depth_raytrace's
    # depth images miss sub-texel leaves and gaps
    ("foliage", "layered"): 0.07,
    ("foliage", "depth_raytrace"): 0.03,
    # thin pillars (about one map texel wide) under a low sun: a pillar's
    # shadow gains or loses a texel
    ("sun_pillars", "layered"): 0.04,
}
# the irradiance passes where the average's bound does not hold: on
# huge_area_light a few samples under the light's centre carry most of the
# irradiance weight (cosines over squared distance), so the 64-sample
# estimate, the reference's too, is far noisier than the average
IRR_EXTRA = {"huge_area_light": 0.15}
# and per method: at a 2 degree light elevation the half of the light below a
# receiver's plane weighs nothing, so layered's LDI depth errors on the
# samples just above it carry the whole pass; irregular takes the emission
# as linear over each term's region, far from true on a light many times
# larger than its distance
IRR_EXTRA_METHOD = {("grazing_area", "layered"): 0.06, ("huge_area_light", "irregular"): 0.06}
# cases where the reference is exact, not estimated: V = 1 (nothing between
# light and receiver) or V = 0 (a closed box between them)
EXACT = {"behind_light": 1.0, "light_in_box": 0.0, "camera_inside": 0.0}


def bound(case: str, method: str) -> float:
    return NOISE + BASE[method] + EXTRA.get((case, method), 0.0)


@functools.lru_cache(maxsize=None)
def prepared(group: str, case: str):
    """(scene, buffers, reach mask, embree reference) for one case, shared by every method."""
    scene = (CASES if group == "stress" else ZERO)[case]
    W, H = scene.resolution
    fb = FrameBuffers(scene, W, H)
    light = scene.lights[0]
    mask = reach_mask(fb.gbuffer, light)
    ref = embree_pass(fb, light, 1 if group == "zero" else REF_SAMPLES, seed=99)
    return scene, fb, mask, ref


def run_method(fb, light, method, visibility="average"):
    """The method on the buffers its needs declare (any other raises), its
    pass in ``visibility``'s definition (the cases' bounds are the average's)."""
    return run_declared(method, fb, light, samples=SAMPLES, seed=5, visibility=visibility)[0]


def check_pass(v, shape):
    assert v.shape == shape
    assert in_range(v), (v.dtype, float(np.nanmin(v)), float(np.nanmax(v)))


def test_the_cases_exercise_what_they_name():
    """The scenes are what their names say (so a passing case means something)."""
    for name in ("square", "grazing_area", "contact", "scale_1e4", "near_far_1e6", "degenerate_subpixel"):
        _, fb, mask, ref = prepared("stress", name)
        pen = mask & (ref > 0.02) & (ref < 0.98)
        assert mask.sum() > 500 and ((ref[mask] < 0.02).sum() > 20 or pen.sum() > 20), name
    for name in ("foliage", "sun_pillars"):         # soft shadows of many small / thin occluders
        _, fb, mask, ref = prepared("stress", name)
        pen = mask & (ref > 0.02) & (ref < 0.98)
        assert pen.sum() > 100 and len(CASES[name].triangles) > 30, name
    for name in ("empty_light_view", "camera_sees_nothing"):
        assert not prepared("stress", name)[2].any(), name
    assert prepared("stress", "camera_sees_nothing")[1].gbuffer.hit.sum() < RES * RES
    assert (prepared("stress", "light_in_box")[3][prepared("stress", "light_in_box")[2]] == 0).all()
    sc = CASES["near_far_1e6"]
    assert sc.camera.clip_end / sc.camera.clip_start == pytest.approx(1e6)
    lo, hi = sc.bounds()
    assert (hi - lo).max() / 0.5 > 1e3       # the occluder's height above the ground vs the scene


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("case", list(CASES))
def test_hard_case(case, method):
    scene, fb, mask, ref = prepared("stress", case)
    light = scene.lights[0]
    res = run_method(fb, light, method)
    shape = (scene.resolution[1], scene.resolution[0])
    for pid, v in res.passes.items():
        check_pass(v, shape)
        # where nothing is seen there is no receiver: every method leaves V = 1
        assert (v[~fb.gbuffer.hit] == 1.0).all(), pid
    v = res.passes[method] if method in res.passes else next(iter(res.passes.values()))
    if case in EXACT:
        if method in PHYSICAL or method == "embree":
            # the answer is exact, so is every physical method's (up to the
            # few texels depth images blur at the box's inner corners)
            d = np.abs(v.astype(np.float64) - EXACT[case])[mask]
            assert d.mean() < 0.01 and np.mean(d > 0.05) < 0.02, (d.mean(), np.mean(d > 0.05))
        assert (ref[mask] == EXACT[case]).all()
    elif method in PHYSICAL:
        err = rmse(v, ref, mask)
        assert err < bound(case, method), f"{method} on {case}: RMSE {err:.4f} >= {bound(case, method):.3f}"
        # the default definition, the irradiance ratio, against the reference of its own
        irr = run_method(fb, light, method, "irradiance").passes[method]
        check_pass(irr, shape)
        assert (irr[~fb.gbuffer.hit] == 1.0).all()
        err_irr = rmse(irr, _irr_reference(case), mask)
        assert err_irr < (bound(case, method) + 0.03 + IRR_EXTRA.get(case, 0.0)
                          + IRR_EXTRA_METHOD.get((case, method), 0.0)), err_irr


@functools.lru_cache(maxsize=None)
def _irr_reference(case):
    scene, fb, _, _ = prepared("stress", case)
    return embree_pass(fb, scene.lights[0], REF_SAMPLES, seed=99, pass_id="embree_irr")


def hard_edge_band(ref, hit, width=2):
    """Pixels within ``width`` pixels of a change of the hard-shadow reference
    (or of the silhouette of what the camera sees): where a depth map's texels
    (one map texel per camera pixel here) may place the edge differently."""
    edge = np.zeros(ref.shape, bool)
    edge[:, 1:] |= ref[:, 1:] != ref[:, :-1]
    edge[:, :-1] |= ref[:, 1:] != ref[:, :-1]
    edge[1:] |= ref[1:] != ref[:-1]
    edge[:-1] |= ref[1:] != ref[:-1]
    edge[:, 1:] |= hit[:, 1:] != hit[:, :-1]
    edge[1:] |= hit[1:] != hit[:-1]
    band = edge.copy()
    for _ in range(width):
        b = band.copy()
        b[1:] |= band[:-1]
        b[:-1] |= band[1:]
        b[:, 1:] |= band[:, :-1]
        b[:, :-1] |= band[:, 1:]
        band = b
    return band


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("case", list(ZERO))
def test_zero_size_light_is_the_hard_shadow(case, method):
    """A light of size zero: the exact hard shadow (embree's single ray per
    pixel) for every method. Ray-traced and analytic methods must match it on
    every pixel; shadow-map methods sample a depth map, so within two pixels
    of the shadow's edge a texel may fall either way (and a filter may blend):
    there V may differ, everywhere else it must match."""
    scene, fb, mask, ref = prepared("zero", case)
    assert scene.lights[0].is_zero_size
    assert ((ref[mask] == 0).sum() > 50) and ((ref[mask] == 1).sum() > 50)
    assert set(np.unique(ref[mask])) <= {0.0, 1.0}
    res = run_method(fb, scene.lights[0], method)
    v = res.passes[method]
    check_pass(v, ref.shape)
    d = np.abs(v.astype(np.float64) - ref) > 1e-6
    d &= mask
    exact_methods = ("embree", "penumbra_casting", "irregular")
    if method in exact_methods:
        assert d.sum() <= 2, np.argwhere(d)[:10]          # a ray grazing the occluder's edge
    else:
        band = hard_edge_band(ref, fb.gbuffer.hit)
        assert not (d & ~band).any(), np.argwhere(d & ~band)[:10]
